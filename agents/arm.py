"""A planar two-link arm as a paper-000 agent's front end: encoders in, contact velocity out.

The arm is horizontal (SCARA-like: gravity is normal to the plane), sits on a fixed base and holds
the load at its contact point through a free pivot. It has joint encoders and a wrist force sensor,
no speed sensor. Per tick the front end

1. integrates the I&I speed observer of paper 004 (``agents.speed_observer``) on the arm's *own*
   model from the previous to the new encoder sample. The input is the generalized force it
   commanded over that interval minus the load's reaction through the Jacobian transpose,
   ``u - J(q)^T f`` (f: the force the arm applied to the load, as the wrist sensor measured it);
2. maps the joint-speed estimate to the contact-point velocity ``v = J(q) x_hat``: the measurement
   ``AgentCore.step`` needs;
3. turns a desired contact force into generalized joint torques ``u = J(q)^T f_cmd``, with
   ``f_cmd`` = the motion plan's tracking force + the force part of AgentCore's wrench.
   AgentCore's torque cannot pass through a pivot and is dropped (the rotation the kinematic phase
   needs comes from the plan, see :class:`MotionPlan`).

Why a motion plan instead of AgentCore's spin regulation: an arm on a fixed base cannot follow a
load that turns continuously, so the team rocks the load, theta(t) = theta0 sin(w t) (1 - e^{-t/tau}),
about a centre the team agreed on, optionally with a small translation; each arm tracks where its
own grasp point must be under that rigid motion, which needs no knowledge of the load.

Coordinates: absolute link angles q1, q2 (from world x, counter-clockwise), the convention of paper
004 Sec. III, so M(q) = [[c1, c2 cos(q1-q2)], [c2 cos(q1-q2), c3]]; generalized forces on absolute
angles equal the torques on the link bodies: u1 = tau_base - tau_elbow, u2 = tau_elbow.

Pure: no clock (time is tick * dt), no RNG, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from agents.speed_observer import (
    ClosedForm,
    ELModel,
    Gains,
    ObserverState,
    SpeedObserver,
    Terms,
    two_link,
)
from config.arm_model import ArmModel

Array = np.ndarray


def el_model(arm: ArmModel) -> ELModel:
    """The arm as an Euler-Lagrange model for the observer: M, C of paper 004 eq. 56, G = 0 (horizontal)."""
    c1, c2, c3 = arm.constants
    m = two_link(c1, c2, c3, 0.0, 0.0)
    # the angles stay within a few rad (fixed base, bounded motion): plain Gauss-Legendre, no periodic split
    return ELModel(2, m.M, m.C, m.G, m.k_m, m.k_M, m.k_c, m.q_low, m.q_high)


@dataclass(frozen=True)
class MotionPlan:
    """Rigid rocking motion of the load that every arm tracks at its own grasp point.

    theta(t) = theta0 sin(2 pi t / period) g(t) about ``centre`` (world, m), plus a translation
    d(t) = shift sin(2 pi t / shift_period) g(t) along ``shift_angle``; g(t) = 1 - exp(-t / ramp) starts
    both from rest (zero position and velocity).
    """

    centre: tuple[float, float]
    theta0: float
    period: float
    ramp: float
    shift: float = 0.0
    shift_period: float = 1.0
    shift_angle: float = 0.0

    def _env(self, t: float) -> tuple[float, float]:
        e = math.exp(-t / self.ramp)
        return 1.0 - e, e / self.ramp

    def angle(self, t: float) -> tuple[float, float]:
        """(theta, theta') of the load relative to its start (rad, rad/s)."""
        g, gd = self._env(t)
        w = 2 * math.pi / self.period
        return self.theta0 * math.sin(w * t) * g, self.theta0 * (w * math.cos(w * t) * g + math.sin(w * t) * gd)

    def offset(self, t: float) -> tuple[Array, Array]:
        """(d, d') translation of the rotation centre (m, m/s)."""
        g, gd = self._env(t)
        w = 2 * math.pi / self.shift_period
        e = np.array([math.cos(self.shift_angle), math.sin(self.shift_angle)])
        return self.shift * math.sin(w * t) * g * e, self.shift * (w * math.cos(w * t) * g + math.sin(w * t) * gd) * e

    def reference(self, t: float, p0: Array) -> tuple[Array, Array]:
        """Where the grasp point that started at ``p0`` should be at t, and its velocity (world, m and m/s)."""
        th, thd = self.angle(t)
        d, dd = self.offset(t)
        c = np.asarray(self.centre, float)
        r0 = np.asarray(p0, float) - c
        cs, sn = math.cos(th), math.sin(th)
        r = np.array([cs * r0[0] - sn * r0[1], sn * r0[0] + cs * r0[1]])
        return c + d + r, dd + thd * np.array([-r[1], r[0]])


@dataclass(frozen=True)
class Tracking:
    """Cartesian PD of the grasp point: f = kp (p_ref - p) + kd (v_ref - v)."""

    kp: float
    kd: float


class ArmFrontEnd:
    """One arm agent's sensing and actuation around an unchanged ``AgentCore`` (see module docstring).

    ``observer=None`` makes it a velocity-measuring agent (same arm, same plan, same tracking): the
    caller passes the sensed contact velocity to :meth:`command` and never calls :meth:`sense`.
    """

    def __init__(
        self,
        model: ArmModel,
        base: Sequence[float],
        plan: MotionPlan,
        tracking: Tracking,
        dt: float,
        q0: Sequence[float],
        observer: SpeedObserver | None = None,
        *,
        x0_hat: Sequence[float] = (0.0, 0.0),
        r0: float = 0.01,
        substeps: int = 1,
    ) -> None:
        self.model = model
        self.base = np.asarray(base, float)
        self.plan = plan
        self.tracking = tracking
        self.dt = float(dt)
        self.substeps = int(substeps)
        q0 = np.asarray(q0, float)
        self.p0 = self.base + model.tip(q0)  # the grasp point the plan moves, from the first encoder sample
        self.q = q0.copy()
        self.u = np.zeros(2)  # generalized torque commanded for the current interval
        self.observer = observer
        self.x_hat = np.asarray(x0_hat, float).copy()
        self.state: ObserverState | None = None
        if observer is not None:
            s_x = np.zeros(2)
            beta = observer.beta_terms(q0, q0, s_x)[0]
            self.state = observer.start(q0, self.x_hat - beta, q0, s_x, r0)

    def sense(self, q: Sequence[float], f: Sequence[float]) -> tuple[Array, Array]:
        """New encoder sample ``q`` and wrist force ``f`` (on the load, averaged over the last interval).

        Returns (contact velocity estimate (2,), joint speed estimate (2,)).
        """
        assert self.observer is not None and self.state is not None, "a velocity-measuring front end has no observer"
        q = np.asarray(q, float)
        J_mid = self.model.jacobian(0.5 * (self.q + q))
        u = self.u - J_mid.T @ np.asarray(f, float)
        ob, st, h = self.observer, self.state, self.dt / self.substeps
        q_prev = self.q
        for s in range(1, self.substeps + 1):
            st = ob.step(st, q_prev + (q - q_prev) * (s / self.substeps), u, h)
        self.state = st
        self.q = q
        self.x_hat = ob.estimate(st.vector(), q)
        return self.model.jacobian(q) @ self.x_hat, self.x_hat

    def command(self, tick: int, q: Sequence[float], v: Sequence[float], f_core: Sequence[float] = (0.0, 0.0)) -> tuple[Array, Array]:
        """Joint torques for [tick, tick + 1): u = J^T (tracking force + f_core). Returns (u, f_cmd)."""
        q = np.asarray(q, float)
        self.q = q
        p = self.base + self.model.tip(q)
        p_ref, v_ref = self.plan.reference(tick * self.dt, self.p0)
        tr = self.tracking
        f = tr.kp * (p_ref - p) + tr.kd * (v_ref - np.asarray(v, float)) + np.asarray(f_core, float)
        self.u = self.model.jacobian(q).T @ f
        return self.u, f


def two_link_closed_form(c1: float, c2: float, c3: float, k1: float) -> ClosedForm:
    """beta (paper 004 eq. 12) and its partials (13)-(15) in closed form for the horizontal two-link arm.

    With D = det M = a - b cos^2(d), a = c1 c3, b = c2^2, d = q1 - q2, every entry of
    H = M^-1 (k1 I - C(q, s_x)) is a combination of 1/D, cos d / D, sin d / D and cos d sin d / D,
    whose primitives are elementary (P0: atan2 continued across periods, Pc: atan, Ps: atanh,
    Pcs: log D / 2b). Column 1 is integrated along d = t - s_y2, column 2 along d = s_y1 - t, so the
    partials in s_y are differences of the integrands at the path ends (fundamental theorem) and
    those in s_x are the integrals of the s_x coefficients (H is affine in s_x). Exact at any angle,
    ~10x cheaper than the quadrature; checked against it in tests/test_arms.py.
    """
    a, b = c1 * c3, c2 * c2
    if not a > b > 0:
        raise ValueError("need c1 c3 > c2^2 > 0 (M positive definite, coupled links)")
    sa, sab = math.sqrt(a), math.sqrt(a - b)
    k0 = 1.0 / math.sqrt(a * (a - b))
    kc, kc_in = 1.0 / math.sqrt(b * (a - b)), math.sqrt(b / (a - b))
    ks, ks_in = 1.0 / math.sqrt(a * b), math.sqrt(b / a)

    def prims(d: float) -> tuple[float, float, float, float]:
        """(P0, Pc, Ps, Pcs) at d: primitives of 1/D, cos/D, sin/D, cos sin/D."""
        c, s = math.cos(d), math.sin(d)
        r = math.remainder(d, 2 * math.pi)
        p0 = k0 * (math.atan2(sa * math.sin(r), sab * math.cos(r)) + (d - r))
        return p0, kc * math.atan(kc_in * s), -ks * math.atanh(ks_in * c), math.log(a - b * c * c) / (2 * b)

    def cols(d: float, sx: Array) -> tuple[Array, Array]:
        """Columns 1 and 2 of H at q1 - q2 = d (they depend on q only through d)."""
        c, s = math.cos(d), math.sin(d)
        D = a - b * c * c
        h1 = np.array([c3 * k1 - b * sx[0] * c * s, -c2 * k1 * c + c1 * c2 * sx[0] * s]) / D
        h2 = np.array([-c2 * c3 * sx[1] * s - c2 * k1 * c, b * sx[1] * c * s + c1 * k1]) / D
        return h1, h2

    cache: dict[str, object] = {"key": None, "val": None}

    def terms(y: Array, sy: Array, sx: Array) -> tuple[Array, Array, Array, Array]:
        key = (float(y[0]), float(y[1]), float(sy[0]), float(sy[1]), float(sx[0]), float(sx[1]))
        if cache["key"] == key:
            return cache["val"]  # type: ignore[return-value]
        i1 = np.subtract(prims(key[0] - key[3]), prims(-key[3]))  # column 1: d from -s_y2 to y1 - s_y2
        i2 = np.subtract(prims(key[2]), prims(key[2] - key[1]))  # column 2: d from s_y1 - y2 to s_y1
        I0_1, Ic_1, Is_1, Ics_1 = i1
        I0_2, Ic_2, Is_2, Ics_2 = i2
        beta = np.array([
            c3 * k1 * I0_1 - b * sx[0] * Ics_1 - c2 * c3 * sx[1] * Is_2 - c2 * k1 * Ic_2,
            -c2 * k1 * Ic_1 + c1 * c2 * sx[0] * Is_1 + b * sx[1] * Ics_2 + c1 * k1 * I0_2,
        ])
        dy = np.column_stack([cols(key[0] - key[3], sx)[0], cols(key[2] - key[1], sx)[1]])
        dsy = np.column_stack([cols(key[2], sx)[1] - cols(key[2] - key[1], sx)[1],
                               -(cols(key[0] - key[3], sx)[0] - cols(-key[3], sx)[0])])
        dsx = np.array([[-b * Ics_1, -c2 * c3 * Is_2], [c1 * c2 * Is_1, b * Ics_2]])
        val = (beta, dy, dsy, dsx)
        cache["key"], cache["val"] = key, val
        return val

    return ClosedForm(beta=lambda y, sy, sx: terms(y, sy, sx)[0], dbeta_dy=lambda y, sy, sx: terms(y, sy, sx)[1],
                      dbeta_dsy=lambda y, sy, sx: terms(y, sy, sx)[2], dbeta_dsx=lambda y, sy, sx: terms(y, sy, sx)[3])


def _norm2(m00: float, m01: float, m10: float, m11: float) -> float:
    """Spectral norm of a 2 x 2 matrix in closed form (largest singular value)."""
    f = m00 * m00 + m01 * m01 + m10 * m10 + m11 * m11
    det = m00 * m11 - m01 * m10
    return math.sqrt(0.5 * (f + math.sqrt(max(f * f - 4.0 * det * det, 0.0))))


class ArmObserver(SpeedObserver):
    """:class:`SpeedObserver` with the right-hand side specialised to the horizontal two-link arm.

    Same equations as ``SpeedObserver.terms`` (tested equal to 1e-12), with 2 x 2 algebra in closed
    form (M^-1, C, spectral norms, the Lemma-2 sum): one evaluation costs a fraction of the generic
    numpy path, which is what lets every arm agent run its observer at 100 Hz in the loop.
    """

    def __init__(self, arm: ArmModel, gains: Gains, *, nodes: int = 8, seed: int = 0) -> None:
        c = arm.constants
        super().__init__(el_model(arm), gains, nodes=nodes, seed=seed, closed_form=two_link_closed_form(*c, gains.k1))
        self._c = c
        mask = 1.0 - np.eye(2)[None, :, :]  # [j, i, k]: column i does not depend on e_i
        self._la = (self._a * mask).reshape(-1)
        self._lb = (self._b * mask[..., None]).reshape(-1, 2)

    def lemma2_L(self, s_x: Array) -> float:
        R = self._la + self._lb @ np.abs(s_x)
        return float(math.sqrt(R @ R))

    def terms(self, obs: Array, y: Array, u: Array) -> Terms:
        g, mdl = self.gains, self.model
        c1, c2, c3 = self._c
        obs = np.asarray(obs, float)
        xi, s_y, s_x, r = obs[0:2], obs[2:4], obs[4:6], float(obs[6])
        y = np.asarray(y, float)
        beta, Bq, Bsy, Bsx = self.beta_terms(y, s_y, s_x)
        x_hat = xi + beta
        d = float(y[0] - y[1])
        cs, sn = math.cos(d), math.sin(d)
        m01 = c2 * cs
        D = c1 * c3 - m01 * m01
        h0, h1 = float(x_hat[0]), float(x_hat[1])
        cc = c2 * sn  # C(y, x) = cc [[0, x2], [-x1, 0]]
        f0 = float(u[0]) - cc * h1 * h1
        f1 = float(u[1]) + cc * h0 * h0
        acc = np.array([(c3 * f0 - m01 * f1) / D, (c1 * f1 - m01 * f0) / D])
        e_y, e_x = s_y - y, s_x - x_hat
        L = self.lemma2_L(s_x)
        lift = r * r / (g.k1 * mdl.k_m)
        b00, b01, b10, b11 = Bq.reshape(-1).tolist()
        psi1 = g.k2 + 0.5 * r * r + lift * (mdl.k_M * L) ** 2  # eq. (53)
        psi2 = g.k3 + 0.5 * r * r * _norm2(b00, b01, b10, b11) ** 2 + lift * mdl.k_c**2  # eq. (54)
        a2 = x_hat - psi1 * e_y  # eq. (44)
        a3 = acc - psi2 * e_x  # eq. (45)
        a1 = acc - Bq @ x_hat - Bsy @ a2 - Bsx @ a3  # eq. (6)
        nDx = abs(cc) * max(abs(float(e_x[0])), abs(float(e_x[1])))  # ||C(y, e_x)|| (eq. 22)
        sx0, sx1 = float(s_x[0]), float(s_x[1])
        # M Delta_y = k1 I - C(y, s_x) - M dbeta/dy
        nDy = _norm2(g.k1 - (c1 * b00 + m01 * b10), -cc * sx1 - (c1 * b01 + m01 * b11),
                     cc * sx0 - (m01 * b00 + c3 * b10), g.k1 - (m01 * b01 + c3 * b11))
        rdot = -g.k1 / (4 * mdl.k_M) * (r - g.c_r) + r / (g.k1 * mdl.k_m) * (nDy**2 + nDx**2)  # eq. (38)
        deriv = np.concatenate([a1, a2, a3, [rdot]])
        return Terms(x_hat, beta, Bq, Bsy, Bsx, e_y, e_x, float(psi1), float(psi2), nDy, nDx, L, deriv)


def make_observer(model: ArmModel, k1: float, k2: float, k3: float, c_r: float, nodes: int, seed: int,
                  closed_form: bool = True) -> SpeedObserver:
    """The paper-004 observer on the arm's own model (P1-P5 checked at construction).

    ``closed_form``: :class:`ArmObserver` (beta from :func:`two_link_closed_form`, 2 x 2 algebra in closed
    form); else the generic observer with its Gauss-Legendre quadrature of ``nodes`` nodes.
    """
    gains = Gains(k1=k1, k2=k2, k3=k3, c_r=c_r)
    if closed_form:
        return ArmObserver(model, gains, nodes=nodes, seed=seed)
    return SpeedObserver(el_model(model), gains, nodes=nodes, seed=seed)


__all__ = ["ArmFrontEnd", "ArmModel", "ArmObserver", "MotionPlan", "Tracking", "el_model", "make_observer",
           "two_link_closed_form"]
