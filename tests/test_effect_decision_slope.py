"""The constant external force (force_bias, a slope) as an online candidate (agents/effect_decision.py,
docs/online-detection.md): its 2-dof test's level and power on synthetic innovations, its normal-equivalent
z, its withdrawal, and its rates in the filter."""

from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np
import pytest

from agents.effect_decision import (
    CH_CNT,
    CH_Z,
    EFFECTS,
    N_EFF,
    N_PAR,
    N_POOL,
    VCH,
    OnlineDetection,
    WindowEvidence,
    chi2_z,
    judge,
    normal_sf,
    pooled,
    reversal_z,
)
from agents.rigid_filter import EFFECT_PARAMS

LAGS = 10
SLOPE = EFFECTS.index("force_bias")
COUL = EFFECTS.index("coulomb_friction")
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
    zs = np.array([pooled(_window(rng, 250, (0.0,) * N_PAR, rho), 1)[1:] for _ in range(600)])[:, :, SLOPE]
    for level in (0.01, 0.05):
        rate = np.mean(np.vectorize(normal_sf)(zs) < level, axis=0)
        sd = math.sqrt(level * (1 - level) / len(zs))
        assert np.all(np.abs(rate - level) < 4 * sd), (level, rate)


def test_the_pool_names_a_slope_signature_and_only_it():
    """A force along a fixed direction (x and y rates 0.08, -0.06) in ten agents' windows, its x signature
    correlated 0.9 with viscous friction's in every window (no reversal tells them apart): viscous friction's
    own score is significant too, and the slope is named only where its score beyond viscous friction's is
    significant as well (its y rate, the rest of its x); elsewhere viscous friction, which explains most of
    it alone. Over 300 draws of another seed: the slope 228, viscous friction 68, nothing 4 (30.4 and 9.1
    expected in 40; the bounds are three binomial sd away); never another candidate."""
    rng = np.random.default_rng(7)
    theta = [0.0] * N_PAR
    theta[EFFECT_PARAMS[SLOPE][0]], theta[EFFECT_PARAMS[SLOPE][1]] = 0.08, -0.06
    named = visc = wrong = 0
    for _ in range(40):
        stats = [_window(rng, 200, theta, 0.9) for _ in range(10)]
        means = list(np.mean(np.array(stats), axis=0))
        zp, zs, zv = pooled(means, 10)
        k, _ = judge(zp, zs, 0.01, 0, zv=zv)
        named += k == SLOPE
        visc += k == 0
        wrong += 0 <= k < N_EFF and k not in (0, SLOPE)
    assert named >= 22 and visc <= 17 and wrong == 0, (named, visc, wrong)


def test_the_slope_needs_its_score_beyond_the_scalar_candidates():
    """Of the significant candidates the largest own z is named; beside a significant scalar the slope counts
    as significant only if its score beyond the best scalar's is too (else the scalar is named); with no
    scalar significant its own score is enough."""
    z_at = NormalDist().inv_cdf(1 - LEVEL)
    nan = math.nan
    zs = [0.0, 0.0, 6.0, 7.0]
    assert judge(0.0, zs, 0.01, 0) == (SLOPE, False)
    assert judge(0.0, zs, 0.01, 0, zv=[nan, nan, nan, z_at + 1e-6]) == (SLOPE, False)
    assert judge(0.0, zs, 0.01, 0, zv=[nan, nan, nan, z_at - 1e-6]) == (COUL, False)
    assert judge(0.0, zs, 0.01, 0, zv=[nan, nan, nan, nan]) == (COUL, False)  # nothing of its own
    assert judge(9.0, [0.0, 0.0, 1.0, 7.0], 0.01, 0, zv=[nan, nan, nan, 1.0]) == (SLOPE, False)


def _coulomb_window(rng, n, kappa, slope, phi, reverse, misfit=0.05):
    """One window of a plant with Coulomb friction ``kappa`` and a slope's rates ``slope``, the load moving
    along phi: while it keeps its direction the plant's -F_c sat(v_C) is a constant force, in the slope's
    span, and the filter's Coulomb signature is that force's up to ``misfit`` (its smoothed sign's, and the
    direction's drift). With ``reverse`` the motion reverses at mid-window and Coulomb friction turns with it
    (a slope does not)."""
    g = np.cumsum(rng.normal(size=(N_PAR, n, 2)), axis=1) / 10.0
    sx, sy = EFFECT_PARAMS[SLOPE]
    coulomb = math.cos(phi) * g[sx] + math.sin(phi) * g[sy]
    if reverse:
        coulomb[n // 2:] *= -1.0
    w = rng.normal(size=(n, 2)) + kappa * coulomb + slope[0] * g[sx] + slope[1] * g[sy]
    g[COUL] = coulomb + misfit * g[COUL]
    ev = WindowEvidence(LAGS)
    for k in range(n):
        ev.observe(w[k, 0], w[k, 1], [(g[p, k, 0], g[p, k, 1]) for p in range(N_PAR)])
    return ev.close()


def _team_verdict(rng, kappa, slope, reverse):
    """Ten agents' windows, one direction of motion for the team: (decision, own z per candidate)."""
    phi = rng.uniform(0.0, 2.0 * math.pi)
    stats = [_coulomb_window(rng, 200, kappa, slope, phi, reverse) for _ in range(10)]
    zp, zs, zv = pooled(list(np.mean(np.array(stats), axis=0)), 10)
    return judge(zp, zs, 0.01, 0, zv=zv)[0], zs


def test_coulomb_friction_in_the_slopes_span_is_named_coulomb():
    """A Coulomb plant whose force lies in the slope's span (the load keeps its direction), the filter's
    Coulomb signature that force's up to a misfit of 0.05 (correlation 0.999): the slope's chi2 is Coulomb's
    z^2 plus a chi2 with 1 dof of noise (and the misfit's z^2 (1 - r^2)). Ranked by own z alone, the slope
    wins when that excess exceeds ~2 log(z sqrt(2 pi)) (5.4 at z = 6); its score beyond Coulomb's (the
    excess alone) must also be significant, at the level (chi2 12.4). 200 seeded draws at Coulomb's z ~4-8:
    named Coulomb in >= 190 (199 measured; the own z alone 197, ranked by the scores orthogonal to the
    others' 117, the slope 78: Coulomb's keeps only the misfit, the slope's a chi2 of the rest). With a
    misfit of 0.3 (correlation 0.958): 188, the own z alone 134."""
    rng = np.random.default_rng(41)
    named, slope, zc = 0, 0, []
    for _ in range(200):
        k, zs = _team_verdict(rng, 0.1, (0.0, 0.0), False)
        named += k == COUL
        slope += k == SLOPE
        zc.append(zs[COUL])
    assert 4.0 < np.median(zc) < 8.0, np.median(zc)
    assert named >= 190, (named, slope)


def test_a_slope_whose_motion_reverses_is_named_the_slope():
    """A slope plant (x and y rates 0.1, -0.08) where the motion reverses within the window: Coulomb
    friction's signature turns with it and explains little; the slope is named in >= 39 of 40 draws and
    Coulomb friction never."""
    rng = np.random.default_rng(43)
    named = coul = 0
    for _ in range(40):
        k, _ = _team_verdict(rng, 0.0, (0.1, -0.08), True)
        named += k == SLOPE
        coul += k == COUL
    assert named >= 39 and coul == 0, (named, coul)


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
    s = kf.s  # a copy of the state: written back whole
    s[4] = 1 / 50
    kf.s = s
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


def _team_means(s: dict[int, float], v: dict[tuple[int, int], float], zp_sum: float = 0.0) -> list[float]:
    """Team means of the pool channels with the rates' scores ``s`` and information ``v`` (1 on the diagonal
    where not given) and the persistence z's mean ``zp_sum``, every agent contributing."""
    x = [0.0] * N_POOL
    for p in range(N_PAR):
        x[p], x[VCH[p, p]] = s.get(p, 0.0), 1.0
    for (p, q), vpq in v.items():
        x[VCH[p, q]] = vpq
    x[CH_CNT] = 1.0
    x[CH_Z] = zp_sum
    return x


def _decisions(d: OnlineDetection, means, ticks: range) -> list[tuple[int, int]]:
    """The decisions applied over ``ticks``; ``means``: the team means, or a function of the tick giving them."""
    out = []
    for tick in ticks:
        k = d.begin_tick(tick, [0.0] * N_POOL, means(tick) if callable(means) else means, [(0.0, 0.0)] * N_EFF)
        if k >= 0:
            out.append((tick, k))
    return out


W, H = 100, 20


def test_the_slope_is_judged_only_on_windows_after_the_push_first_reverses():
    """A slope significant in every window: with the push's first reversal at 3W, the windows starting at 0,
    W and 2W do not judge it (until the push reverses, 1/m F and a constant force along the push are one
    signature) and the first starting at 3W switches it, judged at that window's successor's last tick; without
    a reversal announced the second window does (the first has no window before it to check the force's
    direction against). The windows that wait are structured (persistence z 7) but not ``unexplained``: the
    slope not yet judged explains them."""
    ax, ay = EFFECT_PARAMS[SLOPE]
    means = _team_means({ax: 4.0, ay: 1.0}, {}, zp_sum=5.0)
    d = OnlineDetection(2, W, LAGS, 0.01, H, 0)
    d.push_reverses(3 * W)
    assert _decisions(d, means, range(6 * W)) == [(5 * W - 1 + H, SLOPE)] and d.unexplained == 0
    assert _decisions(OnlineDetection(2, W, LAGS, 0.01, H, 0), means, range(6 * W)) == [(3 * W - 1 + H, SLOPE)]


def test_a_window_that_does_not_judge_the_slope_still_rules_out():
    """Before the reversal a slope pushing along the motion makes Coulomb friction's own score significantly
    negative (-0.95 the slope's x score): that window rules Coulomb friction out (a rule-out does not wait for
    the slope), and the next window, which judges the slope, switches it: Coulomb friction's own score, below
    the quantile, blocks no switch."""
    ax, _ = EFFECT_PARAMS[SLOPE]
    kappa = EFFECT_PARAMS[COUL][0]
    means = _team_means({ax: 5.0, kappa: -4.75}, {(kappa, ax): -0.95})
    d = OnlineDetection(2, W, LAGS, 0.01, H, 0)
    d.push_reverses(W)
    assert _decisions(d, means, range(4 * W)) == [(3 * W - 1 + H, SLOPE)]
    assert d.withdrawn == 1 << COUL and d.unexplained == 1 and d.on == 1 << SLOPE


def test_reversal_z_reads_the_window_before_along_this_windows_force():
    """The same force in both windows: the window before's own z along it; the force turned round: minus
    that; turned a right angle: 0; NaN without information."""
    ax, ay = EFFECT_PARAMS[SLOPE]
    now = _team_means({ax: 3.0, ay: 4.0}, {})
    assert reversal_z(now, now, 4, SLOPE) == pytest.approx(2.0 * 5.0)
    assert reversal_z(_team_means({ax: -3.0, ay: -4.0}, {}), now, 4, SLOPE) == pytest.approx(-10.0)
    assert reversal_z(_team_means({ax: -4.0, ay: 3.0}, {}), now, 4, SLOPE) == pytest.approx(0.0, abs=1e-12)
    assert math.isnan(reversal_z([0.0] * N_POOL, now, 4, SLOPE))


def test_a_force_that_turns_round_from_window_to_window_is_ruled_out():
    """A force significant in every window whose direction turns round each window (a periodic force, half a
    period per window): the first window waits (nothing before it), the second rules the slope out (the
    window before, read along this window's force, z -4.1), and nothing is switched on."""
    ax, ay = EFFECT_PARAMS[SLOPE]
    plus, minus = _team_means({ax: 4.0, ay: 1.0}, {}), _team_means({ax: -4.0, ay: -1.0}, {})
    d = OnlineDetection(2, W, LAGS, 0.01, H, 0)
    assert _decisions(d, lambda t: plus if (t // W) % 2 else minus, range(8 * W)) == []  # no switch
    assert d.on == 0 and d.withdrawn == 1 << SLOPE and d.unexplained == 1
    assert d.last_tick == 3 * W - 1 + H and d.last_z == pytest.approx(-math.sqrt(2.0 * 17.0))


def test_a_switched_slope_that_turns_round_is_withdrawn():
    """A slope switched on a force that held its direction for two windows; the filters' rates (P^-1 r,
    P^-1 on the same channels) then turn round window by window, each far from 0 (their Wald chi2 alone would
    keep it): the first window judged after the switch has settled whose window before was judged too
    withdraws it."""
    ax, ay = EFFECT_PARAMS[SLOPE]
    plus, minus = _team_means({ax: 4.0, ay: 1.0}, {}), _team_means({ax: -4.0, ay: -1.0}, {})
    switch = 3 * W - 1 + H
    d = OnlineDetection(2, W, LAGS, 0.01, H, 0)
    got = _decisions(d, lambda t: plus if t < switch + W or (t // W) % 2 else minus, range(10 * W))
    # the rates are judged on the windows closed a window after the switch (at the ticks 6W-1, 7W-1, ...); the
    # first of them has no judged window just before it (5W-1 judged nothing), the second turns round
    assert got == [(switch, SLOPE), (7 * W - 1 + H, N_EFF + SLOPE)]
    assert d.on == 0 and d.switched == 0 and d.withdrawn == 1 << SLOPE
