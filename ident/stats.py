"""Statistics of the diagnosis: noise floor from the data, whiteness, nested tests.

Pure functions on arrays. See docs/diagnose.md ("Method").
"""

from __future__ import annotations

import math
import warnings

import numpy as np
from scipy import stats

Z95 = 1.959963984540054
_TRIM = 0.99  # share of the squared differences kept (the rest: force steps, outliers)
_TRIM_GAIN = 1 - 2 * stats.norm.ppf(0.5 + _TRIM / 2) * stats.norm.pdf(stats.norm.ppf(0.5 + _TRIM / 2)) / _TRIM


def _trimmed_variance(sq: np.ndarray) -> float:
    """The variance of zero-mean Gaussian values from their squares ``sq``, the largest 1 - _TRIM dropped
    (force steps, glitches) and the truncation corrected for."""
    kept = np.sort(sq)[: max(1, int(_TRIM * sq.size))]
    return float(kept.mean()) / _TRIM_GAIN


def divided_weights(tt: np.ndarray) -> np.ndarray:
    """Newton's divided-difference weights of each window of stamps ``tt`` (K, order + 1), over their norm:
    white noise of variance s^2 gives each weighted difference the variance s^2."""
    k = tt.shape[1]
    gap = tt[:, :, None] - tt[:, None, :]
    gap[:, np.arange(k), np.arange(k)] = 1.0
    c = 1.0 / gap.prod(axis=2)
    return c / np.sqrt((c * c).sum(axis=1, keepdims=True))


def difference_noise(t: np.ndarray, y: np.ndarray, order: int = 3) -> float:
    """Noise sigma of the columns of ``y`` (T, ...) from its ``order``-th divided differences along time.

    A smooth signal sampled finely has small high-order divided differences, on any grid of stamps; white
    noise of variance s^2 gives a divided difference sum_j c_j y_j of variance s^2 sum_j c_j^2, so each is
    taken over its weights' norm (on a regular grid: the plain differences over sqrt(C(2k, k))). Plain
    differences of irregular stamps would count the signal's slope times the jitter as noise. Each column
    is taken on its own samples (agents that log on their own clocks leave the others' stamps empty), in
    runs without gaps (intervals within 1.5x the column's median); a constant column (an axis the
    recording does not measure, written as 0) is left out. The largest 1 % (force steps, outliers) are
    dropped and the truncation corrected for. NaN if there is too little data.
    """
    y = y.reshape(y.shape[0], -1)
    vals = []
    for j in range(y.shape[1]):
        ok = ~np.isnan(y[:, j])
        tc, col = t[ok], y[ok, j]
        if tc.size <= order + 1 or np.ptp(col) == 0.0:
            continue
        dts = np.diff(tc)
        med = np.median(dts)
        idx = np.arange(tc.size - order)[:, None] + np.arange(order + 1)
        good = (np.abs(dts - med) <= 0.5 * med)[idx[:, :-1]].all(axis=1)
        c = divided_weights(tc[idx[good]])
        vals.append((col[idx[good]] * c).sum(axis=1))
    d2 = np.concatenate(vals) ** 2 if vals else np.zeros(0)
    if d2.size < 20:
        return math.nan
    return math.sqrt(_trimmed_variance(d2))


def _kinematic_remainder(vel: np.ndarray, min_stamps: int) -> tuple[np.ndarray, np.ndarray] | None:
    """The relative contact velocities' remainder after their rank-1 part (a rigid body's i omega z_i), at the
    stamps where every agent measured (complex, (K, n)), and those stamps' indices; None for n < 3 or fewer
    than ``min_stamps`` such stamps."""
    full = ~np.isnan(vel).any(axis=(1, 2))
    if full.sum() < min_stamps or vel.shape[1] < 3:
        return None
    w = vel[full, :, 0] + 1j * vel[full, :, 1]
    rel = w - w.mean(axis=1, keepdims=True)
    u, sv, vh = np.linalg.svd(rel, full_matrices=False)
    return rel - (u[:, :1] * sv[0]) @ vh[:1], np.flatnonzero(full)


def kinematic_noise(vel: np.ndarray) -> float:
    """Velocity noise sigma from the rigid-body kinematics alone (n >= 3): relative contact velocities
    of a rigid body are rank 1 (i omega z_i) over (stamp, agent); what is left is noise (a few glitches
    aside: the largest 1 % are dropped and the truncation corrected for)."""
    got = _kinematic_remainder(vel, 20)
    if got is None:
        return math.nan
    resid, n = got[0], vel.shape[1]
    # each component is N(0, s^2 (n - 2) / n)
    return math.sqrt(_trimmed_variance(np.concatenate([resid.real.ravel(), resid.imag.ravel()]) ** 2)
                     * n / max(n - 2, 1))


def kinematic_acf(r: np.ndarray, idx: np.ndarray, lags: int) -> tuple[np.ndarray, np.ndarray]:
    """Autocorrelation r_1..r_lags along time of the rigid-body kinematics' remainder (:func:`kinematic_columns`:
    its columns ``r`` at the stamps ``idx``), over pairs of stamps ``lag`` apart where every agent measured, and
    the number of such pairs per lag. The
    remainder is the noise through one projection per stamp across the agents, the same at every stamp, so
    it keeps the noise's correlation in time: ~0 for white sensor noise, -1/2 at lag 1 for velocities that
    are differences of noisy positions, phi^k for noise that is an AR(1) of per-sample correlation phi (a
    low-passed velocity)."""
    den = float((r * r).sum()) / r.shape[0]
    acf, pairs = np.full(lags, math.nan), np.zeros(lags, int)
    for k in range(1, lags + 1):
        nxt = np.flatnonzero(idx[k:] - idx[:-k] == k)  # stamps k apart, both full
        pairs[k - 1] = nxt.size
        if den > 0 and nxt.size:
            acf[k - 1] = float((r[nxt] * r[nxt + k]).sum()) / nxt.size / den
    return acf, pairs


def kinematic_columns(vel: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The rigid-body kinematics' remainder (:func:`kinematic_noise`) as real columns (K, 2n: each agent's x
    and y) at the stamps where every agent measured, and those stamps' indices; None for n < 3 or too
    little data."""
    got = _kinematic_remainder(vel, 50)
    if got is None:
        return None
    resid, idx = got
    return np.concatenate((resid.real, resid.imag), axis=1), idx


def kinematic_segments(r: np.ndarray, idx: np.ndarray) -> list[np.ndarray]:
    """:func:`kinematic_columns`' ``r`` at the stamps ``idx`` cut into runs of consecutive stamps."""
    return [s for s in np.split(r, np.flatnonzero(np.diff(idx) != 1) + 1) if s.shape[0] > 1]


def burg(segments: list[np.ndarray], order: int) -> np.ndarray:
    """Reflection (partial autocorrelation) coefficients kappa_1..kappa_order of an autoregressive model
    fitted by Burg's method to every column of every segment (T_s, C) together: each kappa minimises the
    forward and backward prediction errors' power summed over them. |kappa| < 1 always, so the filter is
    stable; Yule-Walker's equations on a sample autocorrelation are not, where the spectrum is steep (a
    second-order low-pass's lag-1 correlation 0.996 gave a negative innovation variance)."""
    f = b = segments  # the forward and backward prediction errors of order 0 (rebound, never written to)
    kappa = np.zeros(order)
    for k in range(order):
        num = sum(float((fi[1:] * bi[:-1]).sum()) for fi, bi in zip(f, b))
        den = sum(float((fi[1:] ** 2).sum() + (bi[:-1] ** 2).sum()) for fi, bi in zip(f, b))
        kk = 2.0 * num / den if den > 0 else 0.0
        f, b = [fi[1:] - kk * bi[:-1] for fi, bi in zip(f, b)], [bi[:-1] - kk * fi[1:] for fi, bi in zip(f, b)]
        kappa[k] = kk
    return kappa


def ar_table(kappa: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Levinson's step-up recursion: from reflection coefficients kappa_1..kappa_p, the predictors of every
    order, ``A`` (p + 1, p) (row k: x_t = sum_j A[k, j - 1] x_(t - j) + innovation, j <= k), and each
    order's innovation variance over the process' own, ``v`` (p + 1,). Row k predicts a stationary sample
    from its k predecessors exactly, so the rows 0..p applied to a series' first samples are the Cholesky
    factor of its covariance: whitening with them is exact generalised least squares for an AR(p)."""
    p = len(kappa)
    A = np.zeros((p + 1, p))
    v = np.ones(p + 1)
    for k in range(1, p + 1):
        kk = kappa[k - 1]
        A[k, : k - 1] = A[k - 1, : k - 1] - kk * A[k - 1, : k - 1][::-1]
        A[k, k - 1] = kk
        v[k] = v[k - 1] * (1.0 - kk * kk)
    return A, v


def kinematic_lag1(vel: np.ndarray) -> float:
    """Lag-1 autocorrelation of the rigid-body kinematics' remainder (:func:`kinematic_acf`); NaN for n < 3 or
    too little data."""
    got = kinematic_columns(vel)
    return math.nan if got is None else float(kinematic_acf(*got, 1)[0][0])


def block_average(x: np.ndarray, block: int) -> np.ndarray:
    """Means over consecutive blocks of ``block`` rows (NaN-aware); a trailing partial block is dropped."""
    nb = x.shape[0] // block
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmean(x[: nb * block].reshape(nb, block, *x.shape[1:]), axis=1)


def autocorrelation(x: np.ndarray, lags: int) -> np.ndarray:
    """Sample autocorrelation r_1..r_lags of one series (NaNs dropped, mean removed)."""
    x = x[~np.isnan(x)]
    x = x - x.mean() if x.size else x
    den = float(x @ x)
    if den == 0 or len(x) <= lags:
        return np.zeros(lags)
    return np.array([float(x[:-k] @ x[k:]) / den for k in range(1, lags + 1)])


def ljung_box(series: np.ndarray, lags: int, center: np.ndarray | None = None,
              center_draws: int | None = None) -> tuple[float, int, float]:
    """Ljung-Box on each column of ``series`` (T, K), summed: (Q, dof, p) with dof = K * lags.

    Degrees of freedom: the model is output-error (the fitted parameters act on the simulated,
    noise-free state, not on lagged residuals as ARMA coefficients do), so they use up no lags and
    Q ~ chi2(K lags) for a white residual. ``center`` (K, lags): the autocorrelation a white residual
    has after the fit's projection (the windows' free states remove part of it: see
    :func:`ident.select.whiteness`), subtracted before squaring; tests/test_ident_stats.py checks both.
    ``center_draws``: how many white-noise draws ``center`` is the mean of; its own scatter adds
    1/center_draws to each autocorrelation's variance, so Q is divided by 1 + 1/center_draws.
    """
    Q = 0.0
    K = series.shape[1]
    for j in range(K):
        x = series[:, j]
        N = int(np.count_nonzero(~np.isnan(x)))
        if N <= lags + 1:
            continue
        rho = autocorrelation(x, lags)
        if center is not None:
            rho = rho - center[j]
        Q += N * (N + 2) * float(np.sum(rho**2 / (N - np.arange(1, lags + 1))))
    dof = K * lags
    if center is not None and center_draws:
        Q /= 1 + 1 / center_draws
    return Q, dof, float(stats.chi2.sf(Q, dof))


def nested_f(rss_small: float, rss_big: float, q: int, N: int, P_big: int) -> tuple[float, float]:
    """F statistic and p-value of a model with rss_small nested in one with q more parameters."""
    dfd = max(N - P_big, 1)
    F = max(rss_small - rss_big, 0.0) / max(q, 1) / (rss_big / dfd)
    return F, float(stats.f.sf(F, max(q, 1), dfd))


def score_test(lm: float, q: int) -> tuple[float, float]:
    """(p, log p) of a score (Lagrange multiplier) statistic ~ chi2(q)."""
    return float(stats.chi2.sf(lm, q)), float(stats.chi2.logsf(lm, q))
