"""Centralized batch estimator: the yardstick for the distributed algorithm (issue 3).

Pools every agent's recorded data (contact-point velocity, applied wrench; world frame, one row
per agent per tick) and fits the rigid-body model of paper 000 (Sec. II) by nonlinear least
squares. Pure: arrays in, :class:`BatchFit` out; :func:`fit_run_dir` is the only function that
touches files.

The model is the plant's own discrete step, not the ODE, so noise-free data are fitted exactly.
pymunk moves the pose before the velocities within a step, hence, per tick k (states measured at
tick k, wrench of tick k applied during the step k -> k + 1)::

    v_{k+1}     = v_k + dt a sum_i f_ik                       a = 1/m
    omega_{k+1} = omega_k + dt b T_k,  T_k = sum_i (tau_ik + (R(theta_k) r_i) x f_ik)    b = 1/J
    theta_{k+1} = theta_k + dt omega_k
    y_ik        = v_k + omega_k (R(theta_k) r_i)^perp + noise

r_i are the contact points relative to the CoM in the body frame; the body frame is the world frame
at t = 0 (theta_0 = 0), which fixes the one gauge freedom. Nothing is differentiated: velocities are
compared with the integrated model. Fitting 1/m and 1/J keeps the model linear in them and lets
"no force" mean a = 0 instead of a singular m.

Stages (each one starts the next):

1. kinematics from relative velocities: w_ik = y_ik - mean_j y_jk = i omega_k z_i(t_k) (complex
   numbers) is a rank-1 matrix over (tick, agent); its SVD gives the body-frame geometry about the
   contact centroid and a per-tick h_k = omega_k e^{i theta_k}, whose phase gives theta.
2. linear least squares: (v_0, a, z_C) from the mean contact velocity, then (omega_0, b) from omega.
3. multiple shooting: segments of ``segment_s`` with their own (v, omega, theta), weighted
   continuity residuals, analytic sparse Jacobian, ``least_squares(tr_solver='lsmr')``.
4. the same segments on every tick with exact continuity (Gauss-Newton on the null space of the
   linearised continuity constraints): the single-shooting objective without an open-loop replay of
   the whole recording, which drifts where the recorded forces make the rotation unstable. The
   constrained Jacobian at the solution, scaled by the residual variance, gives the covariance and
   the 95 % intervals.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.sparse as sp
from scipy.optimize import least_squares

Z95 = 1.959963984540054
# lsmr inside TRF: unregularised and tight, so that each step is a true Gauss-Newton step (the
# defaults needed 60+ evaluations without converging on the penalty-weighted problem; these take ~20)
_LSMR_OPTS: dict = {"regularize": False, "atol": 1e-10, "btol": 1e-10}


class BatchFitError(ValueError):
    """The input cannot be fitted (wrong shape, too short, no rotation, ...); the message says why."""


@dataclass(frozen=True)
class FitOptions:
    """Tuning of :func:`fit_recording`; the defaults fit 60-200 s of paper-fig4 data in seconds."""

    segment_s: float = 2.0  # multiple-shooting segment length (s): short enough that the init is inside the basin
    decimate: int = 4  # the multiple-shooting stage uses every this-many ticks' measurements (the polish uses all)
    continuity_weight: float = 100.0  # weight of the continuity residuals (per unit of v, omega, theta)
    max_rel_ci: float = 0.5  # a parameter whose 95 % half-width exceeds this fraction of its value is flagged
    polish: bool = True  # run the exact single-shooting stage (needed for exact CIs)
    max_nfev: int = 60  # per least-squares stage
    min_snr: float = 4.0  # ticks whose rotation signal |h|/sigma_h is below this are not used to initialise theta
    drift_factor: float = 1.5  # a model residual RMS above this times the kinematic noise estimate counts as not fitting


@dataclass(frozen=True)
class Param:
    """A scalar estimate. ``value`` is NaN when the data do not determine it (see ``note``)."""

    value: float
    ci95: float  # half-width of the 95 % interval (same unit), NaN if not identifiable
    identifiable: bool
    note: str = ""
    raw: float = math.nan  # the fitted number even when flagged (for diagnosis only)


@dataclass(frozen=True)
class BatchFit:
    """Result of :func:`fit_recording`. World frame, SI units; arrays are per tick of the recording."""

    m: Param
    J: Param
    r_body: np.ndarray  # (n, 2) contact points relative to the CoM, body frame (= world frame at t = 0)
    r_ci95: np.ndarray  # (n, 2) 95 % half-widths of r_body
    zc_body: np.ndarray  # (2,) p_G - p_C in the body frame (mean of r_body)
    zc_ci95: np.ndarray  # (2,)
    t: np.ndarray  # (T,)
    omega: np.ndarray  # (T,)
    theta: np.ndarray  # (T,) body orientation relative to t = 0
    v_c: np.ndarray  # (T, 2)
    residual_rms: float  # RMS of the velocity residuals per component (m/s): the noise sigma if the model fits
    n_used: int  # velocity components used
    wall_s: float
    nfev: int
    stage_cost: dict[str, float] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()

    @property
    def zi(self) -> np.ndarray:
        """(T, n, 2) z_i(t) = R(theta) (r_i - mean r) = p_Ci - p_G."""
        return _rotate(self.theta, self.r_body - self.zc_body)

    @property
    def zc(self) -> np.ndarray:
        """(T, 2) z_C(t) = p_G - p_C."""
        return _rotate(self.theta, self.zc_body[None, :])[:, 0, :]

    def summary(self) -> dict[str, float | bool | str]:
        """Flat dict of the scalar results (for tables and summary.json)."""
        return {
            "m": self.m.value, "m_ci95": self.m.ci95, "m_identifiable": self.m.identifiable,
            "J": self.J.value, "J_ci95": self.J.ci95, "J_identifiable": self.J.identifiable,
            "zc_x": float(self.zc_body[0]), "zc_y": float(self.zc_body[1]),
            "residual_rms": self.residual_rms, "wall_s": self.wall_s, "nfev": self.nfev,
        }  # fmt: skip


def _rotate(theta: np.ndarray, pts: np.ndarray) -> np.ndarray:
    c, s = np.cos(theta)[:, None], np.sin(theta)[:, None]
    x, y = pts[None, :, 0], pts[None, :, 1]
    return np.stack((c * x - s * y, s * x + c * y), axis=-1)


# --- input -------------------------------------------------------------------------------------
def _check_input(samples: np.ndarray, n: int, dt: float) -> tuple[np.ndarray, list[str]]:
    """Validate (T, n, 5) [vx, vy, fx, fy, tau]; missing wrenches become 0 (with a warning)."""
    if not isinstance(n, (int, np.integer)) or n < 2:
        raise BatchFitError(f"n must be an integer >= 2 (got {n!r})")
    if not (isinstance(dt, (int, float, np.floating)) and math.isfinite(dt) and dt > 0):
        raise BatchFitError(f"dt must be a positive number (got {dt!r})")
    try:
        s = np.array(samples, dtype=float)
    except (TypeError, ValueError) as exc:
        raise BatchFitError(f"samples must be a numeric array of shape (T, n, 5): {exc}") from None
    if s.ndim != 3 or s.shape[1] != n or s.shape[2] != 5:
        raise BatchFitError(f"samples must have shape (T, n={n}, 5) [vx, vy, fx, fy, tau], got {s.shape}")
    if s.shape[0] < 50:
        raise BatchFitError(f"too short: {s.shape[0]} ticks, need at least 50")
    if np.isinf(s).any():
        raise BatchFitError("samples contain inf")
    warn = []
    bad_w = np.isnan(s[..., 2:]).any(axis=-1)
    if bad_w.any():
        warn.append(f"{int(bad_w.sum())} agent-ticks without a wrench were taken as zero wrench")
        s[..., 2:] = np.nan_to_num(s[..., 2:])
    if np.isnan(s[..., :2]).all():
        raise BatchFitError("no velocity measurements")
    return s, warn


# --- stage 1 and 2: initialisation ----------------------------------------------------------------
@dataclass
class _Init:
    r: np.ndarray
    a: float
    b: float
    theta: np.ndarray
    omega: np.ndarray
    v: np.ndarray
    sigma: float
    omega_meas: np.ndarray | None = None  # omega measured from the relative velocities (noisy, no model)


def _cum_impulse(F: np.ndarray, dt: float) -> np.ndarray:
    """S_k = dt sum_{l<k} F_l: the velocity at tick k has seen the wrenches of ticks 0..k-1."""
    out = np.zeros_like(F)
    out[1:] = np.cumsum(F[:-1], axis=0) * dt
    return out


def _torque(theta: np.ndarray, r: np.ndarray, fx: np.ndarray, fy: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """Total torque about the CoM per tick: sum tau_i + (R r_i) x f_i."""
    P = fy @ r[:, 0] - fx @ r[:, 1]
    Q = -(fx @ r[:, 0] + fy @ r[:, 1])
    return tau.sum(axis=1) + np.cos(theta) * P + np.sin(theta) * Q


def _initialise(s: np.ndarray, dt: float, opt: FitOptions) -> tuple[_Init, list[str]]:
    warn: list[str] = []
    T, n, _ = s.shape
    w = s[..., 0] + 1j * s[..., 1]
    full = ~np.isnan(w).any(axis=1)
    if full.sum() < 20:
        raise BatchFitError("fewer than 20 ticks with every agent's velocity: cannot initialise")
    rel = w - w.mean(axis=1, keepdims=True)
    u, sv, vh = np.linalg.svd(rel[full], full_matrices=False)
    zb = np.conj(vh[0])  # body-frame geometry about the centroid, up to a complex factor c
    resid = rel[full] - (u[:, :1] * sv[0]) @ vh[:1]
    sigma = float(np.sqrt(np.mean(np.abs(resid) ** 2) / 2 * n / max(n - 2, 1)))
    # h_k = rel_k . conj(i zb) / |zb|^2 for every tick with any data (missing agents left out)
    wz = np.where(np.isnan(rel), 0, rel)
    ok = ~np.isnan(rel)
    den = (ok * np.abs(zb) ** 2).sum(axis=1)
    h = np.full(T, np.nan + 0j)
    has = den > 0.5
    h[has] = (wz[has] * np.conj(1j * zb)).sum(axis=1) / den[has]
    sigma_h = sigma / math.sqrt(float(np.sum(np.abs(zb) ** 2)))
    good = np.abs(np.nan_to_num(h)) > opt.min_snr * sigma_h
    if good.sum() < 20:
        raise BatchFitError(
            "the load hardly rotates (relative contact velocities at noise level): contact geometry, "
            "omega and J are not observable from these data"
        )
    idx = np.flatnonzero(good)
    phi = np.unwrap(np.angle(h[idx]))
    # signed rate from the local slope of the phase (the phase of h advances at omega whatever its sign)
    win = max(3, round(0.25 / dt))
    slope = np.gradient(np.convolve(phi, np.ones(win) / win, mode="same"), idx * dt)
    sign = np.where(slope >= 0, 1.0, -1.0)
    # |h| = |c| |omega|: the scale of the geometry from the phase rate
    sel = np.abs(slope) > 0.2 * np.median(np.abs(slope))
    cscale = float(np.median(np.abs(h[idx][sel]) / np.abs(slope[sel])))
    theta_g = phi - np.pi * (sign < 0)
    theta = np.interp(np.arange(T), idx, np.unwrap(theta_g))
    zb = zb * cscale * np.exp(1j * theta[0])  # gauge: body frame = world frame at t = 0
    theta = theta - theta[0]
    omega = np.interp(np.arange(T), idx, sign * np.abs(h[idx]) / cscale)
    omega[: idx[0]] = np.abs(h[: idx[0]]) / cscale * sign[0] if idx[0] > 0 else omega[: idx[0]]
    omega = np.nan_to_num(omega)

    fx, fy, tau = s[..., 2], s[..., 3], s[..., 4]
    F = np.stack((fx.sum(axis=1), fy.sum(axis=1)), axis=1)
    S = _cum_impulse(F, dt)
    # ybar_k = v0 + a S_k + i omega_k e^{i theta_k} zc   (complex; unknowns v0 (2), a, zc (2))
    ybar = w.mean(axis=1)  # NaN on ticks with a missing agent: those are left out below (okb)
    okb = ~np.isnan(ybar) & full
    e = 1j * omega * np.exp(1j * theta)
    cols = [np.ones(T) + 0j, 1j * np.ones(T), S[:, 0] + 1j * S[:, 1], e, 1j * e]
    A = np.stack(cols, axis=1)[okb]
    Ar = np.vstack((A.real, A.imag))
    yr = np.concatenate((ybar[okb].real, ybar[okb].imag))
    m_excited = np.ptp(S, axis=0).max() > 1e-9
    if not m_excited:
        Ar[:, 2] = 0.0
    coef = np.linalg.lstsq(Ar, yr, rcond=None)[0]
    a = float(coef[2]) if m_excited else 0.0
    if a <= 0 and m_excited:
        warn.append("initial mass estimate non-positive (weak force excitation); starting from m = 1e3 kg")
        a = 1e-3
    zc = coef[3] + 1j * coef[4]
    v0 = coef[0] + 1j * coef[1]
    r = np.stack(((zb + zc).real, (zb + zc).imag), axis=1)
    # omega_k = omega_0 + b dt sum_{l<k} T_l on the ticks where omega is well measured
    Tq = _torque(theta, r, fx, fy, tau)
    C = _cum_impulse(Tq[:, None], dt)[:, 0]
    Ab = np.stack((np.ones(T), C), axis=1)[good]
    coef_b = np.linalg.lstsq(Ab, omega[good], rcond=None)[0]
    b = float(coef_b[1])
    if not b > 0:
        warn.append("initial 1/J non-positive (weak torque excitation); starting from J = 100 kg m^2")
        b = 0.01
    omega_model = coef_b[0] + b * C
    v = np.stack(((v0 + a * (S[:, 0] + 1j * S[:, 1])).real, (v0 + a * (S[:, 0] + 1j * S[:, 1])).imag), axis=1)
    return _Init(r=r, a=a, b=b, theta=theta, omega=omega_model, v=v, sigma=sigma, omega_meas=omega), warn


# --- the discrete model with sensitivities, vectorised over segments ------------------------------
@dataclass
class _Seg:
    """Data cut into S segments of L ticks (the last one padded with zero wrench, masked)."""

    L: int
    S: int
    T: int
    y: np.ndarray  # (S, L, n, 2) measured velocities, 0 where missing
    mask: np.ndarray  # (S, L, n) 1 where measured (and used)
    fx: np.ndarray  # (S, L, n)
    fy: np.ndarray
    tau: np.ndarray  # (S, L) total
    F: np.ndarray  # (S, L, 2) total
    jsel: np.ndarray  # steps within a segment whose measurements are used (every ``decimate``-th)


def _segments(s: np.ndarray, L: int, decimate: int = 1) -> _Seg:
    T, n, _ = s.shape
    S = -(-T // L)
    pad = S * L - T
    sp_ = np.concatenate((s, np.zeros((pad, n, 5))), axis=0).reshape(S, L, n, 5)
    valid = np.concatenate((~np.isnan(s[..., 0]) & ~np.isnan(s[..., 1]), np.zeros((pad, n), bool)))
    jsel = np.arange(0, L, decimate)
    valid = valid.reshape(S, L, n)[:, jsel].astype(float)
    y = np.nan_to_num(sp_[:, jsel, :, :2])
    fx, fy = sp_[..., 2], sp_[..., 3]
    return _Seg(L=L, S=S, T=T, y=y, mask=valid, fx=fx, fy=fy, tau=sp_[..., 4].sum(axis=2),
                F=np.stack((fx.sum(axis=2), fy.sum(axis=2)), axis=-1), jsel=jsel)  # fmt: skip


def _simulate(seg: _Seg, r: np.ndarray, a: float, b: float, x0: np.ndarray, dt: float, sens: bool = True):
    """Run every segment from its state x0 = (vx, vy, omega, theta), shape (S, 4).

    Returns (v, omega, theta) over L + 1 steps and, if ``sens``, d(omega, theta)/d[r (2n), b, omega0, theta0].
    """
    S, L = seg.S, seg.L
    n = r.shape[0]
    P = seg.fy @ r[:, 0] - seg.fx @ r[:, 1]  # (S, L)
    Q = -(seg.fx @ r[:, 0] + seg.fy @ r[:, 1])
    om = np.empty((S, L + 1))
    th = np.empty((S, L + 1))
    om[:, 0], th[:, 0] = x0[:, 2], x0[:, 3]
    K = 2 * n + 3
    if sens:
        dom = np.zeros((S, L + 1, K))
        dth = np.zeros((S, L + 1, K))
        dom[:, 0, 2 * n + 1] = 1.0
        dth[:, 0, 2 * n + 2] = 1.0
        drT = np.empty((S, 2 * n))
    for j in range(L):
        c, s_ = np.cos(th[:, j]), np.sin(th[:, j])
        Tq = seg.tau[:, j] + c * P[:, j] + s_ * Q[:, j]
        om[:, j + 1] = om[:, j] + dt * b * Tq
        th[:, j + 1] = th[:, j] + dt * om[:, j]
        if sens:
            dTdth = -s_ * P[:, j] + c * Q[:, j]
            fxj, fyj = seg.fx[:, j], seg.fy[:, j]
            drT[:, 0::2] = c[:, None] * fyj - s_[:, None] * fxj
            drT[:, 1::2] = -c[:, None] * fxj - s_[:, None] * fyj
            d = dom[:, j] + (dt * b * dTdth)[:, None] * dth[:, j]
            d[:, : 2 * n] += dt * b * drT
            d[:, 2 * n] += dt * Tq
            dom[:, j + 1] = d
            dth[:, j + 1] = dth[:, j] + dt * dom[:, j]
    Sv = np.zeros((S, L + 1, 2))
    Sv[:, 1:] = np.cumsum(seg.F, axis=1) * dt
    v = x0[:, None, :2] + a * Sv
    if sens:
        return v, om, th, Sv, dom, dth
    return v, om, th, Sv, None, None


def _meas(seg: _Seg, r, a, b, x0, dt, sens=True):
    """Velocity residuals (S, J, n, 2) at the steps ``seg.jsel`` and their Jacobian (S, J, n, 2, 2n + 2 + 4)
    wrt [r, a, b | v0, omega0, theta0]."""
    n = r.shape[0]
    js = seg.jsel
    v, om, th, Sv, dom, dth = _simulate(seg, r, a, b, x0, dt, sens)
    c, s_ = np.cos(th[:, js]), np.sin(th[:, js])
    Rx = c[..., None] * r[:, 0] - s_[..., None] * r[:, 1]  # (S, L, n)
    Ry = s_[..., None] * r[:, 0] + c[..., None] * r[:, 1]
    w = om[:, js, None]
    pred = v[:, js, None, :] + w[..., None] * np.stack((-Ry, Rx), axis=-1)
    m = seg.mask[..., None]
    res = (pred - seg.y) * m
    if not sens:
        return res, (v, om, th, Sv), None
    G = 2 * n + 2
    Jb = np.zeros(res.shape + (G + 4,))
    # through omega_j and theta_j: d pred/d omega = (R r)^perp, d pred/d theta = -omega R r
    A_om = np.stack((-Ry, Rx), axis=-1)  # (S, L, n, 2)
    A_th = -w[..., None] * np.stack((Rx, Ry), axis=-1)
    sensi = A_om[..., None] * dom[:, js, None, None, :] + A_th[..., None] * dth[:, js, None, None, :]
    # K columns [r (2n), b, omega0, theta0] -> [r, a, b | v0x, v0y, omega0, theta0]
    Jb[..., : 2 * n] = sensi[..., : 2 * n]
    Jb[..., 2 * n + 1] = sensi[..., 2 * n]
    Jb[..., G + 2] = sensi[..., 2 * n + 1]
    Jb[..., G + 3] = sensi[..., 2 * n + 2]
    # direct terms
    ii = np.arange(n)
    wv = w
    Jb[:, :, ii, 0, 2 * ii] += -s_[..., None] * wv  # d pred_x / d r_ix = omega (-s)
    Jb[:, :, ii, 1, 2 * ii] += c[..., None] * wv
    Jb[:, :, ii, 0, 2 * ii + 1] += -c[..., None] * wv
    Jb[:, :, ii, 1, 2 * ii + 1] += -s_[..., None] * wv
    Jb[..., 2 * n] = Sv[:, js, None, :]
    Jb[..., 0, G] = 1.0
    Jb[..., 1, G + 1] = 1.0
    Jb *= m[..., None]
    return res, (v, om, th, Sv), (Jb, dom, dth)


def _wrap(x):
    return (x + np.pi) % (2 * np.pi) - np.pi


# --- stage 3: multiple shooting -----------------------------------------------------------------
def _segment_ticks(opt: FitOptions, dt: float) -> int:
    return max(opt.decimate, round(opt.segment_s / dt) // opt.decimate * opt.decimate)


def _ms_trajectory(s: np.ndarray, dt: float, opt: FitOptions, r, a, b, xs) -> tuple[np.ndarray, ...]:
    """(v (T, 2), omega (T,), theta (T,)) of a multiple-shooting solution, segment by segment."""
    L = _segment_ticks(opt, dt)
    T = s.shape[0]
    v, om, th, _, _, _ = _simulate(_segments(s, L, opt.decimate), r, a, b, xs, dt, sens=False)
    return v[:, :L].reshape(-1, 2)[:T], om[:, :L].reshape(-1)[:T], th[:, :L].reshape(-1)[:T]


def _multiple_shooting(s: np.ndarray, dt: float, ini: _Init, opt: FitOptions, fix_a: bool, fix_b: bool,
                       solve: bool = True):  # fmt: skip
    """Stage 3. ``solve=False`` returns the problem instead: (evaluate, unpack, x0, n_meas, keep)."""
    n = s.shape[1]
    L = _segment_ticks(opt, dt)
    seg = _segments(s, L, opt.decimate)
    S = seg.S
    G = 2 * n + 2
    W = opt.continuity_weight
    starts = np.arange(S) * L
    # each segment starts from the measured omega (0.1 s mean), not from the initial b's model: a wrong
    # initial J makes the integrated model drift by tenths of a rad/s over a long recording, which puts
    # late segments outside the basin (a 2 s segment then turns a radian too far)
    om0 = ini.omega
    if ini.omega_meas is not None:
        win = max(1, round(0.1 / dt))
        om0 = np.convolve(ini.omega_meas, np.ones(win) / win, mode="same")
    x0 = np.stack((ini.v[starts, 0], ini.v[starts, 1], om0[starts], ini.theta[starts]), axis=1)
    # unknowns: r, [a], [b], seg states with seg 0's theta fixed at 0
    full_cols = G + 4 * S
    keep = np.ones(full_cols, bool)
    keep[G + 3] = False
    if fix_a:
        keep[2 * n] = False
    if fix_b:
        keep[2 * n + 1] = False
    newidx = np.cumsum(keep) - 1
    full0 = np.concatenate((ini.r.ravel(), [ini.a, ini.b], x0.ravel()))
    full0[G + 3] = 0.0
    P = int(keep.sum())

    def unpack(x):
        f = full0.copy()
        f[keep] = x
        return f[: 2 * n].reshape(n, 2), f[2 * n], f[2 * n + 1], f[G:].reshape(S, 4)

    # sparsity pattern (fixed): measurement rows, then 4 continuity rows per segment boundary
    used = np.repeat(seg.mask.ravel() > 0, 2)  # only the measured (and kept) velocity components
    nm = int(used.sum())
    rows_m = np.repeat(np.arange(nm), G + 4)
    seg_of_row = np.repeat(np.arange(S), len(seg.jsel) * n * 2)[used]
    cols_m = np.concatenate(
        (np.tile(np.arange(G), (nm, 1)), G + 4 * seg_of_row[:, None] + np.arange(4)), axis=1
    ).ravel()
    nd = 4 * (S - 1)
    rows_d = nm + np.repeat(np.arange(nd), G + 8)
    sb = np.repeat(np.arange(S - 1), 4)
    cols_d = np.concatenate(
        (np.tile(np.arange(G), (nd, 1)), G + 4 * sb[:, None] + np.arange(8)), axis=1
    ).ravel()
    rows = np.concatenate((rows_m, rows_d))
    cols = np.concatenate((cols_m, cols_d))
    sel = keep[cols]
    rows, cols = rows[sel], newidx[cols[sel]]
    cache: dict = {}

    def evaluate(x):
        key = x.tobytes()
        if key in cache:
            return cache[key]
        cache.clear()
        r, a, b, xs = unpack(x)
        res, (v, om, th, Sv), (Jb, dom, dth) = _meas(seg, r, a, b, xs, dt)
        # continuity: end of segment k minus start of k + 1
        dv = v[:-1, L] - xs[1:, :2]
        dw = om[:-1, L] - xs[1:, 2]
        dthe = _wrap(th[:-1, L] - xs[1:, 3])
        defect = W * np.concatenate((dv, dw[:, None], dthe[:, None]), axis=1)  # (S-1, 4)
        Jd = np.zeros((S - 1, 4, G + 8))
        Jd[:, 0:2, 2 * n] = Sv[:-1, L]
        Jd[:, 0, G], Jd[:, 1, G + 1] = 1.0, 1.0
        for row, dd in ((2, dom), (3, dth)):
            e = dd[:-1, L]
            Jd[:, row, : 2 * n] = e[:, : 2 * n]
            Jd[:, row, 2 * n + 1] = e[:, 2 * n]
            Jd[:, row, G + 2] = e[:, 2 * n + 1]
            Jd[:, row, G + 3] = e[:, 2 * n + 2]
        Jd[:, 0, G + 4], Jd[:, 1, G + 5], Jd[:, 2, G + 6], Jd[:, 3, G + 7] = -1.0, -1.0, -1.0, -1.0
        Jd *= W
        data = np.concatenate((Jb.reshape(-1, G + 4)[used].ravel(), Jd.ravel()))[sel]
        jac = sp.csr_matrix((data, (rows, cols)), shape=(nm + nd, P))
        out = (np.concatenate((res.ravel()[used], defect.ravel())), jac)
        cache[key] = out
        return out

    if not solve:
        return evaluate, unpack, full0[keep], nm, keep
    sol = least_squares(
        lambda x: evaluate(x)[0], full0[keep], jac=lambda x: evaluate(x)[1], method="trf",
        tr_solver="lsmr", x_scale="jac", max_nfev=opt.max_nfev, xtol=1e-9, ftol=1e-9, gtol=1e-10,
        tr_options=_LSMR_OPTS,
    )  # fmt: skip
    r, a, b, xs = unpack(sol.x)
    sol.segment_states = xs  # (S, 4) for _ms_trajectory
    sol.n_meas = nm
    sol.keep = keep
    return r, a, b, xs[0, :3].copy(), sol


def _ms_exact(s: np.ndarray, dt: float, opt: FitOptions, r, a, b, ms, fix_a: bool, fix_b: bool, iters: int = 8):
    """Stage 4: the stage-3 segments on every tick, continuity exact.

    The same objective as single shooting over the whole recording (the continuity constraints make the
    segments one trajectory), without its open-loop replay: where the recorded world-frame forces make
    the rotation unstable (an error in theta changes the torque, which grows it; the agents' feedback is
    not in a replay) a 120 s single shooting from the stage-3 solution drifts off the data and its polish
    ends in a wrong minimum (paper-fig4 seed 3: J -42 %, residual 2.4 m/s against a noise of 0.3).
    Where single shooting works the two agree to 1e-11 (seed 1), and this is cheaper (13 s CPU, not 19).

    Gauss-Newton on the measurement residuals subject to the linearised continuity constraints (KKT
    system; P ~ 2n + 4 S unknowns, so everything is dense and small), from the stage-3 solution; the
    covariance is the constrained one, s^2 Z (Z^T J^T J Z)^-1 Z^T with Z a basis of the constraints' null
    space, i.e. that of single shooting without its open-loop replay. Returns
    (r, a, b, (v, omega, theta) per tick, measurement residuals, covariance of the unknowns, keep, nfev).
    """
    from scipy.linalg import null_space

    v1, om1, th1 = _ms_trajectory(s, dt, opt, r, a, b, ms.segment_states)
    opt1 = replace(opt, decimate=1)
    evaluate, unpack, x, nm, keep = _multiple_shooting(s, dt, _Init(r, a, b, th1, om1, v1, 0.0), opt1, fix_a, fix_b,
                                                       solve=False)  # fmt: skip
    W = opt1.continuity_weight

    def split(x):
        f, jac = evaluate(x)
        return f[:nm], jac[:nm], f[nm:] / W, (jac[nm:] / W).toarray()

    def basis(C):  # of the null space of the linearised continuity constraints (all of R^P for one segment)
        return null_space(C) if C.shape[0] else np.eye(C.shape[1])

    rm, Jm, c, C = split(x)
    P = Jm.shape[1]
    nfev = 1
    for _ in range(iters):
        # null-space step: d = d_p + Z y with C d_p = -c (minimum norm), y minimising |rm + Jm d|^2
        H = (Jm.T @ Jm).toarray()
        Z = basis(C)
        d_p = np.linalg.lstsq(C, -c, rcond=None)[0] if C.shape[0] else np.zeros(P)
        y = -np.linalg.pinv(Z.T @ H @ Z, rcond=1e-13, hermitian=True) @ (Z.T @ (Jm.T @ rm + H @ d_p))
        step = d_p + Z @ y
        rn, Jn, cn, Cn = split(x + step)
        nfev += 1
        done = abs(rm @ rm - rn @ rn) <= 1e-10 * (rm @ rm) and np.abs(cn).max(initial=0.0) <= 1e-9
        x = x + step

        rm, Jm, c, C = rn, Jn, cn, Cn
        if done:
            break
    H = (Jm.T @ Jm).toarray()
    Z = basis(C)
    sigma2 = float(rm @ rm) / max(nm - Z.shape[1], 1)
    cov = sigma2 * Z @ np.linalg.pinv(Z.T @ H @ Z, rcond=1e-13, hermitian=True) @ Z.T
    r, a, b, xs = unpack(x)
    traj = _ms_trajectory(s, dt, opt1, r, a, b, xs)
    return r, a, b, traj, rm, cov, keep, nfev


def _single_shooting(s, dt, r0, a0, b0, x00, opt: FitOptions, fix_a, fix_b):
    """The whole recording simulated from one initial state, not optimised: residuals and the dense Jacobian
    for the intervals of an unpolished fit (``FitOptions(polish=False)``, as ident.diagnose uses)."""
    n = s.shape[1]
    T = s.shape[0]
    seg = _segments(s, T, 1)
    G = 2 * n + 2
    keep = np.ones(G + 4, bool)
    keep[G + 3] = False  # theta_0 = 0: the gauge
    if fix_a:
        keep[2 * n] = False
    if fix_b:
        keep[2 * n + 1] = False
    full0 = np.concatenate((r0.ravel(), [a0, b0], x00, [0.0]))
    cache: dict = {}

    def unpack(x):
        f = full0.copy()
        f[keep] = x
        return f[: 2 * n].reshape(n, 2), f[2 * n], f[2 * n + 1], f[G:][None, :]

    def evaluate(x):
        key = x.tobytes()
        if key not in cache:
            cache.clear()
            r, a, b, xs = unpack(x)
            res, traj, (Jb, _, _) = _meas(seg, r, a, b, xs, dt)
            cache[key] = (res.ravel(), Jb.reshape(-1, G + 4)[:, keep], traj)
        return cache[key]

    x, nfev = full0[keep], 0
    res, jac, traj = evaluate(x)
    r, a, b, xs = unpack(x)
    return r, a, b, xs[0], res, jac, traj, keep, nfev


# --- public API ----------------------------------------------------------------------------------
def fit_recording(samples: np.ndarray, n: int, dt: float, *, options: FitOptions | None = None,
                  clock: Callable[[], float] | None = None) -> BatchFit:
    """Fit m, J, the contact geometry and the motion to one recording.

    ``samples``: shape (T, n, 5), per tick and agent [vx, vy, fx, fy, tau] (world frame, tick k at
    t = k dt; NaN velocity = not measured). ``clock`` (e.g. ``time.perf_counter``) times the fit
    into ``wall_s`` (0 without it). Raises :class:`BatchFitError` for malformed input or data
    that cannot determine the geometry at all (a load that never rotates).
    """
    opt = options or FitOptions()
    t_start = clock() if clock is not None else 0.0
    s, warn = _check_input(samples, n, dt)
    T = s.shape[0]
    F = s[..., 2:4].sum(axis=1)
    Fscale = float(np.abs(s[..., 2:4]).max(initial=0.0))
    fix_a = bool(np.ptp(_cum_impulse(F, dt), axis=0).max() <= 1e-12 * max(Fscale, 1.0) * T * dt)
    fix_b = bool(np.abs(s[..., 2:]).max(initial=0.0) == 0.0)
    ini, w2 = _initialise(s, dt, opt)
    warn += w2
    if fix_a:
        ini.a = 0.0
    cost = {}
    r, a, b, x00, ms = _multiple_shooting(s, dt, ini, opt, fix_a, fix_b)
    cost["multiple_shooting"] = float(ms.cost)
    nfev = int(ms.nfev)
    if not opt.polish:  # the stage-3 solution as it is, with a single-shooting Jacobian for its intervals
        r, a, b, x00, res, jac, (v, om, th, _), keep, nf2 = _single_shooting(s, dt, r, a, b, x00, opt, fix_a, fix_b)
        v, om, th = v[0, :T], om[0, :T], th[0, :T]
        nfev += nf2
        n_used = int(np.count_nonzero(jac.any(axis=1)))
        rss = float(res @ res)
        p = jac.shape[1]
        sigma2 = rss / max(n_used - p, 1)
        cost["single_shooting"] = 0.5 * rss
        cov = sigma2 * np.linalg.pinv(jac.T @ jac, rcond=1e-13, hermitian=True)
        se = np.full(2 * n + 6, np.nan)
        se[np.flatnonzero(keep)] = np.sqrt(np.clip(np.diag(cov), 0, None))
        full_cov = np.zeros((2 * n + 6, 2 * n + 6))
        kk = np.flatnonzero(keep)
        full_cov[np.ix_(kk, kk)] = cov
    else:
        r, a, b, (v, om, th), res, cov_ms, keep_ms, nf2 = _ms_exact(s, dt, opt, r, a, b, ms, fix_a, fix_b)
        nfev += nf2
        n_used = int(res.size)
        rss = float(res @ res)
        cost["multiple_shooting_exact"] = 0.5 * rss
        # back to the single-shooting layout [r (2n), a, b, v0 (2), omega0, theta0] (only r, a, b used below)
        G = 2 * n + 2
        pos = {int(f): i for i, f in enumerate(np.flatnonzero(keep_ms))}
        idx = np.array([pos.get(j, -1) for j in range(G)])
        ok = np.flatnonzero(idx >= 0)
        full_cov = np.zeros((2 * n + 6, 2 * n + 6))
        full_cov[np.ix_(ok, ok)] = cov_ms[np.ix_(idx[ok], idx[ok])]
        se = np.full(2 * n + 6, np.nan)
        se[ok] = np.sqrt(np.clip(np.diag(full_cov)[ok], 0, None))
    if opt.polish and math.sqrt(rss / max(n_used, 1)) > opt.drift_factor * ini.sigma + 1e-9:
        warn.append(f"the fitted model leaves a residual of {math.sqrt(rss / max(n_used, 1)):.3g} m/s against a "
                    f"noise of {ini.sigma:.3g} m/s: it does not explain the data (not converged, or effects the "
                    f"model lacks: see coload diagnose)")  # fmt: skip

    def inverse_param(val, se_, fixed, name, unit_note):
        if fixed:
            return Param(math.nan, math.nan, False, unit_note, math.nan)
        raw = 1.0 / val if val != 0 else math.inf
        half = Z95 * se_ / val**2 if val != 0 else math.inf
        ok = val > 0 and math.isfinite(half) and half <= opt.max_rel_ci * abs(raw)
        if ok:
            return Param(raw, half, True, "", raw)
        return Param(math.nan, math.nan, False, f"{name}: 95 % interval wider than {opt.max_rel_ci:.0%} of the value "
                     f"(fit {raw:.4g} +- {half:.3g}): weakly excited", raw)  # fmt: skip

    m = inverse_param(a, se[2 * n], fix_a, "m", "sum of forces is zero throughout: m is not observable")
    J = inverse_param(b, se[2 * n + 1], fix_b, "J", "no force or torque applied: J is not observable")
    for p_ in (m, J):
        if not p_.identifiable:
            warn.append(p_.note)
    ridx = np.arange(2 * n)
    r_ci = Z95 * se[ridx].reshape(n, 2)
    avg = np.zeros((2, 2 * n))
    avg[0, 0::2] = 1.0 / n
    avg[1, 1::2] = 1.0 / n
    zc_cov = avg @ full_cov[: 2 * n, : 2 * n] @ avg.T
    zc_ci = Z95 * np.sqrt(np.clip(np.diag(zc_cov), 0, None))
    return BatchFit(
        m=m, J=J, r_body=r, r_ci95=r_ci, zc_body=r.mean(axis=0), zc_ci95=zc_ci,
        t=np.arange(T) * dt, omega=np.array(om, dtype=float), theta=np.array(th, dtype=float),
        v_c=np.array(v, dtype=float),
        residual_rms=math.sqrt(rss / max(n_used, 1)), n_used=n_used,
        wall_s=clock() - t_start if clock is not None else 0.0, nfev=nfev, stage_cost=cost, warnings=tuple(warn),
    )  # fmt: skip


def samples_array(t: np.ndarray, columns: dict[str, np.ndarray], dt: float) -> np.ndarray:
    """(T, n, 5) from a pivoted samples table (``AgentTable``); missing ticks become NaN rows.

    Raises :class:`BatchFitError` if the times are not on the tick grid k dt starting at 0.
    """
    for c in ("vx", "vy", "fx", "fy", "tau"):
        if c not in columns:
            raise BatchFitError(f"samples: missing column {c!r}")
    t = np.asarray(t, dtype=float)
    if t.size == 0:
        raise BatchFitError("samples: no rows")
    k = np.rint(t / dt)
    if np.abs(t - k * dt).max() > 1e-6 * dt + 1e-9 or k.min() < 0:
        raise BatchFitError(f"samples: times are not on the tick grid k * dt (dt = {dt})")
    k = k.astype(int)
    if len(np.unique(k)) != len(k):
        raise BatchFitError("samples: two rows map to the same tick")
    n = columns["vx"].shape[1]
    out = np.full((int(k.max()) + 1, n, 5), np.nan)
    for j, c in enumerate(("vx", "vy", "fx", "fy", "tau")):
        out[k, :, j] = columns[c]
    return out


__all__ = ["BatchFit", "BatchFitError", "FitOptions", "Param", "fit_recording", "samples_array"]
