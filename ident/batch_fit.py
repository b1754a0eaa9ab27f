"""Centralized batch estimator: the yardstick for the distributed algorithm (issue 3).

Pools every agent's recorded data (contact-point velocity, applied wrench; world frame, one row per
agent per tick) and fits the nominal rigid-body model of :mod:`ident.model` (continuous time, the
same model and fit as ``coload diagnose``: :mod:`ident.fit`). Pure: arrays in, :class:`BatchFit` out.
The array convention is the simulator's: the wrench of tick k acts over the step k -> k + 1, i.e. it
is held between ticks (``hold="zoh"``). See docs/batch-fit.md.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ident.fit import FitError, FitOptions, fit_robust, initial_guess, make_problem
from ident.model import simulate
from ident.recording import RecordingError, recording_from_arrays
from ident.stats import kinematic_noise

Z95 = 1.959963984540054
MAX_REL_CI = 0.5  # a parameter whose 95 % half-width exceeds this fraction of its value is flagged


class BatchFitError(ValueError):
    """The input cannot be fitted (wrong shape, too short, no rotation, ...); the message says why."""


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


def _check_input(samples: np.ndarray, n: int, dt: float) -> np.ndarray:
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
    if np.isnan(s[..., :2]).all():
        raise BatchFitError("no velocity measurements")
    return s


def fit_recording(samples: np.ndarray, n: int, dt: float, *, options: FitOptions | None = None,
                  clock: Callable[[], float] | None = None, hold: str = "zoh") -> BatchFit:  # fmt: skip
    """Fit m, J, the contact geometry and the motion to one recording.

    ``samples``: shape (T, n, 5), per tick and agent [vx, vy, fx, fy, tau] (tick k at t = k dt; NaN
    velocity = not measured; a NaN wrench is interpolated, with a warning). ``clock`` times the fit into
    ``wall_s`` (0 without it). Raises :class:`BatchFitError` for malformed input or data that cannot
    determine the geometry at all (a load that never rotates).
    """
    opt = options or FitOptions()
    t_start = clock() if clock is not None else 0.0
    s = _check_input(samples, n, dt)
    T = s.shape[0]
    t = np.arange(T) * dt
    try:
        rec = recording_from_arrays(t, s[..., 2:], vel=s[..., :2], hold=hold, dt=dt)
        sigma = kinematic_noise(rec.vel)
        sig_w = sigma if math.isfinite(sigma) and sigma > 1e-9 else 1.0
        pb = make_problem(rec, sig_w, math.nan, opt)
        g0, x0, warn = initial_guess(pb, rec)
        fit = fit_robust(pb, pb.base, g0, x0, max_iter=opt.max_iter)
    except (FitError, RecordingError) as exc:
        raise BatchFitError(str(exc)) from None
    warn = list(rec.warnings) + warn
    lay = fit.lay
    _, _, XS = simulate(pb.win, lay, fit.g[None], fit.x[None], coulomb_speed=0.0, max_step=pb.max_step)
    XS = XS[0]
    state = np.full((T, 4), np.nan)
    k = 0
    for w in range(pb.win.S):
        m = pb.last[w] + (0 if (w < pb.win.S - 1 and pb.link[w]) else 1)
        state[k : k + m] = XS[w, :m, :4]
        k += m
    rss = fit.rss * sig_w**2
    n_used = fit.N
    rms = math.sqrt(rss / max(n_used, 1))
    if rms > 1.5 * sigma + 1e-9:
        warn.append(f"the fitted model leaves a residual of {rms:.3g} m/s against a kinematic noise of {sigma:.3g} "
                    f"m/s: it does not explain the data (effects the model lacks: see coload diagnose)")  # fmt: skip
    F = s[..., 2:4].sum(axis=1)
    imp = np.cumsum(np.nan_to_num(F), axis=0) * dt
    Fscale = float(np.nanmax(np.abs(s[..., 2:4]), initial=0.0))
    no_force = bool(np.ptp(imp, axis=0).max() <= 1e-12 * max(Fscale, 1.0) * T * dt)
    no_wrench = bool(np.nanmax(np.abs(s[..., 2:]), initial=0.0) == 0.0)

    def inverse_param(val, var, fixed, name, unit_note):
        if fixed:
            return Param(math.nan, math.nan, False, unit_note, math.nan)
        raw = 1.0 / val if val != 0 else math.inf
        half = Z95 * math.sqrt(max(var, 0.0)) / val**2 if val != 0 else math.inf
        ok = val > 0 and math.isfinite(half) and half <= MAX_REL_CI * abs(raw)
        if ok:
            return Param(raw, half, True, "", raw)
        return Param(math.nan, math.nan, False, f"{name}: 95 % interval wider than {MAX_REL_CI:.0%} of the value "
                     f"(fit {raw:.4g} +- {half:.3g}): weakly excited", raw)  # fmt: skip

    cov = fit.cov
    mP = inverse_param(fit.g[lay.ia], cov[lay.ia, lay.ia], no_force, "m",
                       "sum of forces is zero throughout: m is not observable")  # fmt: skip
    JP = inverse_param(fit.g[lay.ib], cov[lay.ib, lay.ib], no_wrench, "J",
                       "no force or torque applied: J is not observable")  # fmt: skip
    for p_ in (mP, JP):
        if not p_.identifiable:
            warn.append(p_.note)
    r = fit.g[: 2 * n].reshape(n, 2)
    r_ci = Z95 * np.sqrt(np.clip(np.diag(cov)[: 2 * n], 0, None)).reshape(n, 2)
    avg = np.zeros((2, 2 * n))
    avg[0, 0::2] = 1.0 / n
    avg[1, 1::2] = 1.0 / n
    zc_ci = Z95 * np.sqrt(np.clip(np.diag(avg @ cov[: 2 * n, : 2 * n] @ avg.T), 0, None))
    return BatchFit(
        m=mP, J=JP, r_body=r, r_ci95=r_ci, zc_body=r.mean(axis=0), zc_ci95=zc_ci, t=t, omega=state[:, 2],
        theta=state[:, 3], v_c=state[:, :2], residual_rms=rms, n_used=n_used,
        wall_s=clock() - t_start if clock is not None else 0.0, nfev=fit.nfev,
        stage_cost={"windows": 0.5 * rss}, warnings=tuple(warn),
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
