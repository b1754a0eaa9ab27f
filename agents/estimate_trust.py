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

The counts run compiled (agents/kernels/window_stats.py); the classes here are views over their rows.
"""

from __future__ import annotations

import array
from collections.abc import Iterable
from itertools import chain
from statistics import NormalDist

import numpy as np

import agents.kernels.window_stats as ws
from net.vocabulary import J_AVERAGE, J_EXCITE, M_AVERAGE, M_EXCITE

# the stages each estimate rests on
M_STAGES = (M_EXCITE, M_AVERAGE)
J_STAGES = (J_EXCITE, J_AVERAGE)
TRUST_NAMES = ("m_trusted", "m_fresh", "m_sd", "J_trusted", "J_fresh", "J_sd")


def wilson_upper(k: int, n: int, alpha: float, z: float | None = None) -> float:
    """One-sided upper confidence bound (level 1 - alpha) of a binomial proportion with k successes
    in n trials (Wilson score); 1.0 without trials. ``z``: the standard normal quantile of 1 - alpha,
    if already known."""
    return ws.wilson_upper(k, n, NormalDist().inv_cdf(1.0 - alpha) if z is None else z)


def poor(fresh: int, slots: int, min_fresh: float, alpha: float, z: float | None = None) -> bool:
    """The stage's data are too poor: fewer than ``min_fresh`` of its ``slots`` fresh, at level ``alpha``."""
    return ws.poor(fresh, slots, min_fresh, NormalDist().inv_cdf(1.0 - alpha) if z is None else z)


class StageCount:
    """Neighbour-state slots and fresh states of one stage (of its last ``tail`` ticks if it has one), and its
    verdict at ``judged`` ticks: a view over a row of the trust's stage counts."""

    __slots__ = ("_c", "_trc", "_b", "_stage")

    def __init__(self, trc: np.ndarray, b: int, stage: int) -> None:
        self._trc, self._b, self._stage = trc, b, stage
        self._c = trc[b, stage]

    slots = property(lambda self: int(self._c[ws.TC_SLOTS]))
    fresh = property(lambda self: int(self._c[ws.TC_FRESH]))
    ticks = property(lambda self: int(self._c[ws.TC_TICKS]))
    judged = property(lambda self: int(self._c[ws.TC_JUDGED]))
    poor = property(lambda self: bool(self._c[ws.TC_POOR]))

    @property
    def fraction(self) -> float:
        return ws.trust_fraction(self._b, self._trc, self._stage)


class EstimateTrust:
    """One agent's evidence per stage and the trust entries of its m and J estimates (module docstring): a view
    over row ``b`` of the trust arrays (agents/kernels/window_stats.py); its own by default."""

    def __init__(self, degree: int, max_age: int, min_fresh: float, alpha: float, tail: int = 0,
                 rows: tuple | None = None, b: int = 0) -> None:
        """``tail``: the ticks over which an averaging stage is judged (0: all of it). ``rows``: the arrays of
        :func:`trust_rows` to view row ``b`` of (default: one row of its own)."""
        self.z = NormalDist().inv_cdf(1.0 - alpha)
        if rows is None:
            rows = ws.trust_rows(1, degree, max_age, min_fresh, self.z, tail)
        self._i, self._f, self._nb, self._trc, self._trr = rows
        self.b = b
        self._out = np.empty(len(TRUST_NAMES))

    @property
    def stages(self) -> dict[int, StageCount]:
        """The stages observed so far, by stage."""
        trc, b = self._trc, self.b
        return {s: StageCount(trc, b, s) for s in range(ws.N_STAGES) if trc[b, s, ws.TC_EXISTS]}

    @property
    def newest(self) -> dict[int, int]:
        """Each neighbour's newest state taken (its send tick)."""
        return dict(self._nb[self.b, :self._i[self.b, ws.TI_HEARD]].tolist())

    def observe(self, tick: int, stage: int, taken: Iterable[tuple[int, int]]) -> None:
        """A tick of ``stage`` in which the neighbour states ``taken`` = [(sender, send tick)] were taken."""
        # a flat array.array: numba's dispatch types it in less time than an ndarray takes to be built
        ws.trust_observe(self.b, self._i, self._nb, self._trc, self._trr, tick, stage,
                         array.array("q", chain.from_iterable(taken)))

    def judge(self, stages: tuple[int, int]) -> tuple[float, float]:
        """(flag, fresh fraction of the poorest stage begun) over ``stages``: (NaN, NaN) before the first."""
        return ws.trust_judge(self.b, self._f, self._trc, *stages)

    def entries(self, m: float, m_sd: float, J: float, J_sd: float) -> dict[str, float]:
        """The trust entries of the estimate (``TRUST_NAMES``), given the values and their uncertainties."""
        ws.trust_entries(self.b, self._f, self._trc, m, m_sd, J, J_sd, self._out)
        return dict(zip(TRUST_NAMES, self._out.tolist(), strict=True))
