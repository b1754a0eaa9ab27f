"""The named constant offsets checked: do they drift over the recording, and what do they identify together.

:func:`offsets_drift` refits the named force and torque offsets to each quarter of the recording apart;
:func:`offsets_together` reports the robots' sum (and the moment) where force_sensor_offset stands beside a
force_bias in the model, as per-robot offsets of their own give.
"""

from __future__ import annotations

import numpy as np
from scipy import stats as sst

from ident.fit import Fit, Problem, fit_parts
from ident.model import expand
from ident.report import Diagnosis
from ident.select import OFFSET_FORMS, DiagnoseOptions
from ident.stats import Z95

OFFSETS = OFFSET_FORMS  # the constant offsets of the vocabulary
PARTS = 4  # runs of windows the named offsets are fitted to apart


def offsets_drift(result: Diagnosis, opt: DiagnoseOptions) -> tuple[str, Fit] | None:
    """The named constant offsets (force and torque biases, sensor offsets) refitted to each of ``PARTS`` runs
    of consecutive windows apart (the final model, its other parameters free too): where their values differ
    between the runs beyond their intervals (the chi-square of the runs about their weighted mean, every
    offset's components pooled, at the selection's level) the offsets are not constant: the text of the finding
    with the runs' values and the model checked, or None (also where that model's residual is above
    ``opt.restart_misfit`` x the noise floor: the test is not made). An `unexplained` diagnosis whose rejected
    model holds offsets (kept by the selection, not named: the residual stayed structured) has them checked
    the same way: a drifting offset leaves such a residual."""
    fit, pb = result.fits.get("augmented"), result.problem
    named = [e["name"] for e in result.effects if e["name"] in OFFSETS]
    if not named and result.unexplained and "rejected" in result.fits:
        fit = result.fits["rejected"]
        named = [c for c in fit.lay.effects if c in OFFSETS]
    if fit is None or pb is None or not named or pb.win.S < 2 * PARTS:
        return None
    if fit.sigma2 > opt.restart_misfit**2:
        # the quarters' intervals hold where the model explains the data to the noise; a misfit far above the
        # floor (a real machine's dynamics outside the vocabulary) moves every quarter's offset with it
        return None
    vals, ses, spans = [], [], []
    for idx, f in fit_parts(pb, fit.lay, fit.g, fit.x, PARTS):
        v = np.concatenate([f.param(c)[0] for c in named])
        se = np.concatenate([f.param(c)[1] for c in named]) / Z95
        vals.append(v)
        ses.append(se)
        spans.append((float(pb.t0[idx[0]]), float(pb.t0[idx[-1]] + (pb.t0[1] - pb.t0[0] if pb.win.S > 1 else 0))))
    v, se = np.array(vals), np.maximum(np.array(ses), 1e-300)
    w = 1.0 / se**2
    mean = (w * v).sum(axis=0) / w.sum(axis=0)
    chi2 = float(((v - mean) ** 2 * w).sum())
    dof = (PARTS - 1) * v.shape[1]
    p = float(sst.chi2.sf(chi2, dof))
    if not p < opt.alpha:
        return None
    runs = "; ".join(f"{a:.3g}-{b:.3g} s: ({', '.join(f'{x:.3g}' for x in row)})" for (a, b), row in zip(spans, v))
    return (f"a force offset drifts: {', '.join(named)} fitted to each quarter of the recording apart read {runs} "
            f"(chi-square {chi2:.3g} on {dof} degrees of freedom, p {p:.2g}: not constant). A sensor's bias that "
            "changes during the run (thermal drift) is outside the vocabulary: the constant offsets are not "
            "named"), fit


def drifting_agent(fit: Fit, pb: Problem, alpha: float) -> dict | None:
    """Which robot's force offset drifts (:func:`which_agent`), from the offsets' sum and moment
    (:func:`offsets_reading`) fitted to each window apart: the model with force_bias and force_sensor_offset,
    its other parameters free too. None where the load does not turn."""
    lay = fit.lay
    if not lay.rotation or lay.n < 2 or pb.win.S < 2 * PARTS:
        return None
    lay_q = lay.with_effects(lay.effects + ("force_bias", "force_sensor_offset"))
    g0 = expand(lay_q, fit.g, lay)
    ys, covs, spans = [], [], []
    # each window apart: the shorter the run, the less a drift within it (a warm-up) moves its reading off one
    # robot's form (drift_visc's warm-up of 8 s: in quarters of 7.5 s agent 1's misfit was 9.4 x below the
    # others', chi-square 163 on 6 degrees of freedom; window by window 10.5 x, 27.5 on 22: its form fits)
    for idx, f in fit_parts(pb, lay_q, g0, fit.x, pb.win.S):
        y, C = offsets_reading(f)
        ys.append(y)
        covs.append(C)
        spans.append((float(pb.t0[idx[0]]), float(pb.t0[idx[-1]] + (pb.t0[1] - pb.t0[0]))))
    return which_agent(np.array(ys), np.array(covs), fit.g[: 2 * lay.n].reshape(lay.n, 2), lay.axes, alpha) | {
        "spans": spans}


def which_agent(ys: np.ndarray, covs: np.ndarray, arms: np.ndarray, axes: tuple[bool, bool], alpha: float) -> dict:
    """Which robot's offset changes between runs, from the runs' readings ``ys`` (K, 4) [sum x, sum y, moment
    at angle 0, at 90 deg] with covariances ``covs`` (K, 4, 4) and the contacts' arms (n, 2) about the centre of
    mass. One robot's offset changing by D_k in run k moves the sum by D_k and the moment by A_i D_k (A_i its
    arm's map); the readings are fitted by generalised least squares with a common reading plus robot i's
    changes, for each robot i (chi-square on 2 (K - 1) degrees of freedom, fewer on an idle axis), and with a
    common reading alone (constant offsets). The robot is named (``agent``) where the constant is rejected at
    level ``alpha`` and every other robot's chi-square exceeds its own beyond the F-test at that level;
    ``change_per_part`` its offset in runs 2.. minus run 1's (N) with ``change_ci95``."""
    K, n = ys.shape[0], arms.shape[0]
    keep = np.r_[np.asarray(axes, bool), True, True]  # an idle axis's sum is not fitted
    W = np.zeros((4 * K, 4 * K))
    for k in range(K):
        blk = np.zeros((4, 4))
        blk[np.ix_(keep, keep)] = np.linalg.pinv(covs[k][np.ix_(keep, keep)], rcond=1e-12, hermitian=True)
        W[4 * k : 4 * k + 4, 4 * k : 4 * k + 4] = blk
    y = ys.reshape(-1)
    obs = K * int(keep.sum())

    def gls(X: np.ndarray) -> tuple[float, int, np.ndarray, np.ndarray]:
        H = X.T @ W @ X
        cov = np.linalg.pinv(H, rcond=1e-12, hermitian=True)
        beta = cov @ X.T @ W @ y
        e = y - X @ beta
        return float(e @ W @ e), obs - int(np.linalg.matrix_rank(H)), beta, cov

    common = np.tile(np.eye(4), (K, 1))
    chi0, dof0 = gls(common)[:2]
    per = []
    for i in range(n):
        A = np.vstack((np.eye(2), [[-arms[i, 1], arms[i, 0]], [-arms[i, 0], -arms[i, 1]]]))  # sum, moment
        X = np.zeros((4 * K, 4 + 2 * (K - 1)))
        X[:, :4] = common
        for k in range(1, K):
            X[4 * k : 4 * k + 4, 4 + 2 * (k - 1) : 4 + 2 * k] = A
        chi, dof, beta, cov = gls(X)
        per.append((float(sst.chi2.sf(chi, dof)) if dof > 0 else float("nan"), dof, beta[4:], np.diag(cov)[4:], chi))
    p0 = float(sst.chi2.sf(chi0, dof0)) if dof0 > 0 else float("nan")
    ps = [q[0] for q in per]
    chis = [q[4] for q in per]
    dof = per[0][1]
    # a drift within each run (a warm-up) leaves every robot's fit some misfit that a constant per run does not
    # follow; the robot named is the one whose misfit the others' exceed beyond the F-test of two variances at
    # level alpha (each other's chi-square over its own, F(dof, dof)): told apart from the others, not perfect
    best = int(np.argmin(chis))
    ratio = min((c / max(chis[best], 1e-300) for j, c in enumerate(chis) if j != best), default=0.0)
    crit = float(sst.f.ppf(1.0 - alpha, dof, dof)) if dof > 0 else float("inf")
    agent = best if p0 < alpha and ratio > crit else None
    out = {"agent": agent, "p_per_agent": ps, "chi2_per_agent": chis, "p_constant": p0, "dof": dof,
           "ratio": ratio, "ratio_critical": crit}
    if agent is not None:
        out["change_per_part"] = per[agent][2].reshape(K - 1, 2).tolist()
        out["change_ci95"] = (Z95 * np.sqrt(np.clip(per[agent][3], 0, None))).reshape(K - 1, 2).tolist()
    return out


def drift_text(d: dict) -> str:
    """The drifting robot's finding in words (:func:`drifting_agent`)."""
    chis = ", ".join(f"agent {i} {c:.3g}" for i, c in enumerate(d["chi2_per_agent"]))
    if d["agent"] is None:
        return ("which robot's offset drifts is not told: the offsets' sum and moment per window, "
                f"fitted as one robot's changing offset, leave chi-square {chis} on {d['dof']} degrees of freedom "
                f"(a robot is named where every other's is above {d['ratio_critical']:.3g} x its own, the F-test at "
                f"the selection's level; here {d['ratio']:.3g} x)")
    i = d["agent"]
    steps = "; ".join(f"{a:.3g}-{b:.3g} s: ({x:.3g}, {y:.3g})" for (a, b), (x, y) in
                      zip(d["spans"][1:], d["change_per_part"]))
    return (f"agent {i}'s force offset drifts: the offsets' sum and moment fitted to each window apart "
            f"change as agent {i}'s sensor would make them (chi-square {chis} on {d['dof']} degrees of freedom: every "
            f"other robot's {d['ratio']:.3g} x or more agent {i}'s, beyond the F-test's {d['ratio_critical']:.3g} x "
            f"at the selection's level; constant offsets p {d['p_constant']:.2g}); agent {i}'s offset from the "
            f"first window's: {steps} N (world frame)")


def unname_drifting(result: Diagnosis, text: str) -> None:
    """Constant offsets that drift are not named: the diagnosis falls back to the nominal model, unexplained."""
    # what the selection said of the model with the constant offsets (named on a structured residual, or
    # not named) gives way to the drift's finding
    walk = "the residual drifts as a random walk"
    result.warnings = [w for w in result.warnings if not w.startswith((walk, "unexplained:"))
                       and not (w.startswith("the residual with ") and ": named" in w)]
    result.warnings.append(text)
    result.warnings.append("unexplained: the offsets fitted to the whole recording differ from quarter to quarter; "
                           "m, J and their 95 % intervals are the nominal model's, which the data reject: they hold "
                           "only as far as that model does")
    for c in result.candidates:
        c["accepted"] = False
    result.effects = [e for e in result.effects if e.get("kind") == "logger"]
    result.augmented, result.random_force, result.unexplained = result.nominal, None, True
    result.fits["augmented"] = result.fits["nominal"]


def offsets_reading(fit: Fit) -> tuple[np.ndarray, np.ndarray]:
    """What per-robot force offsets in the world frame give the load, read from a model with force_bias and
    force_sensor_offset (and a rotation): [Sx, Sy, M0, M90], the offsets' sum over the robots (N, how much too
    high the logged forces read in sum: n x force_sensor_offset - force_bias) and their moment about the centre
    of mass (N m, how much too high the logged torque reads) at the model's angle 0 and 90 deg (the moment
    turns with the load: M(theta) = M0 cos theta + M90 sin theta), with its covariance (the delta method: the
    moment is the contacts' arms times the offset). An idle axis's components are 0 with variance 0."""
    lay = fit.lay
    n = lay.n
    iax = np.flatnonzero(lay.axes)
    b, o = lay.slot("force_bias"), lay.slot("force_sensor_offset")
    idx = np.r_[np.arange(2 * n), np.arange(b.start, b.stop), np.arange(o.start, o.stop)]

    def reading(g: np.ndarray) -> np.ndarray:
        fb, so = np.zeros(2), np.zeros(2)
        fb[iax], so[iax] = g[b], g[o]
        rs = g[: 2 * n].reshape(n, 2).sum(axis=0)  # the model's torque of the offsets is -(R(theta) rsum) x so
        return np.array([n * so[0] - fb[0], n * so[1] - fb[1], rs[0] * so[1] - rs[1] * so[0],
                         -rs[1] * so[1] - rs[0] * so[0]])

    val = reading(fit.g)
    jac = np.zeros((4, idx.size))
    for j, i in enumerate(idx):  # bilinear in the arms and the offset: central differences are exact
        h = 1e-6 * max(abs(float(fit.g[i])), 1.0)
        up, dn = fit.g.copy(), fit.g.copy()
        up[i] += h
        dn[i] -= h
        jac[:, j] = (reading(up) - reading(dn)) / (2 * h)
    return val, jac @ fit.cov[np.ix_(idx, idx)] @ jac.T


def _moment(val: np.ndarray, cov: np.ndarray) -> tuple[float, float]:
    """The moment's size |M| (N m) and its 95 % half-width (the delta method; at |M| = 0 the larger axis's)."""
    m = float(np.hypot(val[2], val[3]))
    grad = val[2:4] / m if m > 0 else np.array([1.0, 0.0])
    var = float(grad @ cov[2:4, 2:4] @ grad) if m > 0 else float(np.max(np.diag(cov)[2:4]))
    return m, float(Z95 * np.sqrt(max(var, 0.0)))


def offsets_together(result: Diagnosis) -> None:
    """force_sensor_offset named beside force_bias in the model (named, or left ambiguous): what the data
    identify is the offsets' sum over the robots (their force on the load) and their moment, which turns with
    the load; robots whose offsets differ give both, and the model's split (one offset on every robot plus a
    bias) is not theirs: its values, read as each robot's offset, would be wrong by the bias over n (5.5 N
    "per robot" for offsets below 0.7 N). The two entries are replaced by one, ``force_offsets_sum``: the sum
    with its 95 % half-widths, and the moment (``moment_Nm``, its size, and at the model's angles 0 and 90 deg);
    a warning says it in words."""
    names = {e["name"]: e for e in result.effects}
    fit = result.fits.get("augmented")
    # force_bias in the model counts too where it is not named (ambiguous with velocity_bias beside friction)
    if fit is None or "force_sensor_offset" not in names or "force_bias" not in fit.lay.effects:
        return
    val, cov = offsets_reading(fit)
    half = Z95 * np.sqrt(np.clip(np.diag(cov), 0, None))
    mag, mag_h = _moment(val, cov)
    axes = fit.lay.axes
    entry = {"name": "force_offsets_sum", "value": [float(val[c]) if axes[c] else None for c in range(2)],
             "unit": "N", "ci95": [float(half[c]) if axes[c] else None for c in range(2)],
             "moment_Nm": mag, "moment_ci95": mag_h, "moment_0_90_Nm": val[2:].tolist(),
             "moment_0_90_ci95": half[2:].tolist(), "kind": "reading",
             "model_split": {k: names[k]["value"] for k in ("force_bias", "force_sensor_offset") if k in names}}
    first = min(i for i, e in enumerate(result.effects) if e["name"] in ("force_bias", "force_sensor_offset"))
    result.effects = [e for e in result.effects if e["name"] not in ("force_bias", "force_sensor_offset")]
    result.effects.insert(first, entry)
    txt = ", ".join(f"{val[c]:.3g} +- {half[c]:.2g}" for c in range(2) if axes[c])
    amb = any("force_bias" in pair for pair in result.ambiguous)
    result.warnings.append(f"force_offsets_sum: the robots' logged forces read ({txt}) N too high in sum, with a "
                           f"moment of {mag:.3g} +- {mag_h:.2g} N m about the centre of mass that turns with the "
                           "load: what force sensors with offsets of their own give (world frame). The data identify "
                           "that sum and that moment, not each robot's offset: correct the team's sum, not each "
                           "sensor by force_sensor_offset (the model's split into the same offset on every robot "
                           "plus a force_bias; a force on the load that does not turn, a slope or a tether, reads "
                           "as part of the sum)" + (" (with friction in the model a velocity offset times it also "
                           "reads as part of it: force_bias and velocity_bias are not told apart)" if amb else ""))


def offset_as_external_force(result: Diagnosis) -> None:
    """force_sensor_offset named without force_bias: the same offset o on every robot's logged force is, in the
    equations, an external force -n o at the contacts' centroid (wind on a symmetric load, a hose, a cable):
    one model, two readings the data cannot tell apart. The equivalent force, with its 95 % half-widths, is
    added to the entry and both readings are said; no number changes."""
    fit = result.fits.get("augmented")
    e = next((e for e in result.effects if e["name"] == "force_sensor_offset"), None)
    if e is None or fit is None or "force_bias" in fit.lay.effects:
        return
    n = fit.lay.n
    e["external_force_at_centroid"] = [None if v is None else -n * v for v in e["value"]]
    e["external_force_at_centroid_ci95"] = [None if h is None else n * h for h in e["ci95"]]
    off = ", ".join(f"{v:.4g}" for v in e["value"] if v is not None)
    ext = ", ".join(f"{v:.4g}" for v in e["external_force_at_centroid"] if v is not None)
    half = ", ".join(f"{h:.2g}" for h in e["external_force_at_centroid_ci95"] if h is not None)
    result.warnings.append(f"force_sensor_offset: every robot's force sensor reads ({off}) N too high (world "
                           f"frame), or, the same model, an external force of ({ext}) +- ({half}) N acts at the "
                           f"contacts' centroid (n x -offset, n = {n}: wind on a load symmetric about that point, "
                           "a hose or a cable pulling there). The data do not tell the two apart; a sensor check "
                           "(each robot's reading with no load) does")
