"""The rigid-body filter of the dynamical phase and the restart fit of its lock check.

:class:`RigidEKF`: an extended Kalman filter on (v_C, q_i, 1/m, omega, 1/J, [b/m, c/J, F_c/m, f/m,] u-bias) from
the agent's own contact velocity and the pooled eq. (9) rate, with the team's total force and torque
(from the consensus) as inputs. :func:`fit_rotation`: a global fit of the own contact velocities over
a window, the restart point of a filter that locked onto a wrong (q_i, omega). Pure: inputs as
arguments, no clock, no RNG. Derivation and tuning: docs/dynamics.md.
"""

from __future__ import annotations

from math import cos, hypot, sin, tanh

import numpy as np

from config.agent_params import DynamicsSpec

_U_BIAS_SD0 = 0.05  # prior std of the eq. (9) rate's error b at a filter start (rad/s): fresh circle fits
# the augmented model's effects (their names as in ident/model.py) and their rate states: 7 beta, 8 gamma,
# 9 kappa, 10 and 11 the constant acceleration a = f/m along x and y (force_bias, a 2-vector)
EFFECTS = ("viscous_friction", "rotational_damping", "coulomb_friction", "force_bias")
N_EFF = len(EFFECTS)
EFFECT_PARAMS = ((0,), (1,), (2,), (3, 4))  # each effect's rates (state 7 + p)
N_PAR = 5


def coulomb_sat(vx: float, vy: float, vs: float) -> tuple[float, float, float, float, float]:
    """The smoothed Coulomb direction sat(v) = tanh(|v|/vs) v/|v| and its Jacobian (j00, j01, j11, symmetric):
    tanh(r/vs)/r (I - u u^T) + sech^2(r/vs)/vs u u^T, u = v/|v|, r = |v|; I/vs at rest (the limit)."""
    r = hypot(vx, vy)
    if r < 1e-9 * vs:
        return vx / vs, vy / vs, 1.0 / vs, 0.0, 1.0 / vs
    th = tanh(r / vs)
    a = th / r
    d = (1.0 - th * th) / vs - a  # the radial slope minus the tangential one
    ux, uy = vx / r, vy / r
    return a * vx, a * vy, a + d * ux * ux, d * ux * uy, a + d * uy * uy


class RigidEKF:
    """Extended Kalman filter on s = (v_Cx, v_Cy, q_x, q_y, mu = 1/m, omega, iota = 1/J, [beta, gamma, kappa, a_x,
    a_y,] b),
    world frame; b (always the last state, index ``ib``) is the pooled rate's own error, u = omega + b, a
    random walk of ``spec.u_bias_walk`` (pinned at 0 when that is 0).

    Model (the plant's own discrete step, semi-implicit Euler): v_C(k+1) = v_C + dt mu F(k),
    q(k+1) = R(omega dt) q, omega(k+1) = omega + dt iota T(k); F, T the total force and torque about the
    CoM, from the consensus. Measurements: the own contact velocity v_Ci = v_C + omega q^perp and the pooled
    eq. (9) rate u = omega (variance 2 sigma^2 / sum_j |z_ij|^2). Estimating omega here, with the torque
    model, removes the lag of the kinematic omega_hat filter (which rotated q and the J-stage forces
    away from the body while omega ramped).

    Augmented model (``spec.estimate_effects``): five more states, beta = b/m (1/s), gamma = c/J (1/s),
    kappa = F_c/m (m/s^2) and a = f/m (m/s^2, world frame, two states), with v_C(k+1) = v_C + dt (mu F -
    beta v_C - kappa sat(v_C) + a) and omega(k+1) = omega + dt (iota T - gamma omega), the plant's step with
    viscous friction -b v_C, smoothed Coulomb friction -F_c tanh(|v_C|/v_s) v_C/|v_C|, a constant external
    force f (a slope) and rotational damping -c omega (simulator/effects.py:
    forces of the state at tick k act over k -> k+1; v_s is ``spec.coulomb_speed``, the filter's, as it
    cannot know the plant's). The rates rather than b, F_c and c keep the model linear in the parameters
    given the (well-measured) velocities, whatever the current mu; b = beta/mu, F_c = kappa/mu,
    c = gamma/iota, f = a/mu. An effect not estimated keeps its states at exactly 0 (zero variance, no walk).
    """

    __slots__ = ("s", "P", "Qd", "r", "ready", "_I", "aug", "ib", "qb", "b0", "nis", "innov", "sens", "sens_h",
                 "walk_eff", "detect", "vs")

    def __init__(self, sigma_v: float, spec: DynamicsSpec, background: bool) -> None:
        self.r = max(sigma_v, 1e-3) ** 2
        self.ready = False
        self.nis = 2.0  # the last update's normalised innovation squared of the own velocity (2 dof)
        self.innov = (0.0, 0.0, 0.0, 0.0, 0.0)  # the last update's own-velocity innovation and its covariance
        walk_mu = spec.mu_walk if background else 0.0
        walk_iota = spec.iota_walk if background else 0.0
        # per-second process noise intensities; q's angle walk is scaled by |q|^2 at each step
        self.Qd = (spec.kf_v_walk**2, spec.kf_angle_walk**2, walk_mu**2, spec.omega_walk**2, walk_iota**2)
        # augmented model: per rate state (7 + p) whether it is free (1) or pinned (0), then the per-second
        # walk intensities; 0 and 0 for an effect not estimated (its states stay exactly 0)
        self.aug: tuple[float, ...] | None = None
        if spec.estimate_effects or spec.online_detection:
            on = tuple(1.0 if e in spec.estimate_effects else 0.0 for e, ps in zip(EFFECTS, EFFECT_PARAMS) for _ in ps)
            w2 = spec.effect_walk**2
            self.aug = on + tuple(o * w2 for o in on)
        self.walk_eff = spec.effect_walk**2
        self.vs = spec.coulomb_speed
        # online detection (agents/effect_decision.py): d(state prediction)/d(beta, gamma, kappa, a_x, a_y) at
        # the pinned 0, through the filter's own prediction and gain, and its own-velocity rows H D of the last update
        self.sens: np.ndarray | None = None
        # (H D)[v_x, rate p], [v_y, rate p] for each rate, then the force error's [v_x], [v_y]
        self.sens_h = (0.0,) * (2 * N_PAR + 2)
        self.detect = spec.online_detection
        # the pooled eq. (9) rate's own slowly varying error b (u = omega + b), the last state; pinned at 0
        # (zero variance, no walk) with u_bias_walk = 0
        self.ib = 7 if self.aug is None else 7 + N_PAR
        self.qb = spec.u_bias_walk**2
        self.b0 = _U_BIAS_SD0**2 if self.qb > 0.0 else 0.0
        self.s = np.zeros(self.ib + 1)
        self.P = np.eye(self.ib + 1)
        self._I = np.eye(self.ib + 1)

    def start(self, v: complex, q0: complex, omega: float) -> None:
        vc = v - omega * 1j * q0
        self.s = np.array([vc.real, vc.imag, q0.real, q0.imag, 0.0, omega, 0.0])
        self.P = np.diag([1.0, 1.0, 1.0, 1.0, 1.0, 0.1, 1e-2])
        if self.aug is not None:  # the rates pinned at 0 until release_effects()
            self.s = np.append(self.s, (0.0,) * N_PAR)
            P = np.zeros((7 + N_PAR, 7 + N_PAR))
            P[:7, :7] = self.P
            self.P = P
        ib = self.ib
        self.s = np.append(self.s, 0.0)
        P = np.zeros((ib + 1, ib + 1))
        P[:ib, :ib] = self.P
        P[ib, ib] = self.b0
        self.P = P
        if self.detect:
            self.sens = np.zeros((ib + 1, N_PAR + 1))  # the rates, the gain of the force error (predict)
        self.ready = True

    def release_effects(self) -> None:
        """Augmented model: let the declared rates move (from 0, prior std 0.3) and restart mu and iota from
        their current values with the start's priors (their cross-covariances dropped).

        Called when the excitation starts (the m stage, or Algorithm 2's background stage). Free from the
        start, beta would explain the decay of the filter's own initial v_C error (q_i still unknown) as
        friction, and that wrong start can outlive the m stage; and what mu and iota learn before, under
        the nominal model, absorbs the friction (iota ~ 0: the regulation torque that holds
        omega against the damping looked like a torque that does not accelerate the load).
        """
        if self.aug is None or not self.ready:
            return
        self._restart(((4, 1.0), (6, 1e-2), *((7 + p, 0.1 * self.aug[p]) for p in range(N_PAR))))

    def release_effect(self, k: int) -> None:
        """Online detection: let effect k's rates (:data:`EFFECTS` order) move from 0 (prior std 0.3 1/s or m/s^2
        each, walk ``effect_walk`` per second) and restart the parameter it shares the data with (1/m for beta,
        kappa and a, 1/J for gamma) from its current value with the start's prior, as :meth:`release_effects`
        does. A constant force (force_bias) restarts v_C's variance too (the start's prior, correlations
        dropped): the nominal model has carried the constant acceleration in v_C's random walk, as a lag of
        v_C's estimate, and a confident v_C would read that lag's decay as 1/m (docs/online-detection.md)."""
        if self.aug is None or not self.ready:
            return
        self._set_effect(k, 1.0, self.walk_eff)
        rates = tuple((7 + p, 0.1) for p in EFFECT_PARAMS[k])
        vc = ((0, 1.0), (1, 1.0)) if len(EFFECT_PARAMS[k]) > 1 else ()
        self._restart(((6, 1e-2), *rates) if k == 1 else ((4, 1.0), *vc, *rates))

    def withdraw_effect(self, k: int) -> None:
        """Online detection: pin effect k's rates (:data:`EFFECTS` order) at 0 again. The filter's state is
        conditioned on the rates being exactly 0 (the Gaussian conditional: s - P[:, r] P_rr^-1 s_r,
        P - P[:, r] P_rr^-1 P[r, :]): 1/m (or 1/J) keeps the data since the switch, corrected to first order by
        its correlation with the rates; a correction only, not the filter that never had the effect
        (docs/online-detection.md, "Withdrawal")."""
        if self.aug is None or not self.ready:
            return
        r = [7 + p for p in EFFECT_PARAMS[k]]
        s, P = self.s.copy(), self.P.copy()
        prr = P[np.ix_(r, r)]
        if np.all(np.diag(prr) > 0.0):
            c = np.linalg.solve(prr, P[r, :]).T  # P[:, r] P_rr^-1
            s = s - c @ s[r]
            P = P - c @ P[r, :]
        s[r] = 0.0
        P[r, :] = 0.0
        P[:, r] = 0.0
        self._set_effect(k, 0.0, 0.0)
        self.s = s
        self.P = 0.5 * (P + P.T)

    def _set_effect(self, k: int, on: float, walk: float) -> None:
        """Effect k's entries of ``aug`` (its rates on or pinned, and their random walk)."""
        aug = list(self.aug)
        for p in EFFECT_PARAMS[k]:
            aug[p] = on
            aug[N_PAR + p] = walk
        self.aug = tuple(aug)

    def _restart(self, entries: tuple[tuple[int, float], ...]) -> None:
        """Each (state k, variance) in ``entries``: its correlations dropped, its variance set; the effect
        rates (k >= 7) also restart from 0, the parameters (1/m, 1/J) from their current values."""
        P = self.P.copy()
        s = self.s.copy()  # replaced, never changed in place (snapshots hold it)
        for k, var in entries:
            if k >= 7:
                s[k] = 0.0
            P[k, :] = 0.0
            P[:, k] = 0.0
            P[k, k] = var
        self.s = s
        self.P = P

    def forget_iota(self, var: float = 1e-2) -> None:
        """Drops what the filter believes about 1/J (variance ``var``, no correlations): before the J stage
        the torque is the agents' regulation torque, whose consensus is off by several N m per tick, and a
        1/J learnt from it is far off yet confident enough to hold the J-stage estimate there
        (docs/dynamics.md)."""
        P = self.P.copy()
        P[6, :] = 0.0
        P[:, 6] = 0.0
        P[6, 6] = var
        self.P = P

    def hold_shape(self) -> None:
        """From here on q is known (held: it only turns with omega) and the pooled rate u measures omega
        without an error of its own (b = 0, pinned). For a load that may stop turning (done under a law or
        braking): at rest q is not observable from v_Ci = v_C + omega q^perp, the q random walk would
        inflate its variance until the updates move it, and b would swallow the slow part of u, which at
        rest is the only measurement of omega's drift (u = omega cos(delta): no pair-angle bias at
        omega = 0); docs/dynamics.md has the numbers."""
        ib = self.ib
        P = self.P.copy()
        for k in (2, 3, ib):
            P[k, :] = 0.0
            P[:, k] = 0.0
        s = self.s.copy()
        s[ib] = 0.0
        self.s = s
        self.P = P
        self.qb = 0.0
        qv, _, qm, qo, qi = self.Qd
        self.Qd = (qv, 0.0, qm, qo, qi)

    def set_omega_walk(self, walk: float) -> None:
        """Process noise of omega (rad/s/sqrt(s)): small where the torque is known exactly (the J stage)."""
        qv, qa, qm, _, qi = self.Qd
        self.Qd = (qv, qa, qm, walk**2, qi)

    def update(self, v: complex, u: float, u_var: float, u_dc: float = 0.0, u_dw: float = 0.0) -> None:
        """Measurement update; H is sparse, so P H^T is three column combinations of P.

        ``u`` may be older than the state (a delayed measurement): it measured omega ``a`` ticks ago,
        omega - dt iota sum T + dt gamma sum omega over those ticks. ``u_dc`` is that dt sum T (the
        torques this filter predicted with), ``u_dw`` the dt sum omega (augmented model), both 0 for a
        current sample; the u row of H gets -u_dc on iota and u_dw on gamma. Taken as current, a sample
        100 ms old during the J stage's ramp conflicts with the own velocity by dt iota T per tick of age,
        which reverses with s(t) and biases J (docs/faults.md)."""
        s, P = self.s, self.P
        qx, qy, om = s[2], s[3], s[5]
        r = self.r
        c0 = P[:, 0] - om * P[:, 3] - qy * P[:, 5]  # P H^T, column for v_x
        c1 = P[:, 1] + om * P[:, 2] + qx * P[:, 5]  # ... v_y
        e0 = v.real - (s[0] - om * qy)
        e1 = v.imag - (s[1] + om * qx)
        s00 = c0[0] - om * c0[3] - qy * c0[5] + r
        s01 = c1[0] - om * c1[3] - qy * c1[5]
        s11 = c1[1] + om * c1[2] + qx * c1[5] + r
        self.innov = (e0, e1, s00, s01, s11)
        d2 = s00 * s11 - s01 * s01
        if d2 > 0.0:  # the lock check's statistic (DynamicPhase): ~2 while the filter explains v_Ci
            self.nis = (s11 * e0 * e0 - 2.0 * s01 * e0 * e1 + s00 * e1 * e1) / d2
        if u == u and u_var > 0.0:
            ib = self.ib
            c2 = P[:, 5] + P[:, ib]  # ... u = omega + b
            e2 = u - om - s[ib]
            if u_dc or u_dw:  # delayed: omega of a ticks ago, d/d iota = -u_dc, d/d gamma = u_dw
                c2 = c2 - u_dc * P[:, 6]
                e2 += u_dc * s[6]
                if self.aug is not None:
                    c2 = c2 + u_dw * P[:, 8]
                    e2 -= u_dw * s[8]
                s22 = c2[5] + c2[ib] - u_dc * c2[6] + (u_dw * c2[8] if self.aug is not None else 0.0) + u_var
            else:
                s22 = c2[5] + c2[ib] + u_var
            s02 = c2[0] - om * c2[3] - qy * c2[5]
            s12 = c2[1] + om * c2[2] + qx * c2[5]
            # explicit inverse of the symmetric 3x3 innovation covariance
            a00 = s11 * s22 - s12 * s12
            a01 = s02 * s12 - s01 * s22
            a02 = s01 * s12 - s02 * s11
            a11 = s00 * s22 - s02 * s02
            a12 = s01 * s02 - s00 * s12
            a22 = s00 * s11 - s01 * s01
            det = s00 * a00 + s01 * a01 + s02 * a02
            if det <= 0.0:
                return
            C = np.column_stack((c0, c1, c2))
            Sinv = np.array(((a00, a01, a02), (a01, a11, a12), (a02, a12, a22))) / det
            K = C @ Sinv
            self.s = s + K @ np.array((e0, e1, e2))
            if self.sens is not None:
                D = self.sens
                hd2 = D[5] + D[ib] - u_dc * D[6] + (u_dw * D[8] if self.aug is not None else 0.0)
                self._sens_update(K, D, qx, qy, om, hd2)
        else:
            det = s00 * s11 - s01 * s01
            if det <= 0.0:
                return
            C = np.column_stack((c0, c1))
            Sinv = np.array(((s11, -s01), (-s01, s00))) / det
            K = C @ Sinv
            self.s = s + K @ np.array((e0, e1))
            if self.sens is not None:
                self._sens_update(K, self.sens, qx, qy, om, None)
        P = P - K @ C.T
        self.P = 0.5 * (P + P.T)

    def _sens_update(self, K: np.ndarray, D: np.ndarray, qx: float, qy: float, om: float,
                     hd2: np.ndarray | None) -> None:
        """The sensitivities through the update, D <- D - K H D; H D's own-velocity rows are kept for the
        detection's score. The gain's own dependence on the rates is left out: it multiplies the innovation,
        zero-mean under the nominal model (tests/test_effect_decision.py: D equals the finite difference of
        the posterior on data the filter predicts exactly)."""
        hd0 = D[0] - om * D[3] - qy * D[5]
        hd1 = D[1] + om * D[2] + qx * D[5]
        self.sens_h = tuple(float(x) for pair in zip(hd0, hd1) for x in pair)
        HD = np.vstack((hd0, hd1) if hd2 is None else (hd0, hd1, hd2))
        self.sens = D - K @ HD

    def predict(self, force: complex, torque: float, dt: float, force_err: complex = 0j) -> None:
        """Prediction by dt under ``force`` and ``torque``. ``force_err``: the known error of ``force`` (the
        applied total minus it, 0 where unknown), used only by the online detection's sensitivity: the
        third column is d(state)/d(delta) for the force force + delta force_err at delta = 0."""
        s = self.s
        qx, qy, mu, om, iota = s[2], s[3], s[4], s[5], s[6]
        c, sn = cos(om * dt), sin(om * dt)
        nq = np.array([
            s[0] + dt * mu * force.real,
            s[1] + dt * mu * force.imag,
            c * qx - sn * qy,
            sn * qx + c * qy,
            mu,
            om + dt * iota * torque,
            iota,
        ])
        A = self._I.copy()
        A[0, 4] = dt * force.real
        A[1, 4] = dt * force.imag
        A[2, 2] = c
        A[2, 3] = -sn
        A[3, 2] = sn
        A[3, 3] = c
        A[2, 5] = dt * (-sn * qx - c * qy)
        A[3, 5] = dt * (c * qx - sn * qy)
        A[5, 6] = dt * torque
        if self.aug is not None:  # augmented model: - dt beta v_C, - dt kappa sat(v_C), + dt a, - dt gamma omega
            beta, gamma, kappa, ax, ay = s[7], s[8], s[9], s[10], s[11]
            sx, sy, j00, j01, j11 = coulomb_sat(s[0], s[1], self.vs)
            nq[0] -= dt * (beta * s[0] + kappa * sx - ax)
            nq[1] -= dt * (beta * s[1] + kappa * sy - ay)
            nq[5] -= dt * gamma * om
            A[0, 0] -= dt * (beta + kappa * j00)
            A[1, 1] -= dt * (beta + kappa * j11)
            A[0, 1] -= dt * kappa * j01
            A[1, 0] -= dt * kappa * j01
            A[0, 7] = -dt * s[0]
            A[1, 7] = -dt * s[1]
            A[5, 5] -= dt * gamma
            A[5, 8] = -dt * om
            A[0, 9] = -dt * sx
            A[1, 9] = -dt * sy
            A[0, 10] = dt
            A[1, 11] = dt
            nq = np.append(nq, (beta, gamma, kappa, ax, ay))
        nq = np.append(nq, s[self.ib])
        if self.sens is not None:
            # d/d rate at the pinned 0: carried through A, plus each rate's own column of A on the states it
            # drives (-dt v_C, -dt omega, -dt sat(v_C), dt along x and along y)
            D = A @ self.sens
            D[:7, :N_PAR] += A[:7, 7:7 + N_PAR]
            D[0, N_PAR] += dt * s[4] * force_err.real
            D[1, N_PAR] += dt * s[4] * force_err.imag
            self.sens = D
        P = A @ self.P @ A.T
        qv, qa, qm, qo, qi = self.Qd
        P[0, 0] += qv * dt
        P[1, 1] += qv * dt
        qq = qa * dt * (qx * qx + qy * qy)
        P[2, 2] += qq
        P[3, 3] += qq
        P[4, 4] += qm * dt
        P[5, 5] += qo * dt
        P[6, 6] += qi * dt
        if self.aug is not None:
            for p in range(N_PAR):
                P[7 + p, 7 + p] += self.aug[N_PAR + p] * dt
        P[self.ib, self.ib] += self.qb * dt
        self.s = nq
        self.P = P

    @property
    def q(self) -> complex:
        return complex(self.s[2], self.s[3])

    @property
    def vc(self) -> complex:
        return complex(self.s[0], self.s[1])

    @property
    def mu(self) -> float:
        return float(self.s[4])

    @property
    def mu_var(self) -> float:
        return float(self.P[4, 4])

    @property
    def omega(self) -> float:
        return float(self.s[5])

    @property
    def iota(self) -> float:
        return float(self.s[6])

    @property
    def iota_var(self) -> float:
        return float(self.P[6, 6])

    @property
    def beta(self) -> float:
        """b/m (1/s), augmented model only."""
        return float(self.s[7])

    @property
    def gamma(self) -> float:
        """c/J (1/s), augmented model only."""
        return float(self.s[8])

    def rate(self, k: int) -> tuple[float, float] | tuple[np.ndarray, np.ndarray]:
        """Effect k's rate (:data:`EFFECTS` order) and its variance, augmented model only; for a vector effect
        (force_bias) the rates' vector and their covariance."""
        r = [7 + p for p in EFFECT_PARAMS[k]]
        if len(r) == 1:
            return float(self.s[r[0]]), float(self.P[r[0], r[0]])
        return self.s[r].copy(), self.P[np.ix_(r, r)].copy()

    @property
    def kappa(self) -> float:
        """F_c/m (m/s^2), augmented model only."""
        return float(self.s[9])

    @property
    def accel(self) -> complex:
        """a = f/m (m/s^2, world frame), augmented model only."""
        return complex(self.s[10], self.s[11])


def fit_rotation(v: np.ndarray, f: np.ndarray, dt: float, omega_max: float) -> tuple[float, complex, float]:
    """Global fit of the own contact velocity over a window: v(k) = a + mu f(k) + i omega e^{i omega k dt} q0
    (v_C = a + mu f, f = dt sum of the total force so far; q turning at a constant omega), for the omega in
    [-omega_max, omega_max] with the least squared residual. Linear in (a, mu, q0) for a given omega, so
    omega is scanned on a grid (step well inside the residual's dip, whose width is ~2 pi / window) and
    refined. Returns (omega, q at the window's last sample, residual RMS per component): a restart point for
    a filter that locked onto a wrong (q_i, omega), from the agent's own data alone."""
    n = len(v)
    t = np.arange(n) * dt
    y = np.concatenate((v.real, v.imag))
    fc = f - f.mean()  # (a absorbs the mean: better conditioned)

    def scan(om: np.ndarray) -> np.ndarray:
        e = 1j * om[:, None] * np.exp(1j * om[:, None] * t[None, :])  # (K, n)
        k = len(om)
        A = np.empty((k, 2 * n, 5))
        A[:, :n, 0], A[:, n:, 0] = 1.0, 0.0
        A[:, :n, 1], A[:, n:, 1] = 0.0, 1.0
        A[:, :n, 2], A[:, n:, 2] = fc.real, fc.imag
        A[:, :n, 3], A[:, n:, 3] = e.real, e.imag
        A[:, :n, 4], A[:, n:, 4] = -e.imag, e.real
        G = np.einsum("kri,krj->kij", A, A)
        b = np.einsum("kri,r->ki", A, y)
        G += np.eye(5) * (1e-9 * np.trace(G, axis1=1, axis2=2))[:, None, None]
        x = np.linalg.solve(G, b[..., None])[..., 0]
        return y @ y - np.einsum("ki,ki->k", b, x), x

    step = min(0.25, 0.5 / (n * dt))
    grid = np.arange(-omega_max, omega_max + step, step)
    res, _ = scan(grid)
    best = grid[int(np.argmin(res))]
    fine = best + np.linspace(-step, step, 41)
    res, x = scan(fine)
    i = int(np.argmin(res))
    om = float(fine[i])
    if 0 < i < len(fine) - 1:
        # the residual is a parabola near its minimum: its vertex, not the fine grid's step, sets omega
        # (a grid point can be step/80 off, which at |q| = 3 m put q 0.026 m off on noise-free data)
        r0, r1, r2 = res[i - 1], res[i], res[i + 1]
        den = r0 - 2.0 * r1 + r2
        if den > 0.0:
            om_v = om + 0.5 * (fine[1] - fine[0]) * (r0 - r2) / den
            res_v, x_v = scan(np.array([om_v]))
            if res_v[0] <= r1:
                om, res, x, i = om_v, res_v, x_v, 0
    q0 = complex(x[i, 3], x[i, 4])
    return om, q0 * complex(cos(om * t[-1]), sin(om * t[-1])), float(np.sqrt(max(res[i], 0.0) / (2 * n)))

