"""The plant: one rigid planar load, pushed at n contact points, integrated in closed form.

Pure: no clock, no sockets, no global RNG. The daemon owns time and transport; this module owns
physics and the sensor model, so that the in-process engine and the daemon share it unchanged.

Design: the state is the centre of mass p_C, the angle, v_C and omega, in Python floats; the outline
and the contact points are stored relative to the CoM (nothing collides). Per tick the agents'
wrenches are reduced to one resultant force and torque about the CoM (vectorised) and one step of
semi-implicit (symplectic) Euler advances the state: positions with the old velocities, then the
velocities, so the wrench of tick k shows in the velocities (and so in the measurements) at tick
k + 1 and in the pose from tick k + 2, and free motion conserves energy and momentum exactly. The
step is pymunk's (Chipmunk's ``cpBodyUpdatePosition``/``cpBodyUpdateVelocity`` with no gravity and
no damping) operation for operation, including the pose readout through the body transform, so its
bits equal a pymunk body's at every tick (tests/test_plant.py); the plant's state is the truth,
whatever the integrator's discretisation error against the continuous model. Two-link arms need
pymunk's constraint solver: simulator/arms.py steps the load in a pymunk space and hands the state
back through :meth:`Plant.take_state`. Docs: docs/fast-core-plan.md, S8.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from config.scenario import Scenario
from simulator import geometry
from simulator.effects import Effects

# Separates the sensor stream from every other stream derived from the same run seed
# (the link fault model seeds from (seed, sender, receiver)).
_SENSOR_STREAM = 0x53454E53  # "SENS"

Vec2 = tuple[float, float]


def _outline_about_centroid(scenario: Scenario) -> np.ndarray:
    """The outline in the body frame whose origin is the polygon's area centroid."""
    load = scenario.load
    if load.shape == "rectangle":
        return geometry.rectangle(load.width, load.height)
    v = np.asarray(load.vertices, dtype=float)
    return v - geometry.centroid(v)


def _contacts_about_centroid(scenario: Scenario, outline: np.ndarray) -> np.ndarray:
    c = scenario.contacts
    if c.layout == "explicit":
        return np.asarray(c.points, dtype=float)
    return geometry.perimeter_points(outline, scenario.n, c.start)


def load_polygon_body(scenario: Scenario) -> list[Vec2]:
    """Outline of the load relative to the CoM, body frame (m), counter-clockwise."""
    off = np.asarray(scenario.load.com_offset, dtype=float)
    return [(float(x), float(y)) for x, y in _outline_about_centroid(scenario) - off]


def contact_points_body(scenario: Scenario) -> list[Vec2]:
    """Contact points relative to the CoM, body frame (m), in agent order.

    ``perimeter``: n points evenly spaced in arc length along the outline, counter-clockwise from
    fraction ``start`` (a rectangle's outline starts at its bottom-left corner). ``explicit``: the
    given points, which are relative to the polygon's centroid.
    """
    outline = _outline_about_centroid(scenario)
    off = np.asarray(scenario.load.com_offset, dtype=float)
    return [(float(x), float(y)) for x, y in _contacts_about_centroid(scenario, outline) - off]


def load_inertia(scenario: Scenario) -> float:
    """J about the CoM: the explicit value, else a uniform lamina's moment moved to the offset CoM."""
    load = scenario.load
    if load.inertia is not None:
        return load.inertia
    j_centroid = load.mass * geometry.polar_moment_per_mass(_outline_about_centroid(scenario))
    ox, oy = load.com_offset
    return j_centroid + load.mass * (ox * ox + oy * oy)  # parallel-axis theorem


def sensor_rng(seed: int) -> np.random.Generator:
    """The measurement-noise stream: a function of the run seed alone, independent of other streams."""
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence(seed, spawn_key=(_SENSOR_STREAM,))))


@dataclass(frozen=True, slots=True)
class Truth:
    """Everything the simulator knows at one tick; world frame, SI units (see paper 000, Sec. II)."""

    tick: int
    t: float
    x: float  # p_C
    y: float
    angle: float
    vc: Vec2
    omega: float
    zc: Vec2  # p_G - p_C
    pg: Vec2  # centroid of the contact points
    zi: tuple[Vec2, ...]  # p_Ci - p_G per agent
    mass: float
    inertia: float


class Plant:
    """The load's rigid-body dynamics plus the contact-point velocity sensor.

    Speed: every per-agent quantity is a fixed body-frame array times a small matrix built from the
    current pose, so a tick costs a few numpy calls whatever n is. In particular the resultant
    torque uses rotation invariance of the cross product, sum_i (R r_i) x f_i = tr(M R) with
    M = sum_i r_i^perp f_i^T, and M comes out of one matmul of the flat wrench vector with a constant
    matrix (no per-tick rebuild of the grasp matrix). The step itself is a dozen float operations.
    """

    __slots__ = (
        "n", "dt", "sigma_v", "mass", "inertia", "tick", "_m_inv", "_i_inv", "_p",
        "_r", "_rbar", "_rrel_t", "_perp1", "_reduce", "_pos", "_vel", "_angle", "_omega", "_c", "_s", "effects",
    )  # fmt: skip

    def __init__(self, scenario: Scenario) -> None:
        self.n = scenario.n
        self.dt = scenario.dt
        self.sigma_v = scenario.noise.sigma_v
        self.tick = 0
        self._set_contacts(np.asarray(contact_points_body(scenario), dtype=float))
        self._set_mass(scenario.load.mass, load_inertia(scenario))
        ini = scenario.initial
        x, y = ini.position
        self._c, self._s = 1.0, 0.0  # the pose is placed at angle 0, then turned (pymunk's order of setters)
        self._place(float(x), float(y))
        self._turn(float(ini.angle))
        vx, vy = ini.v_c
        self._vel = (float(vx), float(vy))
        self._omega = float(ini.omega)
        self.effects = Effects.build(scenario, _outline_about_centroid(scenario))
        if self.effects is not None:
            self.effects.start(self)

    def _set_contacts(self, r: np.ndarray) -> None:
        """Contact points (n, 2) relative to the CoM, body frame, and the constant matrices built from them."""
        n = self.n
        self._r = r
        self._rbar = (float(r[:, 0].mean()), float(r[:, 1].mean()))  # p_G - p_C, body frame
        self._rrel_t = np.ascontiguousarray((r - self._rbar).T)  # z_i in the body frame, (2, n)
        perp = np.stack((-r[:, 1], r[:, 0]), axis=1)  # r_i^perp, body frame
        self._perp1 = np.hstack((perp, np.ones((n, 1))))  # [r_i^perp | 1]: contact velocity = this @ K
        # Flat wrench (fx0, fy0, tau0, fx1, ...) @ _reduce = (sum fx, sum fy, sum tau, M00, M01, M10, M11).
        red = np.zeros((3 * n, 7))
        red[0::3, 0] = 1.0
        red[1::3, 1] = 1.0
        red[2::3, 2] = 1.0
        red[0::3, 3] = perp[:, 0]
        red[1::3, 4] = perp[:, 0]
        red[0::3, 5] = perp[:, 1]
        red[1::3, 6] = perp[:, 1]
        self._reduce = red

    def _set_mass(self, mass: float, inertia: float) -> None:
        self.mass = mass
        self.inertia = inertia
        self._m_inv = 1.0 / mass
        self._i_inv = 1.0 / inertia

    # The pose goes through a body transform as in Chipmunk (centre of gravity at the origin): the
    # stored CoM ``_p`` is placed as R 0 + position and read as R 0 + (p - R 0), whose zero products
    # only ever decide the sign of a zero coordinate, which the CSVs show (repr).
    def _place(self, x: float, y: float) -> None:
        """Puts the CoM at (x, y) under the current rotation (``cpBodySetPosition``)."""
        c, s = self._c, self._s
        self._p = ((c * 0.0 + -s * 0.0) + x, (s * 0.0 + c * 0.0) + y)
        self._read_pose()

    def _turn(self, angle: float) -> None:
        """Sets the angle and the rotation with it (``cpBodySetAngle``)."""
        self._angle = angle
        self._c = math.cos(angle)
        self._s = math.sin(angle)
        self._read_pose()

    def _read_pose(self) -> None:
        c, s = self._c, self._s
        px, py = self._p
        self._pos = ((c * 0.0 + -s * 0.0) + (px - (0.0 * c - 0.0 * s)),
                     (s * 0.0 + c * 0.0) + (py - (0.0 * s + 0.0 * c)))

    def _integrate(self, fx: float, fy: float, torque: float) -> None:
        """One semi-implicit Euler step under the resultant: the pose with the old velocities (the zero
        bias velocities included: they turn a -0.0 speed into +0.0), then the velocities."""
        dt = self.dt
        vx, vy = self._vel
        w = self._omega
        px, py = self._p
        self._p = (px + (vx + 0.0) * dt, py + (vy + 0.0) * dt)
        self._turn(self._angle + (w + 0.0) * dt)
        self._vel = (vx + (0.0 + fx * self._m_inv) * dt, vy + (0.0 + fy * self._m_inv) * dt)
        self._omega = w + torque * self._i_inv * dt

    def take_state(self, position: Vec2, velocity: Vec2, angle: float, omega: float) -> None:
        """The load's state after a step taken elsewhere (the arms' pymunk space); ``tick`` is the caller's."""
        self._turn(angle)
        self._p = self._pos = (position[0], position[1])
        self._vel = (velocity[0], velocity[1])
        self._omega = omega

    @property
    def com_velocity(self) -> Vec2:
        """v_C, world frame."""
        return self._vel

    @property
    def angular_velocity(self) -> float:
        """omega."""
        return self._omega

    def change_load(self, mass: float, inertia: float, com_shift: np.ndarray) -> None:
        """The load's mass, inertia (about its new CoM) and CoM move by ``com_shift`` (body frame); the
        contact points stay on the body and every body point keeps its velocity."""
        c, s = self._c, self._s
        sx, sy = float(com_shift[0]), float(com_shift[1])
        dw = (c * sx - s * sy, s * sx + c * sy)  # world frame
        w = self._omega
        self._place(self._pos[0] + dw[0], self._pos[1] + dw[1])
        self._vel = (self._vel[0] - w * dw[1], self._vel[1] + w * dw[0])  # v of the new CoM point
        self._set_mass(mass, inertia)
        self._set_contacts(self._r - com_shift)

    def contact_velocities(self) -> np.ndarray:
        """v_Ci = v_C + omega R r_i^perp (= v_C + omega (p_Ci - p_C)^perp, perp = +90 deg rotation)."""
        c, s, w = self._c, self._s, self._omega
        vx, vy = self._vel
        k = np.array(((w * c, w * s), (-w * s, w * c), (vx, vy)))
        return self._perp1 @ k

    def velocities(self) -> list[Vec2]:
        """True world-frame velocity of every contact point now."""
        return list(map(tuple, self.contact_velocities().tolist()))

    def measure(self, rng: np.random.Generator) -> np.ndarray:
        """(n, 2): velocities() plus N(0, sigma_v^2 I) noise; one draw of shape (n, 2) per call (+ sensor
        effects). Callers that pass the values on as numbers take ``.tolist()`` (Python floats)."""
        if self.effects is not None:
            return self.effects.measure(self, rng)
        return self.contact_velocities() + rng.normal(0.0, self.sigma_v, size=(self.n, 2))

    def apply_and_step(self, wrenches: np.ndarray | Sequence[tuple[float, float, float]]) -> None:
        """Apply each agent's (fx, fy, tau) at its contact point's current world position; advance dt.
        ``wrenches`` is the (n, 3) float array (taken as is) or any sequence of n triples.

        Raises ValueError for a wrong count, a malformed triple or a non-finite value: a bad wrench
        must never reach the integrator, where it would corrupt the truth for the rest of the run.
        """
        try:
            w = np.asarray(wrenches, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"wrenches must be {self.n} (fx, fy, tau) number triples: {exc}") from None
        if w.shape != (self.n, 3):
            raise ValueError(f"wrenches must have shape ({self.n}, 3), got {w.shape}")
        # Every wrench entry has a unit coefficient in (fx, fy, tau), so a NaN or inf anywhere (or
        # finite values large enough to overflow) shows up there; errstate keeps that path quiet.
        with np.errstate(all="ignore"):
            fx, fy, tau, m00, m01, m10, m11 = (w.reshape(-1) @ self._reduce).tolist()
        if not (math.isfinite(fx) and math.isfinite(fy) and math.isfinite(tau)):
            bad = sorted({int(i) for i in np.argwhere(~np.isfinite(w))[:, 0]})
            raise ValueError(f"non-finite wrench from agent(s) {bad}" if bad else "resultant wrench overflows")
        c, s = self._c, self._s
        torque = tau + m00 * c + m01 * s - m10 * s + m11 * c  # tau + tr(M R)
        effects = self.effects
        if effects is not None:
            fx, fy, torque = effects.wrench(self, fx, fy, torque)
        if not math.isfinite(torque):
            raise ValueError("resultant torque overflows")
        self._integrate(fx, fy, torque)
        self.tick += 1
        if effects is not None:
            effects.after_step(self)

    def truth(self) -> Truth:
        """The state after ``tick`` steps, with the paper's derived quantities z_C, p_G and z_i."""
        px, py = self._pos
        c, s = self._c, self._s
        bx, by = self._rbar
        zcx, zcy = c * bx - s * by, s * bx + c * by
        rot_t = np.array(((c, s), (-s, c)))
        return Truth(
            tick=self.tick,
            t=self.tick * self.dt,
            x=px,
            y=py,
            angle=self._angle,
            vc=self._vel,
            omega=self._omega,
            zc=(zcx, zcy),
            pg=(px + zcx, py + zcy),
            zi=tuple(map(tuple, (self._rrel_t.T @ rot_t).tolist())),
            mass=self.mass,
            inertia=self.inertia,
        )


def kinetic_energy(truth: Truth) -> float:
    """Translational plus rotational kinetic energy (J), for checks and summaries."""
    return 0.5 * truth.mass * (truth.vc[0] ** 2 + truth.vc[1] ** 2) + 0.5 * truth.inertia * truth.omega**2


__all__ = [
    "Plant",
    "Truth",
    "contact_points_body",
    "kinetic_energy",
    "load_inertia",
    "load_polygon_body",
    "sensor_rng",
]
