"""The end of a run at a daemon that exchanges states with neighbours.

Zenoh orders messages per publisher only, and each subscription calls back on a thread of its own:
a neighbour's last state can still be on its way when the simulator's ``done`` notice arrives, and
even after the neighbour's liveliness token is seen to go (a neighbour that finished first and
closed its session). A daemon reports (its link counters, for summary.json) once the last state of
every neighbour it still expects, or that was in step until the end, is in, or after a grace time,
so that the counters tell the run's whole story whatever the arrival order.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Collection, Mapping

FINISH_GRACE_S = 2.0
"""Longest wait for the neighbours' last states after ``done`` (s)."""


class FinishGate:
    """Calls ``report`` once: when every expected neighbour has sent its state of tick ``end - 1``
    (:meth:`check`, called by the daemon on each state and liveliness change), or after the grace time.

    A neighbour whose state of tick ``end - 2`` was in when ``done`` came was in step until the end:
    its last state is waited for even if its token has gone meanwhile (it finished, reported and
    closed its session; the token's withdrawal can overtake its last state)."""

    __slots__ = ("_report", "_grace_s", "_timer", "_in_step", "active", "end", "fired")

    def __init__(self, report: Callable[[], None], grace_s: float = FINISH_GRACE_S) -> None:
        self._report = report
        self._grace_s = grace_s
        self._timer: asyncio.TimerHandle | None = None
        self.active = False  # `done` came
        self.end = 0  # ticks the run lasted, as `done` said
        self._in_step: frozenset[int] = frozenset()  # neighbours in step when `done` came
        self.fired = False

    def begin(self, end: int, last_from: Mapping[int, int], expect: Collection[int]) -> None:
        if self.active:
            return
        self.active = True
        self.end = end
        self._in_step = frozenset(j for j, tick in last_from.items() if tick >= end - 2)
        self._timer = asyncio.get_running_loop().call_later(self._grace_s, self.fire)
        self.check(last_from, expect)

    def check(self, last_from: Mapping[int, int], expect: Collection[int]) -> None:
        if self.active and all(last_from[j] >= self.end - 1 for j in self._in_step.union(expect)):
            self.fire()

    def fire(self) -> None:
        if self.fired:
            return
        self.fired = True
        self.cancel()
        self._report()

    def cancel(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
