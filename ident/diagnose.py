"""``coload diagnose``: trace the residual of the nominal rigid-body model to the effect it lacks.

Input is a recording in the measured-data format only (``samples.csv`` + ``run.toml``; truth.csv is
read only to report errors against it). Pure core: :func:`diagnose` takes arrays and returns a
:class:`Diagnosis`; :func:`diagnose_dir` reads files; the CLI writes JSON and the figure.

Model (integral form, the plant's exact discrete step as in :mod:`ident.batch_fit`): per tick k,
with the wrench of tick k acting over the step k -> k + 1,

    v_{k+1}     = v_k + dt a (F_k + f_b - c_v v_k - F_c v_k / sqrt(|v_k|^2 + eps^2))     a = 1/m
    omega_{k+1} = omega_k + dt b (T_k(theta_k) - c_r omega_k)                              b = 1/J
    theta_{k+1} = theta_k + dt omega_k
    y_ik        = [v + omega (R(theta) r_i)^perp]_(k - d/dt) + v_b + noise

The nominal model has every effect parameter at zero. Velocities are compared with the simulated
model (output error): nothing is differentiated. Parameters are fitted by Levenberg-Marquardt on a
finite-difference Jacobian whose columns are simulated together (one vectorised pass over the ticks
for all perturbed parameter vectors), starting from the batch fit's nominal solution.

Diagnosis (see docs/diagnose.md): residual whiteness by Ljung-Box on the rigid-body modes of the
residual (mean x, mean y, rotation), block-averaged; cross-correlation of the nominal residual with
each candidate's signature (its sensitivity, orthogonal to the nominal parameters); forward
selection by nested F-tests and BIC; an effect is named only if the final model's residual is white.
"""

from __future__ import annotations

import math
import sys
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from ident import tables as rf
from ident.batch_fit import (
    BatchFitError,
    FitOptions,
    _check_input,
    fit_recording,
    samples_array,
)

Z95 = 1.959963984540054
COULOMB_EPS = 0.02
"""Smoothing speed (m/s) of the Coulomb candidate's v/|v| (the plant's own smoothing is unknown here)."""

# name -> (number of parameters, unit, signature shown in the cross-correlation)
CANDIDATES: dict[str, tuple[int, str, str]] = {
    "viscous_friction": (1, "N s/m", "integral of v_C"),
    "coulomb_friction": (1, "N", "integral of sign(v_C)"),
    "rotational_damping": (1, "N m s", "integral of omega"),
    "measurement_delay": (1, "s", "applied-force lag (rate of the prediction)"),
    "force_bias": (2, "N", "constant force (ramp in v_C)"),
    "velocity_bias": (2, "m/s", "constant velocity offset"),
}


class DiagnoseError(ValueError):
    """The recording cannot be diagnosed; the message says why (file, line, column where it applies)."""


@dataclass(frozen=True)
class DiagnoseOptions:
    """Thresholds of the selection; the defaults are the documented ones (docs/diagnose.md)."""

    alpha: float = 1e-3  # family-wise level of the nested F-tests (Bonferroni over the candidates tried)
    alpha_white: float = 0.01  # Ljung-Box level: a residual with p above it counts as white
    lags: int = 20  # Ljung-Box lags (of the block-averaged series)
    block_s: float = 0.1  # block length (s) of the averaging in front of Ljung-Box
    ambiguous_bic: float = 10.0  # two substitutes closer than this in BIC cannot be told apart
    holdout: float = 0.25  # trailing share of the recording held out for the prediction error
    max_effects: int = 2  # at most this many effects are added (the selection stops there)
    max_fits: int = 3  # candidates fitted per selection round: those with the strongest score tests
    max_iter: int = 30  # Levenberg-Marquardt iterations per fit
    candidates: tuple[str, ...] = tuple(CANDIDATES)


# --- data -------------------------------------------------------------------------------------
@dataclass
class _Data:
    y: np.ndarray  # (T, n, 2), 0 where missing
    mask: np.ndarray  # (T, n) bool
    fx: np.ndarray  # (T, n)
    fy: np.ndarray
    tau: np.ndarray  # (T,)
    F: np.ndarray  # (T, 2)
    dt: float

    @property
    def T(self) -> int:
        return self.y.shape[0]

    @property
    def n(self) -> int:
        return self.y.shape[1]

    def head(self, T: int) -> _Data:
        return _Data(self.y[:T], self.mask[:T], self.fx[:T], self.fy[:T], self.tau[:T], self.F[:T], self.dt)


def _data(s: np.ndarray, dt: float) -> _Data:
    vel = s[..., :2]
    mask = ~np.isnan(vel).any(axis=-1)
    fx, fy = s[..., 2], s[..., 3]
    return _Data(np.nan_to_num(vel), mask, fx, fy, s[..., 4].sum(axis=1),
                 np.stack((fx.sum(axis=1), fy.sum(axis=1)), axis=1), dt)  # fmt: skip


# --- the model ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Layout:
    """Parameter vector: [r (2n), a, b, v0x, v0y, omega0, effect parameters in CANDIDATES order]."""

    n: int
    effects: tuple[str, ...]

    @property
    def base(self) -> int:
        return 2 * self.n + 5

    def slot(self, name: str) -> slice:
        k = self.base
        for e in CANDIDATES:
            if e in self.effects:
                q = CANDIDATES[e][0]
                if e == name:
                    return slice(k, k + q)
                k += q
        raise KeyError(name)

    @property
    def size(self) -> int:
        return self.base + sum(CANDIDATES[e][0] for e in self.effects)

    def lower(self) -> np.ndarray:
        """Lower bounds: -inf, except 0 for the dissipative effects and the delay (physical signs)."""
        lo = np.full(self.size, -np.inf)
        for e in ("viscous_friction", "coulomb_friction", "rotational_damping", "measurement_delay"):
            if e in self.effects:
                lo[self.slot(e)] = 0.0
        return lo

    def scales(self, p: np.ndarray) -> np.ndarray:
        """Typical magnitudes, for finite-difference steps."""
        n = self.n
        s = np.ones(self.size)
        s[: 2 * n] = 1.0
        s[2 * n] = max(abs(p[2 * n]), 1e-4)
        s[2 * n + 1] = max(abs(p[2 * n + 1]), 1e-4)
        s[2 * n + 2 : 2 * n + 4] = 0.1
        if "measurement_delay" in self.effects:
            s[self.slot("measurement_delay")] = 0.01
        if "velocity_bias" in self.effects:
            s[self.slot("velocity_bias")] = 0.01
        return s


def _simulate(d: _Data, lay: _Layout, P: np.ndarray) -> np.ndarray:
    """Predicted measurements (B, T, n, 2) for B parameter vectors P (B, size)."""
    n, T, dt = lay.n, d.T, d.dt
    B = P.shape[0]
    r = P[:, : 2 * n].reshape(B, n, 2)
    a, b = P[:, 2 * n], P[:, 2 * n + 1]
    eff = {e: P[:, lay.slot(e)] for e in lay.effects}
    # torque of the forces about the CoM: T_k = tau_k + cos(th) Pq_k + sin(th) Qq_k, (T, B)
    Pq = d.fy @ r[:, :, 0].T - d.fx @ r[:, :, 1].T
    Qq = -(d.fx @ r[:, :, 0].T + d.fy @ r[:, :, 1].T)
    tau = d.tau
    W = np.empty((T, B))
    TH = np.empty((T, B))
    w = P[:, 2 * n + 4].copy()
    th = np.zeros(B)
    cr = eff["rotational_damping"][:, 0] if "rotational_damping" in eff else None
    dtb = dt * b
    cos, sin = np.cos, np.sin
    for k in range(T):
        W[k] = w
        TH[k] = th
        tq = tau[k] + cos(th) * Pq[k] + sin(th) * Qq[k]
        if cr is not None:
            tq = tq - cr * w
        th = th + dt * w
        w = w + dtb * tq
    # translation
    F = d.F
    fb = eff["force_bias"] if "force_bias" in eff else np.zeros((B, 2))
    v0 = P[:, 2 * n + 2 : 2 * n + 4]
    if "coulomb_friction" in eff or "viscous_friction" in eff:
        V = np.empty((T, B, 2))
        v = v0.copy()
        cv = eff["viscous_friction"][:, :1] if "viscous_friction" in eff else None
        fc = eff["coulomb_friction"][:, :1] if "coulomb_friction" in eff else None
        da = dt * a[:, None]
        e2 = COULOMB_EPS**2
        for k in range(T):
            V[k] = v
            acc = F[k] + fb
            if cv is not None:
                acc = acc - cv * v
            if fc is not None:
                acc = acc - fc * v / np.sqrt((v * v).sum(axis=1, keepdims=True) + e2)
            v = v + da * acc
    else:
        S = np.zeros((T, 2))
        S[1:] = np.cumsum(F[:-1], axis=0) * dt
        t = np.arange(T) * dt
        V = v0[None] + a[None, :, None] * (S[:, None, :] + t[:, None, None] * fb[None])
    if "measurement_delay" in eff:
        shift = eff["measurement_delay"][:, 0] / dt  # (B,)
        idx = np.arange(T)[:, None] - shift[None, :]
        idx = np.clip(idx, 0.0, T - 1.0)
        i0 = np.floor(idx).astype(int)
        i1 = np.minimum(i0 + 1, T - 1)
        f = idx - i0
        cols = np.arange(B)[None, :]
        W = W[i0, cols] * (1 - f) + W[i1, cols] * f
        TH = TH[i0, cols] * (1 - f) + TH[i1, cols] * f
        V = V[i0, cols] * (1 - f)[..., None] + V[i1, cols] * f[..., None]
    c, s = np.cos(TH)[..., None], np.sin(TH)[..., None]  # (T, B, 1)
    rx, ry = r[None, :, :, 0], r[None, :, :, 1]  # (1, B, n)
    Rx = c * rx - s * ry
    Ry = s * rx + c * ry
    px = V[..., 0:1] - W[..., None] * Ry
    py = V[..., 1:2] + W[..., None] * Rx
    pred = np.stack((px, py), axis=-1)  # (T, B, n, 2)
    if "velocity_bias" in eff:
        pred = pred + eff["velocity_bias"][None, :, None, :]
    return pred.transpose(1, 0, 2, 3)


@dataclass
class _Fit:
    lay: _Layout
    p: np.ndarray
    cov: np.ndarray
    rss: float
    N: int  # residual components used
    res: np.ndarray  # (T, n, 2) residual y - pred, 0 where missing
    theta: np.ndarray  # (T,) measured-time body angle of the fitted model
    jac: np.ndarray  # (N, size) at the solution
    nfev: int

    @property
    def sigma2(self) -> float:
        return self.rss / max(self.N - self.lay.size, 1)

    @property
    def bic(self) -> float:
        return self.N * math.log(self.rss / self.N) + self.lay.size * math.log(self.N)

    @property
    def aic(self) -> float:
        return self.N * math.log(self.rss / self.N) + 2 * self.lay.size

    def param(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        sl = self.lay.slot(name)
        return self.p[sl], Z95 * np.sqrt(np.clip(np.diag(self.cov)[sl], 0, None))

    def mj(self) -> dict[str, float]:
        n = self.lay.n
        a, b = self.p[2 * n], self.p[2 * n + 1]
        sa, sb = np.sqrt(np.clip(np.diag(self.cov)[[2 * n, 2 * n + 1]], 0, None))
        return {"m": 1 / a, "m_ci95": Z95 * sa / a**2, "J": 1 / b, "J_ci95": Z95 * sb / b**2}


def _residuals(d: _Data, pred: np.ndarray) -> np.ndarray:
    """(B, N) residuals y - pred over the measured components."""
    return (d.y[None] - pred)[:, d.mask].reshape(pred.shape[0], -1)


def _fit(d: _Data, lay: _Layout, p0: np.ndarray, opt: DiagnoseOptions, progress: Callable[[str], None] | None = None,
         label: str = "") -> _Fit:  # fmt: skip
    """Levenberg-Marquardt with a batched forward-difference Jacobian; covariance s^2 (J^T J)^+."""
    p = p0.astype(float).copy()
    P = lay.size
    lam = 1e-3
    nfev = 0
    r0 = _residuals(d, _simulate(d, lay, p[None]))[0]
    rss = float(r0 @ r0)
    jac = None
    for it in range(opt.max_iter):
        h = 1e-6 * np.maximum(np.abs(p), lay.scales(p))
        Pb = np.repeat(p[None], P, axis=0) + np.diag(h)
        R = _residuals(d, _simulate(d, lay, Pb))
        nfev += P
        jac = ((r0[None] - R) / h[:, None]).T  # d pred / d p = -(d res / d p)
        A = jac.T @ jac
        g = jac.T @ r0
        dA = np.diag(A).copy()
        dA[dA <= 0] = 1.0
        # three damping levels in one batched simulation
        lams = np.array([lam / 10, lam, lam * 10])
        steps = np.stack([np.linalg.solve(A + L * np.diag(dA), g) for L in lams])
        lo = lay.lower()
        steps = np.maximum(p[None] + steps, lo[None]) - p[None]  # friction, damping and delay stay >= 0
        trial = _residuals(d, _simulate(d, lay, p[None] + steps))
        nfev += 3
        rss_t = np.einsum("ij,ij->i", trial, trial)
        best = int(np.argmin(rss_t))
        if rss_t[best] < rss:
            gain = (rss - rss_t[best]) / max(rss, 1e-300)
            p = p + steps[best]
            r0, rss = trial[best], float(rss_t[best])
            lam = max(lams[best], 1e-9)
            if gain < 1e-7 or np.all(np.abs(steps[best]) <= 1e-8 * np.maximum(np.abs(p), lay.scales(p))):
                break
        else:
            lam *= 100.0
            if lam > 1e8:
                break
        if progress is not None and it % 5 == 4:
            progress(f"{label} iteration {it + 1}: rss {rss:.6g}")
    # Jacobian at the solution for the covariance
    h = 1e-6 * np.maximum(np.abs(p), lay.scales(p))
    R = _residuals(d, _simulate(d, lay, np.repeat(p[None], P, axis=0) + np.diag(h)))
    jac = ((r0[None] - R) / h[:, None]).T
    N = r0.size
    sigma2 = rss / max(N - P, 1)
    cov = sigma2 * np.linalg.pinv(jac.T @ jac, rcond=1e-12, hermitian=True)
    res = np.zeros_like(d.y)
    res[d.mask] = r0.reshape(-1, 2)
    return _Fit(lay, p, cov, rss, N, res, _theta(d, lay, p), jac, nfev)


def _theta(d: _Data, lay: _Layout, p: np.ndarray) -> np.ndarray:
    """The fitted model's body angle per tick (from a one-member simulation of the rotation)."""
    n = lay.n
    r = p[: 2 * n].reshape(n, 2)
    b = p[2 * n + 1]
    cr = p[lay.slot("rotational_damping")][0] if "rotational_damping" in lay.effects else 0.0
    Pq = d.fy @ r[:, 0] - d.fx @ r[:, 1]
    Qq = -(d.fx @ r[:, 0] + d.fy @ r[:, 1])
    th = np.empty(d.T)
    w, t = float(p[2 * n + 4]), 0.0
    for k in range(d.T):
        th[k] = t
        tq = d.tau[k] + math.cos(t) * Pq[k] + math.sin(t) * Qq[k] - cr * w
        t += d.dt * w
        w += d.dt * b * tq
    return th


def _fit_robust(d: _Data, lay: _Layout, starts: Sequence[np.ndarray], head: int, floor2: float,
                opt: DiagnoseOptions, progress: Callable[[str], None] | None, label: str) -> _Fit:  # fmt: skip
    """Fit from the first start; if the residual stays far above the noise floor (a local minimum of single
    shooting over a long horizon, e.g. a rotation the start model cannot follow), fit again from each other
    start over the head of the recording first, then all of it, and keep the best."""
    best = _fit(d, lay, starts[0], opt, progress, label)
    for p0 in starts[1:]:
        if best.rss / best.N <= 4.0 * floor2:  # within 2 sigma: not the gross misfit of a lost rotation
            break
        if progress is not None:
            progress(f"{label}: residual {math.sqrt(best.rss / best.N):.3g} m/s above the noise floor "
                     f"{math.sqrt(floor2):.3g}; refitting from the head of the recording")  # fmt: skip
        p = p0
        if head < d.T:
            p = _fit(d.head(head), lay, p, opt).p
        cand = _fit(d, lay, p, opt, progress, label)
        if cand.rss < best.rss:
            best = cand
    if progress is not None:
        progress(f"{label}: done ({best.nfev} model evaluations)")
    return best


def _extend(p: np.ndarray, src: _Layout, dst: _Layout, init: dict[str, np.ndarray] | None = None) -> np.ndarray:
    """Map a parameter vector to a layout with more (or other) effects; new effects start at 0 (or ``init``)."""
    out = np.zeros(dst.size)
    out[: dst.base] = p[: src.base]
    for e in dst.effects:
        if e in src.effects:
            out[dst.slot(e)] = p[src.slot(e)]
        elif init and e in init:
            out[dst.slot(e)] = init[e]
    return out


# --- residual analysis -----------------------------------------------------------------------------
def _modes(d: _Data, fit: _Fit) -> np.ndarray:
    """(T, 3) rigid-body modes of the residual: mean x, mean y, and rotation (rad/s); NaN where no agent measured."""
    n = d.n
    r = fit.p[: 2 * n].reshape(n, 2)
    s = r - r.mean(axis=0)
    e, m = fit.res, d.mask
    cnt = m.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        ex = e[..., 0].sum(axis=1) / cnt
        ey = e[..., 1].sum(axis=1) / cnt
        c, sn = np.cos(fit.theta)[:, None], np.sin(fit.theta)[:, None]
        Rx, Ry = c * s[:, 0] - sn * s[:, 1], sn * s[:, 0] + c * s[:, 1]
        num = (e[..., 0] * -Ry + e[..., 1] * Rx) * m
        ew = num.sum(axis=1) / (m * (s**2).sum(axis=1)).sum(axis=1)
    out = np.stack((ex, ey, ew), axis=1)
    out[cnt == 0] = np.nan
    return out


def block_average(x: np.ndarray, block: int) -> np.ndarray:
    """Means over consecutive blocks of ``block`` rows (NaN-aware); a trailing partial block is dropped."""
    nb = x.shape[0] // block
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an all-NaN block (no agent measured) stays NaN
        return np.nanmean(x[: nb * block].reshape(nb, block, *x.shape[1:]), axis=1)


def autocorrelation(x: np.ndarray, lags: int) -> np.ndarray:
    """Sample autocorrelation r_1..r_lags of one series (NaNs dropped, mean removed)."""
    x = x[~np.isnan(x)]
    x = x - x.mean()
    den = float(x @ x)
    if den == 0 or len(x) <= lags:
        return np.zeros(lags)
    return np.array([float(x[:-k] @ x[k:]) / den for k in range(1, lags + 1)])


def ljung_box(series: np.ndarray, lags: int) -> tuple[float, int, float]:
    """Ljung-Box on each column of ``series`` (T, K), summed: (Q, dof, p) with dof = K * lags.

    Degrees of freedom: the model is output-error (the fitted parameters act on the simulated,
    noise-free state, not on lagged residuals as ARMA coefficients do), so the fitted parameters use up
    no lags and Q ~ chi2(K lags) for a white residual; tests/test_diagnose.py checks this calibration.
    """
    Q = 0.0
    K = series.shape[1]
    for j in range(K):
        x = series[:, j]
        N = int(np.count_nonzero(~np.isnan(x)))
        rho = autocorrelation(x, lags)
        Q += N * (N + 2) * float(np.sum(rho**2 / (N - np.arange(1, lags + 1))))
    dof = K * lags
    return Q, dof, float(stats.chi2.sf(Q, dof))


def _whiteness(d: _Data, fit: _Fit, opt: DiagnoseOptions) -> float:
    block = max(1, round(opt.block_s / d.dt))
    return ljung_box(block_average(_modes(d, fit), block), opt.lags)[2]


def _noise_floor(d: _Data) -> float:
    """sigma^2 of the velocity noise from the rigid-body kinematics alone (rank-1 relative velocities)."""
    full = d.mask.all(axis=1)
    w = d.y[full, :, 0] + 1j * d.y[full, :, 1]
    rel = w - w.mean(axis=1, keepdims=True)
    u, sv, vh = np.linalg.svd(rel, full_matrices=False)
    resid = rel - (u[:, :1] * sv[0]) @ vh[:1]
    n = d.n
    return float(np.mean(np.abs(resid) ** 2) / 2 * n / max(n - 2, 1))


@dataclass(frozen=True)
class _Score:
    """A candidate's signature at the current model: correlation with the residual and the score test."""

    name: str
    corr: tuple[float, ...]  # per parameter component, of the residual with the orthogonalised signature
    bound: float  # 95 % bound of corr for a white residual
    p: float  # score (Lagrange multiplier) test p-value, chi2(q)
    half_width: float  # 95 % half-width the data would give the effect (largest component)
    collinear: float  # share of the signature explained by the model's own parameters (1 = structurally absent)
    sig: np.ndarray  # (N, q) orthogonalised signature
    logp: float = 0.0  # natural log of p (no underflow), to rank strong candidates


def _scores(d: _Data, fit: _Fit, names: Sequence[str]) -> dict[str, _Score]:
    r0 = fit.res[d.mask].ravel()
    N = r0.size
    Jn = fit.jac
    # project out the current model's parameter directions once (QR of its Jacobian)
    Qm, Rm = np.linalg.qr(Jn)
    keep = np.abs(np.diag(Rm)) > 1e-10 * max(np.abs(np.diag(Rm)).max(), 1e-300)
    Qm = Qm[:, keep]
    sigma = math.sqrt(fit.sigma2)
    out = {}
    for c in names:
        lay = _Layout(fit.lay.n, tuple(e for e in CANDIDATES if e in fit.lay.effects or e == c))
        p = _extend(fit.p, fit.lay, lay)
        sl = lay.slot(c)
        q = sl.stop - sl.start
        h = 1e-6 * lay.scales(p)[sl]
        Pb = np.repeat(p[None], q + 1, axis=0)
        Pb[1:, sl] += np.diag(h)
        pred = _residuals(d, _simulate(d, lay, Pb))
        sig = ((pred[0][None] - pred[1:]) / h[:, None]).T  # (N, q) d pred / d effect
        norm0 = np.sqrt((sig**2).sum(axis=0))
        sig = sig - Qm @ (Qm.T @ sig)
        norm = np.sqrt((sig**2).sum(axis=0))
        collinear = float(1.0 - (norm / np.maximum(norm0, 1e-300)).min())
        with np.errstate(invalid="ignore", divide="ignore"):
            corr = tuple(float(x) for x in (sig.T @ r0) / (norm * math.sqrt(float(r0 @ r0))))
        if collinear > 1 - 1e-6:
            out[c] = _Score(c, corr, Z95 / math.sqrt(N), 1.0, math.inf, collinear, sig)
            continue
        coef, *_ = np.linalg.lstsq(sig, r0, rcond=None)
        explained = float(np.sum((sig @ coef) ** 2))
        lm = explained / fit.sigma2
        se = sigma / norm
        out[c] = _Score(c, corr, Z95 / math.sqrt(N), float(stats.chi2.sf(lm, q)), float(Z95 * se.max()), collinear, sig,
                        float(stats.chi2.logsf(lm, q)))
    return out


def _lm(sc: _Score) -> float:
    """Strength of a score test, comparable across candidates with different q: -log10 of its p-value."""
    return -sc.logp


def _reference(name: str, m: float, J: float, dt: float) -> float:
    """A realistic small magnitude of each effect; a candidate the data cannot resolve to this is 'not excited'."""
    mg = m * 9.81 if math.isfinite(m) and m > 0 else 500.0
    return {
        "viscous_friction": (m if math.isfinite(m) and m > 0 else 50.0) / 20.0,  # time constant m/b = 20 s
        "coulomb_friction": 0.005 * mg,  # rolling resistance 0.5 %
        "rotational_damping": (J if math.isfinite(J) and J > 0 else 100.0) / 20.0,  # J/c = 20 s
        "measurement_delay": max(0.02, 2 * dt),
        "force_bias": 0.005 * mg,  # a 0.3 degree slope
        "velocity_bias": 0.02,
    }[name]


def _nested(small: _Fit, big: _Fit) -> tuple[float, float]:
    """F statistic and p-value of the nested test small within big."""
    q = big.lay.size - small.lay.size
    dfd = max(big.N - big.lay.size, 1)
    F = max(small.rss - big.rss, 0.0) / q / (big.rss / dfd)
    return F, float(stats.f.sf(F, q, dfd))


# --- result ---------------------------------------------------------------------------------------
@dataclass
class ModelReport:
    effects: tuple[str, ...]
    m: float
    m_ci95: float
    J: float
    J_ci95: float
    zc: tuple[float, float]
    residual_rms: float
    whiteness_p: float
    heldout_rms: float
    bic: float
    m_rel_err: float | None = None
    J_rel_err: float | None = None

    def as_dict(self) -> dict[str, Any]:
        out = {
            "m": self.m, "J": self.J, "residual_rms": self.residual_rms, "whiteness_p": self.whiteness_p,
            "m_ci95": self.m_ci95, "J_ci95": self.J_ci95, "zc": list(self.zc), "heldout_rms": self.heldout_rms,
            "bic": self.bic, "effects": list(self.effects),
        }  # fmt: skip
        if self.m_rel_err is not None:
            out["m_rel_err"] = self.m_rel_err
            out["J_rel_err"] = self.J_rel_err
        return out


@dataclass
class Diagnosis:
    """What :func:`diagnose` found. ``as_dict`` is the JSON of ``coload diagnose --json`` (docs/diagnose.md)."""

    nominal: ModelReport
    augmented: ModelReport
    effects: list[dict[str, Any]]
    unexplained: bool
    warnings: list[str]
    candidates: list[dict[str, Any]]
    signatures: list[dict[str, Any]]
    ambiguous: list[list[str]]
    noise_sigma: float
    wall_s: float
    truth: dict[str, float] | None = None
    # for the figure (not in the JSON): block-averaged residual modes and their block length
    modes_nominal: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)), repr=False)
    modes_augmented: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)), repr=False)
    block_s: float = 0.1
    lags: int = 20

    def as_dict(self) -> dict[str, Any]:
        return {
            "nominal": self.nominal.as_dict(), "augmented": self.augmented.as_dict(), "effects": self.effects,
            "unexplained": self.unexplained, "warnings": self.warnings, "candidates": self.candidates,
            "signatures": self.signatures, "ambiguous": self.ambiguous, "noise_sigma": self.noise_sigma,
            "truth": self.truth, "wall_s": self.wall_s, "residual": residual_panels(self),
        }  # fmt: skip


def _value(x: np.ndarray) -> float | list[float]:
    return float(x[0]) if len(x) == 1 else [float(v) for v in x]


# --- the diagnosis --------------------------------------------------------------------------------
def diagnose(samples: np.ndarray, n: int, dt: float, *, options: DiagnoseOptions | None = None,
             truth: dict[str, float] | None = None, progress: Callable[[str], None] | None = None,
             clock: Callable[[], float] | None = None) -> Diagnosis:  # fmt: skip
    """Diagnose one recording: ``samples`` (T, n, 5) [vx, vy, fx, fy, tau] per tick and agent (NaN velocity =
    not measured). ``truth`` ({"m", "J"}) is used only to report errors. ``clock`` (e.g.
    ``time.perf_counter``) times the diagnosis into ``wall_s``; without it ``wall_s`` is 0 and the
    result depends on the data alone. Raises :class:`DiagnoseError`."""
    opt = options or DiagnoseOptions()
    unknown = [c for c in opt.candidates if c not in CANDIDATES]
    if unknown:
        raise DiagnoseError(f"unknown candidate effect(s) {unknown}; known: {list(CANDIDATES)}")
    say = progress or (lambda msg: None)
    t_start = clock() if clock is not None else 0.0
    try:
        s, warns = _check_input(samples, n, dt)
    except BatchFitError as exc:
        raise DiagnoseError(str(exc)) from None
    warns = list(warns)
    d = _data(s, dt)
    T = d.T
    floor2 = _noise_floor(d)
    head = min(T, max(50, round(15.0 / dt)))
    say(f"initial geometry: batch fit of the first {head * dt:.0f} s")
    try:
        bf = fit_recording(s[:head], n, dt, options=FitOptions(polish=False))
    except BatchFitError as exc:
        raise DiagnoseError(f"cannot identify the nominal model: {exc}") from None
    m0 = bf.m.raw if math.isfinite(bf.m.raw) and bf.m.raw > 0 else 1e3
    J0 = bf.J.raw if math.isfinite(bf.J.raw) and bf.J.raw > 0 else 1e2
    L0 = _Layout(n, ())
    p_head = np.concatenate((bf.r_body.ravel(), [1 / m0, 1 / J0], bf.v_c[0], [bf.omega[0]]))
    say("nominal model: fitting the whole recording")
    nominal = _fit_robust(d, L0, [p_head], head, floor2, opt, say, "nominal")
    p_white0 = _whiteness(d, nominal, opt)
    mj0 = nominal.mj()
    say(f"nominal: m {mj0['m']:.4g} kg, J {mj0['J']:.4g} kg m^2, residual {math.sqrt(nominal.rss / nominal.N):.4g} m/s, "
        f"whiteness p {p_white0:.3g}")  # fmt: skip

    scores0 = _scores(d, nominal, opt.candidates)
    signatures = [
        {"signature": CANDIDATES[c][2], "candidate": c, "corr": list(sc.corr), "bound": sc.bound, "score_p": sc.p}
        for c, sc in scores0.items()
    ]
    for c, sc in scores0.items():
        ref = _reference(c, mj0["m"], mj0["J"], dt)
        if sc.collinear > 1 - 1e-6:
            why = (" (a constant velocity offset is the initial velocity v_C(0) as long as no velocity-dependent "
                   "force is in the model)") if c == "velocity_bias" else ""  # fmt: skip
            warns.append(f"{c}: not identifiable from these data: its signature lies in the span of the nominal "
                         f"parameters{why}")  # fmt: skip
        elif sc.half_width > ref:
            warns.append(f"{c}: not excited enough: the data resolve it only to +-{sc.half_width:.3g} "
                         f"{CANDIDATES[c][1]}, more than a realistic {ref:.3g} {CANDIDATES[c][1]}")  # fmt: skip

    # forward selection: score-test screening, then nested F-test + BIC on the fitted candidates
    current, cur_lay = nominal, L0
    remaining = list(opt.candidates)
    accepted: list[str] = []
    ambiguous: list[list[str]] = []
    table: dict[str, dict[str, Any]] = {}
    scores = scores0
    while remaining:
        alpha_k = opt.alpha / len(remaining)
        screen = sorted((c for c in remaining if scores[c].p < alpha_k), key=lambda c: -_lm(scores[c]))[: opt.max_fits]
        trials: dict[str, tuple[_Fit, float, float]] = {}
        for j, c in enumerate(screen):
            lay = _Layout(n, tuple(e for e in CANDIDATES if e in cur_lay.effects or e == c))
            say(f"candidate {c} ({j + 1}/{len(screen)}) on top of {list(cur_lay.effects) or 'nominal'}")
            starts = [_extend(current.p, cur_lay, lay), _extend(p_head, L0, lay)]
            f = _fit_robust(d, lay, starts, head, floor2, opt, say, c)
            F, pF = _nested(current, f)
            trials[c] = (f, pF, f.bic - current.bic)
            val, ci = f.param(c)
            table.setdefault(c, {}).update({
                "name": c, "unit": CANDIDATES[c][1], "value": _value(val), "ci95": _value(ci), "F": F, "p": pF,
                "delta_bic": f.bic - current.bic, "whiteness_p": _whiteness(d, f, opt),
                "on_top_of": list(cur_lay.effects),
            })  # fmt: skip
        eligible = sorted((c for c, (f, pF, dbic) in trials.items() if pF < alpha_k and dbic < 0),
                          key=lambda c: trials[c][0].bic)  # fmt: skip
        if not eligible:
            break
        best = eligible[0]
        fb_ = trials[best][0]
        for c2 in eligible[1:]:
            if trials[c2][0].bic - fb_.bic >= opt.ambiguous_bic:
                continue
            lay2 = _Layout(n, tuple(e for e in CANDIDATES if e in fb_.lay.effects or e == c2))
            say(f"telling {best} from {c2}: joint fit")
            joint = _fit(d, lay2, _extend(fb_.p, fb_.lay, lay2), opt)
            if _nested(fb_, joint)[1] >= alpha_k or _nested(trials[c2][0], joint)[1] >= alpha_k:
                ambiguous.append([best, c2])
                warns.append(f"{best} and {c2}: the data cannot separate them (BIC within "
                             f"{trials[c2][0].bic - fb_.bic:.1f}, neither adds to the other); naming neither")  # fmt: skip
                remaining.remove(c2)
        accepted.append(best)
        remaining.remove(best)
        current, cur_lay = fb_, fb_.lay
        if len(accepted) >= opt.max_effects:
            break
        scores = _scores(d, current, remaining) if remaining else {}
    white = _whiteness(d, current, opt)
    ambiguous_names = {c for pair in ambiguous for c in pair}
    if white > opt.alpha_white:
        unexplained = False
        named = [c for c in accepted if c not in ambiguous_names]
        final = current
    else:
        unexplained = True
        named = []
        final = nominal
        tried = ", ".join(accepted) if accepted else "none"
        warns.append(f"unexplained: a structured residual remains (Ljung-Box p {white:.2g} with {tried} added; "
                     f"nominal p {p_white0:.2g}); no candidate effect explains it, so none is named")  # fmt: skip
    for c in table:
        table[c]["accepted"] = c in named
    effects = []
    for c in named:
        val, ci = final.param(c)
        effects.append({"name": c, "value": _value(val), "unit": CANDIDATES[c][1], "ci95": _value(ci)})

    def report(f: _Fit, pw: float) -> ModelReport:
        say(f"held-out error of {list(f.lay.effects) or 'nominal'}: fitting the first {1 - opt.holdout:.0%}")
        Tt = max(50, round((1 - opt.holdout) * T))
        ft = _fit(d.head(Tt), f.lay, f.p, opt)
        res = _residuals(d, _simulate(d, f.lay, ft.p[None]))[0]
        tail = d.mask[Tt:].sum() * 2
        held = math.sqrt(float(res[-tail:] @ res[-tail:]) / max(tail, 1)) if tail else math.nan
        mj = f.mj()
        rep = ModelReport(f.lay.effects, mj["m"], mj["m_ci95"], mj["J"], mj["J_ci95"],
                          tuple(f.p[: 2 * n].reshape(n, 2).mean(axis=0).tolist()), math.sqrt(f.rss / f.N), pw,
                          held, f.bic)  # fmt: skip
        if truth:
            rep.m_rel_err = mj["m"] / truth["m"] - 1
            rep.J_rel_err = mj["J"] / truth["J"] - 1
        return rep

    block = max(1, round(opt.block_s / dt))
    nominal_rep = report(nominal, p_white0)
    aug_rep = nominal_rep if final is nominal else report(final, white)
    return Diagnosis(
        nominal=nominal_rep, augmented=aug_rep, effects=effects, unexplained=unexplained, warnings=warns,
        candidates=list(table.values()), signatures=signatures, ambiguous=ambiguous,
        noise_sigma=math.sqrt(floor2), wall_s=clock() - t_start if clock is not None else 0.0, truth=truth,
        modes_nominal=block_average(_modes(d, nominal), block), modes_augmented=block_average(_modes(d, final), block),
        block_s=block * dt, lags=opt.lags,
    )  # fmt: skip


# --- files ----------------------------------------------------------------------------------------
def read_recording(path: str | Path) -> tuple[np.ndarray, int, float, dict[str, float] | None, list[str]]:
    """(samples (T, n, 5), n, dt, truth {"m", "J"} or None, warnings) from a recording directory.

    Only ``run.toml`` (n, dt, edges) and ``samples.csv`` are read for the fit; ``truth.csv``, if present,
    only for the errors. Malformed files raise :class:`DiagnoseError` naming file, line and column.
    """
    path = Path(path)
    if not path.is_dir():
        raise DiagnoseError(f"{path}: not a directory (a recording is a directory with run.toml and samples.csv)")
    try:
        config = rf.read_config(path / rf.RUN_TOML)
        n, dt = int(config["n"]), float(config["dt"])
        csv_path = path / rf.SAMPLES_CSV
        if not csv_path.exists():
            raise DiagnoseError(f"{csv_path}: missing (a recording needs {rf.SAMPLES_CSV})")
        table = rf.read_agent_csv(csv_path, rf.SAMPLES_HEADER, n)
    except rf.RunFormatError as exc:
        raise DiagnoseError(str(exc)) from None
    try:
        samples = samples_array(table.t, table.columns, dt)
    except BatchFitError as exc:
        raise DiagnoseError(f"{csv_path}: {exc}") from None
    warns: list[str] = list(table.warnings)
    truth = None
    tpath = path / rf.TRUTH_CSV
    if tpath.exists():
        try:
            tr = rf.read_truth_csv(tpath, n)
            mass, inertia = tr.columns["mass"], tr.columns["inertia"]
            truth = {"m": float(np.median(mass)), "J": float(np.median(inertia))}
            if np.ptp(mass) > 0 or np.ptp(inertia) > 0:
                warns.append("truth: mass or inertia changes during the recording (the model assumes constant "
                             "m and J); errors are against the median")  # fmt: skip
        except (rf.RunFormatError, KeyError) as exc:
            warns.append(f"truth.csv ignored: {exc}")
    return samples, n, dt, truth, warns


def diagnose_dir(path: str | Path, *, options: DiagnoseOptions | None = None,
                 progress: Callable[[str], None] | None = None) -> Diagnosis:  # fmt: skip
    """Read a recording directory and diagnose it (see :func:`diagnose`)."""
    samples, n, dt, truth, warns = read_recording(path)
    result = diagnose(samples, n, dt, options=options, truth=truth, progress=progress, clock=time.perf_counter)
    result.warnings[:0] = warns
    return result


def stderr_progress(prefix: str = "coload diagnose") -> Callable[[str], None]:
    """Progress lines on stderr with the elapsed time."""
    t0 = time.perf_counter()

    def say(msg: str) -> None:
        print(f"{prefix} [{time.perf_counter() - t0:6.1f} s] {msg}", file=sys.stderr, flush=True)

    return say


__all__ = [
    "CANDIDATES", "DiagnoseError", "DiagnoseOptions", "Diagnosis", "ModelReport", "autocorrelation",
    "block_average", "diagnose", "diagnose_dir", "draw_residuals", "format_diagnosis", "ljung_box",
    "plot_diagnosis", "read_recording", "residual_panels", "stderr_progress",
]  # fmt: skip


# --- presentation ---------------------------------------------------------------------------------
def format_diagnosis(r: Diagnosis) -> str:
    """A short human-readable summary (the JSON has everything)."""
    lines = []
    for label, m in (("nominal", r.nominal), ("augmented", r.augmented)):
        err = ""
        if m.m_rel_err is not None:
            err = f"  [vs truth: m {100 * m.m_rel_err:+.2f} %, J {100 * m.J_rel_err:+.2f} %]"
        lines.append(f"{label:9s} effects {list(m.effects) or '-'}: m {m.m:.4g} +- {m.m_ci95:.2g} kg, "
                     f"J {m.J:.4g} +- {m.J_ci95:.2g} kg m^2, residual {m.residual_rms:.4g} m/s, "
                     f"whiteness p {m.whiteness_p:.3g}, held-out {m.heldout_rms:.4g} m/s{err}")  # fmt: skip
    if r.effects:
        for e in r.effects:
            lines.append(f"effect    {e['name']}: {e['value']} +- {e['ci95']} {e['unit']}")
    else:
        lines.append("effect    none named")
    lines.append(f"unexplained: {str(r.unexplained).lower()}")
    lines += [f"warning   {w}" for w in r.warnings]
    return "\n".join(lines)


MODE_NAMES = ("mean x (m/s)", "mean y (m/s)", "rotation (rad/s)")
"""The residual's rigid-body modes (:func:`_modes`): the agents' mean residual, x and y, and its rotation."""


def _jlist(x: np.ndarray) -> list:
    """Nested lists for JSON, NaN as None (strict JSON has no NaN)."""
    return [_jlist(v) for v in x] if np.ndim(x) > 1 else [float(v) if math.isfinite(v) else None for v in x]


def residual_panels(r: Diagnosis) -> dict[str, Any]:
    """The residual figure's data, JSON-ready (the ``residual`` key of ``coload diagnose --json``): per
    model (nominal = before, augmented = after) the block-averaged rigid-body modes of the residual, their
    autocorrelations r_1..r_lags, and per mode the 95 % bound +-1.96/sqrt(N) of a white residual's
    autocorrelation, N the number of blocks with data. :func:`draw_residuals` draws it."""
    out: dict[str, Any] = {"block_s": r.block_s, "lags": r.lags, "modes": list(MODE_NAMES)}
    for key, modes, rep in (("nominal", r.modes_nominal, r.nominal), ("augmented", r.modes_augmented, r.augmented)):
        out[key] = {
            "effects": list(rep.effects), "whiteness_p": rep.whiteness_p, "series": _jlist(modes),
            "acf": [_jlist(autocorrelation(modes[:, j], r.lags)) for j in range(modes.shape[1])],
        }  # fmt: skip
    counts = [int(np.count_nonzero(~np.isnan(r.modes_nominal[:, j]))) for j in range(r.modes_nominal.shape[1])]
    out["bound"] = [Z95 / math.sqrt(max(nb, 1)) for nb in counts]
    out["unexplained"] = r.unexplained
    return out


def draw_residuals(fig: Any, panels: dict[str, Any], title: str = "") -> None:
    """Draws :func:`residual_panels` (or the ``residual`` key of a diagnosis JSON) into ``fig``: one row per
    mode, the residual's block means before and after on the left, their autocorrelation with the white-
    noise bounds on the right. Axes are labelled ``residual:<j>`` and ``acf:<j>`` (j = mode index)."""
    names = panels["modes"]
    axes = fig.subplots(len(names), 2, gridspec_kw={"width_ratios": [3, 1]}, squeeze=False)
    block_s, lags = float(panels["block_s"]), int(panels["lags"])
    lag_t = np.arange(1, lags + 1) * block_s
    for j, name in enumerate(names):
        ax, axc = axes[j]
        ax.set_label(f"residual:{j}")
        axc.set_label(f"acf:{j}")
        for key, color in (("nominal", "tab:red"), ("augmented", "tab:blue")):
            m = panels[key]
            series = np.array([np.nan if v is None else v for v in (row[j] for row in m["series"])], dtype=float)
            label = f"{'before' if key == 'nominal' else 'after'}: {', '.join(m['effects']) or 'nominal'}"
            ax.plot(np.arange(len(series)) * block_s, series, color=color, lw=0.8, label=label)
            acf = np.array([np.nan if v is None else v for v in m["acf"][j]], dtype=float)
            axc.plot(lag_t, acf, "o-", color=color, ms=3, lw=0.8)
        b = panels["bound"][j]
        axc.axhline(b, color="k", ls="--", lw=0.8)
        axc.axhline(-b, color="k", ls="--", lw=0.8)
        ax.set_ylabel(f"residual, {name}", fontsize=8)
        axc.set_ylabel("autocorrelation", fontsize=8)
    axes[0, 0].legend(loc="upper right", fontsize=8)
    axes[-1, 0].set_xlabel(f"t (s), {block_s:g} s block means")
    axes[-1, 1].set_xlabel("lag (s); dashed: +-1.96/sqrt(N)")
    nom, aug = panels["nominal"], panels["augmented"]
    fig.suptitle(title or (
        f"residual before (nominal, Ljung-Box p = {nom['whiteness_p']:.2g}) and after "
        f"({', '.join(aug['effects']) or 'none'}, p = {aug['whiteness_p']:.2g})"
        f"{'  UNEXPLAINED' if panels.get('unexplained') else ''}"))  # fmt: skip


def plot_diagnosis(r: Diagnosis, path: str | Path) -> Path:
    """diagnose.png: the residual's rigid-body modes before and after (time series, block-averaged) and
    their autocorrelation with the 95 % bounds of a white residual (:func:`draw_residuals`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(12, 8), layout="constrained")
    draw_residuals(fig, residual_panels(r))
    path = Path(path)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
