"""Closed-loop targets of the kinematic phase on the reference scenario (paper 000 Sec. VIII-A).

n = 10 agents on a 4.0 m x 2.2 m, 50 kg, J = 86.89 kg m^2 load (CoM 0.36 m off the centroid), line
graph, dt = 0.01 s, sigma = 0.3 m/s, load at rest at t = 0; default EstimatorSpec / ControlSpec.
At t = 60 s (mean over the last second): EERD below 1 % of its initial value, network-wide and for
every agent's own pairs; RMS over agents of |z_i_hat - z_i| <= 0.05 m; omega RMS error over
t in [40, 60] <= 0.05 rad/s.
"""

from __future__ import annotations


import numpy as np
import pytest

from config.agent_params import ControlSpec
from rigid_truth import line_neighbours, reference_load, run_closed_loop
from test_agent_core import Links

T = 60.0


def _check(r, zi_max: float = 0.05) -> None:
    assert r.at(r.eerd_ratio, T) < 0.01
    assert r.at(r.eerd_agent_max, T) < 0.01
    assert r.at(r.zi_rms, T) <= zi_max
    assert r.omega_rms(T - 20, T) <= 0.05
    assert np.all(r.radius_rel_err < 0.03)  # |d_ij| on its own (errors cancel inside J later)


@pytest.mark.parametrize("seed", [0, 1])
def test_reference_scenario_sigma_03(seed: int) -> None:
    _check(run_closed_loop(reference_load(), line_neighbours(10), sigma=0.3, seconds=T, seed=seed, record_every=20))


@pytest.mark.slow
@pytest.mark.parametrize("seed", [2, 3, 4, 5, 6, 7])
def test_reference_scenario_sigma_03_more_seeds(seed: int) -> None:
    _check(run_closed_loop(reference_load(), line_neighbours(10), sigma=0.3, seconds=T, seed=seed, record_every=20))


@pytest.mark.slow
@pytest.mark.parametrize("sigma", [0.01, 0.1])
@pytest.mark.parametrize("seed", [0, 1])
def test_reference_scenario_low_noise(sigma: float, seed: int) -> None:
    r = run_closed_loop(reference_load(), line_neighbours(10), sigma=sigma, seconds=T, seed=seed, record_every=20)
    _check(r, zi_max=0.02 if sigma <= 0.1 else 0.05)


@pytest.mark.slow
def test_link_faults() -> None:
    """20 % loss, delay 1..5 ticks (reordering), 10 % duplicates on every directed link: the fault-free
    targets (measured z_i 0.038 m; 0.078 m before the delay compensation, the reordered samples and
    the antisymmetrised flows)."""
    r = run_closed_loop(reference_load(), line_neighbours(10), sigma=0.3, seconds=T, seed=0, record_every=20,
                        deliver=Links(1, loss=0.2, delay=1, jitter=4, dup=0.1))
    _check(r)


def test_loss_20_delay_100ms() -> None:
    """The issue-5 condition: 20 % loss and 10..15 ticks (100-150 ms) of delay on every directed link.
    Measured: EERD 0.07 %, z_i 0.041 m, omega RMS 0.035 rad/s, |d_ij| within 1.7 %, EERD < 1 % from
    10.2 s (before the delay compensation: z_i 0.065 m, |d_ij| off by up to 4.1 %, EERD < 1 % from 49.6 s)."""
    r = run_closed_loop(reference_load(), line_neighbours(10), sigma=0.3, seconds=T, seed=1, record_every=20,
                        deliver=Links(1, loss=0.2, delay=10, jitter=5, dup=0.0))
    _check(r, zi_max=0.06)
    assert r.t[np.flatnonzero(r.eerd_ratio >= 0.01)[-1] + 1] <= 15.0  # converged by 15 s, and stays


@pytest.mark.slow
def test_delay_200ms() -> None:
    """20..30 ticks of delay (200-300 ms, heavy reordering), no loss. Measured z_i 0.049 m, omega RMS
    0.034 rad/s, EERD < 1 % from 12.8 s; before the delay compensation EERD never stayed below 1 %."""
    r = run_closed_loop(reference_load(), line_neighbours(10), sigma=0.3, seconds=T, seed=0, record_every=20,
                        deliver=Links(1, loss=0.0, delay=20, jitter=10, dup=0.0))
    _check(r, zi_max=0.06)


def _n40_control() -> ControlSpec:
    # load 4x larger in length, m = 5 n: J grows ~64x, n 4x -> per-agent torques x16
    k = reference_load(40, 4.0).inertia / 86.89 / 4.0
    return ControlSpec(spin_torque=3.0 * k, k_omega=3.0 * k, torque_max=5.0 * k)


@pytest.mark.slow
def test_n40_proportional_load() -> None:
    """n = 40 on a proportionally larger load (same contact spacing), same estimator settings.
    z_i accumulates the pair errors over a 40-agent line: the bound is looser there."""
    r = run_closed_loop(reference_load(40, 4.0), line_neighbours(40), sigma=0.3, seconds=T, seed=0,
                        record_every=50, control=_n40_control())
    assert r.at(r.eerd_ratio, T) < 0.01 and r.at(r.eerd_agent_max, T) < 0.01
    assert r.omega_rms(T - 20, T) <= 0.05
    assert r.at(r.zi_rms, T) <= 0.12
