"""The rigid-body filter of the dynamical phase and the restart fit of its lock check.

:class:`RigidEKF`: an extended Kalman filter on (v_C, q_i, 1/m, omega, 1/J, [b/m, c/J, F_c/m, f/m,] u-bias) from
the agent's own contact velocity and the pooled eq. (9) rate, with the team's total force and torque
(from the consensus) as inputs. :func:`fit_rotation`: a global fit of the own contact velocities over
a window, the restart point of a filter that locked onto a wrong (q_i, omega). Pure: inputs as
arguments, no clock, no RNG. Derivation and tuning: docs/dynamics.md.
"""

from __future__ import annotations

from math import cos, sin

import numpy as np

from agents.kernels import filter as F
from agents.kernels.filter import N_PAR, coulomb_sat  # noqa: F401 (coulomb_sat: the model's, re-exported)
from config.agent_params import DynamicsSpec

_U_BIAS_SD0 = 0.05  # prior std of the eq. (9) rate's error b at a filter start (rad/s): fresh circle fits
# the augmented model's effects (their names as in ident/model.py) and their rate states: 7 beta, 8 gamma,
# 9 kappa, 10 and 11 the constant acceleration a = f/m along x and y (force_bias, a 2-vector)
EFFECTS = ("viscous_friction", "rotational_damping", "coulomb_friction", "force_bias")
N_EFF = len(EFFECTS)
EFFECT_PARAMS = ((0,), (1,), (2,), (3, 4))  # each effect's rates (state 7 + p)


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

    A view: the filter is slot 0 of its own one-agent bank (agents/kernels/filter.py), its maths the bank's
    row kernels. The kernels change the bank in place, so a copy (``copy.copy``: a restart's shadow, the
    slope's twin) copies the bank, and ``s``, ``P``, ``sens`` are copies of the rows.
    """

    __slots__ = ("_bank", "_f", "_x")

    def __init__(self, sigma_v: float, spec: DynamicsSpec, background: bool) -> None:
        aug = spec.estimate_effects or spec.online_detection
        self._set_bank(F.new_bank(1, 1, F.D_AUGMENTED if aug else F.D_NOMINAL))
        init_slot(self._bank, 0, 0, sigma_v, spec, background)

    @classmethod
    def view(cls, bank: tuple[np.ndarray, ...], b: int, k: int) -> RigidEKF:
        """The filter of slot (b, k) of ``bank`` (filter.py's arrays), in place: its methods change the bank."""
        new = cls.__new__(cls)
        new._set_bank(tuple(a[b:b + 1, k:k + 1] for a in bank))
        return new

    def _set_bank(self, bank: tuple[np.ndarray, ...]) -> None:
        self._bank = bank
        self._f = bank[0][0, 0]  # the slot's record (a view)
        self._x = bank[1][0, 0]  # its state row (a view)

    def __copy__(self) -> RigidEKF:
        new = RigidEKF.__new__(RigidEKF)
        new._set_bank(tuple(a.copy() for a in self._bank))
        return new

    def start(self, v: complex, q0: complex, omega: float) -> None:
        fs, s, P, sens = self._bank[:4]
        F.ekf_start(fs, s, P, sens, 0, 0, complex(v), complex(q0), float(omega))

    def release_effects(self) -> None:
        """Augmented model: let the declared rates move (from 0, prior std 0.3) and restart mu and iota from
        their current values with the start's priors (their cross-covariances dropped).

        Called when the excitation starts (the m stage, or Algorithm 2's background stage). Free from the
        start, beta would explain the decay of the filter's own initial v_C error (q_i still unknown) as
        friction, and that wrong start can outlive the m stage; and what mu and iota learn before, under
        the nominal model, absorbs the friction (iota ~ 0: the regulation torque that holds
        omega against the damping looked like a torque that does not accelerate the load).
        """
        fs, s, P, _, _, aug = self._bank[:6]
        F.ekf_release_effects(fs, s, P, aug, 0, 0)

    def release_effect(self, k: int) -> None:
        """Online detection: let effect k's rates (:data:`EFFECTS` order) move from 0 (prior std 0.3 1/s or m/s^2
        each, walk ``effect_walk`` per second) and restart the parameter it shares the data with (1/m for beta,
        kappa and a, 1/J for gamma) from its current value with the start's prior, as :meth:`release_effects`
        does. A constant force (force_bias) restarts v_C's variance too (the start's prior, correlations
        dropped): the nominal model has carried the constant acceleration in v_C's random walk, as a lag of
        v_C's estimate, and a confident v_C would read that lag's decay as 1/m (docs/online-detection.md)."""
        fs, s, P, _, _, aug = self._bank[:6]
        F.ekf_release_effect(fs, s, P, aug, 0, 0, int(k))

    def withdraw_effect(self, k: int) -> None:
        """Online detection: pin effect k's rates (:data:`EFFECTS` order) at 0 again. The filter's state is
        conditioned on the rates being exactly 0 (the Gaussian conditional: s - P[:, r] P_rr^-1 s_r,
        P - P[:, r] P_rr^-1 P[r, :]): 1/m (or 1/J) keeps the data since the switch, corrected to first order by
        its correlation with the rates; a correction only, not the filter that never had the effect
        (docs/online-detection.md, "Withdrawal"). Numpy on the slot's rows: it runs only at a decision."""
        if self.aug is None or not self.ready:
            return
        r = [7 + p for p in EFFECT_PARAMS[k]]
        s, P = self.s, self.P
        prr = P[np.ix_(r, r)]
        if np.all(np.diag(prr) > 0.0):
            c = np.linalg.solve(prr, P[r, :]).T  # P[:, r] P_rr^-1
            s = s - c @ s[r]
            P = P - c @ P[r, :]
        s[r] = 0.0
        P[r, :] = 0.0
        P[:, r] = 0.0
        aug = self._bank[5][0, 0]
        for p in EFFECT_PARAMS[k]:
            aug[p] = 0.0
            aug[N_PAR + p] = 0.0
        self.s = s
        self.P = 0.5 * (P + P.T)

    def forget_iota(self, var: float = 1e-2) -> None:
        """Drops what the filter believes about 1/J (variance ``var``, no correlations): before the J stage
        the torque is the agents' regulation torque, whose consensus is off by several N m per tick, and a
        1/J learnt from it is far off yet confident enough to hold the J-stage estimate there
        (docs/dynamics.md)."""
        F.ekf_forget_iota(self._bank[0], self._bank[2], 0, 0, float(var))

    def hold_shape(self) -> None:
        """From here on q is known (held: it only turns with omega) and the pooled rate u measures omega
        without an error of its own (b = 0, pinned). For a load that may stop turning (done under a law or
        braking): at rest q is not observable from v_Ci = v_C + omega q^perp, the q random walk would
        inflate its variance until the updates move it, and b would swallow the slow part of u, which at
        rest is the only measurement of omega's drift (u = omega cos(delta): no pair-angle bias at
        omega = 0); docs/dynamics.md has the numbers."""
        fs, s, P, _, Qd = self._bank[:5]
        F.ekf_hold_shape(fs, s, P, Qd, 0, 0)

    def set_omega_walk(self, walk: float) -> None:
        """Process noise of omega (rad/s/sqrt(s)): small where the torque is known exactly (the J stage)."""
        F.ekf_set_omega_walk(self._bank[4], 0, 0, float(walk))

    def update(self, v: complex, u: float, u_var: float, u_dc: float = 0.0, u_dw: float = 0.0) -> None:
        """Measurement update by the own contact velocity v and the pooled rate u (NaN, or u_var <= 0: none).

        ``u`` may be older than the state (a delayed measurement): it measured omega ``a`` ticks ago,
        omega - dt iota sum T + dt gamma sum omega over those ticks. ``u_dc`` is that dt sum T (the
        torques this filter predicted with), ``u_dw`` the dt sum omega (augmented model), both 0 for a
        current sample; the u row of H gets -u_dc on iota and u_dw on gamma. Taken as current, a sample
        100 ms old during the J stage's ramp conflicts with the own velocity by dt iota T per tick of age,
        which reverses with s(t) and biases J (docs/faults.md). The sensitivities go through the update
        too (D <- D - K H D; their own-velocity rows H D are kept in ``sens_h``)."""
        fs, s, P, sens, _, _, innov, sens_h = self._bank
        F.ekf_update(fs, s, P, sens, innov, sens_h, 0, 0, complex(v), float(u), float(u_var), float(u_dc),
                     float(u_dw))

    def predict(self, force: complex, torque: float, dt: float, force_err: complex = 0j) -> None:
        """Prediction by dt under ``force`` and ``torque``. ``force_err``: the known error of ``force`` (the
        applied total minus it, 0 where unknown), used only by the online detection's sensitivity: the
        third column is d(state)/d(delta) for the force force + delta force_err at delta = 0."""
        fs, s, P, sens, Qd, aug = self._bank[:6]
        F.ekf_predict(fs, s, P, sens, Qd, aug, 0, 0, complex(force), float(torque), float(dt), complex(force_err))

    @property
    def d(self) -> int:
        return int(self._f["d"])

    @property
    def s(self) -> np.ndarray:
        return self._x[:self.d].copy()

    @s.setter
    def s(self, value: np.ndarray) -> None:
        self._x[:self.d] = value

    @property
    def P(self) -> np.ndarray:
        d = self.d
        return self._bank[2][0, 0, :d, :d].copy()

    @P.setter
    def P(self, value: np.ndarray) -> None:
        d = self.d
        self._bank[2][0, 0, :d, :d] = value

    @property
    def Qd(self) -> tuple[float, ...]:
        """Per-second process noise intensities (v, q angle, 1/m, omega, 1/J)."""
        return tuple(self._bank[4][0, 0].tolist())

    @property
    def qb(self) -> float:
        """The rate error b's walk intensity (0: pinned)."""
        return float(self._f["qb"])

    @property
    def r(self) -> float:
        """The own velocity's measurement variance."""
        return float(self._f["r"])

    @property
    def sens(self) -> np.ndarray | None:
        """d(state prediction)/d(beta, gamma, kappa, a_x, a_y) at the pinned 0 through the filter's own prediction
        and gain, and d/d of the force error (agents/effect_decision.py); None when not carried."""
        return self._bank[3][0, 0, :self.d].copy() if self._f["has_sens"] else None

    @sens.setter
    def sens(self, value: np.ndarray | None) -> None:
        self._f["has_sens"] = value is not None
        if value is not None:
            self._bank[3][0, 0, :self.d] = value

    @property
    def sens_h(self) -> tuple[float, ...]:
        """(H D)[v_x, rate p], [v_y, rate p] for each rate, then the force error's [v_x], [v_y] (last update)."""
        return tuple(self._bank[7][0, 0].tolist())

    @property
    def innov(self) -> tuple[float, ...]:
        """The last update's own-velocity innovation and its covariance (e0, e1, s00, s01, s11)."""
        return tuple(self._bank[6][0, 0].tolist())

    @property
    def nis(self) -> float:
        """The last update's normalised innovation squared of the own velocity (2 dof)."""
        return float(self._f["nis"])

    @nis.setter
    def nis(self, value: float) -> None:
        self._f["nis"] = value

    @property
    def ready(self) -> bool:
        return bool(self._f["ready"])

    @property
    def ib(self) -> int:
        return int(self._f["ib"])

    @property
    def aug(self) -> tuple[float, ...] | None:
        """Augmented model: per rate whether it is free (1) or pinned (0), then their per-second walks."""
        return tuple(self._bank[5][0, 0].tolist()) if self._f["has_aug"] else None

    @property
    def q(self) -> complex:
        x = self._x
        return complex(x[2], x[3])

    @property
    def vc(self) -> complex:
        x = self._x
        return complex(x[0], x[1])

    @property
    def mu(self) -> float:
        return float(self._x[4])

    @property
    def mu_var(self) -> float:
        return float(self._bank[2][0, 0, 4, 4])

    @property
    def omega(self) -> float:
        return float(self._x[5])

    @property
    def iota(self) -> float:
        return float(self._x[6])

    @property
    def iota_var(self) -> float:
        return float(self._bank[2][0, 0, 6, 6])

    @property
    def beta(self) -> float:
        """b/m (1/s), augmented model only."""
        return float(self._x[7])

    @property
    def gamma(self) -> float:
        """c/J (1/s), augmented model only."""
        return float(self._x[8])

    def rate(self, k: int) -> tuple[float, float] | tuple[np.ndarray, np.ndarray]:
        """Effect k's rate (:data:`EFFECTS` order) and its variance, augmented model only; for a vector effect
        (force_bias) the rates' vector and their covariance."""
        r = [7 + p for p in EFFECT_PARAMS[k]]
        P = self._bank[2][0, 0]
        if len(r) == 1:
            return float(self._x[r[0]]), float(P[r[0], r[0]])
        return self._x[r].copy(), P[np.ix_(r, r)].copy()

    @property
    def kappa(self) -> float:
        """F_c/m (m/s^2), augmented model only."""
        return float(self._x[9])

    @property
    def accel(self) -> complex:
        """a = f/m (m/s^2, world frame), augmented model only."""
        x = self._x
        return complex(x[10], x[11])


def init_slot(bank: tuple[np.ndarray, ...], b: int, k: int, sigma_v: float, spec: DynamicsSpec,
              background: bool) -> None:
    """Filter slot (b, k) of a bank set up for ``spec`` (not started): the own velocity's variance, the
    process noise, the augmented model's effects (those declared free, the others pinned at 0) and
    whether the online detection's sensitivities are carried."""
    fs, s, P, sens, Qd, aug = bank[:6]
    f = fs[b, k]
    f["r"] = max(sigma_v, 1e-3) ** 2
    f["ready"] = False
    f["nis"] = 2.0
    walk_mu = spec.mu_walk if background else 0.0
    walk_iota = spec.iota_walk if background else 0.0
    # per-second process noise intensities; q's angle walk is scaled by |q|^2 at each step
    Qd[b, k] = (spec.kf_v_walk**2, spec.kf_angle_walk**2, walk_mu**2, spec.omega_walk**2, walk_iota**2)
    has_aug = bool(spec.estimate_effects or spec.online_detection)
    f["has_aug"] = has_aug
    aug[b, k] = 0.0
    if has_aug:
        # per rate state (7 + p) whether it is free (1) or pinned (0), then the per-second walk intensities
        on = [1.0 if e in spec.estimate_effects else 0.0 for e, ps in zip(EFFECTS, EFFECT_PARAMS) for _ in ps]
        w2 = spec.effect_walk**2
        aug[b, k] = on + [o * w2 for o in on]
    f["walk_eff"] = spec.effect_walk**2
    f["vs"] = spec.coulomb_speed
    f["detect"] = spec.online_detection
    f["has_sens"] = False
    # the pooled eq. (9) rate's own slowly varying error b (u = omega + b), the last state; pinned at 0
    # (zero variance, no walk) with u_bias_walk = 0
    ib = 7 if not has_aug else 7 + N_PAR
    f["d"], f["ib"] = ib + 1, ib
    f["qb"] = spec.u_bias_walk**2
    f["b0"] = _U_BIAS_SD0**2 if f["qb"] > 0.0 else 0.0
    s[b, k] = 0.0
    P[b, k] = 0.0
    for i in range(ib + 1):
        P[b, k, i, i] = 1.0
    sens[b, k] = 0.0


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

