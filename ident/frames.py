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

from ident.fit import FitError, _cumint_windows, _filled, _rotation_kinematics
from ident.recording import Recording


@dataclass(frozen=True)
class FrameCheck:
    """The comparison: the equation error's sums of squares in the world frame and the robot frames, the
    one-sided t-test over windows of the log of their ratio per window, the mounting angles (rad, body frame at the
    first stamp) with their jackknife 95 % half-widths, and the load's angle used (T,)."""

    rss_world: float
    rss_robot: float
    t: float
    p: float
    windows: int
    phi: np.ndarray
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
            theta, omega, _, good = _rotation_kinematics(filled, gap_factor=gap_factor)
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
    # each window's log ratio: the windows differ in excitation, so the ratio, not the difference, is alike
    d = np.log(np.maximum(per_world, 1e-300) / np.maximum(per_robot, 1e-300))  # > 0: robot frames fit better
    sd = float(d.std(ddof=1))
    tt = float(d.mean() / (sd / math.sqrt(m))) if sd > 0 else (math.inf if d.mean() > 0 else -math.inf)
    p = float(sst.t.sf(tt, m - 1))
    return FrameCheck(float(per_world.sum()), float(per_robot.sum()), tt, p, m, phi, phi_ci95, theta)


def to_world(rec: Recording, theta: np.ndarray, phi: np.ndarray) -> Recording:
    """``rec`` with each agent's logged force turned from its frame to the world's: R(theta + phi_i) f_i."""
    w = rec.wrench.copy()
    rot = np.exp(1j * (theta[:, None] + phi[None, :]))
    f = (w[..., 0] + 1j * w[..., 1]) * rot
    w[..., 0], w[..., 1] = f.real, f.imag
    return replace(rec, wrench=w)


__all__ = ["FrameCheck", "frame_check", "to_world"]
