"""Glitches: isolated samples far off their neighbours (a sensor's spike, a dropped bit, a bad packet).

A least-squares fit gives each such sample the pull of its square: a handful of 30-sigma spikes inflate
the residual and every interval while no test points at them. :func:`find_glitches` predicts each sample
of each agent's measured channel from the two samples on either side that are not flagged (the cubic
through them, at the stamps' own times) and flags a sample whose prediction error is more than
``GLITCH_FLOORS`` times what the noise floor gives it. A spike also spoils its neighbours' predictions
(by up to its own size where stamps are jittered), so the flags grow in rounds, the largest error around
each spike first, and a flag is kept only if the sample still stands out when predicted from unflagged
neighbours alone. Pure; docs/diagnose.md, "Input".
"""

from __future__ import annotations

import numpy as np

GLITCH_FLOORS = 8.0  # a white-noise sample is this far off with probability ~1e-15: a flag is a glitch
MAX_SHARE = 0.02  # more flags than this share of a channel's samples are not glitches: none is taken out
GAP = 1.5  # four intervals spanning more than this x their median cross a gap: no prediction there


def _cubic_weights(tn: np.ndarray, x: np.ndarray) -> np.ndarray:
    """(K, 4) weights of the cubic through the stamps ``tn`` (K, 4), evaluated at ``x`` (K,)."""
    w = np.ones(tn.shape)
    for j in range(4):
        for i in range(4):
            if i != j:
                w[:, j] *= (x - tn[:, i]) / (tn[:, j] - tn[:, i])
    return w


def _scores(t: np.ndarray, y: np.ndarray, sigma: float, at: np.ndarray, nodes: np.ndarray, span: float) -> np.ndarray:
    """Prediction error over its noise of the samples ``at`` (indices into ``t``), each from the two
    ``nodes`` (sorted indices) before and the two after it; inf where there are not two on a side or the
    four span more than ``span`` (s)."""
    p = np.searchsorted(nodes, at)  # nodes[p - 1] < at <= nodes[p]; at itself is not a node
    p_after = p + (nodes[np.minimum(p, nodes.size - 1)] == at)
    z = np.full(at.size, np.inf)
    good = (p >= 2) & (p_after + 1 < nodes.size)
    if not good.any():
        return z
    nb = np.stack((nodes[p[good] - 2], nodes[p[good] - 1], nodes[p_after[good]], nodes[p_after[good] + 1]), axis=1)
    tn = t[nb]
    w = _cubic_weights(tn, t[at[good]])
    err = y[at[good]] - np.einsum("kj,kjc->kc", w, y[nb])
    zg = np.abs(err).max(axis=1) / (sigma * np.sqrt(1.0 + (w * w).sum(axis=1)))
    zg[tn[:, 3] - tn[:, 0] > span] = np.inf
    z[good] = zg
    return z


def _one(t: np.ndarray, y: np.ndarray, sigma: float) -> np.ndarray:
    """Indices of the glitches of one agent's samples ``y`` (K, 2) at stamps ``t`` (K,)."""
    K = t.size
    span = GAP * 4 * float(np.median(np.diff(t)))
    flagged = np.zeros(K, bool)
    for _ in range(10):
        keep = np.flatnonzero(~flagged)
        z = _scores(t, y, sigma, keep, keep, span)
        z = np.where(np.isinf(z), 0.0, z)
        # the largest error within two kept samples either side is the spike's own, or the one that hides it
        zp = np.pad(z, 2)
        peak = z > GLITCH_FLOORS
        for d in (1, 2):
            peak &= (z >= zp[2 - d : zp.size - 2 - d]) & (z >= zp[2 + d : zp.size - 2 + d])
        if not peak.any():
            break
        flagged[keep[peak]] = True
    at = np.flatnonzero(flagged)
    if at.size:
        z = _scores(t, y, sigma, at, np.flatnonzero(~flagged), span)
        flagged[at[~(np.isfinite(z) & (z > GLITCH_FLOORS))]] = False
    return np.flatnonzero(flagged)


def find_glitches(t: np.ndarray, y: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """(T, n) bool: the glitches of ``y`` (T, n, 2) (NaN = not measured) with noise floor ``sigma`` (n,)."""
    T, n, _ = y.shape
    out = np.zeros((T, n), bool)
    for i in range(n):
        ok = np.flatnonzero(~np.isnan(y[:, i]).any(axis=1))
        if ok.size < 5 or not np.isfinite(sigma[i]) or sigma[i] <= 0:
            continue
        bad = _one(t[ok], y[ok, i], float(sigma[i]))
        if bad.size <= MAX_SHARE * ok.size:
            out[ok[bad], i] = True
    return out
