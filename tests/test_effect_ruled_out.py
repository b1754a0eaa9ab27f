"""A candidate whose pooled score is significantly negative is ruled out by the team (agents/effect_decision.py,
docs/online-detection.md, periodic force): on one tick at every agent, through the withdrawals' flood, with
no change to the filters, the window ``unexplained``, and never proposed again."""

from __future__ import annotations

import math

import pytest

from agents.effect_decision import CH_CNT, CH_Z, N_EFF, N_POOL, VCH, OnlineDetection, contradicted_by

LAGS = 5
W, H = 100, 20


def pool(*scores: float, zp_sum: float = 0.0, cross: dict | None = None) -> list[float]:
    """Team means of the pool channels whose pooled z of candidate k is scores[k] sqrt(n) (n = 2 here; 0 for
    the candidates not given): s_k = scores[k], V_kk = 1, the cross information ``cross`` {(j, k): V_jk} (0
    where not given), every agent contributing."""
    x = [0.0] * N_POOL
    for k in range(N_EFF):
        x[k], x[VCH[k, k]] = scores[k] if k < len(scores) else 0.0, 1.0
    for (j, k), v in (cross or {}).items():
        x[VCH[j, k]] = v
    x[CH_Z], x[CH_CNT] = zp_sum, 1.0
    return x


def run(dets, views, ticks, proposals=()):
    """Drive the agents over ``ticks`` with views(tick, i) as their team means; returns each one's decisions."""
    log = [[] for _ in dets]
    for tick in ticks:
        for i, d in enumerate(dets):
            dec = d.begin_tick(tick, [0.0] * N_POOL, views(tick, i), [(0.0, 0.0)] * N_EFF)
            if dec >= 0:
                log[i].append((tick, dec))
        for i, d in enumerate(dets):
            for j, o in enumerate(dets):
                if j != i:
                    d.merge(o.flood.best)
            for p in proposals:
                d.merge(p(tick))
    return log


def test_two_agents_rule_a_candidate_out_on_one_tick_and_never_switch_it_on():
    """One agent sees candidate 0 at z -7.1 (the other at -1.4, not significant): after the flood both rule it
    out on the same tick without telling their filters (no decision returned), and later a significant
    positive score of it, or a neighbour proposing it, switches nothing; candidate 1 can still be switched. Both
    count the window ``unexplained``."""
    dets = [OnlineDetection(2, W, LAGS, 0.01, H, 0) for _ in range(2)]
    negative = [pool(-5.0, 0.0), pool(-1.0, 0.0)]

    def views(tick, i):
        if tick < 3 * W:
            return negative[i]
        return pool(9.0, 0.0) if tick < 6 * W else pool(9.0, 4.0)

    log = run(dets, views, range(2 * W - 1, 9 * W),
              [lambda t: (t + H, 0, 9.0) if 4 * W <= t < 5 * W else (-1, -1, 0.0)])
    # candidate 1 is switched on at the first judging tick its score is significant; candidate 0 never
    assert log[0] == log[1] == [(7 * W - 1 + H, 1)]
    for d in dets:
        assert d.withdrawn == 0b01 and d.on == d.switched == 0b10
        assert d.entries()["eff_unexplained"] == 1.0  # the ruled-out window, at both (the persistence z is 0)


def test_the_level_is_the_withdrawals_and_a_rule_out_comes_before_a_switch_in_the_same_window():
    """Ruled out just below the level's lower quantile (alpha / 3 one-sided), not just above it; a window
    that rules one candidate out switches no other on (one decision per window: the structure is not one
    candidate's), the significant one is switched on from a later window. A ruled-out window counts
    ``unexplained`` (no persistence here)."""
    from statistics import NormalDist

    z_at = NormalDist().inv_cdf(1 - 0.01 / (1 + N_EFF)) / math.sqrt(2)  # a score mean of z_at pools to the level
    for eps, ruled in ((1e-6, 0b01), (-1e-6, 0)):
        (d,) = dets = [OnlineDetection(2, W, LAGS, 0.01, H, 0)]
        log = run(dets, lambda t, i: pool(-z_at - eps, 0.0), range(2 * W - 1, 2 * W + H))
        assert d.withdrawn == ruled and log == [[]] and d.unexplained == ruled
    (d,) = dets = [OnlineDetection(2, W, LAGS, 0.01, H, 0)]
    log = run(dets, lambda t, i: pool(-5.0, 4.0), range(2 * W - 1, 8 * W + H))
    # candidate 0 ruled out on the first judged window (2 W - 1), candidate 1 switched on from the next
    assert log == [[(3 * W - 1 + H, 1)]] and d.withdrawn == 0b01 and d.on == 0b10
    assert d.unexplained == 1


def test_a_declared_effect_is_never_ruled_out():
    """An effect in ``estimate_effects`` is the user's: no negative score rules it out, and a neighbour's
    withdrawal of it is ignored."""
    (d,) = dets = [OnlineDetection(2, W, LAGS, 0.01, H, 0, on=0b01)]
    log = run(dets, lambda t, i: pool(-9.0, 0.0), range(2 * W - 1, 5 * W),
              [lambda t: (t + H, N_EFF + 0, -9.0)])
    assert log == [[]] and d.on == 0b01 and d.withdrawn == 0


# candidates 0 and 2 with nearly the same signature (viscous and Coulomb friction's scores are 0.83-0.99
# correlated per window on the bench's plants), 1 independent of both
TWINS = {(0, 2): 0.95}


def _conditional(s0: float, s2: float, n: int = 2) -> float:
    """Candidate 0's pooled score orthogonal to candidate 2's (unit informations, cross 0.95)."""
    return math.sqrt(n) * (s0 - 0.95 * s2) / math.sqrt(1.0 - 0.95**2)


def test_a_switch_whose_model_the_window_contradicts_rules_its_candidate_out():
    """Candidate 2 significantly positive (z 4.2) beside its near-twin 0 slightly negative (z -1.4, not
    significant): had 2 been switched on, 0's score in that model (orthogonal to 2's, z -17) would be far
    below the lower quantile. The structure is positive along 2's signature and negative along 0's, which no
    positive coefficient makes: both agents rule 2 out on one tick, with that statistic and no filter change,
    count the window ``unexplained``, and never switch 2 on, not even on a later window where it alone is
    significant and nothing contradicts it."""
    dets = [OnlineDetection(2, W, LAGS, 0.01, H, 0) for _ in range(2)]
    zc = _conditional(-1.0, 3.0)
    assert contradicted_by(pool(-1.0, 0.0, 3.0, cross=TWINS), 2, 2, 0b111, 0.01) == pytest.approx((zc, 0))
    assert zc < -17.0

    def views(tick, i):
        return pool(-1.0, 0.0, 3.0, cross=TWINS) if tick < 3 * W else pool(0.0, 0.0, 3.0)

    log = run(dets, views, range(2 * W - 1, 6 * W))
    assert log == [[], []]  # no decision reaches the filters
    for d in dets:
        assert d.withdrawn == 0b100 and d.on == d.switched == 0
        e = d.entries()
        assert e["eff_out"] == 4.0 and e["eff_tick"] == 2 * W - 1 + H and e["eff_z"] == pytest.approx(zc)
        assert e["eff_unexplained"] == 1.0


def test_a_switch_its_window_does_not_contradict_is_taken():
    """The same candidate 2 beside a twin whose score is what 2's effect makes (s_0 = 0.95 s_2: its score
    orthogonal to 2's is 0): switched on; and the contradiction's level is the switch's, one-sided (ruled out
    just below the lower quantile, switched on just above it)."""
    from statistics import NormalDist

    (d,) = dets = [OnlineDetection(2, W, LAGS, 0.01, H, 0)]
    log = run(dets, lambda t, i: pool(2.85, 0.0, 3.0, cross=TWINS), range(2 * W - 1, 2 * W + H))
    assert log == [[(2 * W - 1 + H, 2)]] and d.on == 0b100 and d.withdrawn == 0
    z_at = NormalDist().inv_cdf(1 - 0.01 / (1 + N_EFF))
    for eps, out in ((1e-6, 0b100), (-1e-6, 0)):
        # s_0 such that 0's score orthogonal to 2's is -z_at - eps
        s0 = 0.95 * 3.0 + (-z_at - eps) * math.sqrt(1.0 - 0.95**2) / math.sqrt(2)
        assert _conditional(s0, 3.0) == pytest.approx(-z_at - eps, abs=1e-9)
        (d,) = dets = [OnlineDetection(2, W, LAGS, 0.01, H, 0)]
        log = run(dets, lambda t, i: pool(s0, 0.0, 3.0, cross=TWINS), range(2 * W - 1, 2 * W + H))
        assert d.withdrawn == out and d.on == 0b100 ^ out
        assert log == ([[]] if out else [[(2 * W - 1 + H, 2)]])


def test_a_candidate_ruled_out_still_checks_a_later_switch():
    """Candidate 0 ruled out by its own negative score; a later window with its twin 2 significantly positive
    and 0 still negative along 2's model rules 2 out too (the ruled-out candidate's signature still holds the
    structure); candidate 1, independent of both, is still switched on afterwards."""
    (d,) = dets = [OnlineDetection(2, W, LAGS, 0.01, H, 0)]

    def views(tick, i):
        if tick < 3 * W:
            return pool(-5.0, 0.0, 0.0, cross=TWINS)
        return pool(1.0, 0.0, 3.0, cross=TWINS) if tick < 4 * W else pool(1.0, 4.0, 3.0, cross=TWINS)

    log = run(dets, views, range(2 * W - 1, 6 * W + H))
    assert d.withdrawn == 0b101 and d.unexplained == 2
    assert log == [[(5 * W - 1 + H, 1)]] and d.on == 0b010
