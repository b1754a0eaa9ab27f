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
from scipy.ndimage import maximum_filter1d, median_filter

from ident.stats import divided_weights

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


def _scores(t: np.ndarray, y: np.ndarray, sigma: np.ndarray, at: np.ndarray, nodes: np.ndarray,
            span: float) -> np.ndarray:  # fmt: skip
    """Prediction error over its noise (``sigma`` (K,) per sample) of the samples ``at`` (indices into ``t``), each from the two
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
    zg = np.abs(err).max(axis=1) / (sigma[at[good]] * np.sqrt(1.0 + (w * w).sum(axis=1)))
    zg[tn[:, 3] - tn[:, 0] > span] = np.inf
    z[good] = zg
    return z


def _one(t: np.ndarray, y: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Indices of the glitches of one agent's samples ``y`` (K, 2) at stamps ``t`` (K,), noise ``sigma`` (K,)."""
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
    """(T, n) bool: the glitches of ``y`` (T, n, 2) (NaN = not measured) with noise floor ``sigma`` (n,), or
    (T, n) where it varies along the recording."""
    T, n, _ = y.shape
    sigma = np.broadcast_to(np.asarray(sigma, float), (T, n))
    out = np.zeros((T, n), bool)
    for i in range(n):
        ok = np.flatnonzero(~np.isnan(y[:, i]).any(axis=1))
        if ok.size < 5 or not np.isfinite(sigma[ok, i]).all() or not (sigma[ok, i] > 0).all():
            continue
        bad = _one(t[ok], y[ok, i], sigma[ok, i])
        if bad.size <= MAX_SHARE * ok.size:
            out[ok[bad], i] = True
    return out



MAD_NORMAL = 0.6744897501960817  # the median of a standard normal's absolute value
LOCAL = 50  # samples over which a force's floor is its local divided differences' median
SIDE = 15  # samples either side of a force spike in the curve through a velocity across it
SPREAD = 2  # samples either side of a force spike left out of that curve: the wrench's cubic spreads it


def force_spikes(t: np.ndarray, force: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The spikes of the logged forces ``force`` (T, n, 2) (NaN: not logged): (T, n) flags and (T, n, 2) each
    flagged sample's departure from the line through its agent's unflagged neighbours (0 elsewhere). A flag
    is a glitch (:func:`find_glitches`, against each agent's own divided-difference floor of its force) that
    the lines through the two samples on either side, each on its own, also miss by more than
    ``GLITCH_FLOORS`` x their noise, in the same direction and by more than they disagree: a logged command
    has no noise, and its floor (its own smoothness) makes every corner a glitch to the cubic (a clipped force
    entering its plateau), which one of the two sides predicts. The floor is the larger of the local one (:func:`_local_floor`: the spikes
    themselves raise a whole-recording floor, which a command's small one cannot afford) and the rounding's of
    the digits logged (:func:`_resolution`): a command's noise is its log's resolution, which is relative (six
    digits, C's %g: 1e-4 N at 10 N, 1e-6 N at 0.1 N)."""
    tiny = 1e-9 * np.nanstd(force, axis=(0, 2))  # a constant force: no floor to be off by, only a zero
    # a sample's cubic leans on its neighbours, whose last digit may be coarser (10.0 after 9.99999)
    res = maximum_filter1d(_resolution(force).max(axis=-1), 5, axis=0, mode="nearest")
    sig = np.fmax(np.fmax(_local_floor(t, force), res / np.sqrt(12.0)), tiny)
    flags = find_glitches(t, force, sig)
    dep = np.zeros(force.shape)
    for i in np.flatnonzero(flags.any(axis=0)):
        ok = np.flatnonzero(~flags[:, i] & ~np.isnan(force[:, i]).any(axis=1))
        sg = sig[:, i][flags[:, i]]
        at = np.flatnonzero(flags[:, i])
        p = np.searchsorted(ok, at)
        good = (p >= 2) & (p + 1 < ok.size)
        miss, line = [], []
        for a, b in ((ok[np.maximum(p - 1, 0)], ok[np.maximum(p - 2, 0)]),
                     (ok[np.minimum(p, ok.size - 1)], ok[np.minimum(p + 1, ok.size - 1)])):
            w = (t[at] - t[a]) / np.where(t[a] != t[b], t[a] - t[b], 1.0)  # the line through a and b at t[at]
            line.append(force[a, i] + w[:, None] * (force[a, i] - force[b, i]))
            miss.append((force[at, i] - line[-1]) / (sg * np.sqrt(1.0 + (1.0 + w) ** 2 + w * w))[:, None])
        left, right = miss
        spike = good & (np.linalg.norm(left, axis=1) > GLITCH_FLOORS) & (np.linalg.norm(right, axis=1) > GLITCH_FLOORS)
        # ... and more than the two lines disagree with each other: two corners close together (both axes
        # clipping) leave lines that miss a sample alike but disagree as much between themselves
        spike &= ((left * right).sum(axis=1) > 0) & (
            np.linalg.norm(force[at, i] - 0.5 * (line[0] + line[1]), axis=1) > np.linalg.norm(line[0] - line[1], axis=1))
        flags[at[~spike], i] = False
        at = at[spike]
        for c in range(2):
            dep[at, i, c] = force[at, i, c] - np.interp(t[at], t[ok], force[ok, i, c])
    return flags, dep


def _local_floor(t: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(T, n) each agent's noise floor of ``y`` (T, n, 2) around each of its samples: the median of the
    absolute third divided differences (:func:`ident.stats.divided_weights`) over :data:`LOCAL`
    samples, over the normal's median absolute value, the larger axis's; NaN where the agent has no value."""
    T, n, _ = y.shape
    out = np.full((T, n), np.nan)
    for i in range(n):
        ok = np.flatnonzero(~np.isnan(y[:, i]).any(axis=1))
        if ok.size < LOCAL:
            continue
        idx = np.arange(ok.size - 3)[:, None] + np.arange(4)
        c = divided_weights(t[ok][idx])
        d = np.abs(np.einsum("kj,kjc->kc", c, y[ok, i][idx]))
        d = np.pad(d, ((1, 2), (0, 0)), mode="edge")  # each difference at its window's second sample
        med = median_filter(d, size=(LOCAL, 1), mode="nearest")
        h = LOCAL // 2  # within half a window of an end: the end's window (a padded end repeats one difference)
        med[:h], med[-h:] = np.median(d[:LOCAL], axis=0), np.median(d[-LOCAL:], axis=0)
        out[ok, i] = med.max(axis=1) / MAD_NORMAL
    return out


def _resolution(y: np.ndarray, most: int = 15) -> np.ndarray:
    """(T, n, ...) the last digit's unit of each value of ``y`` (T, n, ...) as its agent's log writes them: the
    agent's values need at most D significant digits (a float's repr beyond ``most`` digits: none read), and
    a value of exponent e is rounded to 10^(e - D + 1); 0 where the value is 0 or NaN."""
    a = np.abs(np.nan_to_num(y))
    e = np.floor(np.log10(np.where(a > 0, a, 1.0)))
    digits = np.full(a.shape, most + 1)
    for d in range(most, 0, -1):  # the fewest digits that write each value exactly
        unit = 10.0 ** (e - d + 1)
        exact = np.abs(a / unit - np.round(a / unit)) < 1e-6
        digits = np.where(exact, d, digits)
    axes = tuple(k for k in range(y.ndim) if k != 1)
    D = np.where(a > 0, digits, 0).max(axis=axes, keepdims=True)
    return np.where((a > 0) & (D <= most), 10.0 ** (e - D + 1), 0.0)


def _jump(t: np.ndarray, v: np.ndarray, k: int, rows: np.ndarray, others: np.ndarray) -> np.ndarray:
    """The step of ``v`` (T, 2) at stamp ``k``: a parabola in time through its ``rows`` plus a free step at
    ``k`` and at each of the ``others`` (the stamps of further spikes among them)."""
    x = t[rows] - t[k]
    A = np.column_stack([np.ones(rows.size), x, x * x] + [(rows > o).astype(float) for o in np.r_[k, others]])
    return np.linalg.lstsq(A, v[rows], rcond=None)[0][3]


def spike_response(t: np.ndarray, vel: np.ndarray, flags: np.ndarray, dep: np.ndarray, inv_m: float, inv_J: float,
                   arms: np.ndarray | None) -> tuple[float, float, int]:
    """Do the agents' velocities ``vel`` (T, n, 2) follow the force spikes (``flags``, ``dep`` from
    :func:`force_spikes`)? A real one-sample force adds the impulse q = dep x the sample period to the load:
    the contacts' velocities jump by q / m and the rotation's (R_i x q) / J at each contact (``arms`` (T, n, 2),
    the contacts' arms from the centre of mass in the world frame, None without rotation). The jump seen (the
    step of a parabola through :data:`SIDE` samples either side, :data:`SPREAD` samples around each spike left
    out, a free step at each other spike among them) is regressed on the one predicted: the slope (1: the
    motion follows, 0: it does not), its standard error from the scatter, and the number of spike stamps used
    (those with :data:`SIDE` stamps either side within the recording)."""
    T, n, _ = vel.shape
    rows = np.flatnonzero(flags.any(axis=1))
    spread = np.convolve(flags.any(axis=1), np.ones(2 * SPREAD + 1), "same") > 0
    seen, pred, used = [], [], set()
    for k in rows:
        lo, hi = k - SPREAD - SIDE, k + SPREAD + SIDE
        if lo < 0 or hi >= T:
            continue
        span = np.arange(lo, hi + 1)
        others = rows[(rows >= lo) & (rows <= hi) & (rows != k)]
        dt = 0.5 * (t[k + 1] - t[k - 1])
        q = dep[k].sum(axis=0) * dt
        p = np.broadcast_to(q * inv_m, (n, 2)).copy()
        if arms is not None:
            dw = inv_J * float(np.sum(arms[k, :, 0] * dep[k, :, 1] - arms[k, :, 1] * dep[k, :, 0]) * dt)
            p += dw * np.column_stack((-arms[k, :, 1], arms[k, :, 0]))
        for j in range(n):
            use = span[~spread[span] & ~np.isnan(vel[span, j]).any(axis=1)]
            if (use < k).sum() >= 3 and (use > k).sum() >= 3 and use.size >= 3 * (4 + others.size):
                seen.append(_jump(t, vel[:, j], k, use, others))
                pred.append(p[j])
                used.add(int(k))
    if not seen:
        return np.nan, np.nan, 0
    d, p = np.concatenate(seen), np.concatenate(pred)
    pp = float(p @ p)
    if not pp > 0:
        return np.nan, np.nan, 0
    beta = float(d @ p) / pp
    se = float(np.sqrt(np.sum((d - beta * p) ** 2) / max(d.size - 1, 1) / pp))
    return beta, se, len(used)
