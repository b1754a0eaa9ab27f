"""The plant: one rigid planar load in a pymunk space, pushed at n contact points.

Pure: no clock, no sockets, no global RNG. The daemon owns time and transport; this module owns
physics and the sensor model, so that the in-process engine and the daemon share it unchanged.

Design: the pymunk body's origin is the centre of mass (``center_of_gravity`` = 0), so
``body.position`` is p_C; the outline and the contact points are stored relative to the CoM.
The body's mass and moment are set explicitly; its shape carries no mass and only serves
inspection and drawing (nothing collides). Per tick the agents' wrenches are reduced to one
resultant force and torque about the CoM (the same sum ``apply_force_at_world_point`` would
accumulate, vectorised) and pymunk integrates one step; the plant's state is the truth, whatever
the integrator's discretisation error against the continuous model. Note pymunk (Chipmunk) moves
positions before velocities within a step: the wrench of tick k shows in the velocities (and so in
the measurements) at tick k + 1 and in the pose from tick k + 2; over many ticks this is
semi-implicit (symplectic) Euler, so free motion conserves energy and momentum exactly.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pymunk

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
    matrix (no per-tick rebuild of the grasp matrix).
    """

    __slots__ = (
        "n", "dt", "sigma_v", "mass", "inertia", "tick", "space", "body",
        "_r", "_rbar", "_rrel_t", "_perp1", "_reduce", "_pos", "_vel", "_angle", "_omega", "_c", "_s", "effects",
    )  # fmt: skip

    def __init__(self, scenario: Scenario) -> None:
        self.n = scenario.n
        self.dt = scenario.dt
        self.sigma_v = scenario.noise.sigma_v
        self.mass = scenario.load.mass
        self.inertia = load_inertia(scenario)
        self.tick = 0
        self._set_contacts(np.asarray(contact_points_body(scenario), dtype=float))
        space = pymunk.Space()
        space.gravity = (0.0, 0.0)
        space.damping = 1.0  # no velocity damping: the load is frictionless (g = 0 in the paper)
        body = pymunk.Body(self.mass, self.inertia)
        shape = pymunk.Poly(body, load_polygon_body(scenario))  # massless: mass/moment stay as set
        shape.sensor = True
        ini = scenario.initial
        body.position = ini.position
        body.angle = ini.angle
        body.velocity = ini.v_c
        body.angular_velocity = ini.omega
        space.add(body, shape)
        self.space = space
        self.body = body
        self.refresh()
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

    def refresh(self) -> None:
        """Snapshot the body state once per tick (each pymunk property read crosses the C boundary);
        whoever moves the body outside :meth:`apply_and_step` calls it."""
        b = self.body
        self._pos = tuple(b.position)
        self._vel = tuple(b.velocity)
        self._angle = a = b.angle
        self._omega = b.angular_velocity
        self._c = math.cos(a)
        self._s = math.sin(a)

    @property
    def com_velocity(self) -> Vec2:
        """v_C, world frame, at the last snapshot."""
        return self._vel

    @property
    def angular_velocity(self) -> float:
        """omega at the last snapshot."""
        return self._omega

    def change_load(self, mass: float, inertia: float, com_shift: np.ndarray, outline_about_com: np.ndarray) -> None:
        """The load's mass, inertia (about its new CoM) and CoM move by ``com_shift`` (body frame); the
        contact points stay on the body and every body point keeps its velocity. ``outline_about_com``
        is the load's outline about the new CoM (body frame)."""
        b = self.body
        c, s = self._c, self._s
        dw = (c * com_shift[0] - s * com_shift[1], s * com_shift[0] + c * com_shift[1])  # world frame
        w = self._omega
        b.position = (self._pos[0] + dw[0], self._pos[1] + dw[1])
        b.velocity = (self._vel[0] - w * dw[1], self._vel[1] + w * dw[0])  # v of the new CoM point
        b.mass = mass
        b.moment = inertia
        for shape in list(b.shapes):
            self.space.remove(shape)
        shape = pymunk.Poly(b, [(float(x), float(y)) for x, y in outline_about_com])
        shape.sensor = True
        self.space.add(shape)
        self.mass = mass
        self.inertia = inertia
        self._set_contacts(self._r - com_shift)
        self.refresh()

    def contact_velocities(self) -> np.ndarray:
        """v_Ci = v_C + omega R r_i^perp (= v_C + omega (p_Ci - p_C)^perp, perp = +90 deg rotation)."""
        c, s, w = self._c, self._s, self._omega
        vx, vy = self._vel
        k = np.array(((w * c, w * s), (-w * s, w * c), (vx, vy)))
        return self._perp1 @ k

    def velocities(self) -> list[Vec2]:
        """True world-frame velocity of every contact point now."""
        return list(map(tuple, self.contact_velocities().tolist()))

    def measure(self, rng: np.random.Generator) -> list[Vec2]:
        """velocities() plus N(0, sigma_v^2 I) noise; one draw of shape (n, 2) per call (+ sensor effects)."""
        if self.effects is not None:
            return self.effects.measure(self, rng)
        noisy = self.contact_velocities() + rng.normal(0.0, self.sigma_v, size=(self.n, 2))
        return list(map(tuple, noisy.tolist()))

    def apply_and_step(self, wrenches: Sequence[tuple[float, float, float]]) -> None:
        """Apply each agent's (fx, fy, tau) at its contact point's current world position; advance dt.

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
        b = self.body
        b.force = (fx, fy)
        b.torque = torque
        self.space.step(self.dt)
        self.tick += 1
        self.refresh()
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
