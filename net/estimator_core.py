"""The contract every estimator core keeps, and how the conformance checks drive one (net/conformance.py).

A core is one agent's estimator: a pure function of its tick sequence. Given (tick, own measurement,
inbox of neighbour messages) it returns its outputs; it reads no clock and no global RNG, a seed
fixes it, ticks only increase, and a malformed inbox entry is counted and skipped, never fatal.
Cores keep their own call signatures (``AgentCore.step(tick, vx, vy, inbox)``,
``EstimatorCore.step(tick, z, inbox)``, ``ArmFrontEnd.sense(q, f)``); a :class:`CoreCase` says how
to build, feed and read one. See docs/agent-step.md ("Conformance").
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol, runtime_checkable


@runtime_checkable
class EstimatorCore(Protocol):
    """What every core has: a step from one tick's inputs to its outputs (checked on every core built)."""

    def step(self, tick: int, *inputs: Any) -> Any: ...


class CoreCase(Protocol):
    """How the conformance checks build, feed and read one kind of core."""

    name: str
    has_inbox: bool  # the core takes neighbour messages (else the inbox checks do not apply)
    checks_ticks: bool  # the core sees tick numbers (else the tick check does not apply)

    def make(self, seed: int) -> Any:
        """A fresh core, everything random in it drawn from ``seed``."""

    def inputs(self, seed: int, ticks: int) -> list[tuple[int, Any, list[Any]]]:
        """(tick, measurement, inbox) for ``ticks`` ticks, drawn from ``seed``."""

    def step(self, core: Any, tick: int, measurement: Any, inbox: Sequence[Any]) -> Any:
        """One step of ``core``; returns its outputs (compared by repr)."""

    def malformed(self, entry: Any) -> Any:
        """A broken copy of the valid inbox entry ``entry``."""

    def dropped(self, core: Any) -> int:
        """The inbox entries ``core`` has counted as unusable so far."""
