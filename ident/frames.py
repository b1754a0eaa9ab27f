"""Forces logged in each robot's own frame: a logger's quirk, checked before the diagnosis (docs/diagnose.md).

A robot fixed to the load that logs its force in its own frame writes f_i = R(theta + phi_i)^T f_i,world
(theta the load's angle, phi_i the robot's mounting angle): the force turns with the load, and the
world-frame model reads it as a wrong mass, J and effects. The check compares the translation's equation
error with the forces as logged and turned by the load's angle from the kinematics (the start of
:mod:`ident.fit`, which uses no force), each with its own complex coefficient per agent (the mass and the
mounting angle), per window; a robot-frame log is converted to the world frame and diagnosed as such.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy import stats as sst
from scipy.optimize import minimize_scalar

from ident.fit import FitError, _cumint_windows, _filled, _rotation_kinematics
from ident.recording import Recording, agent_period


@dataclass(frozen=True)
class _FrameTest:
    """An equation error's sums of squares in the world frame and the robots' frames, the one-sided t-test over
    windows of the log of their ratio per window, and each agent's mounting angle (rad)."""

    rss_world: float
    rss_robot: float
    t: float
    p: float
    windows: int
    phi: np.ndarray

    def summary(self, level: float) -> dict:
        """The report's entry: whether the robots' frames pass at ``level``, the sums, the test and the angles
        (deg)."""
        return {"robot_frame": bool(self.p < level), "rss_world": self.rss_world, "rss_robot": self.rss_robot,
                "t": self.t, "p": self.p, "windows": self.windows, "phi_deg": np.degrees(self.phi).tolist()}


def _ratio_test(per_world: np.ndarray, per_robot: np.ndarray) -> tuple[float, float]:
    """The one-sided t-test over windows of the log ratio of the world frame's error to the robots' frames'
    (> 0: the robots' frames fit better): t and p. The windows differ in excitation, so the ratio, not the
    difference, is alike across them."""
    d = np.log(np.maximum(per_world, 1e-300) / np.maximum(per_robot, 1e-300))
    m = d.size
    sd = float(d.std(ddof=1))
    tt = float(d.mean() / (sd / math.sqrt(m))) if sd > 0 else (math.inf if d.mean() > 0 else -math.inf)
    return tt, float(sst.t.sf(tt, m - 1))


@dataclass(frozen=True)
class FrameCheck(_FrameTest):
    """The forces' comparison (the translation's equation error): the mounting angles in the body frame at the
    first stamp, with their jackknife 95 % half-widths, and the load's angle used (T,)."""

    phi_ci95: np.ndarray
    theta: np.ndarray


def _design(rec: Recording, theta: np.ndarray, omega: np.ndarray, wid: np.ndarray, robot: bool):
    """Columns of the complex equation error of the agents' mean velocity: each agent's integrated force
    (turned by the load's angle when ``robot``), the integrated velocity (viscous friction) and the
    centroid's offset (i omega e^{i theta}); each window's start velocity is taken out by removing each
    window's mean (of the rows used) from the columns and the velocity."""
    t = rec.t
    f = rec.wrench[..., 0] + 1j * rec.wrench[..., 1]  # (T, n)
    if robot:
        f = f * np.exp(1j * theta)[:, None]
    y = np.nanmean(rec.vel[..., 0] + 1j * rec.vel[..., 1], axis=1)
    ok = ~np.isnan(y)
    yf = np.interp(t, t[ok], y[ok].real) + 1j * np.interp(t, t[ok], y[ok].imag)
    If = _cumint_windows(t, wid, f, "foh")
    A = np.column_stack((If, _cumint_windows(t, wid, yf, "foh"), 1j * omega * np.exp(1j * theta)))
    return A, y, ok


def _within(x: np.ndarray, wid: np.ndarray, ok: np.ndarray, S: int) -> np.ndarray:
    """``x`` (T, ...) less its mean over each window's rows ``ok``; 0 off them."""
    x = np.where(ok.reshape((-1,) + (1,) * (x.ndim - 1)), x, 0)
    cnt = np.maximum(np.bincount(wid, weights=ok.astype(float), minlength=S), 1)
    flat = x.reshape(x.shape[0], -1)
    out = flat - (_window_sums(flat, wid, S) / cnt[:, None])[wid]
    return np.where(ok[:, None], out, 0).reshape(x.shape)


def _window_sums(x: np.ndarray, wid: np.ndarray, S: int) -> np.ndarray:
    """(S, ...) the sums of complex ``x`` (T, ...) over each window's rows."""
    flat = x.reshape(x.shape[0], -1)
    out = np.stack([np.bincount(wid, weights=c.real, minlength=S) + 1j * np.bincount(wid, weights=c.imag, minlength=S)
                    for c in flat.T], axis=-1)  # fmt: skip
    return out.reshape((S,) + x.shape[1:])


def frame_check(rec: Recording, window_s: float, gap_factor: float = 5.0,
                angle: tuple[np.ndarray, np.ndarray] | None = None, min_rows: int = 10) -> FrameCheck | None:
    """The check on a velocity recording of n >= 2 agents whose load turns; None where it cannot be made
    (fewer than 3 windows with ``min_rows`` rows). ``angle``: the load's angle and rate (T,) each, from a
    fit, in place of the kinematics'."""
    if rec.vel is None or rec.n < 2:
        return None
    filled = _filled(rec, gap_factor)
    if angle is not None:
        theta, omega = angle
        good = np.isfinite(theta)
    else:
        try:
            theta, omega, _, good = _rotation_kinematics(filled, gap_factor=gap_factor, period=agent_period(rec))
        except FitError:
            return None
    t = rec.t
    wid = np.floor((t - t[0]) / window_s).astype(int)
    S = int(wid.max()) + 1

    def fit(robot: bool):
        """Each used window's sum of squared equation error, its normal equations, the coefficients, the
        windows used; None with fewer than 3 windows of ``min_rows`` rows."""
        A, y, ok = _design(filled, theta, omega, wid, robot)
        ok &= good
        rows = np.bincount(wid, weights=ok.astype(float), minlength=S)
        ok &= rows[wid] >= min_rows
        used = np.flatnonzero(rows >= min_rows)
        if used.size < 3:
            return None
        A, y = _within(A, wid, ok, S), _within(y, wid, ok, S)
        # per-window normal equations: the whole fit and each delete-one-window fit by subtraction
        Gs = _window_sums(A.conj()[:, :, None] * A[:, None, :], wid, S)[used]
        bs = _window_sums(A.conj() * y[:, None], wid, S)[used]
        coef = np.linalg.lstsq(Gs.sum(0), bs.sum(0), rcond=None)[0]
        e = np.where(ok, y - A @ coef, 0)
        return np.bincount(wid, weights=np.abs(e) ** 2, minlength=S)[used], Gs, bs, coef

    world, robot = fit(False), fit(True)
    if world is None or robot is None:
        return None
    per_world, (per_robot, Gs, bs, coef) = world[0], robot
    # the mounting angles, left out one window at a time: the equation error is correlated within a window,
    # so the windows are the units of its spread
    n = rec.n
    m = per_robot.size
    jack = np.array([np.angle(np.linalg.lstsq(Gs.sum(0) - Gs[k], bs.sum(0) - bs[k], rcond=None)[0][:n]
                              * np.conj(coef[:n])) for k in range(m)])  # fmt: skip
    se = np.sqrt((m - 1) / m * ((jack - jack.mean(axis=0)) ** 2).sum(axis=0))
    phi, phi_ci95 = np.angle(coef[:n]), sst.t.ppf(0.975, m - 1) * se
    tt, p = _ratio_test(per_world, per_robot)
    return FrameCheck(float(per_world.sum()), float(per_robot.sum()), tt, p, m, phi, phi_ci95, theta)


def to_world(rec: Recording, theta: np.ndarray, phi: np.ndarray) -> Recording:
    """``rec`` with each agent's logged force turned from its frame to the world's: R(theta + phi_i) f_i."""
    w = rec.wrench.copy()
    rot = np.exp(1j * (theta[:, None] + phi[None, :]))
    f = (w[..., 0] + 1j * w[..., 1]) * rot
    w[..., 0], w[..., 1] = f.real, f.imag
    return replace(rec, wrench=w)


@dataclass(frozen=True)
class VelocityFrameCheck(_FrameTest):
    """The velocities' comparison: the kinematics' equation error in the world frame (the agents' relative
    velocities rank one, y_j - y_0 = h(t) d_j, h complex) and in the robots' frames (c_j V_j - V_0 = i omega(t)
    d_j, omega real); the mounting angles relative to agent 0, the load's rate and angle (T,) from the robots'
    frames, and the angle (rad) that turns the result to the world frame of the forces."""

    omega: np.ndarray
    theta: np.ndarray
    alpha: float


def _robot_kinematics(V: np.ndarray, iters: int = 40) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Alternating least squares for c_j V_j - V_0 = i omega d_j (``V`` (T, n) complex, every agent at every row):
    c (n,) unit, c_0 = 1 (each robot's frame turned to robot 0's), d (n,) the contacts relative to agent 0's in
    that frame, omega (T,) real. Start: c_j from V_0 regressed on V_j (the common translation), omega from the
    rank one of what is left, made real by half the angle of the sum of its squares."""
    n = V.shape[1]
    c = np.ones(n, complex)
    for j in range(1, n):
        k = np.vdot(V[:, j], V[:, 0])
        c[j] = k / abs(k) if abs(k) > 0 else 1.0
    R = c[1:] * V[:, 1:] - V[:, [0]]
    U, s, Wh = np.linalg.svd(R, full_matrices=False)
    h = U[:, 0] * s[0]
    ph = 0.5 * np.angle(np.sum(h * h))
    omega = (h * np.exp(-1j * ph)).real
    d = np.r_[0.0, -1j * np.exp(1j * ph) * Wh[0]]
    for _ in range(iters):
        for j in range(1, n):  # c_j and d_j given omega
            A = np.column_stack((V[:, j], -1j * omega))
            sol = np.linalg.lstsq(A, V[:, 0], rcond=None)[0]
            c[j] = sol[0] / abs(sol[0]) if abs(sol[0]) > 0 else 1.0
            d[j] = np.vdot(-1j * omega, V[:, 0] - c[j] * V[:, j]) / max(float(omega @ omega), 1e-300)
        r = c[1:] * V[:, 1:] - V[:, [0]]  # omega per row given c, d: real least squares over the agents
        dd = 1j * d[1:]
        omega = (r * dd.conj()).real.sum(axis=1) / max(float(np.sum(np.abs(dd) ** 2)), 1e-300)
    return c, d, omega


def velocity_frame_check(rec: Recording, window_s: float, level: float, min_rows: int = 10) -> VelocityFrameCheck | None:
    """The check on a velocity recording of n >= 3 agents: the rigid body's kinematics fitted to the velocities
    as logged (world frame) and as each robot's own (turning with the load); None where it cannot be made (fewer
    than 3 windows of ``min_rows`` rows with every agent). The load's angle and ``alpha`` are read only where
    the robots' frames pass at ``level`` (empty and NaN otherwise)."""
    if rec.vel is None or rec.n < 3:
        return None
    V = rec.vel[..., 0] + 1j * rec.vel[..., 1]
    ok = ~np.isnan(V).any(axis=1)
    t = rec.t
    wid = np.floor((t - t[0]) / window_s).astype(int)
    S = int(wid.max()) + 1
    rows = np.bincount(wid, weights=ok.astype(float), minlength=S)
    used = np.flatnonzero(rows >= min_rows)
    if used.size < 3:
        return None
    Vo = V[ok]
    Rw = Vo[:, 1:] - Vo[:, [0]]
    U, s, Wh = np.linalg.svd(Rw, full_matrices=False)
    ew = Rw - np.outer(U[:, 0] * s[0], Wh[0])
    c, d, om = _robot_kinematics(Vo)
    er = c[1:] * Vo[:, 1:] - Vo[:, [0]] - 1j * np.outer(om, d[1:])
    per_w = np.bincount(wid[ok], weights=(np.abs(ew) ** 2).sum(axis=1), minlength=S)[used]
    per_r = np.bincount(wid[ok], weights=(np.abs(er) ** 2).sum(axis=1), minlength=S)[used]
    m = used.size
    tt, p = _ratio_test(per_w, per_r)
    if not p < level:
        return VelocityFrameCheck(float(per_w.sum()), float(per_r.sum()), tt, p, m, np.angle(c), np.zeros(0),
                                  np.zeros(0), math.nan)  # fmt: skip
    # the kinematics in the robots' frames see only omega d_j: omega's scale and sign are open (positions would
    # fix them, velocities do not). The result's frame is robot 0's at the first stamp, a constant turn alpha
    # from the forces' world frame. The scale k and alpha are read from the translation's equation error with
    # the team's force (its coefficient is e^{-i alpha}/m), or with each agent's force turned by the load's angle
    # when the forces are in the robots' frames too: the k that leaves the least error, on a grid of
    # ratios over the contacts' spread taken as 1 m, then refined
    om1 = np.interp(t, t[ok], om) * float(np.mean(np.abs(d[1:])))

    def error(k: float) -> tuple[float, np.ndarray, np.ndarray, float]:
        omega = k * om1
        theta = np.concatenate(([0.0], np.cumsum(0.5 * (omega[1:] + omega[:-1]) * np.diff(t))))
        Y = np.exp(1j * theta)[:, None] * c[None, :] * V
        turned = _filled(replace(rec, vel=np.stack((Y.real, Y.imag), axis=-1)), 5.0)
        out = []
        for robot in (False, True):  # the forces in the world frame (one coefficient), or in the robots' too
            A, y, okd = _design(turned, theta, omega, wid, robot=robot)
            if not robot:
                A = np.column_stack((A[:, : rec.n].sum(axis=1), A[:, rec.n :]))
            okd &= ok
            A, y = _within(A, wid, okd, S), _within(y, wid, okd, S)
            coef = np.linalg.lstsq(A[okd], y[okd], rcond=None)[0]
            # with the forces in the robots' frames too, the world's orientation is nowhere in the data: alpha 0
            out.append((float(np.sum(np.abs(y[okd] - A[okd] @ coef) ** 2)), omega, theta,
                        0.0 if robot else float(-np.angle(coef[0]))))  # fmt: skip
        return min(out, key=lambda e: e[0])

    grid = np.exp(np.linspace(np.log(0.05), np.log(20.0), 61))
    ks = np.r_[grid, -grid]
    errs = [error(k)[0] for k in ks]
    k0 = float(ks[int(np.argmin(errs))])
    step = grid[1] / grid[0]
    res = minimize_scalar(lambda x: error(math.copysign(math.exp(x), k0))[0], method="bounded",
                          bounds=(math.log(abs(k0) / step), math.log(abs(k0) * step)), options={"xatol": 1e-6})
    _, omega, theta, alpha = error(math.copysign(math.exp(res.x), k0))
    return VelocityFrameCheck(float(per_w.sum()), float(per_r.sum()), tt, p, m, np.angle(c), omega, theta, alpha)


def velocities_to_world(rec: Recording, vc: VelocityFrameCheck) -> Recording:
    """``rec`` with each agent's logged velocity turned from its frame to the world's: e^{i (alpha + theta + phi_j)}."""
    V = rec.vel[..., 0] + 1j * rec.vel[..., 1]
    Y = np.exp(1j * (vc.alpha + vc.theta))[:, None] * np.exp(1j * vc.phi)[None, :] * V
    return replace(rec, vel=np.stack((Y.real, Y.imag), axis=-1))


__all__ = ["FrameCheck", "VelocityFrameCheck", "frame_check", "to_world", "velocities_to_world", "velocity_frame_check"]
