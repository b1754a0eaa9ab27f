"""Window statistics of the dynamical phase, compiled: the innovation monitor's windows, the estimate trust's
per-stage counts and the online detection's window evidence, each over a leading agent axis.

Contract (docs/fast-core-plan.md, sections 1.5 and S3): every kernel works on row ``b`` of its arrays and
performs the arithmetic of the Python it replaced in the same order, so compiled == interpreted and batch of
one == batch of n, bit for bit. What needs numpy or ``statistics`` stays in Python at the window's end: the
monitor's p-values (agents/innovation_monitor.py), the evidence's ``close`` (agents/effect_decision.py), the
trust's normal quantile (computed once, passed as ``z``). The classes of those modules are views over these
rows. Monitor: docs/innovation-monitor.md; trust: docs/estimate-trust.md; evidence: docs/online-detection.md.
"""

from __future__ import annotations

import array
import math

import numpy as np

from agents.kernels import jit, register_warm
from net.vocabulary import BACKGROUND, J_AVERAGE, J_EXCITE, M_AVERAGE, M_EXCITE

N_SIG = 4  # the monitor's signatures: v_C, sign(v_C), omega q_i^perp, f_i
N_STAGES = BACKGROUND + 1  # the trust counts every stage
TAIL_STAGES = (M_AVERAGE, J_AVERAGE)  # judged on their tail (trust rings 0 and 1)

# Per-row state is plain arrays with named columns (no record dtypes): a record argument costs numba's
# dispatch ~1 us more per call than a plain array, which at a batch of one is more than the work.
#: the columns of a monitor's row ``mon_f[b]``: the estimate entries (the last complete window's five p-values
#: and alarm, the windows and alarms counted: agents/innovation_monitor.py MONITOR_NAMES), then the level
ME_P, ME_ALARM, ME_WINDOWS, ME_ALARMS, ME_LEVEL = 0, 5, 6, 7, 8
#: the columns of a trust's ``tr_i[b]`` and ``tr_f[b]``: parameters and the number of neighbours heard so far
TI_DEGREE, TI_MAX_AGE, TI_TAIL, TI_HEARD = range(4)
TF_MIN_FRESH, TF_Z = range(2)
#: the columns of a trust stage count ``trc[b, stage]``
TC_EXISTS, TC_SLOTS, TC_FRESH, TC_TICKS, TC_JUDGED, TC_POOR = range(6)
#: the columns of a window evidence's ``ev_i[b]`` (updates, lag history's fill and its oldest) and ``ev_f[b]``
EI_N, EI_HIST_N, EI_HIST_AT = range(3)
EF_WW, EF_HH, EF_WH = range(3)


# ----------------------------------------------------------------------------------------- whitening
@jit
def cholesky2(s00: float, s01: float, s11: float) -> tuple[bool, float, float, float]:
    """(ok, l00, l10, l11): the lower Cholesky factor of [[s00, s01], [s01, s11]]; ok False when it is not
    positive definite (the update is then not tested)."""
    if not (s00 > 0.0):
        return False, 0.0, 0.0, 0.0
    l00 = math.sqrt(s00)
    l10 = s01 / l00
    d = s11 - l10 * l10
    if not (d > 0.0):
        return False, 0.0, 0.0, 0.0
    return True, l00, l10, math.sqrt(d)


@jit
def whiten(l00: float, l10: float, l11: float, x0: float, x1: float) -> tuple[float, float]:
    """L^-1 x by forward substitution, L from :func:`cholesky2`."""
    w0 = x0 / l00
    return w0, (x1 - l10 * w0) / l11


# ----------------------------------------------------------------------------------------- monitor
def monitor_rows(rows: int, window: int, alpha: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mon_k, mon_f, mon_ws): ``rows`` empty monitors; mon_k (rows,) the updates in the window being filled,
    mon_f (rows, 9) the entries and level (ME_*), mon_ws (rows, window, 1 + N_SIG, 2) each update's whitened
    innovation (slot 0) and signatures (slots 1..N_SIG)."""
    mon_f = np.zeros((rows, ME_LEVEL + 1))
    mon_f[:, :ME_WINDOWS] = math.nan
    mon_f[:, ME_LEVEL] = alpha / (1 + N_SIG)
    return np.zeros(rows, np.int64), mon_f, np.zeros((rows, window, 1 + N_SIG, 2))


@jit
def monitor_observe(b: int, mon_k: np.ndarray, mon_ws: np.ndarray, e: complex, s00: float, s01: float,
                    s11: float, vc: complex, om: float, q: complex, f: complex) -> bool:
    """One update's innovation e with covariance [[s00, s01], [s01, s11]] and the signatures' inputs into row
    b's window; True when the window is complete (its p-values are then due: :func:`monitor_judge`)."""
    ok, l00, l10, l11 = cholesky2(s00, s01, s11)
    if not ok or e != e:
        return False
    k = mon_k[b]
    mon_ws[b, k, 0, 0], mon_ws[b, k, 0, 1] = whiten(l00, l10, l11, e.real, e.imag)
    a = abs(vc)
    qp = om * complex(-q.imag, q.real)  # omega q_i^perp
    for c in range(N_SIG):
        if c == 0:
            g = vc
        elif c == 1:
            g = vc / a if a > 0.0 else 0j
        elif c == 2:
            g = qp
        else:
            g = f
        mon_ws[b, k, 1 + c, 0], mon_ws[b, k, 1 + c, 1] = whiten(l00, l10, l11, g.real, g.imag)
    k += 1
    if k == mon_ws.shape[1]:
        mon_k[b] = 0
        return True
    mon_k[b] = k
    return False


@jit
def monitor_judge(b: int, mon_f: np.ndarray, p: np.ndarray) -> None:
    """Row b's complete window with its five p-values ``p``: an alarm when any is below the level."""
    alarm = False
    for i in range(ME_ALARM):
        mon_f[b, ME_P + i] = p[i]
        if p[i] < mon_f[b, ME_LEVEL]:
            alarm = True
    mon_f[b, ME_ALARM] = 1.0 if alarm else 0.0
    mon_f[b, ME_WINDOWS] += 1.0
    mon_f[b, ME_ALARMS] += 1.0 if alarm else 0.0


# ----------------------------------------------------------------------------------------- trust
def trust_rows(rows: int, degree: int, max_age: int, min_fresh: float, z: float,
               tail: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(tr_i, tr_f, tr_nb, trc, trr): ``rows`` empty trusts; tr_i, tr_f (TI_*, TF_*), tr_nb (rows, degree, 2)
    each neighbour's id and the send tick of its newest state taken, in the order first heard, trc (rows,
    N_STAGES, 6) the stage counts (TC_*), trr (rows, 2, tail) the tails of the averaging stages."""
    tr_i = np.zeros((rows, 4), np.int64)
    tr_i[:, TI_DEGREE] = degree
    tr_i[:, TI_MAX_AGE] = max_age
    tr_i[:, TI_TAIL] = tail
    tr_f = np.zeros((rows, 2))
    tr_f[:, TF_MIN_FRESH] = min_fresh
    tr_f[:, TF_Z] = z
    trc = np.zeros((rows, N_STAGES, 6), np.int64)
    trc[:, :, TC_JUDGED] = -1
    return tr_i, tr_f, np.zeros((rows, degree, 2), np.int64), trc, np.zeros((rows, 2, tail), np.int64)


@jit
def wilson_upper(k: int, n: int, z: float) -> float:
    """One-sided upper confidence bound of a binomial proportion with k successes in n trials (Wilson score),
    z the standard normal quantile of its confidence level; 1.0 without trials."""
    if n <= 0:
        return 1.0
    p = k / n
    z2n = z * z / n
    centre = p + 0.5 * z2n
    half = z * math.sqrt(p * (1.0 - p) / n + 0.25 * z2n / n)
    u = (centre + half) / (1.0 + z2n)
    return u if u < 1.0 else 1.0  # min(1.0, u): 1.0 unless u is smaller


@jit
def poor(fresh: int, slots: int, min_fresh: float, z: float) -> bool:
    """Fewer than ``min_fresh`` of the ``slots`` fresh, at the level of ``z``."""
    return wilson_upper(fresh if fresh < slots else slots, slots, z) < min_fresh


@jit
def trust_observe(b: int, tr_i: np.ndarray, tr_nb: np.ndarray, trc: np.ndarray, trr: np.ndarray, tick: int,
                  stage: int, taken: np.ndarray) -> None:
    """A tick of ``stage`` in row b in which the neighbour states ``taken`` (sender, send tick, sender, send tick,
    ...: a flat int64 buffer) were taken: each neighbour's newest state, then the stage's slots and fresh states
    (of its tail)."""
    t = tr_i[b]
    nb = tr_nb[b]
    for i in range(0, len(taken), 2):
        j = taken[i]
        s = 0
        while s < t[TI_HEARD] and nb[s, 0] != j:
            s += 1
        if s == t[TI_HEARD]:  # first heard
            if s == nb.shape[0]:
                raise ValueError("more senders than the trust's degree")
            nb[s, 0] = j
            nb[s, 1] = taken[i + 1]
            t[TI_HEARD] += 1
        elif taken[i + 1] > nb[s, 1]:
            nb[s, 1] = taken[i + 1]
    lim = tick - t[TI_MAX_AGE]
    fresh = 0
    for s in range(t[TI_HEARD]):
        if nb[s, 1] >= lim:
            fresh += 1
    c = trc[b, stage]
    c[TC_EXISTS] = 1
    tail = t[TI_TAIL]
    r = -1
    if tail > 0:
        for i in range(len(TAIL_STAGES)):
            if TAIL_STAGES[i] == stage:
                r = i
    if r >= 0:
        k = c[TC_TICKS] % tail
        if c[TC_TICKS] >= tail:  # the oldest tick leaves the tail
            c[TC_FRESH] -= trr[b, r, k]
            c[TC_SLOTS] -= t[TI_DEGREE]
        trr[b, r, k] = fresh
    c[TC_TICKS] += 1
    c[TC_SLOTS] += t[TI_DEGREE]
    c[TC_FRESH] += fresh


@jit
def trust_fraction(b: int, trc: np.ndarray, stage: int) -> float:
    """The fresh fraction of row b's ``stage`` (NaN without slots)."""
    c = trc[b, stage]
    if not c[TC_SLOTS]:
        return math.nan
    f = c[TC_FRESH] / c[TC_SLOTS]
    return 1.0 if not f < 1.0 else f  # min(1.0, f)


@jit
def trust_judge(b: int, tr_f: np.ndarray, trc: np.ndarray, s0: int, s1: int) -> tuple[float, float]:
    """(flag, fresh fraction of the poorest stage begun) of row b over the stages s0, s1: (NaN, NaN) before
    the first; a finished stage is judged once."""
    flag = math.nan
    worst = math.nan
    for s in (s0, s1):
        c = trc[b, s]
        if not c[TC_EXISTS] or not c[TC_SLOTS]:
            continue
        f = trust_fraction(b, trc, s)
        if not worst <= f:
            worst = f
        if c[TC_JUDGED] != c[TC_TICKS]:
            c[TC_JUDGED] = c[TC_TICKS]
            c[TC_POOR] = poor(c[TC_FRESH], c[TC_SLOTS], tr_f[b, TF_MIN_FRESH], tr_f[b, TF_Z])
        flag = 0.0 if c[TC_POOR] or flag == 0.0 else 1.0
    return flag, worst


@jit
def trust_entries(b: int, tr_f: np.ndarray, trc: np.ndarray, m: float, m_sd: float, J: float, J_sd: float,
                  out: np.ndarray) -> None:
    """Row b's trust entries into ``out`` (m_trusted, m_fresh, m_sd, J_trusted, J_fresh, J_sd): m rests on the
    m excitation and averaging stages, J on the J ones; an sd only with a value and a flag."""
    mt, mf = trust_judge(b, tr_f, trc, M_EXCITE, M_AVERAGE)
    jt, jf = trust_judge(b, tr_f, trc, J_EXCITE, J_AVERAGE)
    out[0] = mt
    out[1] = mf
    out[2] = m_sd if m == m and mt == mt else math.nan
    out[3] = jt
    out[4] = jf
    out[5] = J_sd if J == J and jt == jt else math.nan


# ----------------------------------------------------------------------------------------- evidence
def evidence_rows(rows: int, lags: int, n_par: int) -> tuple[np.ndarray, ...]:
    """(ev_i, ev_f, sw, sh, sg, acc, den, hist): ``rows`` empty window evidences for ``n_par`` rates; ev_i,
    ev_f (EI_*, EF_*), sw, sh (rows, n_par) the sums w.g_k and g_k.h, sg (rows, n_par (n_par + 1) / 2) g_j.g_k
    per pair j <= k in row-major order, acc, den (rows, 2) the lag products and squares per component, hist
    (rows, lags, 2) the last ``lags`` whitened innovations (a ring: EI_HIST_N of them from EI_HIST_AT)."""
    return (np.zeros((rows, 3), np.int64), np.zeros((rows, 3)), np.zeros((rows, n_par)), np.zeros((rows, n_par)),
            np.zeros((rows, n_par * (n_par + 1) // 2)), np.zeros((rows, 2)), np.zeros((rows, 2)),
            np.zeros((rows, lags, 2)))


@jit
def evidence_clear(b: int, ev_i: np.ndarray, ev_f: np.ndarray, sw: np.ndarray, sh: np.ndarray, sg: np.ndarray,
                   acc: np.ndarray, den: np.ndarray) -> None:
    """Row b starts a new window (the lag history stays)."""
    sw[b, :] = 0.0
    sg[b, :] = 0.0
    sh[b, :] = 0.0
    ev_f[b, :] = 0.0
    ev_i[b, EI_N] = 0
    acc[b, :] = 0.0
    den[b, :] = 0.0


@jit
def evidence_restart(b: int, ev_i: np.ndarray) -> None:
    """Row b's filter restarted: no lag products across the restart."""
    ev_i[b, EI_HIST_N] = 0
    ev_i[b, EI_HIST_AT] = 0


@jit
def evidence_observe(b: int, ev_i: np.ndarray, ev_f: np.ndarray, sw: np.ndarray, sh: np.ndarray, sg: np.ndarray,
                     acc: np.ndarray, den: np.ndarray, hist: np.ndarray, w0: float, w1: float, g: np.ndarray,
                     h0: float, h1: float) -> None:
    """One update into row b: whitened innovation (w0, w1), each rate's whitened sensitivity g (n_par x 2)
    and the force error's (h0, h1)."""
    n_par = g.shape[0]
    for k in range(n_par):
        g0 = g[k, 0]
        g1 = g[k, 1]
        sw[b, k] += w0 * g0 + w1 * g1
        sh[b, k] += g0 * h0 + g1 * h1
    i = 0
    for j in range(n_par):
        for k in range(j, n_par):
            sg[b, i] += g[j, 0] * g[k, 0] + g[j, 1] * g[k, 1]
            i += 1
    ev_f[b, EF_HH] += h0 * h0 + h1 * h1
    ev_f[b, EF_WH] += w0 * h0 + w1 * h1
    ev_f[b, EF_WW] += w0 * w0 + w1 * w1
    ev_i[b, EI_N] += 1
    den[b, 0] += w0 * w0
    den[b, 1] += w1 * w1
    lags = hist.shape[1]
    held = ev_i[b, EI_HIST_N]
    at = ev_i[b, EI_HIST_AT]
    for i in range(held):  # oldest first
        r = (at + i) % lags
        acc[b, 0] += w0 * hist[b, r, 0]
        acc[b, 1] += w1 * hist[b, r, 1]
    if held < lags:
        r = (at + held) % lags
        ev_i[b, EI_HIST_N] = held + 1
    else:  # the oldest leaves
        r = at
        ev_i[b, EI_HIST_AT] = (at + 1) % lags
    hist[b, r, 0] = w0
    hist[b, r, 1] = w1


@jit
def detect_observe(b: int, ev_i: np.ndarray, ev_f: np.ndarray, sw: np.ndarray, sh: np.ndarray, sg: np.ndarray,
                   acc: np.ndarray, den: np.ndarray, hist: np.ndarray, innov: np.ndarray, sens_h: np.ndarray,
                   scored: np.ndarray) -> None:
    """One filter update into row b's evidence: innovation (e0, e1, s00, s01, s11) and the sensitivities' rows
    H D (per rate, then the force error's if given), whitened; a rate not ``scored`` counts as (0, 0)."""
    ok, l00, l10, l11 = cholesky2(innov[2], innov[3], innov[4])
    if not ok or innov[0] != innov[0]:
        return
    n_par = scored.shape[0]
    g = np.empty((n_par, 2))
    for p in range(n_par):
        if scored[p]:
            g[p, 0], g[p, 1] = whiten(l00, l10, l11, sens_h[2 * p], sens_h[2 * p + 1])
        else:
            g[p, 0] = 0.0
            g[p, 1] = 0.0
    h0 = h1 = 0.0
    if len(sens_h) > 2 * n_par:
        h0, h1 = whiten(l00, l10, l11, sens_h[2 * n_par], sens_h[2 * n_par + 1])
    w0, w1 = whiten(l00, l10, l11, innov[0], innov[1])
    evidence_observe(b, ev_i, ev_f, sw, sh, sg, acc, den, hist, w0, w1, g, h0, h1)


@register_warm
def warm() -> None:
    """Each kernel once on a row of the production types."""
    mon_k, mon_f, mon_ws = monitor_rows(1, 3, 0.01)
    monitor_observe(0, mon_k, mon_ws, 0.1 + 0.2j, 1.0, 0.1, 2.0, 0.3 + 0.1j, 1.2, 0.5 - 0.3j, 0.2 + 0j)
    monitor_judge(0, mon_f, np.full(5, 0.5))
    tr_i, tr_f, tr_nb, trc, trr = trust_rows(1, 2, 5, 0.5, 2.3, 3)
    trust_observe(0, tr_i, tr_nb, trc, trr, 1, M_AVERAGE, array.array("q", (4, 0)))
    trust_entries(0, tr_f, trc, 1.0, 0.1, 1.0, 0.1, np.empty(6))
    wilson_upper(1, 2, 2.3)
    poor(1, 2, 0.5, 2.3)
    trust_fraction(0, trc, M_AVERAGE)
    ev = evidence_rows(1, 2, 5)
    detect_observe(0, *ev, np.array([0.1, 0.2, 1.0, 0.1, 2.0]), np.ones(12), np.ones(5, np.bool_))
    evidence_observe(0, *ev, 0.1, 0.2, np.ones((5, 2)), 0.0, 0.0)
    evidence_clear(0, *ev[:7])
    evidence_restart(0, ev[0])
