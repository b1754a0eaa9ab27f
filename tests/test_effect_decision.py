"""Online effect detection (agents/effect_decision.py, docs/online-detection.md): the window statistics'
levels and power on synthetic innovations, pooling by flow-updating consensus (lossy, a dead agent), the
flooded decision's agreement, and closed loops that name viscous friction, switch nothing on a clean
plant, and equal over Zenoh processes the in-process engine bit for bit."""

from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agents.consensus import FlowAverage
from agents.effect_decision import (
    CH_CNT,
    CH_Z,
    DETECT_NAMES,
    EFFECTS,
    N_EFF,
    N_PAR,
    N_POOL,
    VCH,
    DecisionFlood,
    OnlineDetection,
    WindowEvidence,
    decode,
    judge,
    normal_sf,
    pooled,
)
from coload.runs.engine import run_inproc
from config.loader import ScenarioError, load_scenario
from net.vocabulary import ESTIMATE_NAMES
from tests.conftest import SCENARIOS, max_table_difference

LAGS = 10
VISC, ROT, COUL = (EFFECTS.index(e) for e in ("viscous_friction", "rotational_damping", "coulomb_friction"))
LEVEL = 0.01 / (1 + N_EFF)  # the default Bonferroni level of each one-sided test


def _theta(**kw):
    return tuple(kw.get(e, 0.0) for e in ("visc", "rot", "coul", "slope_x", "slope_y"))


def _pool(s, v, z=0.0, cnt=1.0, cross=None):
    """Pool channels (team means) from per-rate scores ``s`` and informations ``v`` (the pairs' cross
    information ``cross`` {(j, k): value}, 0 where not given), the persistence z and the count."""
    out = [0.0] * N_POOL
    for k in range(len(s)):
        out[k], out[VCH[k, k]] = s[k], v[k]
    for (j, k), c in (cross or {}).items():
        out[VCH[j, k]] = c
    out[CH_Z], out[CH_CNT] = z, cnt
    return out


def _window(rng, n, theta=(0.0,) * N_PAR, ar=0.0, rho=0.0):
    """One window's evidence: w = sum_k theta_k g_k + e, e AR(1) with coefficient ``ar`` (white at 0), and
    signatures g_k smooth random signals drawn before (independent of e); Coulomb's is correlated ``rho``
    with viscous friction's (the two act on v_C, alike where the speed changes little)."""
    g = np.cumsum(rng.normal(size=(N_PAR, n, 2)), axis=1) / 10.0
    g[COUL] = rho * g[VISC] + math.sqrt(1.0 - rho * rho) * g[COUL]
    e = rng.normal(size=(n, 2))
    for k in range(1, n):
        e[k] += ar * e[k - 1]
    w = e + np.tensordot(np.asarray(theta), g, axes=1)
    ev = WindowEvidence(LAGS)
    for k in range(n):
        ev.observe(w[k, 0], w[k, 1], [(g[c, k, 0], g[c, k, 1]) for c in range(N_PAR)])
    return ev.close()


def _z(stats, n_agents=1):
    """Pooled statistics (z_p, own z, the vector's beyond the others) of a list of agents' window stats (the team sums; no consensus)."""
    means = np.mean(np.array(stats), axis=0)
    return pooled(list(means), n_agents)


def _verdict(stats, n_agents=1):
    zp, zs, zv = _z(stats, n_agents)
    return judge(zp, zs, 0.01, 0, zv=zv)


@pytest.mark.parametrize("rho", [0.0, 0.95])
def test_each_test_rejects_at_its_level_on_white_innovations(rho):
    """Under H0 the one-sided scores (Coulomb's signature correlated ``rho`` with viscous friction's) and the
    persistence z are N(0, 1): rejection rate at 1 % and 5 % within four binomial sd over 600 windows of 250
    updates (the closed loop's shortest)."""
    rng = np.random.default_rng(3)
    zs = np.array([[zp, *z] for zp, z, _ in (_z([_window(rng, 250, rho=rho)]) for _ in range(600))])
    for level in (0.01, 0.05):
        rate = np.mean(np.vectorize(normal_sf)(zs) < level, axis=0)
        sd = math.sqrt(level * (1 - level) / len(zs))
        assert np.all(np.abs(rate - level) < 4 * sd), (level, rate)


def test_pooling_ten_agents_names_an_effect_one_agent_cannot():
    """An effect whose score is ~1.2 sd in one agent's window is named by the pool of ten (~3.8 sd), and the
    right one: the other candidate stays insignificant."""
    rng = np.random.default_rng(5)
    named = single = wrong = 0
    for _ in range(60):
        stats = [_window(rng, 200, theta=_theta(visc=0.06)) for _ in range(10)]
        k, unexplained = _verdict(stats, 10)
        named += k == 0
        wrong += k > 0
        k1, _ = _verdict(stats[:1])
        single += k1 == 0
    assert named >= 40 and single <= 10 and wrong == 0, (named, single, wrong)


@pytest.mark.parametrize("truth,other", [(COUL, VISC), (VISC, COUL)])
def test_correlated_candidates_are_told_apart_by_their_own_scores(truth, other):
    """Viscous and Coulomb friction's signatures correlated 0.95 (the measured 0.83-0.99 per window): each
    one's own score is significant whichever is the plant's, and the pool names the plant's effect (the
    largest own z: the one that explains the most alone) and never the other."""
    rng = np.random.default_rng(23)
    z_at = NormalDist().inv_cdf(1 - LEVEL)
    raw_other = named = wrong = 0
    for _ in range(60):
        seed = int(rng.integers(1 << 30))
        theta = tuple(0.3 if k == truth else 0.0 for k in range(N_PAR))
        stats = [_window(np.random.default_rng(seed + i), 200, theta=theta, rho=0.95) for i in range(10)]
        zp, zs, zv = _z(stats, 10)
        raw_other += zs[other] > z_at
        k, _ = judge(zp, zs, 0.01, 0, zv=zv)
        named += k == truth
        wrong += k == other
    assert raw_other >= 55 and named >= 55 and wrong == 0, (raw_other, named, wrong)


def test_structure_no_candidate_explains_is_unexplained():
    """A slowly varying residual (AR(1), 0.5) unrelated to either signature: structured, no switch."""
    rng = np.random.default_rng(11)
    stats = [_window(rng, 200, ar=0.5) for _ in range(10)]
    k, unexplained = _verdict(stats, 10)
    assert k == -1 and unexplained


def _window_with_force_error(rng, n, theta, delta, with_h):
    """One window with a residual of the force model's error delta h as well as theta_0 g_0: h, the force
    error's sensitivity, shares half its shape with viscous friction's g_0 (both act on v_C)."""
    g = np.cumsum(rng.normal(size=(N_PAR, n, 2)), axis=1) / 10.0
    h = 0.5 * g[0] + np.cumsum(rng.normal(size=(n, 2)), axis=0) / 10.0
    w = rng.normal(size=(n, 2)) + theta * g[0] + delta * h
    ev = WindowEvidence(LAGS)
    for k in range(n):
        ev.observe(w[k, 0], w[k, 1], [(g[c, k, 0], g[c, k, 1]) for c in range(N_PAR)],
                   (h[k, 0], h[k, 1]) if with_h else (0.0, 0.0))
    return ev.close()


def test_a_force_error_common_to_the_team_is_not_named_friction():
    """The team's force model off by the same delta at every agent (the consensus force lagging the applied
    one): without its sensitivity the pool of ten takes it for viscous friction in most windows; with it
    (the score orthogonal to the force error's) the false rate stays at the level's scale, and a real
    friction beside the force error is still named."""
    rng = np.random.default_rng(17)
    trials = 60
    false_raw = false_orth = named = 0
    for _ in range(trials):
        raw = [_window_with_force_error(rng, 200, 0.0, 0.15, False) for _ in range(10)]
        orth = [_window_with_force_error(rng, 200, 0.0, 0.15, True) for _ in range(10)]
        both = [_window_with_force_error(rng, 200, 0.06, 0.15, True) for _ in range(10)]
        false_raw += _verdict(raw, 10)[0] == 0
        false_orth += _verdict(orth, 10)[0] == 0
        named += _verdict(both, 10)[0] == 0
    # level 0.01 / 5 per window: 60 windows expect 0.12 false switches; 3 is beyond four binomial sd
    assert false_raw >= 40 and false_orth <= 2 and named >= 20, (false_raw, false_orth, named)


def test_a_window_nobody_offered_is_not_judged_on_the_consensus_residue():
    """Every agent withheld the window (a stage switch): the delayed consensus still holds a small residue
    of the last window's sums; the team count below one agent says no data, whatever the residue's z."""
    n = 10
    # team means: count 0.02 agents; else z_p 4.7, z_b 40
    residue = _pool([0.4, 0.02, 0.0], [1e-3, 1e-4, 1e-4], 0.066, 0.002)
    zp, zs, zv = pooled(residue, n)
    assert zp != zp and all(z != z for z in zs + zv)
    assert judge(zp, zs, 0.01, 0) == (-1, False)
    one = _pool([0.4 / n, 0.0, 0.0], [1.0 / n] * 3, 3.0 / n, 1.0 / n)  # one agent's window, the others nothing
    zp, zs, _ = pooled(one, n)
    assert zp == pytest.approx(3.0) and zs[0] == pytest.approx(0.4)


def test_judge_level_is_bonferroni_and_skips_effects_already_on():
    z_at = NormalDist().inv_cdf(1 - LEVEL)  # P(Z > z_at) = LEVEL
    assert judge(0.0, [z_at + 1e-6, 0.0, 0.0], 0.01, 0) == (0, False)
    assert judge(0.0, [z_at - 1e-6, 0.0, 0.0], 0.01, 0) == (-1, False)
    assert judge(0.0, [5.0, 6.0, 0.0], 0.01, 0) == (1, False)  # the one that explains best
    assert judge(0.0, [5.0, 6.0, 7.0], 0.01, 0b100) == (1, False)
    assert judge(0.0, [5.0, 6.0, 0.0], 0.01, 0b10) == (0, False)
    assert judge(9.0, [5.0, 6.0, 7.0], 0.01, 0b111) == (-1, True)
    assert judge(9.0, [-5.0, math.nan, 0.0], 0.01, 0) == (-1, True)  # a negative coefficient is no candidate


def test_judge_withdraws_a_switched_effect_whose_rate_is_negative():
    """For an effect switched on online zs[k] is the Wald z of its released rate: below the lower quantile of
    the same level the effect is withdrawn and the window is unexplained; a declared effect is never tested,
    and a withdrawn one (in ``on``) is not proposed again."""
    z_at = NormalDist().inv_cdf(1 - LEVEL)
    assert judge(0.0, [-z_at - 1e-6, 0.0, 0.0], 0.01, 0b01, 0b01) == (N_EFF + 0, True)
    assert judge(0.0, [-z_at + 1e-6, 0.0, 0.0], 0.01, 0b01, 0b01) == (-1, False)
    assert judge(0.0, [-5.0, -6.0, 0.0], 0.01, 0b11, 0b11) == (N_EFF + 1, True)  # the most negative first
    assert judge(0.0, [-5.0, 9.0, 0.0], 0.01, 0b01, 0b01) == (N_EFF + 0, True)  # before any switch
    assert judge(0.0, [0.0, 0.0, -9.0], 0.01, 0b100, 0b100) == (N_EFF + 2, True)
    assert judge(0.0, [-9.0, 0.0, 0.0], 0.01, 0b01, 0) == (-1, False)  # declared
    assert judge(0.0, [9.0, 0.0, 0.0], 0.01, 0b01, 0) == (-1, False)  # withdrawn


def test_a_switched_rate_is_pooled_by_inverse_variance():
    """The rates' pair is (r / P, 1 / P): the team z is the inverse-variance weighted mean over its standard
    error, and an agent whose filter has just restarted (its rate at the prior, P = 0.1) does not mask the
    others' evidence (with (r, P) pooled plainly it would take z from -3 to -0.28)."""
    w = 100
    inputs = []
    for rate in [(-0.01, 1e-4)] * 9 + [(0.0, 0.1)]:
        d = OnlineDetection(10, w, LAGS, 0.01, 20, 0)
        d.on = d.switched = 0b01
        u = [0.0] * N_POOL
        d.begin_tick(w, u, [0.0] * N_POOL, [rate] + [(0.0, 0.0)] * (N_EFF - 1))
        inputs.append(u)
    zp, zs, _ = pooled(list(np.mean(inputs, axis=0)), 10, held=0b01)
    assert zp != zp and zs[0] == pytest.approx(-900 / math.sqrt(9e4 + 10)) and zs[1] != zs[1]
    assert zs[0] == pytest.approx(-3.0, rel=1e-3)


def test_the_team_withdraws_a_switch_on_one_tick_and_never_proposes_it_again():
    """Two agents switch effect 0 on; a settled window later one sees its rate significantly negative, the
    other does not (and a significant effect 1, not judged yet: new switches wait a second window after a
    switch): after the flood both withdraw effect 0 on the same tick, count the window unexplained, and
    ignore later proposals of effect 0 and echoes."""
    w, h = 100, 20
    dets = [OnlineDetection(2, w, LAGS, 0.01, h, 0) for _ in range(2)]
    switch = _pool([4.0, 0.0, 0.0], [1.0] * 3)  # z_0 = 4 sqrt 2
    views = [_pool([-5.0, 0.0, 0.0], [1.0] * 3), _pool([-1.0, 3.0, 0.0], [1.0] * 3)]  # Wald -5 sqrt 2; z_1 = 3 sqrt 2
    again = _pool([9.0, 0.0, 0.0], [1.0] * 3)
    log = [[], []]
    for tick in range(2 * w - 1, 12 * w):
        for i, d in enumerate(dets):
            x = switch if tick < 2 * w + h else views[i] if tick < 6 * w else again
            dec = d.begin_tick(tick, [0.0] * N_POOL, x, [(0.0, 0.0)] * N_EFF)
            if dec >= 0:
                log[i].append((tick, dec))
        for i, d in enumerate(dets):
            d.merge(dets[1 - i].flood.best)
            if tick >= 6 * w:
                d.merge((tick + h, 0, 9.0))  # a neighbour proposing effect 0 again
    # switched at the first judging tick + h; its rate judged at the first window close a window after the
    # switch (4w), on the tick before 5w
    assert log[0] == log[1] == [(2 * w - 1 + h, 0), (5 * w - 1 + h, N_EFF + 0)]
    for d in dets:
        e = d.entries()
        assert e["eff_on"] == 0.0 and e["eff_tick"] == 5 * w - 1 + h and e["eff_z"] == pytest.approx(-5 * math.sqrt(2))
        assert e["eff_unexplained"] == 1.0


def test_withdrawing_an_effect_pins_its_rate_at_the_gaussian_conditional():
    """The filter's state conditioned on the rate being exactly 0 (1/m corrected by its correlation with the
    rate), the rate's variance and walk zero: it stays 0 through further steps."""
    from agents.rigid_filter import RigidEKF
    from config.agent_params import DynamicsSpec

    kf = RigidEKF(0.1, DynamicsSpec(algorithm="sequential", online_detection=True), False)
    kf.start(complex(0.3, -0.2), complex(1.5, 0.4), 0.8)
    kf.release_effect(0)
    rng = np.random.default_rng(4)
    dt, vc = 0.01, complex(0.3, -0.2)
    for t in range(600):
        force = 150 * complex(math.cos(0.02 * t), math.sin(0.013 * t))
        kf.predict(force, 0.0, dt)
        vc += dt * (force / 50 - 0.3 * vc)  # friction 0.3 1/s
        kf.update(vc + complex(*rng.normal(0, 0.1, 2)), math.nan, 0.0)
    s, P = kf.s.copy(), kf.P.copy()
    assert kf.beta > 0.1 and abs(P[4, 7]) > 0.0
    kf.withdraw_effect(0)
    np.testing.assert_allclose(kf.s[4], s[4] - P[4, 7] / P[7, 7] * s[7], rtol=1e-12)
    np.testing.assert_allclose(kf.P[4, 4], P[4, 4] - P[4, 7] ** 2 / P[7, 7], rtol=1e-9)
    for _ in range(50):
        kf.predict(150j, 0.0, dt)
        kf.update(vc, math.nan, 0.0)
        assert kf.beta == 0.0 and not kf.P[7].any() and not kf.P[:, 7].any()


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 50), st.integers(0, 2 * N_EFF - 1), st.floats(2.0, 20.0)), min_size=1,
                max_size=6), st.randoms())
def test_the_flooded_proposal_does_not_depend_on_the_order_of_arrival(props, rnd):
    props = [(t, e, z if e < N_EFF else -z) for t, e, z in props]  # switches (z > 0) and withdrawals (z < 0)
    a, b = DecisionFlood(), DecisionFlood()
    for p in props:
        a.merge(p)
    order = list(props)
    rnd.shuffle(order)
    for p in order:
        b.merge(p)
        b.merge(b.best)  # a neighbour echoing our own flood back
    assert a.best == b.best == min(props, key=lambda p: (p[0], -abs(p[2]), p[1]))
    assert decode(a.encode()) == a.best


@pytest.mark.parametrize("k", range(N_PAR))
def test_filter_sensitivity_is_the_derivative_of_its_estimate_in_the_rate(k):
    """The filter's D equals d(posterior state)/d(rate) by finite differences: a twin filter with the rate
    pinned at eps instead of 0, on measurements that the first filter predicts exactly (so that the gain's
    own dependence on the rate multiplies a zero innovation)."""
    import copy

    from agents.rigid_filter import RigidEKF
    from config.agent_params import DynamicsSpec

    spec = DynamicsSpec(algorithm="sequential", online_detection=True)
    kf = RigidEKF(0.1, spec, False)
    kf.start(complex(0.3, -0.2), complex(1.5, 0.4), 0.8)
    s = kf.s  # a copy of the state: written back whole
    s[4], s[6] = 1 / 50, 1 / 87  # 1/m, 1/J known roughly
    kf.s = s
    twin = copy.copy(kf)
    eps = 1e-7
    s[7 + k] = eps
    twin.s = s
    dt = 0.01
    for t in range(400):
        force = 150 * complex(math.cos(0.02 * t), math.sin(0.013 * t))
        torque = 30 * math.sin(0.05 * t)
        for f in (kf, twin):
            f.predict(force, torque, dt)
        s = kf.s
        v = complex(s[0] - s[5] * s[3], s[1] + s[5] * s[2])  # kf's own prediction: its innovation is 0
        for f in (kf, twin):
            f.update(v, math.nan, 0.0)
    keep = [0, 1, 2, 3, 4, 5, 6, kf.ib]  # every state but the rates themselves (d beta / d beta = 1 is not carried)
    fd = ((twin.s - kf.s) / eps)[keep]
    d = kf.sens[keep, k]
    assert np.max(np.abs(d)) > 1e-3
    assert np.max(np.abs(fd - d)) < 1e-4 * np.max(np.abs(d)) + 1e-9, (fd, d)


def _line_pool(n, inputs, ticks, rng, loss=0.0, dead=None):
    """Flow-updating consensus of the pool channels on a line of n agents; ``dead`` stops sending and
    receiving after its first exchange. Returns every agent's channels."""
    nbrs = [[j for j in (i - 1, i + 1) if 0 <= j < n] for i in range(n)]
    fa = [FlowAverage(nbrs[i], N_POOL) for i in range(n)]
    for i in range(n):
        fa[i].u = list(inputs[i])
    for t in range(ticks):
        msgs = {i: (list(fa[i].x), {j: list(f) for j, f in fa[i].flow.items()}, fa[i].deg) for i in range(n)}
        for i in range(n):
            if dead == i and t > 0:
                continue
            for j in nbrs[i]:
                if (dead == j and t > 0) or rng.random() < loss:
                    continue
                x, flows, deg = msgs[j]
                fa[i].receive(j, x, flows[i], deg)
            fa[i].update()
    return [f.x for f in fa]


def test_consensus_pools_the_team_statistic_with_loss_and_a_dead_agent():
    """Every agent's view of the pooled z equals the centralized one (20 % of the states lost), and with an
    agent dead after the first exchange the others still agree with each other."""
    rng = np.random.default_rng(2)
    n = 10
    inputs = [_window(rng, 200, theta=_theta(visc=0.01)) for _ in range(n)]
    central = _z(inputs, n)
    for x in _line_pool(n, inputs, 1500, rng, loss=0.2):
        zp, zs, _ = pooled(x, n)
        assert abs(zp - central[0]) < 1e-3
        assert max(abs(a - b) for a, b in zip(zs, central[1], strict=True)) < 1e-3
    views = [pooled(x, n) for i, x in enumerate(_line_pool(n, inputs, 1500, rng, loss=0.2, dead=9)) if i != 9]
    for zp, zs, _ in views:
        assert abs(zp - views[0][0]) < 1e-3 and abs(zs[0] - views[0][1][0]) < 1e-3


def test_every_agent_switches_on_the_agreed_tick():
    """Two agents judge a window with slightly different views (one finds effect 0 significant, the other
    effect 1 more so); after the flood both switch the stronger one on the same tick, and ignore its echo."""
    w, h = 100, 20
    dets = [OnlineDetection(2, w, LAGS, 0.01, h, 0) for _ in range(2)]
    views = [_pool([4.0, 0.0, 0.0], [1.0] * 3), _pool([0.0, 5.0, 0.0], [1.0] * 3)]  # z_0 = 4 sqrt 2, z_1 = 5 sqrt 2
    on = [[], []]
    for tick in range(2 * w - 1, 4 * w):
        for i, d in enumerate(dets):
            k = d.begin_tick(tick, [0.0] * N_POOL, views[i])
            if k >= 0:
                on[i].append((tick, k))
        for i, d in enumerate(dets):  # one exchange per tick
            d.merge(dets[1 - i].flood.best)
    assert on[0] == on[1] == [(2 * w - 1 + h, 1)]
    assert dets[0].entries()["eff_on"] == dets[1].entries()["eff_on"] == 2.0


def test_estimate_names_end_with_the_detection_entries():
    assert ESTIMATE_NAMES[-len(DETECT_NAMES):] == DETECT_NAMES


def test_online_detection_needs_the_dynamical_phase_and_its_windows():
    with pytest.raises(ScenarioError, match="dynamics.online_detection"):
        load_scenario(SCENARIOS / "quick.toml", ["dynamics.online_detection=true"])
    with pytest.raises(ScenarioError, match="dynamics.online_detection"):
        load_scenario(SCENARIOS / "quick.toml", ['dynamics.algorithm="sequential"', "dynamics.online_detection=true",
                                                 "dynamics.monitor_window_s=0"])


# quick.toml (n = 5, sigma 0.1) with a short kinematic settle, m and J stages of 10 s, windows of 2.5 s
SHORT = ['dynamics.algorithm="sequential"', "dynamics.kin_settle_s=3", "dynamics.m_excite_s=10",
         "dynamics.j_excite_s=10", "duration=30", "dynamics.monitor_window_s=2.5", "dynamics.online_detection=true"]
VISCOUS = ["plant.friction={viscous=5.0}"]


@pytest.fixture(scope="module")
def viscous_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("detect") / "inproc"
    return d, run_inproc(load_scenario(SCENARIOS / "quick.toml", SHORT + VISCOUS + ["seed=1"]), d)


def test_closed_loop_names_viscous_friction_and_only_it(viscous_run):
    """Undeclared viscous friction: the team switches it on, every agent on the same tick, nothing else (~12 s)."""
    _, s = viscous_run
    eff = s["effects"]
    assert eff["on"] == ["viscous_friction"] and eff["agree"]
    (ev,) = eff["events"]
    assert ev["agents"] == [0, 1, 2, 3, 4] and ev["statistic"] > NormalDist().inv_cdf(1 - LEVEL)
    assert [e["effect"] for e in s["events"] if e["event"] == "effect_switch"] == ["viscous_friction"]


def test_closed_loop_clean_plant_switches_nothing(tmp_path):
    s = run_inproc(load_scenario(SCENARIOS / "quick.toml", SHORT + ["seed=1"]), tmp_path / "clean")
    assert s["effects"]["events"] == [] and s["effects"]["on"] == []


@pytest.mark.slow
@pytest.mark.zenoh
def test_lockstep_over_zenoh_reproduces_the_decision(tmp_path, viscous_run):
    """Router, simulator and agents as processes, lockstep == the in-process engine with detection on (~30 s)."""
    from coload.runs.orchestrate import run_processes

    a, sa = viscous_run
    b = tmp_path / "zenoh"
    sb = run_processes(load_scenario(SCENARIOS / "quick.toml", SHORT + VISCOUS + ["seed=1"]), b, quiet=True)
    assert sb is not None and sb["engine"] == "zenoh"
    for name, keys in (("samples.csv", 2), ("estimates.csv", 2), ("truth.csv", 1)):
        assert max_table_difference(a, b, name, keys) <= 1e-9, name
    assert sb["effects"] == sa["effects"] and sa["effects"]["events"]
