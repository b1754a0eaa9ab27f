"""When a run may end early: a set time after every agent has reached the done stage.

Algorithm 1 ends at a stage the agents agree on (``net.vocabulary.DONE``), often well before the
scenario's duration; what follows is the braking phase, which a campaign does not need. Both engines
apply the same rule to the same data -- the ``phase`` of the estimates the agents publish on the
recording grid -- so a Zenoh run and an in-process run of one scenario end on the same tick. The end
lies ``after_ticks`` past the tick that completed the set, so an estimate still on its way when the
simulator passes that tick (Zenoh) is in long before the end.
"""

from __future__ import annotations

from config.scenario import Scenario
from net.vocabulary import DONE


class DoneStop:
    """Tracks the agents' latest stage; ``end`` is the number of ticks the run lasts (``ticks`` until
    every agent has been seen done, then that tick + 1 + ``after_ticks``, capped at ``ticks``)."""

    __slots__ = ("_done", "_left", "after_ticks", "end")

    def __init__(self, n: int, ticks: int, after_ticks: int) -> None:
        if after_ticks < 0:
            raise ValueError(f"after_ticks must be >= 0 (got {after_ticks})")
        self._done = [False] * n
        self._left = n
        self.after_ticks = after_ticks
        self.end = ticks

    def see(self, tick: int, agent: int, phase: float) -> None:
        """One recorded estimate's stage; only the first time each agent is seen done counts."""
        if self._done[agent] or phase != DONE:
            return
        self._done[agent] = True
        self._left -= 1
        if self._left == 0:
            self.end = min(self.end, tick + 1 + self.after_ticks)

    @property
    def triggered(self) -> bool:
        return self._left == 0


def done_stop(scenario: Scenario) -> DoneStop | None:
    """The scenario's rule (``stop_after_done_s``), or None when it runs its whole duration."""
    if scenario.stop_after_done_s is None:
        return None
    return DoneStop(scenario.n, scenario.ticks, int(round(scenario.stop_after_done_s / scenario.dt)))
