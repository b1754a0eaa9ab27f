"""The agents that one process steps, behind one call per tick: the engines' side of the team core.

:meth:`TeamCore.step` (tick, measured velocities (B, 2), :class:`Inbox`) -> wrenches (B, 3): every agent's
tick. The agents' messages of the tick stay in the team's OUT ring (slot ``tick % ring``); an inbox names
each agent's due messages as a CSR over a ring of messages, in the order the agent takes them:
``ref[ptr[b]:ptr[b + 1]]`` = rows (ring slot, sender row, block). Estimates are built on demand
(:meth:`TeamCore.estimates`), on the ticks that are recorded. docs/fast-core-plan.md, sections 2 and 4 (S7).

Each row is an :class:`agents.agent.AgentCore` and a message is its ``StateMsg`` (block 0, the whole
message), until the compiled team step replaces the loop over the rows.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from agents.agent import AgentCore
from net.messages import Estimate, StateMsg


@dataclass(frozen=True, slots=True)
class Inbox:
    """The due messages of every agent of a tick: ``ref[ptr[b]:ptr[b + 1]]`` are agent b's, in taking order."""

    msgs: Sequence[Sequence[StateMsg]]  # the ring the rows point into: msgs[slot][row]
    ptr: np.ndarray  # (B + 1,) int64
    ref: np.ndarray  # (E, 3) int64: ring slot, sender row, block


class TeamCore:
    """B agents' estimators and controllers, stepped together (module docstring)."""

    def __init__(self, cores: Sequence[AgentCore], ring: int = 2) -> None:
        """``ring``: slots of the OUT ring; an inbox may reach back ``ring - 1`` ticks (a message sent at
        tick k - ring + 1 is the oldest one due at tick k)."""
        if ring < 2:
            raise ValueError("the OUT ring needs 2 slots at least (messages are due a tick after they are sent)")
        self.cores = list(cores)
        self.B = len(self.cores)
        self.ring = ring
        # out[slot][row]: the message of agent `row` of the tick in that slot
        self.out: list[list[StateMsg | None]] = [[None] * self.B for _ in range(ring)]
        self.stages = [0] * self.B  # each agent's stage at the last tick

    def agent(self, i: int) -> AgentCore:
        """Row i's core (read by tests and tools)."""
        return self.cores[i]

    def step(self, tick: int, meas: Sequence[Sequence[float]], inbox: Inbox) -> np.ndarray:
        """Every agent's tick: ``meas[b]`` its measured (vx, vy), ``inbox`` its due messages; the wrenches
        (B, 3). The messages land in the OUT ring's slot ``tick % ring`` after every agent has read its inbox."""
        ptr = inbox.ptr.tolist()
        ref = inbox.ref.tolist()
        msgs = inbox.msgs
        states: list[StateMsg | None] = [None] * self.B
        wrenches = []
        stages = self.stages
        for b, core in enumerate(self.cores):
            vx, vy = meas[b]
            state, w = core.advance(tick, vx, vy, [msgs[s][r] for s, r, _ in ref[ptr[b]:ptr[b + 1]]])
            states[b] = state
            stages[b] = core.stage
            wrenches.append((w.fx, w.fy, w.tau))
        self.out[tick % self.ring] = states
        return np.array(wrenches, dtype=np.float64)

    def estimates(self) -> list[Estimate]:
        """Every agent's estimate of the last tick stepped (valid until the next step)."""
        return [core.estimate() for core in self.cores]

    def states(self, tick: int) -> list[StateMsg]:
        """Every agent's message of ``tick`` (one of the last ``ring`` ticks stepped)."""
        return self.out[tick % self.ring]  # type: ignore[return-value]


def inbox_rows(ptr: Sequence[int], ref: Sequence[Sequence[int]]) -> tuple[np.ndarray, np.ndarray]:
    """A CSR's two arrays (``ref`` may be empty)."""
    return np.asarray(ptr, dtype=np.int64), np.asarray(ref, dtype=np.int64).reshape(-1, 3)


def lockstep_inboxes(team: TeamCore, senders: Sequence[Sequence[int]], age: int) -> list[Inbox]:
    """The inboxes of fault-free links of one fixed delay, where every message is due ``age`` ticks after it
    was sent: receiver b gets the messages of ``senders[b]`` (ascending, ``DelayLine``'s order) of tick
    k - age. Static: the inbox of tick k >= age is ``[k % team.ring]`` of the list returned; ticks < age
    have :func:`empty_inbox`."""
    if not 1 <= age < team.ring:
        raise ValueError(f"a message due {age} ticks after it is sent needs a ring of more than {age} slots")
    out = []
    for k in range(team.ring):
        slot = (k - age) % team.ring
        ptr = [0]
        ref = []
        for row in senders:
            ref += [(slot, s, 0) for s in row]
            ptr.append(len(ref))
        out.append(Inbox(team.out, *inbox_rows(ptr, ref)))
    return out


def empty_inbox(team: TeamCore) -> Inbox:
    """No message for anyone."""
    return Inbox(team.out, *inbox_rows([0] * (team.B + 1), []))


def handle_inbox(team: TeamCore, tick: int, due: Sequence[Sequence[tuple[int, int]]]) -> Inbox:
    """The inbox of ``tick`` from each receiver's due handles (send tick, sender), in taking order: the
    messages that a link model delayed, lost, reordered or duplicated (a duplicate is two rows naming one
    message)."""
    ring = team.ring
    ptr = [0]
    ref = []
    for handles in due:
        for t, s in handles:
            if not 0 < tick - t < ring:
                raise ValueError(f"a message of tick {t} is due at {tick}: beyond the OUT ring ({ring} slots)")
            ref.append((t % ring, s, 0))
        ptr.append(len(ref))
    return Inbox(team.out, *inbox_rows(ptr, ref))
