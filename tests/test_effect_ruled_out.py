"""A candidate whose pooled score is significantly negative is ruled out by the team (agents/effect_decision.py,
docs/online-detection.md, periodic force): on one tick at every agent, through the withdrawals' flood, with
no change to the filters, the window ``unexplained``, and never proposed again."""

from __future__ import annotations

import math

from agents.effect_decision import CH_CNT, CH_Z, N_EFF, N_POOL, VCH, OnlineDetection

LAGS = 5
W, H = 100, 20


def pool(*scores: float, zp_sum: float = 0.0) -> list[float]:
    """Team means of the pool channels whose pooled z of candidate k is scores[k] sqrt(n) (n = 2 here; 0 for
    the candidates not given): s_k = scores[k], V_kk = 1, no cross terms, every agent contributing."""
    x = [0.0] * N_POOL
    for k in range(N_EFF):
        x[k], x[VCH[k, k]] = scores[k] if k < len(scores) else 0.0, 1.0
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
