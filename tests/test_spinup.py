"""The kinematic phase keeps lock at high noise through spin-up (docs/spinup.md).

The Monte Carlo grid's cell n5-s0.8-r1 (paper-fig4 resized to n = 5 on a line, sigma_v = 0.8 m/s, the
campaign's seed for run 1), kinematic phase alone, on the pymunk plant. Neighbours are 0.9-1.25 m
apart, so |omega| |z_ij| ~ 1.4-2.9 m/s stays mostly below the axis form's gate 2.5 sqrt(2) sigma =
2.8 m/s: with ``angle_meas = "axis"`` the first pair's angle is dead-reckoned with omega_hat (seeded
0.4 rad/s low during the spin-up overshoot), eq. (9) returns omega cos(angle error) < omega and
omega_hat's lag feeds itself until it collapses (omega_hat 0 at t = 12 s) and the regulation spins the
load up without bound. The linear radial measurement corrects the angle at any noise level (with a process noise
``angle_walk`` large enough for the angle loop to outrun omega_hat's lag).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from coload.analysis.campaign import campaign_scenario, run_seed
from coload.runs.engine import run_inproc
from config.loader import load_scenario

ROOT = Path(__file__).resolve().parent.parent


def _cell(tmp_path: Path, *sets: str) -> dict:
    overrides = ['dynamics.algorithm="none"', *sets]
    base = load_scenario(ROOT / "config" / "scenarios" / "paper-fig4.toml", overrides)
    sc = campaign_scenario(base, 5, 0.8, run_seed(0, 5, 0.8, 1)).model_copy(update={"duration": 40.0})
    return run_inproc(sc, tmp_path)["errors"]


def test_kinematic_phase_keeps_lock_through_spin_up_at_sigma_08(tmp_path: Path) -> None:
    err = _cell(tmp_path)
    # omega_hat within 0.15 rad/s RMS of the truth over the last 20 s (regulated at 1.5 rad/s); the
    # lost lock gave omega errors of rad/s to tens of rad/s (the load spinning up without bound)
    assert err["omega_rms"] < 0.15
    # z_i (|z_i| 0.5-1.1 m) on the body: < 0.2 m RMS over agents, over the last 20 s (lost: ~0.9 m)
    assert err["zi_rms_window"] < 0.2


def test_the_gated_axis_form_loses_lock_there(tmp_path: Path) -> None:
    """The cause, kept as a check that the cell above is a real test: the former form fails on it."""
    err = _cell(tmp_path, 'estimator.angle_meas="axis"', "estimator.angle_walk=0.02")
    assert err["omega_rms"] > 1.0 and err["zi_rms_window"] > 0.5


@pytest.mark.long  # a minute on a quiet machine: out of CI's budget
def test_a_late_short_pair_is_helped_by_the_omega_boost(tmp_path: Path) -> None:
    """Grid cell n8-s0.9-r0 with the whole Algorithm 1: pair 3-4 is 0.89 m apart, and at 1.5 rad/s
    its tangential speed 1.34 m/s is under the circle-fit window's per-sample noise sqrt(2) sigma =
    1.27 m/s plus margin, so the team waited ~65 s for it and finished at 138 s (docs/spinup.md).
    Spinning at control.omega_boost = 2.5 rad/s from 30 s while the team is not ready gets the fit
    within seconds: done by ~107 s, J and m as accurate as in the cells that were never late."""
    base = load_scenario(ROOT / "config" / "scenarios" / "paper-fig4.toml", ["stop_after_done_s=2"])
    sc = campaign_scenario(base, 8, 0.9, run_seed(0, 8, 0.9, 0)).model_copy(update={"duration": 200.0})
    boosted = run_inproc(sc, tmp_path / "boost")["errors"]
    assert boosted["finished_s"] < 115.0
    assert boosted["J_rel"] < 0.005 and boosted["m_rel"] < 0.01
    plain = run_inproc(sc.model_copy(update={"control": sc.control.model_copy(update={"omega_boost": 0.0})}),
                       tmp_path / "plain")["errors"]
    assert plain["finished_s"] > 130.0  # without it: the wait this test is about
