"""What a daemon that exchanges states with its neighbours waits for: each neighbour's last state tick,
which of them a lockstep step waits for, and the end-of-run gate (:mod:`net.finish`).

Shared by the agent daemon and the H-infinity estimator daemon; the protocol is in docs/wire.md
("Lockstep waits"). The daemons keep their timers and their pending measurements; this holds the
rules that decide them.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable

from net.finish import FinishGate

MAX_TICK_LEAD = 10_000
"""A measurement or state further ahead than this many ticks is treated as hostile."""


class NeighbourWait:
    """The neighbours' last state ticks, the lockstep wait set, and the end-of-run gate.

    ``lead``: in lockstep, how far past the daemon's next tick a neighbour that skipped ticks may come
    back (a neighbour cut off meanwhile rejoins at a tick the daemon has reached; further is a forgery).
    """

    __slots__ = ("expect", "finish", "last_from", "lead", "mode")

    def __init__(self, neighbours: Iterable[int], mode: str, report: Callable[[], None], lead: int) -> None:
        self.last_from: dict[int, int] = {j: -1 for j in neighbours}
        # neighbours whose previous-tick state a lockstep step waits for: all of them at the start (the
        # simulator starts only when every daemon is up); a dead one leaves, and comes back with its
        # first message
        self.expect: set[int] = set(self.last_from)
        self.mode = mode
        self.lead = lead
        self.finish = FinishGate(report)  # after `done`: the neighbours' last states, then report

    def admit(self, sender: int, tick: int, next_tick: int, horizon: float = math.inf) -> str | None:
        """Takes ``sender``'s state of ``tick`` (None), or says why it is dropped ("stale", "future").

        ``horizon``: in real time, the furthest tick a genuine message can carry now.
        """
        last = self.last_from[sender]
        if tick <= last:
            return "stale"
        if tick > next_tick + MAX_TICK_LEAD or tick > horizon or (
                self.mode == "lockstep" and tick != last + 1 and tick > next_tick + self.lead):
            return "future"
        self.last_from[sender] = tick
        self.expect.add(sender)
        return None

    def ready(self, k: int) -> bool:
        """Whether tick ``k`` can be stepped: every awaited neighbour's state of ``k - 1`` is in."""
        if self.mode == "realtime" or k == 0:
            return True
        return all(self.last_from[j] >= k - 1 for j in self.expect)

    def stop_waiting(self, k: int) -> list[int]:
        """Tick ``k`` timed out: the neighbours it waited for leave the wait set (back once they speak)."""
        missing = [j for j in self.expect if self.last_from[j] < k - 1]
        self.expect.difference_update(missing)
        return missing

    def gone(self, j: int) -> bool:
        """Neighbour ``j``'s token went: it is not waited for (False: ``j`` is no neighbour)."""
        if j not in self.last_from:
            return False
        self.expect.discard(j)
        return True

    def rejoin_at(self, k: int) -> None:
        """Going on from tick ``k`` after the run went on without this daemon: wait only for the
        neighbours whose state of ``k - 1`` is here already (a state sent before this daemon listened
        would only cost a timeout)."""
        self.expect = {j for j in self.last_from if self.last_from[j] >= k - 1}

    def done(self, end: int) -> None:
        """The simulator's ``done`` notice: the run lasted ``end`` ticks."""
        self.finish.begin(end, self.last_from, self.expect)

    def check_finish(self) -> None:
        """Called after every state and liveliness change: reports once the last states are in."""
        self.finish.check(self.last_from, self.expect)
