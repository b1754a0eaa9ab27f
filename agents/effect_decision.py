"""Online effect detection: the team pools its filters' evidence and agrees which missing effect to switch on.

Every agent's filter (agents/rigid_filter.py, ``sens``) carries the sensitivity of its own-velocity
prediction to each candidate effect's rate (beta = b/m: viscous friction; gamma = c/J: rotational
damping; kappa = F_c/m: Coulomb friction; a = f/m along x and y: a constant external force, force_bias,
the one vector candidate), propagated through the filter's own prediction and gain: what
the innovation would look like if the effect were there, after the filter's states (1/m, omega, 1/J, ...)
had absorbed what they can. Per update, :class:`WindowEvidence` takes the whitened innovation w and the
whitened sensitivities g_k (both from S = L L^T) and sums, over global windows of ``window`` ticks
(tick // window, the same at every agent):

- per candidate k the score numerator s_k = sum w.g_k and the information V_jk = sigma^2 sum g_j.g_k
  between every two candidates (sigma^2 = sum |w|^2 / 2N): the Lagrange-multiplier test of the rates at
  0, made orthogonal to the score of the team force's known error (the force error's whitened
  sensitivity h: s_k - (g_k.h / h.h) h.w, V_jk - sigma^2 (g_j.h)(g_k.h) / h.h; Neyman's C(alpha) score
  with the force error's gain a nuisance): the consensus force the filter integrates lags the applied
  one, and that lag, common to every agent, must not read as friction;
- the persistence z of the window (agents/innovation_monitor.py: positive autocorrelation at lags 1..h).

Pooling without a coordinator: each agent puts its window's (s_k, V_jk (j <= k), z, 1) on flow-updating
average consensus channels (agents/consensus.py) for the next window. The team sums S_k and V_jk give each
candidate's own score z_k = S_k / sqrt(V_kk), and with z_p = sum_i z_i / sqrt(count) (:func:`pooled`) each is
N(0, 1) under the nominal model for independent agents. At the next window's last tick each agent judges
them (:func:`judge`): each z_k one-sided at the Bonferroni level ``alpha / (1 + candidates)``; of the
significant candidates the one with the largest z_k, the effect that explains the most added alone (forward
selection: one effect is switched at a time), is proposed with a switch tick ``horizon`` later; structure
(z_p significant) with no significant candidate is ``unexplained``. Viscous and Coulomb friction have nearly
the same signature when the speed changes little: either plant makes both z_k significant, and the larger
is the plant's (with two candidates this is the order of their scores orthogonal to each other's too:
z_b^2 + zc|b^2 = z_c^2 + zb|c^2, the pair's joint chi2). Proposals are flooded
(:class:`DecisionFlood`): the earliest switch tick, then the largest |z| wins, so every agent that has
heard all proposals by the switch tick switches the same effect on the same tick.

Withdrawal: once a switch has settled for a window, the effect's (S_k, V_kk) channels carry each filter's released
rate r_i and variance P_i as (r_i / P_i, 1 / P_i) (a snapshot at every window close) instead of its score:
the team's Wald z = sum r_i / P_i / sqrt(sum 1 / P_i) is that of the inverse-variance weighted mean (a
filter just restarted, its rate at the prior, weighs nothing). Below the level's lower quantile the
coefficient is negative, and the team withdraws the effect through the same flood (the rate pinned at 0
again in every filter on one tick, the window ``unexplained``, the effect never proposed again).
Before a switch, the lower tail of a candidate's score says the same: below the level's lower quantile the
data favour a negative coefficient, which no candidate has, so structure along its signature is something
else (a periodic force alternates the sign window by window and passes the one-sided test in its positive
windows). The team rules the candidate out through the same flood and code as a withdrawal: never proposed
again, the window ``unexplained``; the filters, which never released it, are untouched. A window that rules
a candidate out switches nothing on: the candidates are correlated (Coulomb and viscous friction's scores by
0.83-0.99), and one significantly negative beside another significantly positive is structure that neither
explains; unless the positive one's model explains it: no score orthogonal to its rates is below the quantile
(a slope pushing along the motion half the time makes friction's own score negative, and none once the slope
is fitted; two positively correlated frictions never pass this). A switch is also checked against the model it makes (:func:`contradicted_by`): with k's rate free,
another candidate j's score is its score orthogonal to k's, z_j|k; below the lower quantile while j's own
score z_j is not, k's fitted effect is what makes j's coefficient negative, so the structure along their
shared signature is not k's: k is ruled out instead (the statistic z_j|k). A j contradicted by its own score
is structure no switch changes and blocks no candidate. A ruled-out candidate's score is still pooled and
still checks the later switches of its near-twins.

The vector candidate (force_bias) has no sign: its score is the chi2 with 2 dof of its two rates' scores
and their 2 x 2 information, judged at the same level and ranked on the same scale through its
normal-equivalent z (:func:`chi2_z`: its second rate pays for the noise it fits, ~2 log(z sqrt(2 pi)) of
chi2 at large z). Its rates span every constant force, and within a window where the load keeps its
direction that is what Coulomb friction (-F_c sat(v_C)) looks like: so where a scalar candidate is
significant too, the slope counts as significant only if its score orthogonal to the rate of the scalar
candidate with the largest own z, j (zv: S_a - V_aj / V_jj S_j, V_aa - V_aj V_ja / V_jj; C(alpha) again,
j's rate the nuisance), is significant as well: the nested test of the general model against the special
one the window would name instead. Orthogonal to every other candidate's rate (their signs free) it would
be too strict: on a slope plant the frictions' own scores are significantly negative (a force along the
motion is negative friction while the load keeps its direction), and with their rates free the slope keeps
nothing of its own. It is never ruled out by its own score (there is no negative
to contradict) nor contradicts another's switch, but a scalar candidate's score orthogonal to it can rule it
out; its withdrawal is the same rule on its rates' Wald chi2 (below the level's lower quantile). It is judged
only on windows that start once the m stage's common force has first reversed
(:meth:`OnlineDetection.push_reverses`): while the push keeps its direction a constant force along it and
1/m F are one signature (a constant acceleration), and the filter's 1/m, restarted at the stage's start,
takes up part of any constant force along the push, Coulomb friction's included; the window holding the first
reversal still carries that transient (a Coulomb plant's slope beyond Coulomb friction's score reached 3.55
there). A window that does not judge the slope still rules a candidate out (its score significantly negative),
and structure the slope would explain is not counted ``unexplained``. A constant force also keeps its
direction from window to window (:func:`reversal_z`): the window just before, read along the force this
window estimates, must not be significantly negative, or the slope is ruled out (before a switch) or
withdrawn (after it, its rates' snapshots read so); without a judged window just before, a proposed slope
waits a window. A slope switched on replaces each agent's filter by its twin, which has estimated the slope
beside 1/m from the m stage's start (DynamicPhase): a filter that released it only at the switch would
restart 1/m and rest on what is left of the stage.

Pure: no clock, socket or RNG. See docs/online-detection.md.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from statistics import NormalDist

import numpy as np

import agents.kernels.window_stats as ws

# candidate k: its rates EFFECT_PARAMS[k], filter states 7 + p (beta, gamma, kappa, a_x, a_y)
from agents.rigid_filter import EFFECT_PARAMS, EFFECTS, N_EFF, N_PAR, RigidEKF

ALL = (1 << N_EFF) - 1  # every candidate's bit
VECTOR = sum(1 << k for k, ps in enumerate(EFFECT_PARAMS) if len(ps) > 1)  # candidates without a sign (force_bias)
SLOPE = EFFECTS.index("force_bias")  # the candidate a twin filter carries from the m stage's start (DynamicPhase)
# the rates' pairs (p <= q) in the order of their information channels
PAIRS = tuple((j, k) for j in range(N_PAR) for k in range(j, N_PAR))
VCH = {p: N_PAR + i for i, p in enumerate(PAIRS)} | {(k, j): N_PAR + i for i, (j, k) in enumerate(PAIRS)}
# consensus channels per window: the score s_p per rate, the information V_pq per pair (VCH), then the
# persistence z and the count
N_POOL = N_PAR + len(PAIRS) + 2
CH_Z = N_POOL - 2
CH_CNT = N_POOL - 1
DECISION_KEYS = ("Ds", "De", "Dz")  # StateMsg.shared: switch tick (-1: none), effect index, statistic
DETECT_NAMES = ("eff_on", "eff_out", "eff_tick", "eff_z", "eff_unexplained", "eff_zp", "eff_zb", "eff_zc", "eff_zf",
                "eff_zs")
_NORMAL = NormalDist()


def normal_sf(z: float) -> float:
    """P(Z > z) for a standard normal Z."""
    return 0.5 * math.erfc(z / math.sqrt(2.0))


def chi2_z(x: float) -> float:
    """The normal-equivalent z of a chi2 statistic ``x`` with 2 degrees of freedom (a planar vector
    candidate's): the z with P(Z > z) = P(X > x) = exp(-x / 2), so that the vector candidate's test and the
    scalar one-sided ones share one level and one order; far in the tail z solves z^2 + 2 log(z sqrt(2 pi))
    = x (the normal tail's asymptote, exact to ~1/z^2 in log p), where exp(-x / 2) underflows."""
    if not x > 0.0:
        return -math.inf if x == 0.0 else math.nan
    if x < 1400.0:
        p = math.exp(-0.5 * x)
        return -_NORMAL.inv_cdf(p) if p < 0.5 else _NORMAL.inv_cdf(-math.expm1(-0.5 * x))
    z = math.sqrt(x)
    for _ in range(4):
        z = math.sqrt(x - 2.0 * math.log(z * math.sqrt(2.0 * math.pi)))
    return z


def _score_z(s: np.ndarray, v: np.ndarray, n: int) -> float:
    """The team's score statistic of one candidate from the team means ``s`` (its rates' scores) and ``v``
    (their information, positive diagonal): signed z = sqrt(n) s / sqrt(v) for a scalar rate, the chi2
    n s^T v^-1 s's normal-equivalent z (:func:`chi2_z`) for a vector; NaN where a vector's ``v`` is singular."""
    if len(s) == 1:
        return math.sqrt(n) * float(s[0]) / math.sqrt(float(v[0, 0]))
    if not np.linalg.eigvalsh(v)[0] > 0.0:
        return math.nan
    return chi2_z(n * float(s @ np.linalg.solve(v, s)))  # the vector candidates are planar: 2 rates


def _gram(means: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """The team means of the rates' scores (N_PAR) and their information matrix (N_PAR x N_PAR)."""
    S = np.array(means[:N_PAR], dtype=float)
    V = np.array([[means[VCH[p, q]] for q in range(N_PAR)] for p in range(N_PAR)], dtype=float)
    return S, V


def pooled(means: Sequence[float], n: int, held: int = 0,
           out: int = 0) -> tuple[float, list[float], list[float]]:
    """(z_p, [z_k], [zv_k]) from the team means of the :data:`N_POOL` channels over ``n`` agents; NaN where no
    agent contributed. Means times n are the team sums S_p, V_pq: a candidate's own score z_k = S_k /
    sqrt(V_kk); for the vector candidate (force_bias: its rates a_x, a_y) the chi2 S_k^T V_kk^-1 S_k with 2 dof
    as its normal-equivalent z (:func:`chi2_z`), and zv_k, the same chi2 of its score orthogonal to the rate
    of the scalar candidate with the largest own z, j (S_k - V_kj / V_jj S_j, V_kk - V_kj V_jk / V_jj; NaN for
    a scalar candidate, and where the vector's information is all in j's). The candidates are the
    effects not in ``out`` (bit k: on, declared or withdrawn: not tested), whose z are NaN. For an effect
    switched on (bit k of ``held``) its rates' channels carry (P^-1 r, P^-1) (r the released rates, P their
    covariance): z_k is the team's Wald z of the inverse-variance weighted mean (a vector's: the Wald chi2's
    normal-equivalent z).

    The count's team sum is a whole number of agents; below one half no agent contributed a score window,
    and what the channels hold is what the consensus has not yet forgotten of an earlier window (with delayed
    states a residue of ~0.002 agents is left), not data: NaN. The rates' pairs are offered at every window's
    close, whatever the count."""
    nan = math.nan
    empty = n * means[CH_CNT] < 0.5
    zs = [nan] * N_EFF
    zv = [nan] * N_EFF
    S, V = _gram(means)
    cand = [k for k in range(N_EFF)
            if not ((out | held) >> k) & 1 and all(V[p, p] > 0.0 for p in EFFECT_PARAMS[k])]
    for k in range(N_EFF):
        ps = list(EFFECT_PARAMS[k])
        if all(V[p, p] > 0.0 for p in ps) and ((held >> k) & 1 or (k in cand and not empty)):
            zs[k] = _score_z(S[ps], V[np.ix_(ps, ps)], n)
    if empty:
        return nan, zs, zv
    scalars = [j for j in cand if not (VECTOR >> j) & 1 and zs[j] == zs[j]]
    if scalars:  # the scalar candidate the window names if not the vector: the one with the largest own z
        j = EFFECT_PARAMS[max(scalars, key=lambda j: zs[j])][0]
        for k in cand:
            if not (VECTOR >> k) & 1:
                continue
            ps = list(EFFECT_PARAMS[k])
            c = V[j, ps] / V[j, j]  # the part of its score that j's rate explains is j's
            s, v = S[ps] - c * S[j], V[np.ix_(ps, ps)] - np.outer(c, V[j, ps])
            # what is left of its information below rounding: nothing of its own
            zv[k] = _score_z(s, v, n) if np.linalg.eigvalsh(v)[0] > 1e-9 * float(np.max(np.diag(V)[ps])) else nan
    zsum, cnt = means[CH_Z], means[CH_CNT]
    zp = math.sqrt(n) * zsum / math.sqrt(cnt) if cnt > 0.0 else nan
    return zp, zs, zv


def window_level(alpha: float, cands: int = N_EFF) -> float:
    """The one-sided level of every test of a window: ``alpha`` over (1 + the number of candidates ``cands``),
    the persistence test and each candidate's, whatever has been switched (module docstring)."""
    return alpha / (1 + cands)


def reversal_z(prev: Sequence[float], means: Sequence[float], n: int, k: int) -> float:
    """The previous judged window's statistic along the direction this window estimates for the vector
    candidate k (a constant force): with a = V_kk^-1 S_k of this window's team means ``means`` (a score's
    one-step estimate, or a switched rate's weighted mean), the previous window's ``prev`` read along a:
    sqrt(n) a.S' / sqrt(a^T V' a), N(0, 1) where the previous window holds no force along a. A constant
    force keeps its direction from window to window, so this is positive wherever the window's is
    significant; below the level's lower quantile the force has turned round between the windows
    (a periodic force, half a period per window). Either window may carry scores or a switched rate's
    (P^-1 r, P^-1): the sign along a means the same in both. NaN where either window's information is
    not positive definite."""
    ps = list(EFFECT_PARAMS[k])
    S, V = _gram(means)
    Sp, Vp = _gram(prev)
    vkk = V[np.ix_(ps, ps)]
    if not np.linalg.eigvalsh(vkk)[0] > 0.0 or not np.linalg.eigvalsh(Vp[np.ix_(ps, ps)])[0] > 0.0:
        return math.nan
    a = np.linalg.solve(vkk, S[ps])
    den = float(a @ Vp[np.ix_(ps, ps)] @ a)
    return math.sqrt(n) * float(a @ Sp[ps]) / math.sqrt(den) if den > 0.0 else math.nan


def contradicted_by(means: Sequence[float], n: int, k: int, scored: int, alpha: float,
                    every: bool = False, cands: int = N_EFF) -> tuple[float, int]:
    """(z, j): the lowest score z_j|k of another effect j (bit j of ``scored``: its pool channels carry a
    score) orthogonal to candidate k's, the score test of j in the model with k's rates free, among those below
    the level's lower quantile whose own score z_j is not; (NaN, -1) if none. Such a j says that switching k on
    makes a model the window that proposes it contradicts, and k's fitted effect is what makes it: k does not
    explain the structure along their shared signature (module docstring). A j whose own score is below the
    quantile too is structure no switch changes (it is ruled out on its own) and blocks no candidate; with
    ``every`` it counts too (the window's rule-out then waits for no switch that does not explain it). Only a
    scalar j has a sign to contradict (a vector's chi2 has none); k may be either."""
    level = window_level(alpha, cands)
    worst = (math.nan, -1)
    S, V = _gram(means)
    ks = list(EFFECT_PARAMS[k])
    vkk = V[np.ix_(ks, ks)]
    if not all(V[p, p] > 0.0 for p in ks) or n * means[CH_CNT] < 0.5:
        return worst
    ikk = np.linalg.pinv(vkk)
    for j in range(N_EFF):
        if j == k or not (scored >> j) & 1 or (VECTOR >> j) & 1:
            continue
        p = EFFECT_PARAMS[j][0]
        vjj, vjk = V[p, p], V[p, ks]
        if not vjj > 0.0:
            continue
        v = vjj - float(vjk @ ikk @ vjk)
        if v > 1e-9 * vjj:  # collinear with k (to rounding): no part of its own to test
            z = math.sqrt(n) * (S[p] - float(vjk @ ikk @ S[ks])) / math.sqrt(v)
            own = math.sqrt(n) * S[p] / math.sqrt(vjj)
            if normal_sf(-z) < level and (every or level <= normal_sf(-own)) and not z >= worst[0]:
                worst = (z, j)
    return worst


def judge(zp: float, zs: Sequence[float], alpha: float, on: int, held: int = 0,
          zv: Sequence[float] | None = None, cands: int = N_EFF) -> tuple[int, bool]:
    """The team's verdict on one window: (decision or -1, unexplained). Decision k < N_EFF: switch candidate
    k on; N_EFF + k: withdraw effect k.

    Every test is one-sided (a missing effect has a positive coefficient; the persistence test is one-sided
    too) at alpha / (1 + number of candidates); candidates already on or withdrawn (bit k of ``on``) are not
    tested for a switch but still count in the level, which stays the same whatever has been switched.
    Whether an effect is missing is each candidate's own score test (zs); which one, among those significant,
    the one with the largest own z: the effect that, added alone to the nominal model, explains the most, its
    evidence measured on one scale whatever its number of rates (a vector's chi2 through its
    normal-equivalent z, so that its second rate pays for the noise it fits). When a scalar candidate is
    significant, a vector candidate (its rates span every constant force, which is what a scalar effect looks
    like within one window) is significant only if its score orthogonal to the best scalar's (``zv``) is
    too: the general model is switched over the special one the window would name only where the data hold
    something of it that the special one does not explain (module docstring). For an effect
    switched on online (bit k of ``held``) zs[k] is the Wald z of its released rate instead: below the
    level's lower quantile the team's estimate is inconsistent with a positive coefficient, the effect is
    withdrawn (the most negative first), and the structure it was switched on for stays unexplained.
    ``cands``: the number of candidates the level is shared by."""
    level = window_level(alpha, cands)
    worst, zworst = -1, math.inf
    for k, z in enumerate(zs):
        if (held >> k) & 1 and z == z and normal_sf(-z) < level and z < zworst:
            worst, zworst = k, z
    if worst >= 0:
        return N_EFF + worst, True
    best, zbest = -1, -math.inf
    free = [(k, z) for k, z in enumerate(zs) if not ((on | held) >> k) & 1 and z == z and normal_sf(z) < level]
    special = any(not (VECTOR >> k) & 1 for k, _ in free)  # a scalar candidate is significant
    for k, z in free:
        if special and (VECTOR >> k) & 1 and zv is not None and not normal_sf(zv[k]) < level:
            continue
        if best < 0 or z > zbest:
            best, zbest = k, z
    structured = zp == zp and normal_sf(zp) < level
    return best, best < 0 and structured


class WindowEvidence:
    """One agent's sums over the current global window (module docstring): a view over row ``b`` of the evidence
    arrays (agents/kernels/window_stats.py); its own by default. ``close`` reads them at the window's end."""

    __slots__ = ("lags", "scored", "b", "_rows")

    def __init__(self, lags: int, cand: int = (1 << N_EFF) - 1, rows: tuple | None = None, b: int = 0) -> None:
        """``cand``: the candidates (bit k: EFFECTS[k]) whose rates a filter update scores (:meth:`observe_update`);
        ``rows``: the arrays of :func:`evidence_rows` to view row ``b`` of."""
        self.lags = lags
        # a rate of an effect that is no candidate is never scored
        self.scored = np.ones(N_PAR, np.bool_)
        for k, ps in enumerate(EFFECT_PARAMS):
            if not (cand >> k) & 1:
                self.scored[list(ps)] = False
        self._rows = ws.evidence_rows(1, lags, N_PAR) if rows is None else rows
        self.b = b

    n = property(lambda self: int(self._rows[0][self.b, ws.EI_N]))
    sww = property(lambda self: float(self._rows[1][self.b, ws.EF_WW]))
    shh = property(lambda self: float(self._rows[1][self.b, ws.EF_HH]))
    swh = property(lambda self: float(self._rows[1][self.b, ws.EF_WH]))
    sw = property(lambda self: self._rows[2][self.b].tolist())
    sh = property(lambda self: self._rows[3][self.b].tolist())  # g_p.h: each rate's sensitivity against h
    sg = property(lambda self: self._rows[4][self.b].tolist())  # sum g_j.g_k per candidate pair (PAIRS order)
    acc = property(lambda self: self._rows[5][self.b].tolist())  # sum over lags 1..h of the lag products
    den = property(lambda self: self._rows[6][self.b].tolist())

    def clear(self) -> None:
        """A new window."""
        ws.evidence_clear(self.b, *self._rows[:7])

    def restart(self) -> None:
        """The filter restarted: no lag products across the restart."""
        ws.evidence_restart(self.b, self._rows[0])

    def observe(self, w0: float, w1: float, g: Sequence[tuple[float, float]],
                h: tuple[float, float] = (0.0, 0.0)) -> None:
        """One update's whitened innovation (w0, w1), each rate's whitened sensitivity (:data:`N_PAR`; rates
        not given have none) and the force error's ``h`` (the nuisance)."""
        ga = np.zeros((N_PAR, 2))
        if len(g):
            ga[:len(g)] = g
        ws.evidence_observe(self.b, *self._rows, w0, w1, ga, *h)

    def observe_update(self, innov: np.ndarray, sens_h: np.ndarray) -> None:
        """One filter update: innovation (e0, e1, s00, s01, s11) and the sensitivities' rows H D (per rate, then
        the force error's if given), whitened here; the rates not ``scored`` count as none."""
        ws.detect_observe(self.b, *self._rows, innov, sens_h, self.scored)

    def close(self) -> list[float] | None:
        """The window's :data:`N_POOL` consensus inputs, None if it had too few updates to test (the sums are
        cleared either way)."""
        out = None
        n, sww = self.n, self.sww
        if n > 2 * self.lags and sww > 0.0:
            sigma2 = sww / (2 * n)
            shh, sh, swh = self.shh, self.sh, self.swh
            # the part of each g_k along h is the force error's, not the candidate's
            out = [s - sh[k] / shh * swh if shh > 0.0 else s for k, s in enumerate(self.sw)]
            for (j, k), gg in zip(PAIRS, self.sg, strict=True):
                if shh > 0.0:
                    gg -= sh[j] * sh[k] / shh
                out.append(sigma2 * (max(gg, 0.0) if j == k else gg))
            r = sum(a / d for a, d in zip(self.acc, self.den, strict=True) if d > 0.0)
            out += [math.sqrt(n) * r / math.sqrt(2 * self.lags), 1.0]
        self.clear()
        return out


def better(a: tuple[int, int, float], b: tuple[int, int, float]) -> bool:
    """Is proposal a = (switch tick, decision, z) preferred to b? The earliest tick, then the largest |z|
    (a withdrawal's z is negative), then the lowest decision index: a total order, so every agent picks the
    same from the same set."""
    if a[0] < 0:
        return False
    if b[0] < 0:
        return True
    return (a[0], -abs(a[2]), a[1]) < (b[0], -abs(b[2]), b[1])


class DecisionFlood:
    """One agent's view of the pending switch (module docstring); ``done`` is the last applied switch tick."""

    __slots__ = ("best", "done")

    def __init__(self) -> None:
        self.best: tuple[int, int, float] = (-1, -1, 0.0)
        self.done = -1

    def merge(self, prop: tuple[int, int, float]) -> None:
        if prop[0] > self.done and better(prop, self.best):
            self.best = prop

    def due(self, tick: int) -> tuple[int, int, float] | None:
        """The pending proposal if its switch tick has come (then it is applied: cleared, ``done`` set)."""
        b = self.best
        if b[0] < 0 or tick < b[0]:
            return None
        self.done = b[0]
        self.best = (-1, -1, 0.0)
        return b

    def encode(self) -> dict[str, float]:
        s, e, z = self.best
        return {"Ds": float(s), "De": float(e), "Dz": z if z == z else 0.0}


def decode(sh: Mapping[str, float]) -> tuple[int, int, float]:
    """A neighbour's flooded proposal; KeyError or ValueError if malformed."""
    s, e, z = float(sh["Ds"]), float(sh["De"]), float(sh["Dz"])
    if s != int(s) or e != int(e) or not (-1 <= e < 2 * N_EFF) or z - z != 0.0:
        raise ValueError("bad decision")
    return int(s), int(e), z


class OnlineDetection:
    """One agent's part of the online detection: its window sums, its view of the pooled statistics, the
    flooded proposal and what the team has switched on (module docstring). Driven by DynamicPhase: the pool
    channels are ``ch0 .. ch0 + N_POOL - 1`` of its FlowAverage."""

    __slots__ = ("window", "horizon", "alpha", "n", "ch0", "ev", "flood", "on", "switched", "withdrawn",
                 "last_tick", "last_z", "unexplained", "zp", "zs", "settle_from", "score_from", "late",
                 "mixed", "cand", "ncand", "vector_from", "prev")

    def __init__(self, n: int, window: int, lags: int, alpha: float, horizon: int, ch0: int, on: int = 0,
                 cand: int = ALL) -> None:
        # the candidates (bit k: EFFECTS[k]); the others' rates are never scored (their sensitivities are
        # not offered) and the level is shared by these alone
        self.cand = cand
        self.ncand = bin(cand).count("1")
        self.n = n
        self.window = window
        self.horizon = horizon
        self.alpha = alpha
        self.ch0 = ch0
        self.ev = WindowEvidence(lags, cand)
        self.flood = DecisionFlood()
        self.on = on  # bit k: effect k is in the filters (declared beforehand or switched on)
        self.switched = 0  # bit k: effect k is in the filters by a team switch (tested for a withdrawal)
        self.withdrawn = 0  # bit k: effect k was switched on and withdrawn (never proposed again)
        self.last_tick = -1  # the last switch: its tick and statistic
        self.last_z = math.nan
        self.unexplained = 0  # windows judged structured with no candidate significant
        self.zp = math.nan  # the last judged window's pooled statistics (this agent's view)
        self.zs = [math.nan] * N_EFF
        self.settle_from = 0  # windows starting before this tick are not offered (a switch is settling)
        self.score_from = 0  # ... nor judged for a new switch (a switched filter is still re-learning)
        self.late = 0
        self.mixed = False  # the window being filled spans a change of regime (see regime_change)
        self.vector_from = 0  # windows starting before this tick do not judge the slope (see push_reverses)
        self.prev: tuple[int, list[float]] | None = None  # the last judged window holding a vector's data: tick, means

    def push_reverses(self, tick: int) -> None:
        """The m stage started and its common force first reverses at ``tick``: the slope is judged only on
        windows that start from then on. While the push keeps its direction a constant force along it and
        1/m F are one signature (a constant acceleration), and the filter's 1/m, restarted at the stage's
        start, takes up any constant force along the push; only the reversed push separates them, and the
        window holding the first reversal still carries the transient of that 1/m (docs/online-detection.md,
        "Decision and switch")."""
        self.vector_from = max(self.vector_from, tick)

    def regime_change(self) -> None:
        """The agent's stage changed or its filter (re)started: the window being filled is not offered. The
        scores hold for a filter whose other states have converged under one excitation; across a stage
        switch (the m stage's force starting, 1/J forgotten) or a filter start they are still moving, and
        the transient correlates with the candidates' sensitivities (a clean plant's viscous score reached
        z = 3.0 in the window of the m stage's start, friction-online seed 1)."""
        self.mixed = True

    def observe(self, innov: Sequence[float], sens_h: Sequence[float]) -> None:
        """One filter update: innovation (e0, e1, s00, s01, s11) and the sensitivities' rows H D (per
        candidate, then the force error's if given)."""
        self.ev.observe_update(np.asarray(innov, float), np.asarray(sens_h, float))

    def begin_tick(self, tick: int, u: list[float], x: Sequence[float],
                   rates: Sequence[tuple[float, float]] | None = None) -> int:
        """Window bookkeeping at the start of ``tick``: closes a finished window into the pool inputs ``u``,
        judges the previous one on the team means ``x`` at a window's last tick, and returns the decision due
        at this tick (-1: none; k < N_EFF: switch effect k on; N_EFF + k: withdraw it). ``rates``: the filter's
        (estimate, variance) of each effect's rate now; a switched effect's pool pair carries them instead of
        its score (module docstring)."""
        w = self.window
        r = tick % w
        if r == 0 and tick > 0:
            stats = self.ev.close()
            if self.mixed or (tick - w) < self.settle_from:
                stats = None
            self.mixed = False
            c = self.ch0
            u[c:c + N_POOL] = stats if stats is not None else [0.0] * N_POOL
            # a switched effect's rate: a snapshot, valid at any close once the switch has settled for a window
            # (not a window's sum: a regime change inside the window does not void it)
            for k in range(N_EFF):
                if (self.switched >> k) & 1:
                    self._offer_rate(u, k, rates[k] if rates is not None and tick >= self.settle_from else None)
        elif r == w - 1 and tick + 1 >= 2 * w:
            c = self.ch0
            held = self.switched
            scores = (tick + 1 - 2 * w) >= self.score_from  # the window started after the last switch settled
            if scores or (held and (tick + 1 - w) >= self.settle_from):  # ... or at least its close did
                zp, zs, zv = pooled(x[c:c + N_POOL], self.n, held, self.on | self.withdrawn)
                prev = self.prev[1] if self.prev is not None and self.prev[0] == tick - w else None
                if any(z == z for k, z in enumerate(zs) if (VECTOR >> k) & 1):
                    self.prev = (tick, list(x[c:c + N_POOL]))
                if scores:
                    self.zp, self.zs = zp, zs
                else:  # only the switched rates are judged
                    zp = math.nan
                    zs = [z if (held >> k) & 1 else math.nan for k, z in enumerate(zs)]
                    self.zs = [z if (held >> k) & 1 else self.zs[k] for k, z in enumerate(zs)]
                early = tick + 1 - 2 * w < self.vector_from  # the slope waits for the push's first reversal
                unjudged = VECTOR & self.cand & ~(self.on | self.withdrawn) if early else 0
                k, unexplained = judge(zp, zs, self.alpha, self.on | self.withdrawn | unjudged, held, zv, self.ncand)
                if unexplained and unjudged:  # structure a slope not yet judged would explain is not unexplained
                    unexplained = judge(zp, zs, self.alpha, self.on | self.withdrawn, held, zv, self.ncand)[1]
                z = zs[k % N_EFF]
                out = self._contradicted(zs, self.on | self.withdrawn | held)
                # a rule-out comes before a switch in the same window, unless the switch's model explains it: no
                # score orthogonal to the switched rates below the quantile (module docstring)
                if out >= 0 and k < N_EFF and (k < 0 or contradicted_by(x[c:c + N_POOL], self.n, k, ALL & ~self.on,
                                                                        self.alpha, True, self.ncand)[1] >= 0):
                    k, z = N_EFF + out, zs[out]
                elif 0 <= k < N_EFF:  # a switch whose model the same window contradicts rules its candidate out
                    zc, j = contradicted_by(x[c:c + N_POOL], self.n, k, ALL & ~self.on, self.alpha, cands=self.ncand)
                    if j >= 0:
                        k, z = N_EFF + k, zc
                k, z = self._turned(k, z, prev, x[c:c + N_POOL], held)
                if k >= 0:
                    self.flood.merge((tick + self.horizon, k, z))
                # a withdrawal's window is counted where it is applied: by every agent, whatever its own view
                self.unexplained += unexplained and k < N_EFF
        due = self.flood.due(tick)
        if due is None:
            return -1
        if tick > due[0]:
            self.late += 1
        k = due[1] % N_EFF
        if due[1] >= N_EFF and not (self.switched >> k) & 1:  # ruled out before any switch: the filters keep it at 0
            self.withdrawn |= 1 << k
            self.unexplained += 1  # structure along its signature that no candidate explains
            self.last_tick, self.last_z = due[0], due[2]
            return -1
        if due[1] < N_EFF:
            self.on |= 1 << k
            self.switched |= 1 << k
        else:
            self.on &= ~(1 << k)
            self.switched &= ~(1 << k)
            self.withdrawn |= 1 << k
            self.unexplained += 1  # the structure it was switched on for is not explained
        self.last_tick, self.last_z = due[0], due[2]
        # offer and judge the rates again on windows that start after the switched (or withdrawn) effect has
        # settled for a window; judge new switches only on windows that start three windows after a switch: a
        # switch restarts 1/m (1/J) and the released rate, and while the filter re-learns them its innovations
        # carry a transient that a correlated candidate's score takes up (docs/online-detection.md, "Decision
        # and switch")
        self.settle_from = due[0] + w
        self.score_from = due[0] + (3 * w if due[1] < N_EFF else w)
        return due[1]

    def _turned(self, k: int, z: float, prev: Sequence[float] | None, means: Sequence[float],
                held: int) -> tuple[int, float]:
        """The window's decision (k, z) with the vector candidates' check across windows: a constant force
        keeps its direction, so the window just before, ``prev`` (None if it was not judged), read along the
        direction this window estimates (:func:`reversal_z`) must not be significantly negative. A switched
        slope that turned round is withdrawn; a proposed one is ruled out instead, and without the window
        before to check it waits for the next (docs/online-detection.md, "The slope holds its direction")."""
        level = window_level(self.alpha, self.ncand)
        for j in range(N_EFF):
            if not ((VECTOR & self.cand) >> j) & 1 or not ((held >> j) & 1 or k == j):
                continue
            zr = reversal_z(prev, means, self.n, j) if prev is not None else math.nan
            if normal_sf(-zr) < level and (k < N_EFF or zr < z):
                k, z = N_EFF + j, zr
            elif k == j and zr != zr:
                k, z = -1, math.nan
        return k, z

    def _offer_rate(self, u: list[float], k: int, rate: tuple | None) -> None:
        """A switched effect's rates r and their covariance P (the filter's, a snapshot) on its rates' pool
        channels as (P^-1 r, P^-1); zeros (it weighs nothing) when there is none or P is not positive definite."""
        ps = EFFECT_PARAMS[k]
        c = self.ch0
        info, wr = np.zeros((len(ps), len(ps))), np.zeros(len(ps))
        if rate is not None:
            r, P = np.atleast_1d(np.asarray(rate[0], float)), np.atleast_2d(np.asarray(rate[1], float))
            if np.all(np.isfinite(r)) and np.all(np.isfinite(P)) and np.all(np.linalg.eigvalsh(P) > 0.0):
                info = 1.0 / P if len(ps) == 1 else np.linalg.inv(P)
                wr = r / P[0] if len(ps) == 1 else info @ r
        for i, p in enumerate(ps):
            u[c + p] = float(wr[i])
            for j, q in enumerate(ps):
                u[c + VCH[p, q]] = float(info[i, j])

    def _contradicted(self, zs: Sequence[float], skip: int) -> int:
        """The candidate (not in ``skip``) whose pooled score is most significantly negative, at the level of
        a switch, or -1: the data favour a negative coefficient, which no candidate has. A vector candidate
        (its chi2 has no sign) is never contradicted so."""
        skip |= VECTOR
        level = window_level(self.alpha, self.ncand)
        neg = [(z, j) for j, z in enumerate(zs) if not (skip >> j) & 1 and z == z and normal_sf(-z) < level]
        return min(neg)[1] if neg else -1

    def step_filters(self, tick: int, u: list[float], x: Sequence[float], filters: Sequence[RigidEKF],
                     twin: RigidEKF | None = None) -> int:
        """:meth:`begin_tick` with the first filter's rates; the decision due is applied to every filter given
        (the agent's, and the one a restart on trial replaced): the effect's rate moves from here on, or is
        pinned again. ``twin``: a filter that has carried the slope's rates free from the m stage's start; any
        other decision is applied to it too. Returns the decision (-1: none)."""
        kf = filters[0]
        rates = ([kf.rate(k) for k in range(N_EFF)] if kf.ready and kf.aug is not None and tick % self.window == 0
                 else None)
        dec = self.begin_tick(tick, u, x, rates)
        for f in (*filters, *(() if twin is None or dec == SLOPE else (twin,))) if dec >= 0 else ():
            if dec < N_EFF:
                f.release_effect(dec)
            else:
                f.withdraw_effect(dec - N_EFF)
        return dec

    def undecided(self, k: int) -> bool:
        """Is effect k a candidate the team has neither switched on nor ruled out (nor declared)?"""
        return bool((self.cand >> k) & 1) and not ((self.on | self.withdrawn) >> k) & 1

    def filter_replaced(self) -> None:
        """The agent's filter was replaced by another that has run beside it: no lag products across the two,
        the window not offered."""
        self.ev.restart()
        self.regime_change()

    def restart_filter(self, kf: RigidEKF) -> None:
        """The agent's filter restarted (the lock check): no lag products across it, the window not offered,
        and the effects the team switched on released in it again."""
        self.filter_replaced()
        for k in range(N_EFF):
            if (self.switched >> k) & 1:
                kf.release_effect(k)

    def merge(self, prop: tuple[int, int, float]) -> None:
        """A neighbour's flooded proposal (a switch ignored for an effect already on or withdrawn, a withdrawal
        for one declared or already withdrawn; a withdrawal of one not switched on here rules it out)."""
        if prop[0] < 0:
            return
        k = prop[1] % N_EFF
        if ((self.on | self.withdrawn) if prop[1] < N_EFF else (self.on & ~self.switched) | self.withdrawn) >> k & 1:
            return
        self.flood.merge(prop)

    def entries(self) -> dict[str, float]:
        """The estimate entries (:data:`DETECT_NAMES`)."""
        return {"eff_on": float(self.on), "eff_out": float(self.withdrawn), "eff_tick": float(self.last_tick),
                "eff_z": self.last_z,
                "eff_unexplained": float(self.unexplained), "eff_zp": self.zp, "eff_zb": self.zs[0],
                "eff_zc": self.zs[1], "eff_zf": self.zs[2], "eff_zs": self.zs[3]}
