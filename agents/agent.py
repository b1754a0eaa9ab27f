"""The agent core: one robot's estimator and controller, a team of one behind the wire's edge codec.

:meth:`AgentCore.step` (tick, own measured velocity, neighbour messages) -> :class:`StepResult`
(message to the neighbours, wrench to the plant, estimate): deterministic, no clock, socket or RNG.
It is an :class:`agents.team.TeamCore` of one agent: the inbox's :class:`net.messages.StateMsg`\\ s become
IN rows (agents/kernels/message_rows.py ``in_rows``: decoded by net/rows.py ``raw_values``, checked by the
compiled ``check_rows``, the checks an in-process team's gather runs), the team's tick runs on them, and the
agent's OUT row becomes its message (``state_from_row``). The wire content: docs/agent-step.md; the estimate names:
:data:`net.vocabulary.ESTIMATE_NAMES`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from agents.kernels.message_rows import in_rows
from agents.laws import LawInput
from agents.team import AgentView, Member, TeamCore, assumed_sigma_v
from config.agent_params import ControlSpec, DynamicsSpec, EstimatorSpec
from net.messages import Estimate, StateMsg, Wrench


@dataclass(frozen=True, slots=True)
class StepResult:
    """One tick's outputs: ``state`` (to the neighbours), ``wrench`` (to the plant), ``estimate``."""

    state: StateMsg
    wrench: Wrench
    estimate: Estimate


class AgentCore(TeamCore, AgentView):
    """Agent i's estimator and controller (module docstring); its state: :class:`agents.team.AgentView`."""

    def __init__(
        self,
        agent_id: int,
        neighbours: Sequence[int],
        n: int,
        dt: float,
        sigma_v: float,
        estimator: EstimatorSpec,
        control: ControlSpec,
        dynamics: DynamicsSpec | None = None,
        law: Callable[[LawInput], Sequence[float]] | None = None,
    ) -> None:
        """``law``: a control law of the user's (agents/laws.py), called where the dynamical phase allows."""
        me = Member(agent_id, neighbours, n, dt, sigma_v, estimator, control, dynamics, law)
        TeamCore.__init__(self, [me])
        self._team, self._row = self, 0
        self.n = int(n)
        self.dt = float(dt)
        self.sigma_v = assumed_sigma_v(me)  # the noise the agent assumes
        self.spec = estimator
        self._no_rows = np.zeros((0, self._lay.size_in))
        self._in_ptr = np.zeros(2, np.int64)

    def step(self, tick: int, vx: float, vy: float, inbox: Sequence[StateMsg]) -> StepResult:
        state, wrench = self.advance(tick, vx, vy, inbox)
        return StepResult(state, wrench, self.estimate())

    def advance(self, tick: int, vx: float, vy: float, inbox: Sequence[StateMsg]) -> tuple[StateMsg, Wrench]:
        """:meth:`step` without the estimate, which :meth:`estimate` builds on demand (an engine needs it only
        on recorded ticks)."""
        lay = self._lay
        me = self.ids[0]
        n = len(inbox)
        rows = in_rows(inbox, me, lay) if n else self._no_rows
        self._in_ptr[1] = n
        inp = self._inp
        inp[0, 0] = vx
        inp[0, 1] = vy
        fx, fy, tau = self._tick(tick, rows, self._in_ptr)[0].tolist()
        return self.message(tick, 0), Wrench(tick, me, fx, fy, tau)

    def estimate(self) -> Estimate:
        """The estimate of the last :meth:`advance`'s tick (valid until the next advance)."""
        return self.estimates()[0]
