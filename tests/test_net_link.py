"""Link fault model: determinism, independence, and rates within 5-sigma bounds.

Every statistical check uses a bound derived from the model (binomial, or Markov-corrected for the
Gilbert-Elliott chain), five standard deviations wide, so a correct model fails with probability
below 1e-6 per check; the seeds are fixed, so the suite is also reproducible.
"""

from __future__ import annotations

import math
import random

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import net.link
from config.scenario import LinkSpec, LossSpec
from net.link import DelayLine, LinkModel, LinkStats

N = 200_000


def _spec(**kw: object) -> LinkSpec:
    loss = kw.pop("loss", None)
    return LinkSpec(loss=LossSpec(**loss) if loss else LossSpec(), **kw)  # type: ignore[arg-type]


def _run(link: LinkModel, n: int = N) -> list[tuple]:
    return [link.deliveries(k) for k in range(n)]


def _within_5_sigma(count: int, n: int, p: float) -> bool:
    return abs(count - n * p) <= 5 * math.sqrt(n * p * (1 - p)) + 1e-9


GE = {"model": "gilbert_elliott", "p_good_to_bad": 0.05, "p_bad_to_good": 0.25, "loss_good": 0.02, "loss_bad": 0.8}
ALL_FAULTS = _spec(delay_ticks=2, jitter_ticks=3, duplicate=0.1, loss=GE)


# ---------------------------------------------------------------------------------------------
# Determinism and independence


def test_same_seed_same_draws_different_seed_different() -> None:
    a = _run(LinkModel(ALL_FAULTS, 7, 1, 2), 5000)
    assert a == _run(LinkModel(ALL_FAULTS, 7, 1, 2), 5000)
    assert a != _run(LinkModel(ALL_FAULTS, 8, 1, 2), 5000)
    assert a != _run(LinkModel(ALL_FAULTS, 7, 2, 1), 5000)  # each direction has its own stream


def test_draws_do_not_depend_on_interleaving_with_other_links() -> None:
    alone = _run(LinkModel(ALL_FAULTS, 3, 0, 1), 3000)
    links = [LinkModel(ALL_FAULTS, 3, s, r) for s, r in [(1, 0), (0, 1), (0, 2)]]
    rng = random.Random(0)
    got = []
    for k in range(3000):
        for other in rng.sample([links[0], links[2]], 2):
            other.deliveries(k)
        got.append(links[1].deliveries(k))
    assert got == alone


def test_block_size_is_only_an_optimisation(monkeypatch: pytest.MonkeyPatch) -> None:
    batched = _run(LinkModel(ALL_FAULTS, 11, 4, 5), 1000)
    monkeypatch.setattr(net.link, "_BLOCK", 1)
    assert _run(LinkModel(ALL_FAULTS, 11, 4, 5), 1000) == batched


def test_turning_on_duplication_or_jitter_keeps_the_loss_pattern() -> None:
    bern = {"model": "bernoulli", "p": 0.3}
    plain = [len(d) == 0 for d in _run(LinkModel(_spec(loss=bern), 5, 0, 1), 5000)]
    noisy = [len(d) == 0 for d in _run(LinkModel(_spec(loss=bern, duplicate=0.5, jitter_ticks=4), 5, 0, 1), 5000)]
    assert plain == noisy


def test_losses_on_different_links_are_uncorrelated() -> None:
    spec = _spec(loss={"model": "bernoulli", "p": 0.3})
    x = np.array([len(d) == 0 for d in _run(LinkModel(spec, 1, 0, 1))], dtype=float)
    y = np.array([len(d) == 0 for d in _run(LinkModel(spec, 1, 1, 0))], dtype=float)
    r = np.corrcoef(x, y)[0, 1]
    assert abs(r) < 5 / math.sqrt(N)  # sample correlation of independent series ~ N(0, 1/N)


def test_ticks_must_not_go_back() -> None:
    link = LinkModel(_spec(), 0, 0, 1)
    link.deliveries(5)
    link.deliveries(5)  # several messages in one tick are fine
    with pytest.raises(ValueError):
        link.deliveries(4)


def test_bad_arguments() -> None:
    with pytest.raises(ValueError):
        LinkModel(_spec(), 0, 0, 1, mode="wallclock")  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        LinkModel(_spec(), -1, 0, 1)


# ---------------------------------------------------------------------------------------------
# The fault-free link


@given(
    delay=st.integers(0, 50),
    delay_s=st.floats(0, 5),
    seed=st.integers(0, 2**32),
    n=st.integers(1, 300),
)
@settings(max_examples=50)
def test_none_link_delivers_everything_once_with_the_fixed_delay(delay: int, delay_s: float, seed: int, n: int) -> None:
    spec = _spec(delay_ticks=delay, delay_s=delay_s)
    assert _run(LinkModel(spec, seed, 0, 1), n) == [(delay,)] * n
    assert _run(LinkModel(spec, seed, 0, 1, mode="realtime"), n) == [(delay_s,)] * n


# ---------------------------------------------------------------------------------------------
# Rates


@pytest.mark.parametrize("p", [0.0, 0.05, 0.3, 1.0])
def test_bernoulli_loss_rate(p: float) -> None:
    lost = sum(len(d) == 0 for d in _run(LinkModel(_spec(loss={"model": "bernoulli", "p": p}), 2, 0, 1)))
    assert _within_5_sigma(lost, N, p)


def _ge_loss_sd(pgb: float, pbg: float, lg: float, lb: float, n: int) -> tuple[float, float]:
    """Stationary loss rate of the chain and the standard deviation of its n-message estimate.

    Losses are correlated through the state: Cov(L_k, L_k+m) = (lb - lg)^2 pi (1 - pi) lam^m with
    lam = 1 - pgb - pbg, so Var(sum) / n = p (1 - p) + 2 (lb - lg)^2 pi (1 - pi) lam / (1 - lam).
    """
    pi = pgb / (pgb + pbg)
    lam = 1 - pgb - pbg
    p = pi * lb + (1 - pi) * lg
    var = p * (1 - p) + 2 * (lb - lg) ** 2 * pi * (1 - pi) * lam / (1 - lam)
    return p, math.sqrt(var / n)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_gilbert_elliott_stationary_loss_rate(seed: int) -> None:
    lost = sum(len(d) == 0 for d in _run(LinkModel(_spec(loss=GE), seed, 0, 1)))
    p, sd = _ge_loss_sd(GE["p_good_to_bad"], GE["p_bad_to_good"], GE["loss_good"], GE["loss_bad"], N)
    assert abs(lost / N - p) <= 5 * sd


def test_gilbert_elliott_mean_burst_length() -> None:
    """With loss_bad = 1, loss_good = 0 a burst is a stay in the bad state: geometric, mean 1/p_bg."""
    pgb, pbg = 0.05, 0.25
    spec = _spec(loss={"model": "gilbert_elliott", "p_good_to_bad": pgb, "p_bad_to_good": pbg,
                       "loss_good": 0.0, "loss_bad": 1.0})
    bursts: list[int] = []
    run = 0
    for d in _run(LinkModel(spec, 4, 2, 3)):
        if not d:
            run += 1
        elif run:
            bursts.append(run)
            run = 0
    mean = 1 / pbg
    sd = math.sqrt((1 - pbg) / pbg**2 / len(bursts))
    assert abs(np.mean(bursts) - mean) <= 5 * sd
    # and the chain spends the stationary share of messages in the bad state
    pi = pgb / (pgb + pbg)
    assert abs(sum(bursts) / N - pi) <= 5 * _ge_loss_sd(pgb, pbg, 0.0, 1.0, N)[1]


def test_gilbert_elliott_starts_from_the_stationary_distribution() -> None:
    pgb, pbg = 0.05, 0.25
    spec = _spec(loss={"model": "gilbert_elliott", "p_good_to_bad": pgb, "p_bad_to_good": pbg})
    n = 4000
    bad = sum(LinkModel(spec, 9, 0, j).in_bad_state for j in range(n))
    assert _within_5_sigma(bad, n, pgb / (pgb + pbg))


def test_duplication_rate_among_delivered() -> None:
    spec = _spec(duplicate=0.1, loss={"model": "bernoulli", "p": 0.2})
    fates = _run(LinkModel(spec, 6, 0, 1))
    delivered = [d for d in fates if d]
    dups = sum(len(d) == 2 for d in delivered)
    assert all(1 <= len(d) <= 2 for d in delivered)
    assert _within_5_sigma(dups, len(delivered), 0.1)
    assert _within_5_sigma(N - len(delivered), N, 0.2)


@pytest.mark.parametrize("delay, jitter", [(0, 0), (0, 1), (3, 4)])
def test_lockstep_delays_are_uniform_in_delay_plus_jitter(delay: int, jitter: int) -> None:
    spec = _spec(delay_ticks=delay, jitter_ticks=jitter, duplicate=0.3)
    delays = [x for d in _run(LinkModel(spec, 8, 0, 1)) for x in d]
    assert all(type(x) is int for x in delays)
    assert min(delays) >= delay and max(delays) <= delay + jitter
    counts = np.bincount(np.array(delays) - delay, minlength=jitter + 1)
    for c in counts:
        assert _within_5_sigma(int(c), len(delays), 1 / (jitter + 1))


def test_realtime_delays_are_uniform_seconds() -> None:
    spec = _spec(delay_s=0.02, jitter_s=0.01, delay_ticks=9, jitter_ticks=9)
    delays = np.array([x for d in _run(LinkModel(spec, 8, 0, 1, mode="realtime")) for x in d])
    assert delays.min() >= 0.02 and delays.max() <= 0.03
    # mean of U[0, 0.01]: 0.005 with sd 0.01/sqrt(12 n)
    assert abs(delays.mean() - 0.025) <= 5 * 0.01 / math.sqrt(12 * len(delays))


def test_jitter_reorders() -> None:
    spec = _spec(jitter_ticks=3)
    arrivals = [k + d[0] for k, d in enumerate(_run(LinkModel(spec, 1, 0, 1), 1000))]
    assert any(b < a for a, b in zip(arrivals, arrivals[1:]))


# ---------------------------------------------------------------------------------------------
# DelayLine and LinkStats


def test_delay_line_pops_due_messages_in_canonical_order() -> None:
    entries = [(d, s, k, c, f"m{d}{s}{k}{c}") for d in range(4) for s in range(3) for k in range(2) for c in range(2)]
    orders = []
    for seed in range(5):
        shuffled = entries[:]
        random.Random(seed).shuffle(shuffled)
        line: DelayLine[str] = DelayLine()
        for e in shuffled:
            line.push(*e)
        orders.append([line.pop_due(t) for t in range(-1, 4)])
        assert len(line) == 0 and line.next_due() is None
    assert all(o == orders[0] for o in orders)
    assert orders[0][0] == []
    assert [m for batch in orders[0] for m in batch] == [e[4] for e in sorted(entries)]


@given(st.lists(st.tuples(st.integers(0, 5), st.integers(0, 3), st.integers(0, 5), st.integers(0, 1)), max_size=40),
       st.randoms())
def test_delay_line_order_is_independent_of_push_order(
    keys: list[tuple[int, int, int, int]], rnd: random.Random
) -> None:
    keys = sorted(set(keys))  # one message per (deliver, sender, send tick, copy), as in the engines
    shuffled = keys[:]
    rnd.shuffle(shuffled)
    a: DelayLine[tuple] = DelayLine()
    b: DelayLine[tuple] = DelayLine()
    for k in keys:
        a.push(*k, k)
    for k in shuffled:
        b.push(*k, k)
    assert a.pop_due(2) == b.pop_due(2)
    assert a.pop_due(10) == b.pop_due(10)


def test_offer_buffers_copies_at_send_tick_plus_delay_and_counts() -> None:
    spec = _spec(delay_ticks=1, jitter_ticks=2, duplicate=0.2, loss={"model": "bernoulli", "p": 0.25})
    link, twin = LinkModel(spec, 5, 3, 0), LinkModel(spec, 5, 3, 0)
    line: DelayLine[tuple[int, int]] = DelayLine()
    stats = LinkStats()
    expected: dict[int, list[tuple[int, int, tuple[int, int]]]] = {}
    n = 2000
    for k in range(n):
        fate = twin.deliveries(k)  # the same stream as `link`: what offer() must have done
        for c, d in enumerate(fate):
            expected.setdefault(k + d, []).append((k, c, (k, c)))
        assert line.offer(link, k, (k, -1), stats) == len(fate)
    got = {t: due for t in range(n + 3) if (due := line.pop_due(t))}
    assert sorted(got) == sorted(expected)
    for t, entries in expected.items():
        assert [m[0] for m in got[t]] == [k for k, _, _ in sorted(entries)]
    assert len(line) == 0
    copies = sum(len(v) for v in expected.values())
    assert stats.sent == n and stats.delivered == 0 and stats.late == 0
    assert copies == n - stats.dropped + stats.duplicated
    assert stats.dropped > 0 and stats.duplicated > 0


def test_offer_refuses_realtime_links() -> None:
    with pytest.raises(ValueError):
        DelayLine().offer(LinkModel(_spec(), 0, 0, 1, mode="realtime"), 0, "m")


def test_link_stats() -> None:
    a = LinkStats(sent=3, delivered=2, dropped=1)
    b = LinkStats(sent=1, duplicated=1, late=2, malformed=4)
    assert (a + b).as_dict() == {"sent": 4, "delivered": 2, "dropped": 1, "duplicated": 1, "late": 2, "malformed": 4,
                                 "partitioned": 0, "stale_age": 0}
    assert list(LinkStats().as_dict()) == ["sent", "delivered", "dropped", "duplicated", "late", "malformed",
                                           "partitioned", "stale_age"]
