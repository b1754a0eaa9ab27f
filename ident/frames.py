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


def _design(rec: Recording, theta: np.ndarray, omega: np.ndarray, z: np.ndarray, wid: np.ndarray, robot: bool):
    """Columns of the complex equation error of the agents' mean velocity: each window's start velocity,
    each agent's integrated force (turned by the load's angle when ``robot``), the integrated velocity
    (viscous friction) and the centroid's offset (i omega e^{i theta})."""
    t = rec.t
    f = rec.wrench[..., 0] + 1j * rec.wrench[..., 1]  # (T, n)
    if robot:
        f = f * np.exp(1j * theta)[:, None]
    y = np.nanmean(rec.vel[..., 0] + 1j * rec.vel[..., 1], axis=1)
    ok = ~np.isnan(y)
    yf = np.interp(t, t[ok], y[ok].real) + 1j * np.interp(t, t[ok], y[ok].imag)
    S = int(wid.max()) + 1
    cols = [(wid == s).astype(complex) for s in range(S)]
    If = _cumint_windows(t, wid, f, "foh")
    cols += [If[:, i] for i in range(rec.n)]
    cols += [_cumint_windows(t, wid, yf, "foh"), 1j * omega * np.exp(1j * theta)]
    return np.column_stack(cols), y, ok


def frame_check(rec: Recording, window_s: float, gap_factor: float = 5.0,
                angle: tuple[np.ndarray, np.ndarray] | None = None) -> FrameCheck | None:
    """The check on a velocity recording of n >= 2 agents whose load turns; None where it cannot be made.
    ``angle``: the load's angle and rate (T,) each, from a fit, in place of the kinematics'."""
    if rec.vel is None or rec.n < 2:
        return None
    filled = _filled(rec, gap_factor)
    if angle is not None:
        theta, omega = angle
        z, good = None, np.isfinite(theta)
    else:
        try:
            theta, omega, z, good = _rotation_kinematics(filled, gap_factor=gap_factor)
        except FitError:
            return None
    t = rec.t
    wid = np.floor((t - t[0]) / window_s).astype(int)
    S = int(wid.max()) + 1
    if S < 3:
        return None
    out = {}
    for robot in (False, True):
        A, y, ok = _design(filled, theta, omega, z, wid, robot)
        ok &= good
        coef = np.linalg.lstsq(A[ok], y[ok], rcond=None)[0]
        e = np.where(ok, y - A @ coef, 0)
        per = np.bincount(wid, weights=np.abs(e) ** 2, minlength=S)
        # the mounting angles left out one window at a time: the equation error is correlated within a
        # window, so the windows are the independent units of its spread
        jack = []
        for s in range(S):
            keep = ok & (wid != s)
            c = np.linalg.lstsq(A[keep], y[keep], rcond=None)[0]
            jack.append(np.angle(c[S : S + rec.n] * np.conj(coef[S : S + rec.n])))
        jack = np.array(jack)
        se = np.sqrt((S - 1) / S * ((jack - jack.mean(axis=0)) ** 2).sum(axis=0))
        out[robot] = (per, np.angle(coef[S : S + rec.n]), sst.t.ppf(0.975, S - 1) * se)
    # each window's log ratio: the windows differ in excitation, so the ratio, not the difference, is alike
    d = np.log(out[False][0] / np.maximum(out[True][0], 1e-300))  # > 0 where the robot frames fit better
    sd = float(d.std(ddof=1))
    tt = float(d.mean() / (sd / math.sqrt(S))) if sd > 0 else (math.inf if d.mean() > 0 else -math.inf)
    p = float(sst.t.sf(tt, S - 1))
    return FrameCheck(float(out[False][0].sum()), float(out[True][0].sum()), tt, p, S, out[True][1], out[True][2],
                      theta)


def to_world(rec: Recording, theta: np.ndarray, phi: np.ndarray) -> Recording:
    """``rec`` with each agent's logged force turned from its frame to the world's: R(theta + phi_i) f_i."""
    w = rec.wrench.copy()
    rot = np.exp(1j * (theta[:, None] + phi[None, :]))
    f = (w[..., 0] + 1j * w[..., 1]) * rot
    w[..., 0], w[..., 1] = f.real, f.imag
    return replace(rec, wrench=w)


__all__ = ["FrameCheck", "frame_check", "to_world"]
