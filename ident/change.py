"""A load that changes during the recording: where, and the model on each side (docs/diagnose.md, "A load
that changes").

A load that changes part-way (a payload added, a contact moved) leaves the constant-parameter fit with a
structured residual that no effect of the vocabulary explains. :func:`find_change` locates the most
likely change at a boundary between two windows from the fit's own linearisation: each window's score of
the global parameters with the window's own start state profiled out, summed from the first window on
(a CUSUM); the Lagrange-multiplier statistic of "the parameters differ after window k" is the largest
where the change is (Andrews' sup-LM). It then fits the model to each side apart and keeps the change
when the two fits lower the residual more than the added parameters can by chance (an F-test at the
diagnosis' level, divided by the number of boundaries searched) and remove at least half of the excess
residual (a structured residual lowers under any split; a change accounts for most of it).
:func:`diagnose_sides` then diagnoses the recording before and after the two windows that may hold the
change, each side as a recording of its own, and the change is reported when each side is explained by
its own model with a white residual; where a side stays structured, the model fitted to each quarter of
the recording on its own (:func:`mass_per_part`) says whether m drifts instead of stepping.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ident import stats
from ident.fit import Fit, Lin, Problem, fit_parts, lm_fit, subset
from ident.recording import Recording, RecordingError, recording_from_arrays
from ident.report import Diagnosis
from ident.select import DiagnoseError, DiagnoseOptions, diagnose

TRIM = 0.15  # each side keeps at least this share of the windows (and two whole windows)
SPLIT_SHARE = 0.5  # share of the excess residual that the split fits must remove before the sides are diagnosed


def window_scores(lin: Lin) -> tuple[np.ndarray, np.ndarray]:
    """Per window s, the score of the global parameters g and its information, with the window's own
    state profiled out: J = Jg - Jx (Jx^T Jx)^+ Jx^T Jg, score J^T r, information J^T J. (S, G), (S, G, G)."""
    S, _, G = lin.Jg.shape
    sc = np.zeros((S, G))
    info = np.zeros((S, G, G))
    for s in range(S):
        Q, Jg = lin.Jx[s], lin.Jg[s]
        Jp = Jg - Q @ (np.linalg.pinv(Q.T @ Q, hermitian=True) @ (Q.T @ Jg))
        sc[s] = Jp.T @ lin.r[s]
        info[s] = Jp.T @ Jp
    return sc, info


def break_statistic(sc: np.ndarray, info: np.ndarray, sigma2: float) -> np.ndarray:
    """LM statistic of a break before window k, k = 1..S-1 (NaN at k = 0): the partial score sum made
    orthogonal to the whole one (a Brownian bridge under constant parameters), in its own metric."""
    S = sc.shape[0]
    total_i = info.sum(axis=0)
    inv = np.linalg.pinv(total_i, hermitian=True)
    cs, ci = np.cumsum(sc, axis=0), np.cumsum(info, axis=0)
    out = np.full(S, math.nan)
    for k in range(1, S):
        c = cs[k - 1] - ci[k - 1] @ inv @ cs[-1]
        V = ci[k - 1] - ci[k - 1] @ inv @ ci[k - 1]
        out[k] = float(c @ np.linalg.pinv(V, rcond=1e-10, hermitian=True) @ c) / sigma2
    return out


def find_change(pb: Problem, fit: Fit, alpha: float) -> dict[str, Any]:
    """The boundary with the largest break statistic and what was measured there (JSON-ready); ``window``
    (the window before and the one after the boundary, s from the first stamp: where the change is) only
    when the fits of the two sides pass the F-test at ``alpha`` / (boundaries searched) and remove
    ``SPLIT_SHARE`` of the excess residual."""
    S = pb.win.S
    lo = max(3, math.ceil(TRIM * S))
    ks = np.arange(lo, S - lo + 1)
    info: dict[str, Any] = {"searched": int(ks.size)}
    if ks.size == 0 or fit.lin is None:
        info["why"] = f"{S} windows: too few to split"
        return info
    sc, inf = window_scores(fit.lin)
    lm = break_statistic(sc, inf, fit.sigma2)
    k = int(ks[np.nanargmax(lm[ks])])
    head, tail = np.arange(k), np.arange(k, S)
    before = lm_fit(subset(pb, head), fit.lay, fit.g, fit.x[head])
    after = lm_fit(subset(pb, tail), fit.lay, fit.g, fit.x[tail])
    F, p = stats.nested_f(fit.rss, before.rss + after.rss, fit.lay.G, fit.N, fit.P + fit.lay.G)
    # the share of the residual's excess over the noise floor the split removes (none to share at the floor)
    share = (fit.rss - before.rss - after.rss) / (fit.rss - fit.N) if fit.rss > fit.N else math.nan
    level = alpha / ks.size
    t0 = pb.t0
    info.update({"k": k, "t": float(t0[k]), "lm": float(lm[k]), "F": F, "p": p, "level": level, "split_share": share})
    if p < level and share >= SPLIT_SHARE:
        info["window"] = [float(t0[k - 1]), float(t0[k + 1])]  # k + 1 < S: at least `lo` windows follow k
    return info


def _part(rec: Recording, keep: np.ndarray) -> Recording:
    vel, pos = (None if a is None else a[keep] for a in (rec.vel, rec.pos))
    out = recording_from_arrays(rec.t[keep] + rec.t0, rec.wrench[keep], vel, pos, hold=rec.hold, dt=rec.dt)
    out.hold_source = rec.hold_source
    return out


def _side(d: Diagnosis, span: tuple[float, float]) -> dict[str, Any]:
    a = d.augmented
    return {"from_s": span[0], "to_s": span[1], "m": a.m, "m_ci95": a.m_ci95, "J": a.J, "J_ci95": a.J_ci95,
            "effects": d.effects, "unexplained": d.unexplained, "whiteness_p": a.whiteness_p,
            "residual_over_floor": a.residual_over_floor}  # fmt: skip


def diagnose_sides(rec: Recording, result: Diagnosis, options: DiagnoseOptions | None = None,
                   progress: Any = None) -> dict[str, Any] | None:  # fmt: skip
    """When ``result`` (the diagnosis of ``rec``) leaves a residual that is not white, look for a change of
    the load; if one is kept, diagnose the recording before and after the two windows around it. Returns
    the ``change`` block of the JSON (None when the residual is white or nothing was searched)."""
    opt = options or DiagnoseOptions()
    fit = result.fits.get("augmented")
    if fit is None or result.problem is None or result.augmented.whiteness_p > opt.alpha_white:
        return None
    say = progress or (lambda msg: None)
    say("a structured residual remains: looking for a change of the load")
    out: dict[str, Any] = {"found": False, **find_change(result.problem, fit, opt.alpha)}
    if "window" not in out:
        return out
    t, (a, b) = rec.t, out["window"]
    sides = {}
    for key, keep, span in (("before", t < a, (float(t[0]), a)), ("after", t >= b, (b, float(t[-1])))):
        say(f"diagnosing the recording {key} the change ({span[0]:.4g} to {span[1]:.4g} s)")
        try:
            sides[key] = _side(diagnose(_part(rec, keep), options=opt, progress=progress), span)
        except (DiagnoseError, RecordingError) as exc:
            sides[key] = {"from_s": span[0], "to_s": span[1], "error": str(exc)}
    out.update(sides)
    if all("error" not in d and not d["unexplained"] for d in sides.values()):
        # the excess over the noise floor the sides leave (weighted by their durations), against the whole's
        r0 = result.augmented.residual_over_floor
        w = np.array([d["to_s"] - d["from_s"] for d in sides.values()])
        left = float(np.sum(w * [max(d["residual_over_floor"] ** 2 - 1, 0.0) for d in sides.values()]) / w.sum())
        out["share"] = 1 - left / max(r0 * r0 - 1, 1e-300)
    white = all("error" not in d and d["whiteness_p"] > opt.alpha_white for d in sides.values())
    # a change explains the data only where it leaves each side white: a smooth drift of the load also lowers
    # the residual under a split (by the share of the drift each side's own mean takes up), but leaves both
    # sides structured; the model per stretch of windows then says whether m drifts
    out["found"] = white and all(not d["unexplained"] for d in sides.values())
    if not white:
        out["m_per_part"] = mass_per_part(result.problem, fit)
    return out


def mass_per_part(pb: Problem, fit: Fit, parts: int = 4) -> list[dict[str, float]]:
    """The model fitted to each of ``parts`` runs of consecutive windows on its own (from ``fit``): each run's
    time span, m, J and their 95 % half-widths (a load whose mass drifts shows m trending from run to run, a
    payload that slides across it J more than m; J is NaN without rotation)."""
    out = []
    for idx, f in fit_parts(pb, fit.lay, fit.g, fit.x, parts):
        mj = f.mj()
        t1 = float(pb.win.t[idx[-1]][pb.win.t[idx[-1]] > -np.inf].max())
        out.append({"from_s": float(pb.t0[idx[0]]), "to_s": t1, "m": mj["m"], "m_ci95": mj["m_ci95"],
                    "J": mj["J"], "J_ci95": mj["J_ci95"]})
    return out


def _ends(parts: list[dict[str, float]], key: str) -> float | None:
    """The relative change of ``key`` from the first run to the last where the two differ beyond their
    intervals; None otherwise (or where a run has no value)."""
    v = np.array([p.get(key, math.nan) for p in parts])
    ci = np.array([p.get(f"{key}_ci95", math.nan) for p in parts])
    if v.size < 3 or not np.all(np.isfinite(v)) or not np.all(np.isfinite(ci)):
        return None
    return float(v[-1] / v[0] - 1) if abs(v[-1] - v[0]) > ci[0] + ci[-1] else None


def _one_way(parts: list[dict[str, float]], key: str) -> bool:
    d = np.diff([p[key] for p in parts])
    return bool(np.all(d > 0) or np.all(d < 0))


def drift_hint(parts: list[dict[str, float]]) -> str | None:
    """A warning when m or J per run of windows moves one way and its ends differ beyond their intervals: a
    mass that changes moves both alike, a payload sliding across the load (its mass distribution) moves J far
    more than m, and not always one way (its arm about the moving centre of mass first grows). J's ends count
    beside an m that drifts even where J does not move one way."""
    dm, dj = _ends(parts, "m"), _ends(parts, "J")
    dm = dm if dm is not None and _one_way(parts, "m") else None
    if dj is not None and dm is None and not _one_way(parts, "J"):
        dj = None
    if dm is None and dj is None:
        return None
    said = [q for q, d in (("m", dm), ("J", dj)) if d is not None]
    runs = "; ".join(f"{q} " + ", ".join(f"{p[q]:.4g} +- {p[q + '_ci95']:.2g} ({p['from_s']:.3g}-{p['to_s']:.3g} s)"
                                         for p in parts) for q in said)
    if dj is not None and (dm is None or abs(dj) > 2.0 * abs(dm)):
        why = ("J changes more than m: a load whose mass distribution changes gradually (a payload sliding or "
               "shifting across it) fits that better than a mass that changes")
    else:
        why = "a load whose mass (and inertia) changes gradually fits that"
    return (f"{' and '.join(said)} {'drifts' if len(said) == 1 else 'change'}: fitted on its own to each quarter of "
            f"the recording it reads {runs}; a change at one time leaves each side structured here, {why}")
