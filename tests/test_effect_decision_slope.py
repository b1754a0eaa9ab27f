"""The constant external force (force_bias, a slope) as an online candidate (agents/effect_decision.py,
docs/online-detection.md): its 2-dof test's level and power on synthetic innovations, its normal-equivalent
z, its withdrawal, and its rates in the filter."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agents.effect_decision import (
    EFFECTS,
    N_EFF,
    N_PAR,
    N_POOL,
    VCH,
    WindowEvidence,
    chi2_z,
    judge,
    normal_sf,
    pooled,
)
from agents.rigid_filter import EFFECT_PARAMS

LAGS = 10
SLOPE = EFFECTS.index("force_bias")
LEVEL = 0.01 / (1 + N_EFF)


def _window(rng, n, theta, rho=0.0):
    """One window: w = sum_p theta_p g_p + white noise, g_p smooth random signatures; the slope's x signature
    correlated ``rho`` with viscous friction's (both act on v_C)."""
    g = np.cumsum(rng.normal(size=(N_PAR, n, 2)), axis=1) / 10.0
    sx = EFFECT_PARAMS[SLOPE][0]
    g[sx] = rho * g[0] + math.sqrt(1.0 - rho * rho) * g[sx]
    w = rng.normal(size=(n, 2)) + np.tensordot(np.asarray(theta), g, axes=1)
    ev = WindowEvidence(LAGS)
    for k in range(n):
        ev.observe(w[k, 0], w[k, 1], [(g[p, k, 0], g[p, k, 1]) for p in range(N_PAR)])
    return ev.close()


def test_chi2_z_is_the_normal_equivalent_of_the_2_dof_tail():
    for x in (0.01, 0.5, 2.0, 11.98, 30.0, 200.0, 1000.0, 1399.0):
        assert normal_sf(chi2_z(x)) == pytest.approx(math.exp(-0.5 * x), rel=1e-6)
    # the asymptote beyond exp's underflow continues the exact branch
    assert chi2_z(1400.0) == pytest.approx(chi2_z(1399.999), rel=1e-4)
    assert chi2_z(1e5) > chi2_z(1e4) > chi2_z(1400.0)
    assert chi2_z(0.0) == -math.inf


@pytest.mark.parametrize("rho", [0.0, 0.9])
def test_the_2_dof_test_rejects_at_its_level_on_white_innovations(rho):
    """Under H0 the slope's chi2 (own, and orthogonal to the scalar candidates; its x signature correlated
    ``rho`` with viscous friction's) rejects at its level: 600 windows, within four binomial sd at 1 % and 5 %."""
    rng = np.random.default_rng(31)
    zs = []
    for _ in range(600):
        _, z, o = pooled(_window(rng, 250, (0.0,) * N_PAR, rho), 1)
        zs.append((z[SLOPE], o[SLOPE]))
    zs = np.array(zs)
    for level in (0.01, 0.05):
        rate = np.mean(np.vectorize(normal_sf)(zs) < level, axis=0)
        sd = math.sqrt(level * (1 - level) / len(zs))
        assert np.all(np.abs(rate - level) < 4 * sd), (level, rate)


def test_the_pool_names_a_slope_signature_and_only_it():
    """A force along a fixed direction (x and y rates 0.08, -0.06) in ten agents' windows: the pool names the
    slope in most windows, with its x signature correlated 0.9 with viscous friction's (viscous friction's own
    score is then significant too: only the orthogonal scores tell, and viscous friction's, N(0, 1), exceeds
    the slope's now and then: 1 of 40 here)."""
    rng = np.random.default_rng(7)
    theta = [0.0] * N_PAR
    theta[EFFECT_PARAMS[SLOPE][0]], theta[EFFECT_PARAMS[SLOPE][1]] = 0.08, -0.06
    named = wrong = 0
    for _ in range(40):
        stats = [_window(rng, 200, theta, 0.9) for _ in range(10)]
        means = list(np.mean(np.array(stats), axis=0))
        zp, zs, zo = pooled(means, 10)
        k, _ = judge(zp, zs, 0.01, 0, zo=zo)
        named += k == SLOPE
        wrong += 0 <= k < N_EFF and k != SLOPE
    assert named >= 36 and wrong <= 2, (named, wrong)


def test_a_switched_slope_is_withdrawn_only_when_its_wald_chi2_is_below_the_lower_quantile():
    """The released 2-vector's (P^-1 r, P^-1) pooled: the Wald chi2's normal-equivalent z, withdrawn (the
    window unexplained) below the level's lower quantile, kept above; a slope is never ruled out by its own
    score (it has no sign)."""
    sx, sy = EFFECT_PARAMS[SLOPE]

    def held_pool(r, info):
        out = [0.0] * N_POOL
        wr = np.asarray(info) @ np.asarray(r)
        out[sx], out[sy] = wr
        out[VCH[sx, sx]], out[VCH[sx, sy]], out[VCH[sy, sy]] = info[0][0], info[0][1], info[1][1]
        out[-1] = 1.0
        return out

    bit = 1 << SLOPE
    q = -2.0 * math.log1p(-LEVEL)  # the 2-dof chi2's lower quantile at the level
    info = [[2.0, 0.5], [0.5, 1.0]]
    for scale, withdrawn in ((0.9, True), (1.1, False)):
        # r with r^T info r = scale * q
        r = np.array([1.0, 0.0]) * math.sqrt(scale * q / info[0][0])
        _, zs, _ = pooled(held_pool(r, info), 1, held=bit)
        assert normal_sf(-zs[SLOPE]) == pytest.approx(1.0 - math.exp(-0.5 * scale * q), rel=1e-6)
        assert judge(math.nan, zs, 0.01, bit, bit) == ((N_EFF + SLOPE, True) if withdrawn else (-1, False))
    _, zs, _ = pooled(held_pool([10.0, -5.0], info), 1, held=bit)
    assert zs[SLOPE] > 5.0 and judge(math.nan, zs, 0.01, bit, bit) == (-1, False)


def test_the_filter_carries_a_constant_force_and_finds_it():
    """One filter with force_bias released, on a plant with a constant 2 N along (0.6, -0.8) and an
    alternating force: a = f/m found within 5 %, and the withdrawal pins both rates at 0."""
    from agents.rigid_filter import RigidEKF
    from config.agent_params import DynamicsSpec

    spec = DynamicsSpec(algorithm="sequential", online_detection=True)
    kf = RigidEKF(0.05, spec, False)
    kf.start(complex(0.0, 0.0), complex(1.5, 0.4), 0.0)
    kf.s = kf.s.copy()
    kf.s[4] = 1 / 50
    kf.release_effect(SLOPE)
    rng = np.random.default_rng(9)
    dt, vc, f = 0.01, 0j, 2.0 * complex(0.6, -0.8)
    for t in range(4000):
        force = 30.0 * (1 if (t // 500) % 2 == 0 else -1) * complex(0.8, 0.6)
        kf.predict(force, 0.0, dt)
        vc += dt * (force + f) / 50.0
        kf.update(vc + complex(*rng.normal(0, 0.05, 2)), math.nan, 0.0)
    assert abs(kf.accel / kf.mu - f) < 0.05 * abs(f), kf.accel / kf.mu
    kf.withdraw_effect(SLOPE)
    assert kf.accel == 0 and not kf.P[10:12].any() and not kf.P[:, 10:12].any()
