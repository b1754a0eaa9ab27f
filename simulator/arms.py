"""Two-link arms in a pymunk space with the load, holding it at its contact points.

Each arm is two rigid links (uniform rods, pymunk bodies without shapes: nothing collides, the
arms are SCARA-like and move above the load) joined by pivot joints: ground - upper link at the
base, upper link - forearm at the elbow, forearm - load at the contact point (a free pivot: no
torque passes). Joint torques are body torques on absolute angles (u1 on the upper link, u2 on the
forearm; see agents/arm.py). The load is a pymunk body at the scenario's initial state, in a space of
this module's own (:class:`simulator.plant.Plant` steps in closed form, without constraints); after each
tick its state goes to the plant (``Plant.take_state``), whose truth and sensor then read it as usual.

Wrist force sensor: pymunk exposes only the magnitude of a joint's impulse, so the force each arm
applies to the load is recovered from the links' momentum balance, substep by substep. In a pymunk
step positions move first, then forces and constraint impulses change the velocities exactly
(position drift is corrected through separate bias velocities), so per link
m dv = sum of joint impulses, I dw = h u + sum r x impulse, with r from the pose after the step.
Three joint impulses (base, elbow, wrist) and two links give six equations for six unknowns; the
two angular equations alone fix the wrist impulse (a 2 x 2 system, regular away from a
stretched or folded elbow). The force on the load over a tick is minus the sum of the wrist
impulses divided by dt (tested against the load's own momentum change and pymunk's |impulse|).
"""

from __future__ import annotations

import math

import numpy as np
import pymunk

from config.arm_model import ArmModel
from config.scenario import ArmsSpec, Scenario
from simulator.plant import Plant, contact_points_body, load_inertia, load_polygon_body

# keep the contacts this far inside the workspace annulus at start-up (fraction of the reach)
_REACH_MARGIN = 0.05


class ArmSetupError(ValueError):
    """An arm cannot hold its contact point (out of reach, singular); names the arm and the field."""


def arm_model(spec: ArmsSpec) -> ArmModel:
    return ArmModel(spec.l1, spec.l2, spec.m1, spec.m2)


def load_body(scenario: Scenario) -> tuple[pymunk.Space, pymunk.Body]:
    """A space (no gravity, no damping) holding the load as a pymunk body at the scenario's initial state,
    its origin the CoM; its shape carries no mass and collides with nothing (the outline, for inspection)."""
    space = pymunk.Space()
    space.gravity = (0.0, 0.0)
    space.damping = 1.0
    body = pymunk.Body(scenario.load.mass, load_inertia(scenario))
    shape = pymunk.Poly(body, load_polygon_body(scenario))  # massless: mass/moment stay as set
    shape.sensor = True
    ini = scenario.initial
    body.position = ini.position
    body.angle = ini.angle
    body.velocity = ini.v_c
    body.angular_velocity = ini.omega
    space.add(body, shape)
    return space, body


def contact_world(load: pymunk.Body, points_body: np.ndarray) -> np.ndarray:
    """World positions of body-frame points of the load (about its CoM) at its current pose."""
    c, s = math.cos(load.angle), math.sin(load.angle)
    px, py = load.position
    return np.stack([px + c * points_body[:, 0] - s * points_body[:, 1],
                     py + s * points_body[:, 0] + c * points_body[:, 1]], axis=1)


def default_bases(contacts: np.ndarray, offset: float) -> np.ndarray:
    """Each base on the ray from the contacts' centroid through its contact, ``offset`` beyond the contact."""
    g = contacts.mean(axis=0)
    d = contacts - g
    norm = np.hypot(d[:, 0], d[:, 1])
    if np.any(norm < 1e-9):
        raise ArmSetupError("arms.bases: a contact sits on the contacts' centroid; give the bases explicitly")
    return contacts + d / norm[:, None] * offset


def add_arm(space: pymunk.Space, model: ArmModel, base: np.ndarray, q: np.ndarray,
            load: pymunk.Body | None = None) -> tuple[pymunk.Body, pymunk.Body, pymunk.PivotJoint | None]:
    """Add one arm at absolute angles q to ``space``: two links, base and elbow pivots, and a wrist
    pivot to ``load`` at the tip when given. Returns (upper link, forearm, wrist joint or None)."""
    i1, i2 = model.inertias
    b = np.asarray(base, dtype=float)
    u1 = np.array([math.cos(q[0]), math.sin(q[0])])
    u2 = np.array([math.cos(q[1]), math.sin(q[1])])
    link1 = pymunk.Body(model.m1, i1)
    link1.position = tuple(b + 0.5 * model.l1 * u1)
    link1.angle = float(q[0])
    link2 = pymunk.Body(model.m2, i2)
    elbow = b + model.l1 * u1
    link2.position = tuple(elbow + 0.5 * model.l2 * u2)
    link2.angle = float(q[1])
    space.add(link1, link2)
    joints = [pymunk.PivotJoint(space.static_body, link1, tuple(b)), pymunk.PivotJoint(link1, link2, tuple(elbow))]
    if load is not None:
        joints.append(pymunk.PivotJoint(link2, load, tuple(elbow + model.l2 * u2)))
    for j in joints:
        j.collide_bodies = False
    space.add(*joints)
    return link1, link2, joints[2] if load is not None else None


class ArmPlant:
    """The load plant plus ``n`` two-link arms; :meth:`step` advances one tick under joint torques."""

    def __init__(self, scenario: Scenario) -> None:
        spec = scenario.arms
        if spec is None:
            raise ArmSetupError("arms: the scenario has no [arms] section")
        self.plant = plant = Plant(scenario)
        if getattr(plant, "effects", None) is not None:
            raise ArmSetupError("plant: physical effects are not supported together with arms")
        self.space, self.body = space, body = load_body(scenario)
        self.spec = spec
        self.model = model = arm_model(spec)
        self.n = n = scenario.n
        self.dt = scenario.dt
        self.substeps = spec.substeps
        self.h = scenario.dt / spec.substeps
        r_body = np.asarray(contact_points_body(scenario), dtype=float)
        contacts = contact_world(body, r_body)
        if spec.bases is not None:
            bases = np.asarray(spec.bases, dtype=float)
        else:
            bases = default_bases(contacts, spec.base_offset)
        self.bases = bases
        lo, hi = model.reach
        space.iterations = spec.solver_iterations
        self.links: list[tuple[pymunk.Body, pymunk.Body]] = []
        self.wrists: list[pymunk.PivotJoint] = []
        for i in range(n):
            d = float(np.hypot(*(contacts[i] - bases[i])))
            margin = _REACH_MARGIN * hi
            if not lo + margin < d < hi - margin:
                raise ArmSetupError(
                    f"arms.bases: arm {i}: its contact point is {d:.3f} m from the base, outside the usable reach "
                    f"({lo + margin:.3f}, {hi - margin:.3f}) m of links {model.l1} + {model.l2} m"
                )
            q = model.ik(contacts[i] - bases[i], spec.elbow)
            link1, link2, wrist = add_arm(space, model, bases[i], q, body)
            self.links.append((link1, link2))
            self.wrists.append(wrist)  # type: ignore[arg-type]
        self._m = np.array([model.m1, model.m2])
        self._inertia = np.array(model.inertias)
        self.forces = np.zeros((n, 2))  # force of each arm on the load, mean over the last tick (N)
        self.last_wrist_impulse = np.zeros((n, 2))  # on the forearm, last substep (N s): checks against pymunk

    # -- state ------------------------------------------------------------------------------------
    def angles(self) -> np.ndarray:
        """(n, 2) true absolute link angles q1, q2 (rad), continuous (not wrapped)."""
        return np.array([[l1.angle, l2.angle] for l1, l2 in self.links])

    def joint_speeds(self) -> np.ndarray:
        """(n, 2) true q1', q2' (rad/s)."""
        return np.array([[l1.angular_velocity, l2.angular_velocity] for l1, l2 in self.links])

    def tip_velocities(self) -> np.ndarray:
        """(n, 2) J(q) q' of every arm (world, m/s): the contact velocity as the arm's model sees it."""
        q, qd = self.angles(), self.joint_speeds()
        return np.array([self.model.jacobian(q[i]) @ qd[i] for i in range(self.n)])

    def _link_states(self) -> np.ndarray:
        """(n, 2 links, 6): vx, vy, w, x, y, angle of every link."""
        out = np.empty((self.n, 2, 6))
        for i, (l1, l2) in enumerate(self.links):
            for k, b in enumerate((l1, l2)):
                vx, vy = b.velocity
                x, y = b.position
                out[i, k] = (vx, vy, b.angular_velocity, x, y, b.angle)
        return out

    # -- stepping ---------------------------------------------------------------------------------
    def step(self, u: np.ndarray) -> None:
        """Apply generalized joint torques u (n, 2) (N m, held over the tick) and advance one tick.

        Afterwards ``forces`` holds each arm's mean force on the load over the tick.
        """
        u = np.asarray(u, dtype=float)
        if u.shape != (self.n, 2) or not np.all(np.isfinite(u)):
            raise ValueError(f"joint torques must be a finite ({self.n}, 2) array, got shape {u.shape}")
        plant, model, h = self.plant, self.model, self.h
        impulse = np.zeros((self.n, 2))
        before = self._link_states()
        l1, l2 = model.l1, model.l2
        for _ in range(self.substeps):
            for (a, b), (ua, ub) in zip(self.links, u.tolist()):
                a.torque = ua
                b.torque = ub
            self.space.step(h)
            after = self._link_states()
            dv = after[..., 0:2] - before[..., 0:2]
            dw = after[..., 2] - before[..., 2]
            ang = after[..., 5]
            e1 = np.stack([np.cos(ang[:, 0]), np.sin(ang[:, 0])], axis=1)  # upper link direction
            e2 = np.stack([np.cos(ang[:, 1]), np.sin(ang[:, 1])], axis=1)
            # anchors relative to the link CoMs: upper link base -l1/2 e1, elbow +l1/2 e1;
            # forearm elbow -l2/2 e2, wrist +l2/2 e2
            rb1, re1 = -0.5 * l1 * e1, 0.5 * l1 * e1
            re2, rw2 = -0.5 * l2 * e2, 0.5 * l2 * e2
            m1dv = self._m[0] * dv[:, 0]
            m2dv = self._m[1] * dv[:, 1]
            # forearm angular:  (rw2 - re2) x Jw = I2 dw2 - h u2 - re2 x m2 dv2
            # upper angular:    (rb1 - re1) x Jw = rb1 x m1 dv1 + (rb1 - re1) x m2 dv2 - I1 dw1 + h u1
            a_row = rw2 - re2
            b_row = rb1 - re1
            rhs_a = self._inertia[1] * dw[:, 1] - h * u[:, 1] - _cross(re2, m2dv)
            rhs_b = _cross(rb1, m1dv) + _cross(b_row, m2dv) - self._inertia[0] * dw[:, 0] + h * u[:, 0]
            # a x J = a_x J_y - a_y J_x : rows [-a_y, a_x]
            A = np.stack([np.stack([-a_row[:, 1], a_row[:, 0]], axis=1), np.stack([-b_row[:, 1], b_row[:, 0]], axis=1)],
                         axis=1)
            jw = np.linalg.solve(A, np.stack([rhs_a, rhs_b], axis=1)[..., None])[..., 0]
            impulse -= jw  # the load gets minus the wrist impulse on the forearm
            self.last_wrist_impulse = jw
            before = after
        self.forces = impulse / self.dt
        plant.tick += 1
        b = self.body
        plant.take_state(tuple(b.position), tuple(b.velocity), b.angle, b.angular_velocity)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]


__all__ = ["ArmPlant", "ArmSetupError", "add_arm", "arm_model", "contact_world", "default_bases", "load_body"]
