"""Scenario models: everything a run needs, validated once at the edge.

A scenario is a TOML file (see ``config/scenarios/``); :func:`config.loader.load_scenario` reads it,
applies ``--set key=value`` overrides and reports errors with file, line and field. Every model
forbids unknown keys so that a misspelt key is an error, not a silently ignored value.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from config.agent_params import ControlSpec, DynamicsSpec, EstimatorSpec

Vec2 = tuple[float, float]


class _Strict(BaseModel):
    # allow_inf_nan=False: a NaN or inf in a pose, a size or a delay would silently poison the plant.
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class LoadSpec(_Strict):
    """The rigid planar load. Body frame: origin at the polygon's centroid, axes along the polygon's."""

    shape: Literal["rectangle", "polygon"] = Field("rectangle", description="outline: a width x height rectangle or the given vertices")
    width: float = Field(4.0, gt=0, description="rectangle side along body x (m)")
    height: float = Field(2.2, gt=0, description="rectangle side along body y (m)")
    vertices: list[Vec2] | None = Field(
        None,
        description="polygon vertices (m), counter-clockwise, simple; the body frame is re-centred on their area"
        " centroid, so any origin may be used",
    )
    mass: float = Field(50.0, gt=0, description="kg")
    inertia: float | None = Field(
        None, gt=0, description="about the CoM (kg m^2); default: uniform density over the shape"
    )
    com_offset: Vec2 = Field((0.0, 0.0), description="CoM relative to the centroid, body frame (m)")

    @model_validator(mode="after")
    def _shape_has_geometry(self) -> LoadSpec:
        if self.shape == "polygon" and (self.vertices is None or len(self.vertices) < 3):
            raise ValueError("shape = 'polygon' needs 'vertices' with at least 3 points")
        if self.shape == "polygon" and self.vertices is not None:
            problem = _polygon_problem(self.vertices)
            if problem:
                raise ValueError(f"vertices: {problem}")
        return self


class ContactSpec(_Strict):
    """Where the agents hold the load. ``perimeter`` spaces n points evenly along the outline."""

    layout: Literal["perimeter", "explicit"] = Field("perimeter", description="perimeter: evenly spaced on the outline; explicit: the given points")
    start: float = Field(0.0, ge=0, lt=1, description="perimeter layout: first point as a fraction of the outline")
    points: list[Vec2] | None = Field(None, description="explicit layout: body-frame points (m), one per agent")


class NoiseSpec(_Strict):
    """Velocity-sensor noise of the plant (the agents are told only its level, as a sensor spec)."""

    sigma_v: float = Field(0.3, ge=0, description="std of additive Gaussian noise on each velocity component (m/s)")


class GraphSpec(_Strict):
    """The undirected communication graph; agents numbered from 0 in contact order."""

    topology: Literal["line", "ring", "complete", "explicit"] = Field(
        "line", description="line: i talks to i-1 and i+1; ring: line plus n-1 to 0; complete: all pairs; explicit: edges"
    )
    edges: list[tuple[int, int]] | None = Field(None, description="explicit topology: [i, j] pairs")

    @model_validator(mode="after")
    def _explicit_has_edges(self) -> GraphSpec:
        if self.topology == "explicit" and not self.edges:
            raise ValueError("topology = 'explicit' needs a non-empty 'edges' list")
        return self


class LossSpec(_Strict):
    """Packet loss on one directed link. ``gilbert_elliott`` is a two-state (good/bad) Markov chain."""

    model: Literal["none", "bernoulli", "gilbert_elliott"] = Field("none", description="loss process of the link")
    p: float = Field(0.0, ge=0, le=1, description="bernoulli: loss probability")
    p_good_to_bad: float = Field(0.01, ge=0, le=1, description="gilbert_elliott: per-message probability good -> bad")
    p_bad_to_good: float = Field(0.2, ge=0, le=1, description="gilbert_elliott: per-message probability bad -> good (mean burst 1/p)")
    loss_good: float = Field(0.0, ge=0, le=1, description="gilbert_elliott: loss probability in the good state")
    loss_bad: float = Field(0.8, ge=0, le=1, description="gilbert_elliott: loss probability in the bad state")


class PartitionSpec(_Strict):
    """A network partition over a time window: the listed links carry nothing from ``start`` to ``end``.

    Give either ``cut`` (undirected edges, both directions cut) or ``groups`` (every edge between two
    different groups is cut; agents listed in no group form one more group together, so
    ``groups = [[0, 1, 2]]`` splits agents 0-2 from the rest). A message sent on a cut link at a tick
    t with ``start <= t * dt < end`` is lost (counted as ``partitioned``, or as ``stale_age`` with
    ``drop = "stale_age"``); the links heal at ``end``.
    """

    start: float = Field(..., ge=0, description="time the partition begins (s, simulated time)")
    end: float = Field(..., gt=0, description="time the links heal (s, simulated time; after start)")
    cut: list[tuple[int, int]] | None = Field(None, description="undirected edges [i, j] cut during the window")
    groups: list[list[int]] | None = Field(
        None, description="disjoint groups of agents; every edge between two groups is cut during the window"
    )
    drop: Literal["partitioned", "stale_age"] = Field(
        "partitioned",
        description="what the window models: partitioned (the links carry nothing) or stale_age (the states "
                    "arrive older than timing.max_age_s and the receiver drops them unused, as a heavily loaded "
                    "machine does in real time; reproducible in lockstep); counted under this name in the "
                    "link statistics",
    )

    @model_validator(mode="after")
    def _one_kind(self) -> PartitionSpec:
        if self.end <= self.start:
            raise ValueError(f"end ({self.end}) must be after start ({self.start})")
        if (self.cut is None) == (self.groups is None):
            raise ValueError("give exactly one of 'cut' (edges) or 'groups' (agent groups)")
        if self.cut is not None and any(i == j or min(i, j) < 0 for i, j in self.cut):
            raise ValueError("cut: every edge is a pair of distinct non-negative agent ids")
        if self.groups is not None:
            flat = [i for g in self.groups for i in g]
            if not self.groups or any(not g for g in self.groups):
                raise ValueError("groups: give at least one non-empty group")
            if len(set(flat)) != len(flat) or min(flat) < 0:
                raise ValueError("groups: the groups must be disjoint lists of non-negative agent ids")
        return self

    def cuts(self, i: int, j: int) -> bool:
        """True if this partition cuts the link between agents ``i`` and ``j`` (either direction)."""
        if self.cut is not None:
            return any((a, b) in ((i, j), (j, i)) for a, b in self.cut)
        assert self.groups is not None

        def group(k: int) -> int:
            for g, members in enumerate(self.groups):  # type: ignore[arg-type]
                if k in members:
                    return g
            return -1  # the implicit group of agents listed nowhere

        return group(i) != group(j)


class LinkSpec(_Strict):
    """Fault model applied at the receiving end of every directed agent-to-agent link.

    Delays are in ticks in lockstep mode and in seconds in real-time mode; jitter is uniform in
    [0, jitter] added to the fixed delay.
    """

    delay_ticks: int = Field(0, ge=0, description="lockstep: fixed delay (ticks) on top of the one-tick exchange")
    jitter_ticks: int = Field(0, ge=0, description="lockstep: extra delay uniform in 0..jitter_ticks (reorders)")
    delay_s: float = Field(0.0, ge=0, description="realtime: fixed delay (s)")
    jitter_s: float = Field(0.0, ge=0, description="realtime: extra delay uniform in [0, jitter_s] (s)")
    loss: LossSpec = LossSpec()
    duplicate: float = Field(0.0, ge=0, le=1, description="probability that a delivered message arrives twice")
    partitions: list[PartitionSpec] = Field(
        [], description="time windows during which some links carry nothing (see PartitionSpec); they heal at the end"
    )


class InitialSpec(_Strict):
    """The load's state at t = 0 (world frame)."""

    position: Vec2 = Field((0.0, 0.0), description="CoM position at t = 0, world frame (m)")
    angle: float = Field(0.0, description="body x axis from world x at t = 0, counter-clockwise (rad)")
    v_c: Vec2 = Field((0.0, 0.0), description="CoM velocity at t = 0 (m/s)")
    omega: float = Field(0.0, description="angular rate at t = 0 (rad/s)")


class TimingSpec(_Strict):
    """Waits of the daemons. A timeout is counted in summary.json, never fatal."""

    startup_timeout_s: float = Field(30.0, gt=0, description="wait for every daemon to come alive")
    wrench_timeout_s: float = Field(2.0, gt=0, description="lockstep: simulator waits this long for a wrench")
    neighbour_timeout_s: float = Field(2.0, gt=0, description="lockstep: agent waits this long for a neighbour")
    rejoin_after_s: float = Field(
        0.5, gt=0,
        description="lockstep: an agent whose next measurement is missing (cut off, restarted) takes a later one "
                    "and rejoins at its tick after this long; a forged early one is ignored while the real stream goes on",
    )
    max_age_s: float = Field(
        0.5, gt=0,
        description="realtime: an agent drops neighbour states older than this when it steps (ticks since they "
                    "were sent x dt: wall-clock seconds in real time), counted as stale_age in summary.json drops",
    )
    sim_restart_wait_s: float = Field(
        30.0, gt=0,
        description="a restarted simulator (resuming from its journal) waits this long for the agents that were "
                    "alive before it died; those still missing are recorded as agent_down",
    )
    sim_lost_timeout_s: float = Field(
        300.0, gt=0,
        description="an agent daemon whose simulator went away mid-run waits this long (wall-clock s) for it to "
                    "come back (a restart resumes the run), then sends its report and exits with status 1",
    )


class RecordSpec(_Strict):
    """What the run directory keeps. Samples (the measured data) are always kept at full rate."""

    every_ticks: int = Field(
        10, ge=1, description="keep estimates, pairs and truth every this many ticks (agents publish estimates only then)"
    )
    batch_fit: bool = Field(
        False,
        description="at the end of the run, fit the centralized batch estimator to all of samples.csv and add "
                    "'centralized' and 'distributed_over_centralized' to summary.json (seconds to a minute of "
                    "CPU; `coload run` turns it on unless --no-batch-fit, library and test runs leave it off)",
    )


class FrictionSpec(_Strict):
    """Floor friction on the load (the agents' model has none). Forces act at the CoM, torques about it."""

    viscous: float = Field(0.0, ge=0, description="viscous floor friction on the CoM: F = -viscous v_C (N s/m)")
    coulomb: float = Field(
        0.0, ge=0,
        description="Coulomb friction magnitude on the CoM (N), smoothed: F = -coulomb tanh(|v_C|/coulomb_speed) v_C/|v_C|",
    )
    coulomb_speed: float = Field(0.01, gt=0, description="smoothing speed of the Coulomb friction (m/s)")
    rotational: float = Field(0.0, ge=0, description="rotational damping about the CoM: torque = -rotational omega (N m s)")


class SensorEffectSpec(_Strict):
    """Imperfections of every agent's velocity sensor (on top of noise.sigma_v); truth stays the true state."""

    delay: float = Field(
        0.0, ge=0,
        description="measurement delay (s), rounded to whole ticks: the measurement at tick k is the true "
                    "contact-point velocity of tick k - round(delay/dt) (of tick 0 before that) plus noise",
    )
    velocity_bias: Vec2 = Field((0.0, 0.0), description="constant bias added to every measured velocity, world frame (m/s)")


class LoadChangeSpec(_Strict):
    """A step change of the load at simulated time t (Algorithm 2 of paper 000): mass, inertia and CoM jump.

    The contact points stay where they are on the body; the rigid-body velocity field is continuous
    at the change (every point of the body keeps its velocity; omega is unchanged).
    """

    t: float = Field(..., ge=0, description="time of the change (s, simulated; applied at the first tick k with k dt >= t)")
    mass: float = Field(..., gt=0, description="new mass (kg)")
    inertia: float | None = Field(
        None, gt=0, description="new J about the new CoM (kg m^2); default: uniform density over the shape"
    )
    com_offset: Vec2 | None = Field(
        None, description="new CoM relative to the polygon centroid, body frame (m), like load.com_offset; default: unchanged"
    )


class PeriodicForceSpec(_Strict):
    """An external force that oscillates along a fixed world direction: F(t) = amplitude sin(2 pi t / period_s) u."""

    amplitude: float = Field(0.0, ge=0, description="peak force on the CoM (N); 0: no periodic force")
    period_s: float = Field(10.0, gt=0, description="period of the oscillation (s, simulated)")
    direction_deg: float = Field(
        0.0, description="direction u of the force from the world x axis (degrees, counter-clockwise)"
    )


class PlantSpec(_Strict):
    """Physical effects of the plant that the agents' model lacks. Never told to the agents (see docs/diagnose.md)."""

    friction: FrictionSpec = FrictionSpec()
    sensor: SensorEffectSpec = SensorEffectSpec()
    actuator_gain: float = Field(
        1.0, gt=0, description="factor on the applied wrench: the plant gets actuator_gain times what the agents command (-)"
    )
    external_force: Vec2 = Field(
        (0.0, 0.0), description="constant external force on the CoM, world frame, e.g. a slope m g sin(alpha) (N)"
    )
    periodic_force: PeriodicForceSpec = Field(
        PeriodicForceSpec(),
        description="an oscillating external force on the CoM, world frame (outside the agents' online vocabulary)",
    )
    load_changes: list[LoadChangeSpec] = Field(
        [], description="step changes of mass, inertia and CoM during the run, in time order"
    )

    @model_validator(mode="after")
    def _changes_in_order(self) -> PlantSpec:
        times = [c.t for c in self.load_changes]
        if any(b <= a for a, b in zip(times, times[1:])):
            raise ValueError(f"load_changes: times must be strictly increasing (got {times})")
        return self

    @property
    def active(self) -> bool:
        """True if any effect is configured (with none, the plant runs its untouched nominal path)."""
        return self != PlantSpec()


class ArmMotionSpec(_Strict):
    """The rigid rocking motion every arm tracks at its grasp point (agents/arm.py MotionPlan).

    theta(t) = amplitude sin(2 pi t / period) g(t) about the contacts' centroid at t = 0, plus a
    translation shift sin(2 pi t / shift_period) g(t) along shift_angle; g(t) = 1 - exp(-t / ramp).
    """

    amplitude: float = Field(0.8, gt=0, lt=1.6, description="rotation amplitude theta0 (rad)")
    period: float = Field(6.0, gt=0, description="period of the rocking rotation (s)")
    ramp: float = Field(1.5, gt=0, description="time constant of the start-up envelope g(t) (s)")
    shift: float = Field(0.1, ge=0, description="amplitude of the translation of the rotation centre (m)")
    shift_period: float = Field(4.3, gt=0, description="period of the translation (s)")
    shift_angle: float = Field(0.3, description="direction of the translation, world frame, from +x (rad)")
    kp: float = Field(400.0, ge=0, description="grasp-point tracking stiffness: f = kp (p_ref - p) + kd (v_ref - v) (N/m)")
    kd: float = Field(80.0, ge=0, description="grasp-point tracking damping, on the agent's sensed velocity (N s/m)")


class ArmObserverSpec(_Strict):
    """The paper-004 speed observer each arm runs on its own model (agents/speed_observer.py)."""

    k1: float = Field(20.0, gt=4, description="rate of the ideal error dynamics, > 4 (paper 004 eq. 55) (1/s)")
    k2: float = Field(8.0, gt=0, description="extra damping of e_y (eq. 53) (1/s)")
    k3: float = Field(25.0, gt=0, description="extra damping of e_x (eq. 54) (1/s)")
    c_r: float = Field(1e-3, gt=0, description="lower bound of the dynamic scaling r (eq. 38) (-)")
    r0: float = Field(0.01, gt=0, description="initial r; must exceed c_r (-)")
    nodes: int = Field(8, ge=2, le=64, description="Gauss-Legendre nodes per integral of beta (eq. 12)")
    substeps: int = Field(1, ge=1, le=20, description="RK4 steps of the observer per encoder sample")
    initial_error: Vec2 = Field(
        (0.5, -0.5), description="initial joint-speed estimate minus the true (zero) speed, to show convergence (rad/s)"
    )


class ArmsSpec(_Strict):
    """Agents that are planar two-link arms on fixed bases (``coload arms run``).

    Horizontal (SCARA-like) arms with uniform links hold the load at the contact points through free
    pivots, sense joint angles and the wrist force, and have no speed sensor. Only ``coload arms run``
    reads this section; the other engines ignore it.
    """

    l1: float = Field(0.8, gt=0, description="length of the upper link (m)")
    l2: float = Field(0.8, gt=0, description="length of the forearm (m)")
    m1: float = Field(4.0, gt=0, description="mass of the upper link, uniform rod (kg)")
    m2: float = Field(2.0, gt=0, description="mass of the forearm, uniform rod (kg)")
    bases: list[Vec2] | None = Field(
        None,
        description="world positions of the arms' bases, one per agent (m); default: each base on the ray from the "
                    "contacts' centroid through its contact point, base_offset beyond the contact",
    )
    base_offset: float = Field(0.6, gt=0, description="default base placement: distance beyond the contact point (m)")
    elbow: Literal[-1, 1] = Field(1, description="elbow branch of the initial inverse kinematics (+1 or -1)")
    encoder_sigma: float = Field(5e-5, ge=0, description="std of the joint-encoder noise (rad)")
    force_sigma: float = Field(0.05, ge=0, description="std of the wrist force-sensor noise per component (N)")
    substeps: int = Field(10, ge=1, le=100, description="pymunk steps per tick (the pivot chain needs short steps)")
    solver_iterations: int = Field(30, ge=1, le=1000, description="pymunk constraint-solver iterations per step")
    sigma_v_assumed: float = Field(
        0.02, gt=0,
        description="contact-velocity noise the arm agents tell their AgentCore (m/s): the observer's error level "
                    "(the velocity-measuring comparison run uses noise.sigma_v)",
    )
    motion: ArmMotionSpec = ArmMotionSpec()
    observer: ArmObserverSpec = ArmObserverSpec()


class Scenario(_Strict):
    name: str = Field("unnamed", description="run label (free text)")
    n: int = Field(10, ge=2, le=1000, description="number of agents")
    dt: float = Field(0.01, gt=0, description="tick length (s)")
    duration: float = Field(60.0, gt=0, description="simulated time (s)")
    stop_after_done_s: float | None = Field(
        None, ge=0,
        description="end the run this long (s) after every agent's recorded estimates show the done stage of "
                    "Algorithm 1 (both engines, same tick; the duration stays the cap); unset: run the whole "
                    "duration",
    )
    seed: int = Field(0, ge=0, description="run seed: sensor noise and every link's faults derive from it")
    mode: Literal["lockstep", "realtime"] = Field(
        "lockstep", description="lockstep: the simulator is the clock (reproducible); realtime: wall-clock pace"
    )
    load: LoadSpec = LoadSpec()
    contacts: ContactSpec = ContactSpec()
    noise: NoiseSpec = NoiseSpec()
    graph: GraphSpec = GraphSpec()
    link: LinkSpec = LinkSpec()
    initial: InitialSpec = InitialSpec()
    control: ControlSpec = ControlSpec()
    estimator: EstimatorSpec = EstimatorSpec()
    dynamics: DynamicsSpec = DynamicsSpec()
    timing: TimingSpec = TimingSpec()
    record: RecordSpec = RecordSpec()
    plant: PlantSpec = PlantSpec()
    arms: ArmsSpec | None = Field(
        None, description="agents are two-link arms on fixed bases (only `coload arms run` reads it; see ArmsSpec)"
    )

    @model_validator(mode="after")
    def _consistent(self) -> Scenario:
        # Messages start with the dotted field they concern: config.loader turns that prefix into the
        # error's field and file line (a model-level validator has no location of its own).
        if self.contacts.layout == "explicit":
            pts = self.contacts.points
            if pts is None or len(pts) != self.n:
                got = "none" if pts is None else len(pts)
                raise ValueError(f"contacts.points: must list exactly n = {self.n} points (got {got})")
            if len(set(pts)) != len(pts):
                raise ValueError("contacts.points: contact points must be distinct")
        for i, j in self.graph.edges or ():
            if not (0 <= i < self.n and 0 <= j < self.n) or i == j:
                raise ValueError(f"graph.edges: [{i}, {j}] is not a pair of distinct agents in 0..{self.n - 1}")
        for p, part in enumerate(self.link.partitions):
            ids = [i for e in part.cut or () for i in e] + [i for g in part.groups or () for i in g]
            bad = [i for i in ids if i >= self.n]
            if bad:
                raise ValueError(f"link.partitions: partition {p} names agent {bad[0]}, not in 0..{self.n - 1}")
            edges = set(self.edges())
            for i, j in part.cut or ():
                if (min(i, j), max(i, j)) not in edges:
                    raise ValueError(f"link.partitions: partition {p} cuts [{i}, {j}], not an edge of the graph")
        if self.control.law and self.dynamics.algorithm == "none":
            raise ValueError('control.law: a law acts where the dynamical phase allows one: set dynamics.algorithm '
                             '= "sequential" (from done on) or "background"')
        dyn = self.dynamics
        if dyn.online_detection and (dyn.algorithm == "none" or dyn.monitor_window_s <= 0):
            raise ValueError('dynamics.online_detection: needs the dynamical phase (dynamics.algorithm "sequential" or '
                             '"background") and its windows (dynamics.monitor_window_s > 0)')
        if self.arms is not None and self.arms.bases is not None and len(self.arms.bases) != self.n:
            raise ValueError(f"arms.bases: must list exactly n = {self.n} bases (got {len(self.arms.bases)})")
        if self.ticks < 1:
            raise ValueError(f"duration: {self.duration:g} s is less than one tick (dt = {self.dt:g} s): "
                             "the run would record nothing")
        for field, offset in [("load.com_offset", self.load.com_offset)] + [
                (f"plant.load_changes: change {k}'s com_offset", c.com_offset)
                for k, c in enumerate(self.plant.load_changes) if c.com_offset is not None]:
            if not _inside(offset, _outline_about_centroid(self.load)):
                raise ValueError(f"{field}: ({offset[0]:g}, {offset[1]:g}) lies outside the load's outline "
                                 "(the CoM of a rigid load is inside its convex hull)")
        pf = self.plant.periodic_force
        if pf.amplitude > 0 and pf.period_s < 4 * self.dt:
            raise ValueError(f"plant.periodic_force.period_s: {pf.period_s:g} s is shorter than four ticks "
                             f"(dt = {self.dt:g} s): the sampled force would alias")
        if not _connected(self.n, self.edges()):
            field = "graph.edges" if self.graph.topology == "explicit" else "graph"
            raise ValueError(f"{field}: the communication graph must be connected (agents 0..{self.n - 1})")
        return self

    @property
    def ticks(self) -> int:
        return int(round(self.duration / self.dt))

    def edges(self) -> list[tuple[int, int]]:
        """Undirected edges (i < j), sorted."""
        n = self.n
        topo = self.graph.topology
        if topo == "line":
            e = [(i, i + 1) for i in range(n - 1)]
        elif topo == "ring":
            e = [(i, i + 1) for i in range(n - 1)] + ([(0, n - 1)] if n > 2 else [])
        elif topo == "complete":
            e = [(i, j) for i in range(n) for j in range(i + 1, n)]
        else:
            e = [(min(i, j), max(i, j)) for i, j in self.graph.edges or ()]
        return sorted(set(e))

    def neighbours(self) -> list[list[int]]:
        nb: list[list[int]] = [[] for _ in range(self.n)]
        for i, j in self.edges():
            nb[i].append(j)
            nb[j].append(i)
        return [sorted(x) for x in nb]

    def agent_view(self, agent: int) -> AgentView:
        """What agent ``agent`` is told of this scenario (see :class:`AgentView`)."""
        if not 0 <= agent < self.n:
            raise ValueError(f"agent {agent} is not an agent of this scenario (0..{self.n - 1})")
        sigma = self.estimator.sigma_v
        return AgentView(
            agent=agent, n=self.n, dt=self.dt, duration=self.duration, seed=self.seed, mode=self.mode,
            neighbours=tuple(self.neighbours()[agent]), sigma_v=self.noise.sigma_v if sigma is None else sigma,
            estimator=self.estimator, control=self.control, dynamics=self.dynamics, timing=self.timing,
            link=self.link, record=self.record, stop_after_done_s=self.stop_after_done_s,
        )  # fmt: skip


@dataclass(frozen=True)
class AgentView:
    """What one agent knows of a scenario: the team's size and timing, its own neighbours, its
    sensor's noise level, its own parameters and the links that end at it. Nothing of the load,
    the plant's effects or the rest of the graph: the agent daemon and the core are built from this
    alone (docs/agent-step.md)."""

    agent: int
    n: int
    dt: float
    duration: float
    seed: int
    mode: Literal["lockstep", "realtime"]
    neighbours: tuple[int, ...]
    sigma_v: float
    estimator: EstimatorSpec
    control: ControlSpec
    dynamics: DynamicsSpec
    timing: TimingSpec
    link: LinkSpec
    record: RecordSpec
    stop_after_done_s: float | None

    @property
    def ticks(self) -> int:
        return int(round(self.duration / self.dt))


def _outline_about_centroid(load: LoadSpec) -> list[Vec2]:
    """The outline's vertices about its area centroid (the body frame's origin)."""
    if load.shape == "rectangle":
        w, h = 0.5 * load.width, 0.5 * load.height
        return [(-w, -h), (w, -h), (w, h), (-w, h)]
    v = load.vertices or []
    m = len(v)
    cross = [v[k][0] * v[(k + 1) % m][1] - v[(k + 1) % m][0] * v[k][1] for k in range(m)]
    a3 = 3.0 * sum(cross)  # six times the area, over two
    cx = sum((v[k][0] + v[(k + 1) % m][0]) * cross[k] for k in range(m)) / a3
    cy = sum((v[k][1] + v[(k + 1) % m][1]) * cross[k] for k in range(m)) / a3
    return [(x - cx, y - cy) for x, y in v]


def _inside(p: Vec2, outline: list[Vec2]) -> bool:
    """Whether ``p`` lies inside the closed polygon or on its boundary (even-odd rule; the boundary counts)."""
    x, y = p
    m = len(outline)
    inside = False
    for k in range(m):
        (x1, y1), (x2, y2) = outline[k], outline[(k + 1) % m]
        cross = (x2 - x1) * (y - y1) - (y2 - y1) * (x - x1)
        if cross == 0 and min(x1, x2) <= x <= max(x1, x2) and min(y1, y2) <= y <= max(y1, y2):
            return True
        if (y1 > y) != (y2 > y) and x < x1 + (y - y1) * (x2 - x1) / (y2 - y1):
            inside = not inside
    return inside


def _polygon_problem(vertices: list[Vec2]) -> str | None:
    """Why the outline cannot be a load (None if it can): degenerate, clockwise or self-intersecting."""
    m = len(vertices)
    cross2 = sum(
        vertices[k][0] * vertices[(k + 1) % m][1] - vertices[(k + 1) % m][0] * vertices[k][1] for k in range(m)
    )
    if cross2 == 0 or len(set(vertices)) != m:
        return "the polygon is degenerate (zero area or repeated vertices)"
    if cross2 < 0:
        return "the vertices run clockwise; list them counter-clockwise"
    for a in range(m):
        for b in range(a + 2, m):
            if a == 0 and b == m - 1:
                continue  # adjacent through the closing edge
            if _segments_cross(vertices[a], vertices[(a + 1) % m], vertices[b], vertices[(b + 1) % m]):
                return f"the outline intersects itself (edges {a} and {b})"
    return None


def _segments_cross(p1: Vec2, p2: Vec2, q1: Vec2, q2: Vec2) -> bool:
    """Closed-segment intersection test (touching counts: a pinched outline is not simple either)."""

    def orient(a: Vec2, b: Vec2, c: Vec2) -> float:
        return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])

    def on_segment(a: Vec2, b: Vec2, c: Vec2) -> bool:
        return min(a[0], b[0]) <= c[0] <= max(a[0], b[0]) and min(a[1], b[1]) <= c[1] <= max(a[1], b[1])

    d1, d2 = orient(q1, q2, p1), orient(q1, q2, p2)
    d3, d4 = orient(p1, p2, q1), orient(p1, p2, q2)
    if ((d1 > 0 > d2) or (d1 < 0 < d2)) and ((d3 > 0 > d4) or (d3 < 0 < d4)):
        return True
    return (
        (d1 == 0 and on_segment(q1, q2, p1))
        or (d2 == 0 and on_segment(q1, q2, p2))
        or (d3 == 0 and on_segment(p1, p2, q1))
        or (d4 == 0 and on_segment(p1, p2, q2))
    )


def _connected(n: int, edges: list[tuple[int, int]]) -> bool:
    adj: list[list[int]] = [[] for _ in range(n)]
    for i, j in edges:
        adj[i].append(j)
        adj[j].append(i)
    seen = {0}
    stack = [0]
    while stack:
        for j in adj[stack.pop()]:
            if j not in seen:
                seen.add(j)
                stack.append(j)
    return len(seen) == n
