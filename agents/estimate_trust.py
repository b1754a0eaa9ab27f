"""Estimate trust: the evidence each stage of the dynamical phase actually got, and whether the m and J
estimates that rest on it may be reported as done.

:class:`EstimateTrust` is fed once per tick (stage, the send ticks of the neighbour states taken that
tick, the agent's m and J values) and returns the trust entries of the estimate: per estimate a flag
(1 trusted, 0 untrusted, NaN before its stages began), the fresh fraction of its poorest stage and an
uncertainty (one standard deviation, kg and kg m^2). Pure: no clock, socket or RNG.

Criterion (docs/estimate-trust.md): at each tick of a stage, each neighbour is a slot, filled when the
newest state the agent has taken from it is at most ``max_age`` ticks old (what the consensus runs on
is current; lost, late or reordered states do not matter while newer ones keep coming). A stage is
poor when the one-sided
Wilson upper bound, at confidence 1 - ``alpha``, of its fresh fraction is below ``min_fresh``: the
hypothesis "at least ``min_fresh`` of the stage's slots were fresh" is rejected at level ``alpha`` (the
slots are taken as independent trials). An estimate is untrusted when any stage it rests
on is poor (m: the m excitation and averaging stages; J: the J excitation and averaging stages). An
excitation stage is judged on all its ticks (the filter integrates over the whole stage); an averaging
stage on its last ``tail`` ticks only (the convergence check's window and the agreement's horizon):
a consensus that waited through a gap and converged on fresh states after it is sound.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from statistics import NormalDist

from net.vocabulary import J_AVERAGE, J_EXCITE, M_AVERAGE, M_EXCITE

# the stages each estimate rests on
M_STAGES = (M_EXCITE, M_AVERAGE)
J_STAGES = (J_EXCITE, J_AVERAGE)
TRUST_NAMES = ("m_trusted", "m_fresh", "m_sd", "J_trusted", "J_fresh", "J_sd")
_NEVER = -(2**62)  # the send tick of a state never taken


def wilson_upper(k: int, n: int, alpha: float, z: float | None = None) -> float:
    """One-sided upper confidence bound (level 1 - alpha) of a binomial proportion with k successes
    in n trials (Wilson score); 1.0 without trials. ``z``: the standard normal quantile of 1 - alpha,
    if already known."""
    if n <= 0:
        return 1.0
    if z is None:
        z = NormalDist().inv_cdf(1.0 - alpha)
    p = k / n
    z2n = z * z / n
    centre = p + 0.5 * z2n
    half = z * math.sqrt(p * (1.0 - p) / n + 0.25 * z2n / n)
    return min(1.0, (centre + half) / (1.0 + z2n))


def poor(fresh: int, slots: int, min_fresh: float, alpha: float, z: float | None = None) -> bool:
    """The stage's data are too poor: fewer than ``min_fresh`` of its ``slots`` fresh, at level ``alpha``."""
    return wilson_upper(min(fresh, slots), slots, alpha, z) < min_fresh


def spread_sd(own: float, neighbours: Iterable[float]) -> float:
    """Root-mean-square difference between the own consensus value and the neighbours' latest ones (0.0
    without neighbour values): what the averaging has not yet removed."""
    acc = 0.0
    k = 0
    for v in neighbours:
        if v == v:
            acc += (v - own) ** 2
            k += 1
    return math.sqrt(acc / k) if k else 0.0


class StageCount:
    """Neighbour-state slots and fresh states of one stage (of its last ``tail`` ticks if ``tail`` > 0),
    and its verdict at ``judged`` ticks."""

    __slots__ = ("slots", "fresh", "judged", "poor", "ticks", "ring", "degree")

    def __init__(self, degree: int, tail: int = 0) -> None:
        self.degree = degree
        self.slots = 0
        self.fresh = 0
        self.ticks = 0
        self.judged = -1
        self.poor = False
        self.ring = [0] * tail  # fresh states of each of the last ``tail`` ticks

    def add(self, fresh: int) -> None:
        """One tick with ``fresh`` fresh states."""
        ring = self.ring
        if ring:
            k = self.ticks % len(ring)
            if self.ticks >= len(ring):  # the oldest tick leaves the tail
                self.fresh -= ring[k]
                self.slots -= self.degree
            ring[k] = fresh
        self.ticks += 1
        self.slots += self.degree
        self.fresh += fresh

    @property
    def fraction(self) -> float:
        return min(1.0, self.fresh / self.slots) if self.slots else math.nan


class EstimateTrust:
    """One agent's evidence per stage and the trust entries of its m and J estimates (module docstring)."""

    def __init__(self, degree: int, max_age: int, min_fresh: float, alpha: float, tail: int = 0) -> None:
        """``tail``: the ticks over which an averaging stage is judged (0: all of it)."""
        self.degree = degree
        self.tail = {M_AVERAGE: tail, J_AVERAGE: tail}
        self.max_age = max_age
        self.min_fresh = min_fresh
        self.alpha = alpha
        self.z = NormalDist().inv_cdf(1.0 - alpha)
        self.stages: dict[int, StageCount] = {}
        self.newest: dict[int, int] = {}  # each neighbour's newest state taken (its send tick)

    def observe(self, tick: int, stage: int, taken: Iterable[tuple[int, int]]) -> None:
        """A tick of ``stage`` in which the neighbour states ``taken`` = [(sender, send tick)] were taken."""
        newest = self.newest
        for j, t in taken:
            if t > newest.get(j, _NEVER):
                newest[j] = t
        c = self.stages.get(stage)
        if c is None:
            c = self.stages[stage] = StageCount(self.degree, self.tail.get(stage, 0))
        lim = tick - self.max_age
        fresh = 0
        for t in newest.values():
            if t >= lim:
                fresh += 1
        c.add(fresh)

    def judge(self, stages: tuple[int, ...]) -> tuple[float, float]:
        """(flag, fresh fraction of the poorest stage begun) over ``stages``: (NaN, NaN) before the first."""
        flag = math.nan
        worst = math.nan
        for s in stages:
            c = self.stages.get(s)
            if c is None or not c.slots:
                continue
            f = c.fraction
            if not worst <= f:
                worst = f
            if c.judged != c.ticks:  # a finished stage is judged once
                c.judged = c.ticks
                c.poor = poor(c.fresh, c.slots, self.min_fresh, self.alpha, self.z)
            flag = 0.0 if c.poor or flag == 0.0 else 1.0
        return flag, worst

    def entries(self, m: float, m_sd: float, J: float, J_sd: float) -> dict[str, float]:
        """The trust entries of the estimate (``TRUST_NAMES``), given the values and their uncertainties."""
        mt, mf = self.judge(M_STAGES)
        jt, jf = self.judge(J_STAGES)
        nan = math.nan
        return {
            "m_trusted": mt,
            "m_fresh": mf,
            "m_sd": m_sd if m == m and mt == mt else nan,
            "J_trusted": jt,
            "J_fresh": jf,
            "J_sd": J_sd if J == J and jt == jt else nan,
        }
