"""The plant model of ``ident``: continuous-time planar rigid-body dynamics with the effect vocabulary.

One rigid-body step (:func:`simulate`) serves the batch fit and the diagnosis. The state is the
CoM velocity v, the angular rate omega, the body angle theta and the CoM position p::

    dv/dt     = a (F(t) + f_b + R(theta) f_B - n b_s - c_v v - R(theta) D R(theta)^T v
                   - F_c v / sqrt(|v|^2 + v_s^2))                                                 a = 1/m
    domega/dt = b (tau(t) + (R(theta) r_i) x (f_i(t) - b_s) - c_r omega)            b = 1/J
    dtheta/dt = omega,  dp/dt = v
    contact velocity  y_i = v + omega (R(theta) r_i)^perp + v_b   (at t - d)
    contact position  q_i = p + R(theta) r_i                     (at t - d)

The wrench is known only at the sample stamps; between stamps it is the cubic through them with
centred-difference slopes (``cubic``, the default for a recording that does not say: smooth forces),
the straight line (first-order hold, ``foh``), or held (zero-order hold, ``zoh``) when the recording
says its actuators hold it. The ODE is integrated by classical RK4 with substeps no longer than ``max_step`` between
stamps (stamps may be irregular). A measurement delay d is the same model driven by the input
d earlier, since every window starts from a free state; a force sensor that lags by d (its rows stamped d late,
or a low-pass of time constant about d) is the input d later: the two are one shift of the input with two
signs, each a non-negative effect of its own. A force sensor's first-order low-pass of time constant T is the
input F + T dF/dt (the same as d = T at low frequency, not above it). Per agent (``PER_AGENT``): agent i's force is
scaled by its gain g_i, and an agent whose rows are stamped d_i late has its force taken d_i later and its
velocity predicted d_i earlier. See docs/diagnose.md ("Model").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

EFFECTS: dict[str, tuple[str, str]] = {
    "viscous_friction": ("N s/m", "integral of v_C"),
    "anisotropic_friction": ("N s/m", "viscous friction stronger along one axis of the load than across it (wheels, "
                             "casters, a cart): D = [[d1, d2], [d2, -d1]] in the load's frame at the model's angle 0, "
                             "beside viscous_friction's isotropic part; integral of R D R^T v_C"),
    "coulomb_friction": ("N", "integral of sign(v_C)"),
    "rotational_damping": ("N m s", "integral of omega"),
    "measurement_delay": ("s", "applied-force lag (rate of the prediction)"),
    "force_sensor_lag": ("s", "logged-force lag: the motion leads the logged force (rate of the prediction, the "
                         "other sign)"),
    "force_sensor_lowpass": ("s", "the force sensors' first-order low-pass: the motion leads the logged force "
                             "(its rate, as force_sensor_lag at low frequency)"),
    "force_bias": ("N", "constant force (ramp in v_C)"),
    "torque_bias": ("N m", "constant torque (ramp in omega)"),
    "velocity_bias": ("m/s", "constant velocity offset"),
    "sensor_offset_body": ("N, N, N m", "the same offset on every agent's logged force in its own frame, the robot "
                           "fixed to the load: the team's offset as a force fixed in the load's frame and a torque"),
    "force_sensor_offset": ("N", "the same offset on every agent's logged force (world frame): a force at the "
                            "contacts' centroid (or an external force there: the same model)"),
    "agent_actuator_gain": ("-", "one agent's force scaled (its share of the acceleration)"),
    "agent_clock_offset": ("s", "one agent's rows shifted in time (its force and its velocity)"),
}
"""Effect name -> (unit, the signature it leaves in the residual)."""
VECTOR_EFFECTS = ("force_bias", "velocity_bias", "force_sensor_offset")
PLANAR = ("anisotropic_friction",)
"""Effects that exist only on a turning load moving along both axes (n >= 2, no idle axis): two parameters."""
PER_AGENT = ("agent_actuator_gain", "agent_clock_offset")
"""Effects with one value per agent relative to a reference agent (``Layout.ref``): a gain common to the
team is m/g and J/g, a clock offset common to the team is no offset at all, so only n - 1 are identifiable.
The parameters are the other agents' deviations: gain - 1, offset (s; the agent's rows stamped that late)."""
NONNEGATIVE = ("viscous_friction", "coulomb_friction", "rotational_damping", "measurement_delay", "force_sensor_lag",
               "force_sensor_lowpass")
MIRRORS = {"measurement_delay": "force_sensor_lag", "force_sensor_lag": "measurement_delay"}
"""The input's shift with its two signs (velocities measured late, forces logged late): one parameter, each sign
a candidate that stays >= 0, so that either bound says which sensor lags."""
TIMING = ("measurement_delay", "force_sensor_lag", "force_sensor_lowpass")
"""The effects on the timing of the input against the motion: the same signature at first order (the input's
rate), told apart by its sign and, between a late stamp and a low-pass, at higher frequencies."""


@dataclass
class Windows:
    """A recording cut into S windows of at most L stamps (padded: repeated last stamp, mask 0).

    ``t`` (S, L) stamps; ``F`` (S, L, 2) total force; ``fx``, ``fy`` (S, L, n) per-agent forces; ``tau``
    (S, L) total torque; ``vel``/``vmask`` (S, L, n, 2)/(S, L, n) measured contact velocities,
    ``pos``/``pmask`` the same for positions (None when absent). ``u_t``, ``u`` are the whole input series
    (T,), (T, 2 + 2n + 1) [Fx, Fy, fx_1..n, fy_1..n, tau] for delayed inputs.
    """

    t: np.ndarray
    F: np.ndarray
    fx: np.ndarray
    fy: np.ndarray
    tau: np.ndarray
    vel: np.ndarray | None
    vmask: np.ndarray | None
    pos: np.ndarray | None
    pmask: np.ndarray | None
    u_t: np.ndarray
    u: np.ndarray
    rotation: bool  # the model has a rotational state (n >= 2)
    axes: np.ndarray  # (2,) bool: axes with motion or force; an idle axis is left out of the model
    hold: str = "foh"

    @property
    def S(self) -> int:
        return self.t.shape[0]

    @property
    def L(self) -> int:
        return self.t.shape[1]

    @property
    def n(self) -> int:
        return self.fx.shape[2]


@dataclass(frozen=True)
class Layout:
    """Where each unknown sits. Global vector: [r (2n) if rotation, a, b if rotation, effects...];
    local (per window) vector: [v (active axes), omega, theta if rotation, p (active axes) if positions]."""

    n: int
    rotation: bool
    axes: tuple[bool, bool]
    positions: bool
    effects: tuple[str, ...] = ()
    ref: int = 0  # the per-agent effects' reference agent (its gain 1, its clock the model's)

    def q(self, name: str) -> int:
        if name in PER_AGENT:
            return self.n - 1
        if name == "sensor_offset_body":  # the force's components in the load's frame and the torque
            return int(sum(self.axes)) + 1
        if name in PLANAR:
            return 2
        return int(sum(self.axes)) if name in VECTOR_EFFECTS else 1

    @property
    def n_geom(self) -> int:
        return 2 * self.n if self.rotation else 0

    @property
    def ia(self) -> int:
        return self.n_geom

    @property
    def ib(self) -> int | None:
        return self.n_geom + 1 if self.rotation else None

    @property
    def base(self) -> int:
        return self.n_geom + (2 if self.rotation else 1)

    def slot(self, name: str) -> slice:
        k = self.base
        for e in EFFECTS:
            if e in self.effects:
                if e == name:
                    return slice(k, k + self.q(e))
                k += self.q(e)
        raise KeyError(name)

    @property
    def G(self) -> int:
        return self.base + sum(self.q(e) for e in self.effects)

    @property
    def K(self) -> int:
        na = int(sum(self.axes))
        return na + (2 if self.rotation else 0) + (na if self.positions else 0)

    def with_effects(self, effects) -> Layout:
        return Layout(self.n, self.rotation, self.axes, self.positions, tuple(e for e in EFFECTS if e in effects),
                      self.ref)

    def per_agent(self, g: np.ndarray, name: str) -> np.ndarray | None:
        """(B, n) effect ``name``'s deviation per agent from ``g`` (B, G), 0 at the reference; None if absent."""
        if name not in self.effects:
            return None
        out = np.zeros(g.shape[:-1] + (self.n,))
        out[..., np.arange(self.n) != self.ref] = g[..., self.slot(name)]
        return out

    def lower(self) -> np.ndarray:
        lo = np.full(self.G, -np.inf)
        for e in NONNEGATIVE:
            if e in self.effects:
                lo[self.slot(e)] = 0.0
        return lo


def expand(layout: Layout, g: np.ndarray, src: Layout, init: dict | None = None) -> np.ndarray:
    """Map global vector ``g`` of layout ``src`` to ``layout``; effects not in ``src`` start at 0 (or ``init``)."""
    out = np.zeros(g.shape[:-1] + (layout.G,))
    out[..., : layout.base] = g[..., : src.base]
    for e in layout.effects:
        if e in src.effects:
            out[..., layout.slot(e)] = g[..., src.slot(e)]
        elif init and e in init:
            out[..., layout.slot(e)] = init[e]
    return out


def _logged(w: Windows, lowpass: np.ndarray | None) -> list[np.ndarray]:
    """The input series (T, C) each batch member is driven by: as logged, or where the force sensors low-pass
    with time constant T_k (T_k dF/dt + F = the applied force, F logged), the applied force F + T_k dF/dt."""
    if lowpass is None or not np.any(lowpass):
        return [w.u] * (1 if lowpass is None else lowpass.size)
    du = np.gradient(w.u, w.u_t, axis=0)
    return [w.u + T * du if T else w.u for T in lowpass]


def _rk_inputs(w: Windows, r: np.ndarray, delay: np.ndarray, gain: np.ndarray | None = None,
               clock: np.ndarray | None = None, lowpass: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    """Input channels at the stamps for each batch member: (B, S, L) each of Fx, Fy, tau, P, Q with
    torque = tau + cos(theta) P + sin(theta) Q; shifted by each member's delay (linear interpolation);
    ``gain`` (B, n) scales each agent's force, ``clock`` (B, n) shifts it (agent i's force at model time t
    is the one logged at t + clock_i); ``lowpass`` (B,) the force sensors' time constants (:func:`_logged`)."""
    if gain is not None or clock is not None:
        return _agent_inputs(w, r, delay, gain, clock, lowpass)
    B = r.shape[0]
    n = w.n
    lp = np.zeros(B) if lowpass is None else lowpass
    if np.any(delay != 0) or np.any(lp != 0):
        series = _logged(w, lp)
        out = []
        for k in range(B):
            if delay[k] == 0 and lp[k] == 0:
                out.append(None)
                continue
            ts = (w.t - delay[k]).ravel()
            u = np.stack([np.interp(ts, w.u_t, series[k][:, c]) for c in range(w.u.shape[1])], axis=-1)
            out.append(u.reshape(w.S, w.L, -1))
    else:
        out = [None] * B
    Fx = np.empty((B, w.S, w.L))
    Fy = np.empty_like(Fx)
    tau = np.empty_like(Fx)
    P = np.zeros_like(Fx)
    Q = np.zeros_like(Fx)
    for k in range(B):
        if out[k] is None:
            Fx[k], Fy[k], tau[k] = w.F[..., 0], w.F[..., 1], w.tau
            fx, fy = w.fx, w.fy
        else:
            u = out[k]
            Fx[k], Fy[k], tau[k] = u[..., 0], u[..., 1], u[..., 2 + 2 * n]
            fx, fy = u[..., 2 : 2 + n], u[..., 2 + n : 2 + 2 * n]
        if w.rotation:
            rx, ry = r[k, :, 0], r[k, :, 1]
            P[k] = fy @ rx - fx @ ry
            Q[k] = -(fx @ rx + fy @ ry)
    return Fx, Fy, tau, P, Q


def _agent_inputs(w: Windows, r: np.ndarray, delay: np.ndarray, gain: np.ndarray | None,
                  clock: np.ndarray | None, lowpass: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    """:func:`_rk_inputs` with per-agent gains and clocks: each agent's force taken on its own."""
    B, n = r.shape[0], w.n
    Fx = np.empty((B, w.S, w.L))
    Fy, tau = np.empty_like(Fx), np.empty_like(Fx)
    P, Q = np.zeros_like(Fx), np.zeros_like(Fx)
    lp = np.zeros(B) if lowpass is None else lowpass
    series = _logged(w, lp)
    for k in range(B):
        lag = delay[k] - (clock[k] if clock is not None else np.zeros(n))  # (n,): agent i's input from t - lag_i
        u = series[k]
        if np.any(lag != 0) or lp[k]:
            fx = np.stack([np.interp(w.t - lag[i], w.u_t, u[:, 2 + i]) for i in range(n)], axis=-1)
            fy = np.stack([np.interp(w.t - lag[i], w.u_t, u[:, 2 + n + i]) for i in range(n)], axis=-1)
        else:
            fx, fy = w.fx, w.fy
        # the logged torque column is the team's sum: delayed with the team, neither scaled nor shifted per agent
        tau[k] = np.interp(w.t - delay[k], w.u_t, u[:, 2 + 2 * n]) if delay[k] or lp[k] else w.tau
        if gain is not None:
            fx, fy = fx * gain[k], fy * gain[k]
        Fx[k], Fy[k] = fx.sum(axis=-1), fy.sum(axis=-1)
        if w.rotation:
            rx, ry = r[k, :, 0], r[k, :, 1]
            P[k] = fy @ rx - fx @ ry
            Q[k] = -(fx @ rx + fy @ ry)
    return Fx, Fy, tau, P, Q


def _shifted_states(t: np.ndarray, XS: np.ndarray, DS: np.ndarray, clock: np.ndarray) -> np.ndarray:
    """(B, S, L, n, 6) the state at each stamp minus each agent's clock offset: the cubic Hermite through the
    simulated states ``XS`` and their derivatives ``DS`` (B, S, L, 6) at the stamps, on the interval holding
    the time (beyond a window's ends, its first or last interval's cubic, extended)."""
    B, S, L, _ = XS.shape
    n = clock.shape[1]
    tau = t[None, :, :, None] - clock[:, None, None, :]  # (B, S, L, n)
    inc = np.diff(t, axis=1) > 0  # padding repeats the last stamp: zero-length intervals
    jmax = np.array([np.flatnonzero(inc[s]).max() if inc[s].any() else 0 for s in range(S)])
    idx = np.empty(tau.shape, int)
    for s in range(S):
        idx[:, s] = np.searchsorted(t[s, : jmax[s] + 2], tau[:, s], side="right") - 1
    idx = np.clip(idx, 0, jmax[None, :, None, None])
    t0 = t[np.arange(S)[None, :, None, None], idx]
    h = t[np.arange(S)[None, :, None, None], idx + 1] - t0
    h = np.where(h > 0, h, 1.0)
    u = ((tau - t0) / h)[..., None]
    flat = idx.reshape(B, S, L * n, 1)

    def at(A, off):
        return np.take_along_axis(A, flat + off, axis=2).reshape(B, S, L, n, 6)

    u2, u3 = u * u, u * u * u
    hh = h[..., None]
    return ((2 * u3 - 3 * u2 + 1) * at(XS, 0) + (u3 - 2 * u2 + u) * hh * at(DS, 0)
            + (3 * u2 - 2 * u3) * at(XS, 1) + (u3 - u2) * hh * at(DS, 1))  # fmt: skip


def input_slopes(t: np.ndarray, U: np.ndarray) -> np.ndarray:
    """dU/dt at each window's stamps (``t`` (S, L), ``U`` (B, S, L, C)): the centred difference over the
    neighbouring stamps, one-sided at a window's ends. Padding repeats the last stamp and its input, so
    the last real stamp gets the backward difference and the padding a zero slope."""
    dtc = np.empty_like(t)
    dtc[:, 1:-1] = t[:, 2:] - t[:, :-2]
    dtc[:, 0], dtc[:, -1] = t[:, 1] - t[:, 0], t[:, -1] - t[:, -2]
    dU = np.empty_like(U)
    dU[:, :, 1:-1] = U[:, :, 2:] - U[:, :, :-2]
    dU[:, :, 0], dU[:, :, -1] = U[:, :, 1] - U[:, :, 0], U[:, :, -1] - U[:, :, -2]
    ok = dtc > 0
    return np.where(ok[None, ..., None], dU / np.where(ok, dtc, 1.0)[None, ..., None], 0.0)


@dataclass(frozen=True)
class _Segment:
    """The input over one stamp interval as a function of the fraction s in [0, 1] of it: held (zoh),
    the straight line (foh), or the cubic Hermite through both ends with the slopes ``m`` (cubic)."""

    u0: np.ndarray
    u1: np.ndarray
    hold: str
    m: tuple[np.ndarray, np.ndarray] | None
    H: np.ndarray

    def at(self, s: float) -> np.ndarray:
        if self.hold == "zoh":
            return self.u0
        if self.hold == "foh" or self.m is None:
            return self.u0 + s * (self.u1 - self.u0)
        s2, s3 = s * s, s * s * s
        return ((2 * s3 - 3 * s2 + 1) * self.u0 + (s3 - 2 * s2 + s) * self.H * self.m[0]
                + (3 * s2 - 2 * s3) * self.u1 + (s3 - s2) * self.H * self.m[1])  # fmt: skip


def simulate(w: Windows, lay: Layout, g: np.ndarray, x0: np.ndarray, *, coulomb_speed: float, max_step: float,
             interval_mean: bool = False):
    """Simulate every window from its initial state for B parameter sets.

    ``g`` (B, G) global parameters, ``x0`` (B, S, K) window states. Returns predicted contact velocities
    (B, S, L, n, 2) or None (with ``interval_mean``, each stamp's velocity is the mean over the interval
    before it, the contact's displacement over the interval's length: what a difference of positions
    measures; a window's first stamp has none and keeps the instant's), positions (B, S, L, n, 2) or None,
    and the state (B, S, L, 6) [vx, vy, omega,
    theta, px, py] at the stamps.
    """
    B, S, L, n = g.shape[0], w.S, w.L, w.n
    ax = np.array(lay.axes, float)
    na = int(sum(lay.axes))
    iax = np.flatnonzero(lay.axes)
    r = g[:, : 2 * n].reshape(B, n, 2) if lay.rotation else np.zeros((B, n, 2))
    a = g[:, lay.ia][:, None]
    b = g[:, lay.ib][:, None] if lay.rotation else None

    def eff(name, default=0.0):
        if name in lay.effects:
            return g[:, lay.slot(name)]
        return None

    cv, fc = eff("viscous_friction"), eff("coulomb_friction")
    an = eff("anisotropic_friction")  # (B, 2): D's d1, d2
    cr, d, dl = eff("rotational_damping"), eff("measurement_delay"), eff("force_sensor_lag")
    lp = eff("force_sensor_lowpass")
    tb = eff("torque_bias")
    fb = np.zeros((B, 2))
    if "force_bias" in lay.effects:
        fb[:, iax] = g[:, lay.slot("force_bias")]
    # every agent's logged force reads b too high: the load gets n b less force, and the torque of -b at each
    # contact, -(R(theta) sum_i r_i) x b, turns with the load
    so = np.zeros((B, 2))
    if "force_sensor_offset" in lay.effects:
        so[:, iax] = g[:, lay.slot("force_sensor_offset")]
    fb = fb - n * so
    # every agent's sensor reads the same offset in its own frame, fixed to the load: the logged team force reads
    # R(theta) B too high (B in the load's frame at the model's angle 0) and the logged torque T too high
    bb = None
    if "sensor_offset_body" in lay.effects:
        bb = np.zeros((B, 2))
        sob = g[:, lay.slot("sensor_offset_body")]
        bb[:, iax] = -sob[:, :na]
        tb = -sob[:, na:] if tb is None else tb - sob[:, na:]
    rsum = r.sum(axis=1)  # (B, 2) sum of the contacts' body-frame arms
    sop = "force_sensor_offset" in lay.effects and lay.rotation
    vb = np.zeros((B, 2))
    if "velocity_bias" in lay.effects:
        vb[:, iax] = g[:, lay.slot("velocity_bias")]
    delay = d[:, 0] if d is not None else np.zeros(B)
    if dl is not None:  # the logged force lags the applied one: the input at t is the one logged at t + dl
        delay = delay - dl[:, 0]
    dgain = lay.per_agent(g, "agent_actuator_gain")
    clock = lay.per_agent(g, "agent_clock_offset")
    U = np.stack(_rk_inputs(w, r, delay, None if dgain is None else 1.0 + dgain, clock,
                            None if lp is None else lp[:, 0]), axis=-1)  # (B, S, L, 5)
    # state (B, S, 6): vx, vy, omega, theta, px, py
    X = np.zeros((B, S, 6))
    X[..., iax] = x0[..., :na]
    k = na
    if lay.rotation:
        X[..., 2:4] = x0[..., k : k + 2]
        k += 2
    if lay.positions:
        X[..., 4 + iax] = x0[..., k : k + na]
    e2 = coulomb_speed**2
    fbv = fb[:, None, :]
    cvv = cv[:, :1, None] if cv is not None else None
    fcc = fc[:, :1, None] if fc is not None else None
    crr = cr[:, :1] if cr is not None else None
    tbb = tb[:, :1] if tb is not None else None
    a3 = a[:, :, None] * ax
    rot = b is not None

    def deriv(X, U):
        v = X[..., 0:2]
        gf = U[..., 0:2] + fbv
        if bb is not None:
            cb, sb = np.cos(X[..., 3]), np.sin(X[..., 3])
            gf = gf + np.stack((cb * bb[:, 0:1] - sb * bb[:, 1:2], sb * bb[:, 0:1] + cb * bb[:, 1:2]), axis=-1)
        if cvv is not None:
            gf = gf - cvv * v
        if an is not None:
            # R D R^T for the traceless symmetric D is D turned by 2 theta: (d1 + i d2) e^{2 i theta}
            c2, s2 = np.cos(2 * X[..., 3]), np.sin(2 * X[..., 3])
            A = an[:, 0:1] * c2 - an[:, 1:2] * s2
            C = an[:, 0:1] * s2 + an[:, 1:2] * c2
            gf = gf - np.stack((A * v[..., 0] + C * v[..., 1], C * v[..., 0] - A * v[..., 1]), axis=-1)
        if fcc is not None:
            gf = gf - fcc / np.sqrt((v * v).sum(axis=-1, keepdims=True) + e2) * v
        out = np.empty_like(X)
        out[..., 0:2] = a3 * gf
        if rot:
            th = X[..., 3]
            tq = U[..., 2] + np.cos(th) * U[..., 3] + np.sin(th) * U[..., 4]
            if crr is not None:
                tq = tq - crr * X[..., 2]
            if tbb is not None:
                tq = tq + tbb
            if sop:  # -(R(theta) rsum) x b
                c_, s_ = np.cos(th), np.sin(th)
                Rx = c_ * rsum[:, 0:1] - s_ * rsum[:, 1:2]
                Ry = s_ * rsum[:, 0:1] + c_ * rsum[:, 1:2]
                tq = tq - (Rx * so[:, 1:2] - Ry * so[:, 0:1])
            out[..., 2] = b * tq
            out[..., 3] = X[..., 2]
        else:
            out[..., 2:4] = 0.0
        out[..., 4:6] = v
        return out

    XS = np.empty((B, S, L, 6))
    DS = np.empty((B, S, L, 6)) if clock is not None else None  # the state's derivative at the stamps
    M = input_slopes(w.t, U) if w.hold == "cubic" else None
    for j in range(L):
        XS[:, :, j] = X
        if j == L - 1:
            if DS is not None:
                DS[:, :, j] = deriv(X, U[:, :, j])
            break
        H = w.t[:, j + 1] - w.t[:, j]  # (S,)
        nsub = max(1, int(np.ceil(H.max() / max_step - 1e-9)))
        h = (H / nsub)[None, :, None]
        seg = _Segment(U[:, :, j], U[:, :, j + 1], w.hold, None if M is None else (M[:, :, j], M[:, :, j + 1]),
                       H[None, :, None])  # fmt: skip
        for s_ in range(nsub):
            U0, Uh, U1 = seg.at(s_ / nsub), seg.at((s_ + 0.5) / nsub), seg.at((s_ + 1) / nsub)
            k1 = deriv(X, U0)
            if DS is not None and s_ == 0:
                DS[:, :, j] = k1
            k2 = deriv(X + 0.5 * h * k1, Uh)
            k3 = deriv(X + 0.5 * h * k2, Uh)
            k4 = deriv(X + h * k3, U1)
            X = X + h / 6 * (k1 + 2 * (k2 + k3) + k4)
    VX, VY, OM, TH = XS[..., 0], XS[..., 1], XS[..., 2], XS[..., 3]
    PX = XS[..., 4] if lay.positions else None
    PY = XS[..., 5] if lay.positions else None
    vel = pos = None
    if clock is not None:  # each agent's rows are at its own clock's time: the state there, per agent
        XA = _shifted_states(w.t, XS, DS, clock)  # (B, S, L, n, 6)
        VX, VY, OM, TH = XA[..., 0], XA[..., 1], XA[..., 2], XA[..., 3]
        VX1, VY1 = VX, VY
        PX = XA[..., 4] if lay.positions else None
        PY = XA[..., 5] if lay.positions else None
    else:
        VX1, VY1 = VX[..., None], VY[..., None]
        if lay.positions:
            PX, PY = PX[..., None], PY[..., None]
        TH, OM = TH[..., None], OM[..., None]
    if lay.rotation:
        c, s = np.cos(TH), np.sin(TH)  # (B, S, L, 1) or per agent (B, S, L, n)
        rx, ry = r[:, None, None, :, 0], r[:, None, None, :, 1]
        Rx = c * rx - s * ry
        Ry = s * rx + c * ry
    if w.vel is not None:
        if lay.rotation:
            ux = VX1 - OM * Ry
            uy = VY1 + OM * Rx
        else:
            ux = np.broadcast_to(VX1, VX1.shape[:-1] + (n,)).copy()
            uy = np.broadcast_to(VY1, VY1.shape[:-1] + (n,)).copy()
        if interval_mean:
            qx = XS[..., 4][..., None] + (Rx if lay.rotation else 0.0)
            qy = XS[..., 5][..., None] + (Ry if lay.rotation else 0.0)
            span = np.diff(w.t, axis=1)[None, :, :, None]
            span = np.where(span > 0, span, 1.0)  # a window's padding repeats its last stamp
            ux, uy = np.broadcast_to(ux, qx.shape).copy(), np.broadcast_to(uy, qy.shape).copy()
            ux[:, :, 1:], uy[:, :, 1:] = np.diff(qx, axis=2) / span, np.diff(qy, axis=2) / span
        vel = np.stack((ux + vb[:, None, None, None, :1][..., 0], uy + vb[:, None, None, None, 1:][..., 0]), axis=-1)
    if w.pos is not None and PX is not None:
        if lay.rotation:
            qx, qy = PX + Rx, PY + Ry
        else:
            qx = np.broadcast_to(PX, PX.shape[:-1] + (n,)).copy()
            qy = np.broadcast_to(PY, PY.shape[:-1] + (n,)).copy()
        pos = np.stack((qx, qy), axis=-1)
    return vel, pos, XS
