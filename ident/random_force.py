"""A random force as the residual's noise model: what an unmeasured, unpredictable force leaves.

A force that nobody logged and nothing predicts (a force sensor's own noise on the logged wrench, an
actuator's ripple, a floor's bumps) drives the load's velocity and rate as a random walk that the
output-error fit cannot follow: within each window the residual's rigid-body modes (the agents' mean x
and y, the rotation: :func:`rigid_modes`) drift. The tests of :mod:`ident.select` assume a white
residual; with such a drift they see structure everywhere, and a small candidate that absorbs a piece
of it passes its F-test. This module fits, per mode, the local-level model (the mode = a random walk
of diffusion q plus white noise of the floor's variance, the walk starting afresh in each window, whose
start state the fit frees) by maximum likelihood (:func:`fit_random_force`), and gives the covariance
the walk adds to any linear function of the residual (:func:`walk_covariance`), from which
:func:`robust_wald` tests a fitted effect against the white noise plus the walk. Velocity channels
only (a position's walk is integrated twice; recordings of positions keep the white tests).
See docs/diagnose.md, "A random force".
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.stats import chi2, f_oneway

from ident import stats
from ident.fit import Fit, Problem, normal_equations, window_valid
from ident.model import Layout

MODE_NAMES = ("x", "y", "rotation")


@dataclass(frozen=True)
class RandomForce:
    """Per rigid-body mode (``modes``, of :data:`MODE_NAMES`): the walk's diffusion ``q`` in the weighted
    residual's units (floor^2 per s; 0 where the likelihood ratio ``lr`` is below its level), and the
    Ljung-Box p of the modes' standardised one-step innovations under the fitted walk; ``p_motion`` the
    one-way analysis of variance of each walking mode's innovations over eight quantile bins of its own
    rate (x and y velocity of the centre of mass, the angular rate), Bonferroni over the modes: a random
    force does not depend on the motion, a friction outside the vocabulary does."""

    modes: tuple[str, ...]
    q: np.ndarray
    lr: np.ndarray
    p_white: float
    p_motion: float = 1.0  # the innovations' dependence on the motion (a force that is a function of it)

    @property
    def present(self) -> bool:
        return bool(np.any(self.q > 0))


NONE = RandomForce((), np.zeros(0), np.zeros(0), 1.0)


def _rows(pb: Problem, valid: np.ndarray, chained: bool) -> np.ndarray:
    """(R, Lmax) flat (S * L) indices of the stamps each walk runs over, -1 as padding: one row per window,
    or with ``chained`` one per run of linked windows (the fit carries the body's angle and rate across a
    link, so the rotation's walk does not start afresh there)."""
    w = pb.win
    groups: list[list[int]] = []
    for s in range(w.S):
        if chained and s and pb.link[s - 1]:
            groups[-1].append(s)
        else:
            groups.append([s])
    rows = [np.concatenate([s * w.L + np.flatnonzero(valid[s]) for s in grp]) for grp in groups]
    out = np.full((len(rows), max(r.size for r in rows)), -1)
    for i, r in enumerate(rows):
        out[i, : r.size] = r
    return out


def _take(a: np.ndarray, idx: np.ndarray, fill: float) -> np.ndarray:
    """``a`` (S, L, ...) gathered at the flat indices ``idx`` (R, Lmax); ``fill`` at the padding."""
    flat = a.reshape(-1, *a.shape[2:])
    out = flat[np.maximum(idx, 0)].astype(float)
    out[idx < 0] = fill
    return out


def _steps(t: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """(R, Lmax) the interval before each stamp of a row (0 at a row's first and at the padding)."""
    tr = _take(t, idx, np.nan)
    dt = np.diff(tr, axis=1, prepend=tr[:, :1])
    return np.nan_to_num(dt, nan=0.0)


def centred_arms(lay: Layout, g: np.ndarray, theta: np.ndarray, about_com: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(S, L, n) x and y of each contact point about the contacts' centroid (or the centre of mass),
    world frame, at each stamp."""
    r = g[: 2 * lay.n].reshape(lay.n, 2)
    s_ = r if about_com else r - r.mean(axis=0)
    cth, sth = np.cos(theta)[..., None], np.sin(theta)[..., None]
    return cth * s_[:, 0] - sth * s_[:, 1], sth * s_[:, 0] + cth * s_[:, 1]


def rigid_modes(e: np.ndarray, mask: np.ndarray, lay: Layout, g: np.ndarray, theta: np.ndarray,
                velocity: bool) -> list[np.ndarray]:  # fmt: skip
    """The rigid-body modes of one channel's residual ``e`` (S, L, n, 2) measured where ``mask`` (S, L, n):
    per active axis the agents' mean, and with rotation the least-squares rotation (a rate for
    velocities, an angle for positions); each (S, L), NaN where no agent measured."""
    cnt = mask.sum(axis=2)
    out = []
    with np.errstate(invalid="ignore", divide="ignore"):
        for c in range(2):
            if lay.axes[c]:
                out.append((e[..., c] * mask).sum(axis=2) / cnt)
        if lay.rotation:
            Rx, Ry = centred_arms(lay, g, theta)
            r = g[: 2 * lay.n].reshape(lay.n, 2)
            ss = ((r - r.mean(axis=0)) ** 2).sum(axis=1)
            num = (e[..., 0] * -Ry + e[..., 1] * Rx) if velocity else (e[..., 0] * Rx + e[..., 1] * Ry)
            out.append((num * mask).sum(axis=2) / (mask * ss).sum(axis=2))
    for c in out:
        c[cnt == 0] = np.nan
    return out


def _mode_variances(mask: np.ndarray, lay: Layout, g: np.ndarray) -> list[np.ndarray]:
    """Each velocity mode's variance per stamp for a white residual of unit variance (the floor's)."""
    cnt = mask.sum(axis=2).astype(float)
    with np.errstate(divide="ignore"):
        out = [1.0 / cnt for c in range(2) if lay.axes[c]]
    if lay.rotation:
        r = g[: 2 * lay.n].reshape(lay.n, 2)
        with np.errstate(divide="ignore"):
            out.append(1.0 / (mask * ((r - r.mean(axis=0)) ** 2).sum(axis=1)).sum(axis=2))
    return out


def _local_level(y: np.ndarray, R: np.ndarray, dt: np.ndarray, q: float) -> tuple[float, np.ndarray]:
    """Negative log-likelihood and standardised innovations of a random walk (diffusion ``q``) seen
    through white noise of variance ``R``, every row (a window, or a run of linked windows) on its own from
    a diffuse start. Scalar Kalman recursion over plain floats: a row runs over up to every stamp of the
    recording, where per-step numpy calls would cost a hundred times the arithmetic."""
    S, L = y.shape
    inn = np.full((S, L), np.nan)
    nll = 0.0
    for r, (yr, Rr, dr) in enumerate(zip(y.tolist(), R.tolist(), dt.tolist())):
        x = P = None
        out = inn[r]
        for k in range(L):
            yk = yr[k]
            if x is not None:
                P += q * dr[k]
            if math.isnan(yk):  # not measured
                continue
            if x is None:
                x, P = yk, Rr[k]
                continue
            V = P + Rr[k]
            e = yk - x
            out[k] = e / math.sqrt(V)
            nll += 0.5 * (math.log(V) + e * e / V)
            K = P / V
            x += K * e
            P *= 1.0 - K
    return nll, inn


def _motion_anova(inn: np.ndarray, rate: np.ndarray, bins: int = 8) -> float:
    """p of the one-way analysis of variance of ``inn`` over ``bins`` quantile bins of ``rate``."""
    ok = np.isfinite(inn) & np.isfinite(rate)
    x, r = inn[ok], rate[ok]
    if x.size < 10 * bins:
        return 1.0
    edges = np.quantile(r, np.linspace(0, 1, bins + 1)[1:-1])
    b = np.searchsorted(edges, r)
    groups = [x[b == k] for k in range(bins) if np.count_nonzero(b == k) > 1]
    return float(f_oneway(*groups).pvalue) if len(groups) > 1 else 1.0


def fit_random_force(pb: Problem, fit: Fit, states: np.ndarray, *, alpha: float, lags: int,
                     block: int) -> RandomForce:  # fmt: skip
    """The walk's diffusion per velocity mode of ``fit``'s residual by maximum likelihood; a mode's q is
    kept where its likelihood ratio against q = 0 passes ``alpha`` (q = 0 is the boundary: half the
    chi2(1) tail), and ``p_white`` is the Ljung-Box p (``lags`` of ``block``-averaged innovations).
    ``states`` (S, L, 6): the fitted model's [vx, vy, omega, theta, px, py] at the stamps."""
    w = pb.win
    theta = states[..., 3]
    if w.vel is None or pb.vel_lag1 or pb.vel_ar is not None:
        return NONE  # the walk is modelled on an uncorrelated residual (a correlated sensor's is whitened)
    valid = window_valid(pb)
    M = w.L * w.n * 2
    e = fit.res[:, :M].reshape(w.S, w.L, w.n, 2)
    mask = w.vmask * valid[..., None]
    ys = rigid_modes(e, mask, fit.lay, fit.g, theta, velocity=True)
    Rs = _mode_variances(mask, fit.lay, fit.g)
    if fit.lay.rotation:
        # the agents' mean moves with the centroid; the centre of mass's velocity is what a force drives:
        # v_C = mean - omega x (centroid - C), and the rotation's estimate is uncorrelated with the mean
        Rx, Ry = centred_arms(fit.lay, fit.g, theta, about_com=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            gx, gy = (Rx * mask).sum(axis=2) / mask.sum(axis=2), (Ry * mask).sum(axis=2) / mask.sum(axis=2)
        lever = {0: gy, 1: -gx}  # omega x (gx, gy) = (-omega gy, omega gx), subtracted
        j = 0
        for c in range(2):
            if fit.lay.axes[c]:
                ys[j] = ys[j] + ys[-1] * lever[c]
                Rs[j] = Rs[j] + lever[c] ** 2 * Rs[-1]
                j += 1
    names = tuple(n for n, on in zip(MODE_NAMES, (*fit.lay.axes, fit.lay.rotation)) if on)
    crit = float(chi2.isf(2 * alpha, 1))
    q = np.zeros(len(ys))
    lr = np.zeros(len(ys))
    inns = []
    p_motion = 1.0
    rates = [states[..., c] for c in range(2) if fit.lay.axes[c]] + ([states[..., 2]] if fit.lay.rotation else [])
    for j, (y, R) in enumerate(zip(ys, Rs)):
        idx = _rows(pb, valid, chained=names[j] == "rotation")
        y, R, dt = _take(y, idx, np.nan), _take(R, idx, np.inf), _steps(w.t, idx)
        nll0, inn0 = _local_level(y, R, dt, 0.0)
        # q in units of the mode's own white variance per sample interval
        scale = float(np.median(R[np.isfinite(R)])) / max(float(np.median(dt[dt > 0])), 1e-12)
        res = minimize_scalar(lambda u: _local_level(y, R, dt, scale * math.exp(u))[0],
                              bounds=(math.log(1e-8), math.log(1e3)), method="bounded",
                              options={"xatol": 0.02})  # fmt: skip
        lr[j] = max(2.0 * (nll0 - float(res.fun)), 0.0)
        if lr[j] > crit:
            q[j] = scale * math.exp(float(res.x))
            inns.append(_local_level(y, R, dt, q[j])[1])
            p_motion = min(p_motion, len(ys) * _motion_anova(inns[-1], _take(rates[j], idx, np.nan)))
        else:
            inns.append(inn0)
    Q, dof = 0.0, 0
    for i in inns:
        qj, dj, _ = stats.ljung_box(stats.block_average(i[np.isfinite(i)], block)[:, None], lags)
        Q, dof = Q + qj, dof + dj
    p = float(chi2.sf(Q, dof)) if dof else 1.0
    return RandomForce(names, q, lr, p, min(p_motion, 1.0))


def walk_covariance(pb: Problem, fit: Fit, rf: RandomForce, A: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """(k, k) covariance the walk adds to A^T r, for ``A`` (S, M_rows, k) columns over the weighted
    residual's rows: for a walk W of diffusion q, var(sum_l a_l W(t_l)) = q sum_l dt_l (sum_{l' >= l} a_l')^2
    over each of the walk's rows (a window; for the rotation a run of linked windows)."""
    w = pb.win
    k = A.shape[2]
    C = np.zeros((k, k))
    if not rf.present:
        return C
    valid = window_valid(pb)
    Av = A[:, : w.L * w.n * 2].reshape(w.S, w.L, w.n, 2, k) * valid[..., None, None, None]
    P = [Av[..., c, :].sum(axis=2) for c in range(2) if fit.lay.axes[c]]
    if fit.lay.rotation:
        Rx, Ry = centred_arms(fit.lay, fit.g, theta, about_com=True)
        P.append((Av[..., 0, :] * -Ry[..., None] + Av[..., 1, :] * Rx[..., None]).sum(axis=2))
    for name, qm, Pm in zip(rf.modes, rf.q, P):
        if qm > 0:
            idx = _rows(pb, valid, chained=name == "rotation")
            C += qm * walk_form(_take(Pm, idx, 0.0), _steps(w.t, idx))
    return C


def walk_form(P: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """(k, k) covariance of sum_l P_l W(t_l) over rows of a unit-diffusion walk W from 0 at each row's
    first stamp: ``P`` (R, L, k) the weights, ``dt`` (R, L) the interval before each stamp (0 at the first):
    sum_l dt_l (sum_{l' >= l} P_l') (sum_{l' >= l} P_l')^T."""
    tail = np.cumsum(P[:, ::-1], axis=1)[:, ::-1]
    return np.einsum("sl,slq,slr->qr", dt, tail, tail)


def robust_covariance(pb: Problem, fit: Fit, rf: RandomForce, theta: np.ndarray) -> np.ndarray:
    """(G, G) covariance of ``fit``'s global parameters under the residual's white noise (the floor's unit
    variance) plus the walk ``rf``: the sandwich H^-1 (H + J^T Sigma_walk J) H^-1, H the Gauss-Newton
    information over every parameter and window state; J H^-1 restricted to the global parameters' columns
    is what each estimate's error is a linear function of."""
    lin = fit.lin
    H, _ = normal_equations(lin)
    G, K = lin.Jg.shape[2], lin.Jx.shape[2]
    Hi = np.linalg.pinv(H, rcond=1e-13, hermitian=True)[:, :G]
    A = np.einsum("smg,gq->smq", lin.Jg, Hi[:G])
    for s in range(pb.win.S):
        A[s] += lin.Jx[s] @ Hi[G + s * K : G + (s + 1) * K]
    return Hi[:G] + walk_covariance(pb, fit, rf, A, theta)


def robust_wald(fit: Fit, name: str, cov: np.ndarray) -> float:
    """p of the Wald test that effect ``name`` (fitted in ``fit``) is 0 under the covariance ``cov``
    (:func:`robust_covariance`): d^T cov^-1 d ~ chi2(q)."""
    sl = fit.lay.slot(name)
    d = fit.g[sl]
    W = float(d @ np.linalg.solve(cov[sl, sl], d))
    return float(chi2.sf(W, sl.stop - sl.start))


def significant_walk(pb: Problem, fit: Fit, states: np.ndarray, *, alpha: float, lags: int,
                     block: int) -> RandomForce | None:  # fmt: skip
    """The random force's walk in ``fit``'s residual (``states``: :func:`ident.fit.states_of`) when one is
    significant, else None."""
    rf = fit_random_force(pb, fit, states, alpha=alpha, lags=lags, block=block)
    return rf if rf.present else None


def walk_values(rf: RandomForce, pb: Problem, fit: Fit, dt: float) -> dict[str, Any]:
    """The walk in physical units: per mode the force (N; torque, N m) that, white and held over each
    sample period ``dt``, drives the velocity (rate) walk: sigma = m sigma_v sqrt(q / dt), sigma_v the floor."""
    sv = float(np.median(pb.sigma_v))
    mj = fit.mj()
    out: dict[str, Any] = {"sample_period_s": dt, "innovations_whiteness_p": rf.p_white}
    for name, q, lr in zip(rf.modes, rf.q, rf.lr):
        inertia = mj["J"] if name == "rotation" else mj["m"]
        key = "torque_N_m" if name == "rotation" else f"force_{name}_N"
        out[key] = inertia * sv * math.sqrt(q / dt) if math.isfinite(inertia) else None
        out[f"lr_{name}"] = lr
    return out


def walk_warning(info: dict[str, Any], rf: RandomForce) -> str:
    parts = [f"{info[k]:.3g} N along {k.split('_')[1]}" for k in ("force_x_N", "force_y_N") if info.get(k)]
    if info.get("torque_N_m"):
        parts.append(f"a torque of {info['torque_N_m']:.3g} N m")
    return (f"the residual drifts as a random walk within each window, and with the walk fitted its innovations "
            f"are white (Ljung-Box p {rf.p_white:.2g}): an unmeasured random force of {', '.join(parts)} per "
            f"{info['sample_period_s']:.3g} s sample (noise on the logged wrench, or a process noise); the 95 % "
            "intervals include it")
