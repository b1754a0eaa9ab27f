"""Plain message types shared by the pure cores, the engines and the wire codec.

They carry no validation: the codec in :mod:`net.schema` validates at the edge and hands the cores
these already-checked objects. Vectors are floats, not arrays, because they are tiny and hot.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True, slots=True)
class Measurement:
    """Simulator -> agent: the noisy velocity of agent ``agent``'s contact point at ``tick`` (m/s, world)."""

    tick: int
    agent: int
    vx: float
    vy: float


@dataclass(frozen=True, slots=True)
class Wrench:
    """Agent -> simulator: force (N, world frame) at the contact point and torque (N m) for ``tick``."""

    tick: int
    agent: int
    fx: float
    fy: float
    tau: float


@dataclass(frozen=True, slots=True)
class StateMsg:
    """Agent -> one-hop neighbours, once per tick.

    ``vx, vy`` is the sender's measured contact velocity at ``tick`` (so that relative velocities pair
    samples of the same instant). ``shared`` holds the consensus states broadcast to every neighbour,
    by name; ``pair`` holds values meant for one neighbour (keyed by that neighbour's id).
    """

    tick: int
    sender: int
    vx: float
    vy: float
    phase: int = 0
    shared: dict[str, float] = field(default_factory=dict)
    pair: dict[int, tuple[float, ...]] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class Estimate:
    """Agent -> observers: the agent's current estimates.

    ``values`` by name (see ``net.vocabulary.ESTIMATE_NAMES``); ``pairs`` maps each neighbour j to the
    agent's estimate of z_ij = p_Ci - p_Cj (m, world frame).
    """

    tick: int
    agent: int
    values: dict[str, float]
    pairs: dict[int, tuple[float, float]] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class Control:
    """Simulator -> everyone: run lifecycle notices. ``kind`` is 'start', 'progress' or 'done'."""

    kind: str
    tick: int
    ticks: int


@dataclass(frozen=True, slots=True)
class LoadPose:
    """Simulator -> monitors, on recorded ticks: where the load truly is (no daemon reads it; a live view does).

    ``x, y`` the CoM and ``angle`` the orientation (m, rad, world frame); ``pg_x, pg_y`` the geometric
    centre G; ``z`` every agent's z_i = p_Ci - p_G flattened as (x0, y0, x1, y1, ...) (m, world frame).
    """

    tick: int
    x: float
    y: float
    angle: float
    pg_x: float
    pg_y: float
    z: tuple[float, ...] = ()


@dataclass(frozen=True, slots=True)
class AgentReport:
    """Agent -> simulator when the run ends: its receive-side counters, for summary.json.

    ``links`` maps each sender to that link's counters (sent, delivered, dropped, duplicated, late,
    malformed); ``drops`` counts rejected messages by reason; ``timeouts`` counts lockstep waits that
    ran out.
    """

    agent: int
    links: dict[int, dict[str, int]]
    drops: dict[str, int]
    timeouts: int
    ticks: int
