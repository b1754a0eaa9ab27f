"""PairEstimator: |z_ij| from the integral-form circle fit, sign, angle tracking, freezing."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agents.pair_estimator import PairEstimator
from config.agent_params import EstimatorSpec


def _pair(sigma: float, dt: float = 0.01) -> PairEstimator:
    e = EstimatorSpec()
    return PairEstimator(
        dt=dt, sigma_v=sigma, fit_arc=e.fit_arc, fit_min_ticks=e.fit_min_ticks, fit_max_ticks=e.fit_max_ticks,
        fit_check_ticks=e.fit_check_ticks, max_gap_ticks=e.max_gap_ticks, angle_walk=e.angle_walk, gate_snr=e.gate_snr,
    )


def _drive(pe: PairEstimator, z0: complex, omega, sigma: float, ticks: int, rng: np.random.Generator,
           omega_hat=None, dt: float = 0.01, skip=()) -> complex:
    """Feed samples of a rigidly rotating z_ij; the owner's prediction uses omega_hat (default: truth)."""
    z = z0
    phase = 0.0
    for k in range(ticks):
        om = omega(k * dt) if callable(omega) else omega
        omh = om if omega_hat is None else omega_hat
        w = 1j * om * z + complex(*(rng.normal(0.0, sigma * math.sqrt(2), 2) if sigma > 0 else (0.0, 0.0)))
        if k not in skip:
            pe.sample(k, w, 1.0, omh, dt)
        pe.predict(complex(math.cos(omh * dt), math.sin(omh * dt)))
        phase += om * dt
        z = z0 * complex(math.cos(phase), math.sin(phase))
    return z


@pytest.mark.parametrize("omega", [1.5, -1.5])
@pytest.mark.parametrize("sigma", [0.0, 0.01, 0.3])
def test_radius_and_vector_from_integrated_relative_velocity(omega: float, sigma: float) -> None:
    """|z_ij| within 1 % and z_ij (with its sign) within a few cm, for either spin direction."""
    rng = np.random.default_rng(7)
    z0 = 1.24 * complex(math.cos(0.4), math.sin(0.4))
    pe = _pair(sigma)
    z = _drive(pe, z0, omega, sigma, 3000, rng)
    assert pe.ready and pe.windows >= 5
    assert abs(pe.r / 1.24 - 1) < 0.01
    assert abs(pe.z - z) < (0.005 if sigma <= 0.01 else 0.08)


def test_accelerating_rotation_from_rest() -> None:
    """Spin-up from rest (the kinematic phase's start): the fit still locks, sign correct."""
    rng = np.random.default_rng(2)
    z0 = complex(-0.3, 1.1)
    pe = _pair(0.3)
    z = _drive(pe, z0, lambda t: min(0.3 * t, 1.5), 0.3, 4000, rng)
    assert pe.ready
    assert abs(pe.r / abs(z0) - 1) < 0.02
    assert abs(pe.z - z) < 0.1


def test_noise_alone_never_yields_a_radius() -> None:
    """Load at rest, pure noise: the gates reject the noise curls of the integrated velocity."""
    rng = np.random.default_rng(5)
    pe = _pair(0.3)
    _drive(pe, complex(1.0, 0.0), 0.0, 0.3, 6000, rng)
    assert not pe.ready and pe.z == 0j


def test_estimate_freezes_below_gate() -> None:
    """When the load stops turning the estimate is held (rotated by omega_hat = 0: unchanged)."""
    rng = np.random.default_rng(9)
    pe = _pair(0.3)
    z0 = complex(1.0, 0.5)
    _drive(pe, z0, 1.5, 0.3, 3000, rng)
    held, r = pe.z, pe.r
    # now omega = 0: only noise; omega_hat = 0 -> no prediction, gate closed
    for k in range(3000, 4000):
        w = complex(*rng.normal(0.0, 0.3 * math.sqrt(2), 2))
        pe.sample(k, w, 1.0, 0.0, 0.01)
        pe.predict(1 + 0j)
    assert pe.z == held
    assert abs(pe.r - r) < 0.02 * r


def test_missing_samples_are_bridged() -> None:
    rng = np.random.default_rng(11)
    pe = _pair(0.1)
    z0 = complex(0.9, -0.8)
    skip = set(int(v) for v in rng.choice(3000, 600, replace=False))
    z = _drive(pe, z0, 1.5, 0.1, 3000, rng, skip=skip)
    assert pe.ready and abs(pe.r / abs(z0) - 1) < 0.01
    assert abs(pe.z - z) < 0.05
