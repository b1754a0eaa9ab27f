"""The centralized yardstick of a run: the batch fit (ident.batch_fit) on all of its samples.csv, and
the agents' final errors over the fit's (summary.json's ``centralized`` and
``distributed_over_centralized`` blocks; docs/batch-fit.md)."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from coload.analysis.metrics import last_finite
from coload.rundir.format import RunData, read_run
from ident.batch_fit import (
    BatchFit,
    BatchFitError,
    FitOptions,
    fit_recording,
    samples_array,
)


def fit_run_dir(run_dir: str | Path, *, options: FitOptions | None = None) -> BatchFit:
    """Read ``run_dir`` with :func:`coload.rundir.format.read_run` and fit its samples.csv."""
    run = read_run(run_dir)
    if run.samples is None:
        raise BatchFitError(f"{run_dir}: no samples")
    arr = samples_array(run.samples.t, run.samples.columns, run.dt)
    return fit_recording(arr, run.n, run.dt, options=options, clock=time.perf_counter)


# --- the run summary's yardstick blocks ---------------------------------------------------------------
CENTRAL_KEYS = ("m", "J", "m_ci95", "J_ci95", "m_rel", "J_rel", "m_in_ci95", "J_in_ci95", "zc_x", "zc_y",
                "residual_rms", "t0", "t1", "fit_s", "nfev", "flags", "reason")  # fmt: skip
"""Keys of summary.json's ``centralized`` block, always all present (null when unknown)."""
RATIO_KEYS = ("J", "m", "J_dist_rel", "m_dist_rel", "J_over_ci95", "m_over_ci95", "reason")
"""Keys of summary.json's ``distributed_over_centralized`` block, always all present (null when unknown).
``J``, ``m``: the distributed error over the centralized error on the same data (heavy-tailed over seeds:
the centralized error is itself one noise draw and can be near zero); ``*_over_ci95``: the distributed
error over the centralized 95 % half-width, a steadier yardstick (the half-width does not depend on the
draw)."""


def _jnum(x: Any) -> float | None:
    """JSON-safe float: NaN and inf become None."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def distributed_rel_errors(run: RunData, col: str, truth_col: str) -> np.ndarray | None:
    """Each agent's final relative error (x_i - x) / x of estimate column ``col``: its last finite estimate
    against the truth at the time it reported it (as :func:`coload.analysis.metrics.final_errors`); NaN for an
    agent that never reported one; None if the run has no such column or no truth."""
    est, truth = run.estimates, run.truth
    if est is None or truth is None or not est.has(col) or truth_col not in truth.columns:
        return None
    true = truth.columns[truth_col][run.truth_index(est.t)]
    rel, _ = last_finite((est.columns[col] - true[:, None]) / true[:, None])
    return rel


def centralized_blocks(run: RunData, *, options: FitOptions | None = None) -> dict[str, dict[str, Any]]:
    """summary.json's ``centralized`` and ``distributed_over_centralized`` blocks for one run.

    The centralized estimate is :func:`fit_recording` on the whole of samples.csv (every agent, every
    tick: the centralized limit on the same data the agents had). The distributed error of x in {J, m}
    is the median over agents of |x_i - x| / x, x_i each agent's final consensus estimate (see
    :func:`distributed_rel_errors`); the ratio is that over |x_c - x| / x. Never raises: a fit that fails
    or a parameter the data cannot determine gives nulls and a ``reason``.
    """
    central: dict[str, Any] = dict.fromkeys(CENTRAL_KEYS)
    central["flags"] = []
    ratio: dict[str, Any] = dict.fromkeys(RATIO_KEYS)
    truth = run.truth
    true: dict[str, float | None] = {"m": None, "J": None}
    why: list[str] = []
    if truth is not None and "mass" in truth.columns and "inertia" in truth.columns and len(truth.t):
        mass, inertia = truth.columns["mass"], truth.columns["inertia"]
        if np.ptp(mass) > 0 or np.ptp(inertia) > 0:
            central["reason"] = ("the load's m or J changes during the run; the batch fit assumes them constant "
                                 "(not fitted)")  # fmt: skip
            ratio["reason"] = central["reason"]
            return {"centralized": central, "distributed_over_centralized": ratio}
        true = {"m": float(mass[0]), "J": float(inertia[0])}
    else:
        why.append("no truth (truth.csv) to compare with")
    fit = None
    try:
        if run.samples is None:
            raise BatchFitError("no samples")
        arr = samples_array(run.samples.t, run.samples.columns, run.dt)
        fit = fit_recording(arr, run.n, run.dt, options=options, clock=time.perf_counter)
    except (BatchFitError, ValueError, np.linalg.LinAlgError, FloatingPointError) as exc:
        central["reason"] = f"batch fit failed: {exc}"
    if fit is not None:
        central.update(
            t0=float(fit.t[0]), t1=float(fit.t[-1]), zc_x=_jnum(fit.zc_body[0]), zc_y=_jnum(fit.zc_body[1]),
            residual_rms=_jnum(fit.residual_rms), fit_s=fit.wall_s, nfev=fit.nfev, flags=list(fit.warnings),
        )  # fmt: skip
        notes = []
        for name, p_ in (("m", fit.m), ("J", fit.J)):
            central[name] = _jnum(p_.value)
            central[f"{name}_ci95"] = _jnum(p_.ci95)
            if not p_.identifiable:
                notes.append(p_.note)
            elif true[name]:
                err = p_.value - true[name]
                central[f"{name}_rel"] = err / true[name]
                central[f"{name}_in_ci95"] = bool(abs(err) <= p_.ci95)
        if notes:
            central["reason"] = "; ".join(notes)
    no_dynamics = (run.config.get("dynamics") or {}).get("algorithm") == "none"
    if no_dynamics:
        why.append("no dynamical phase (dynamics.algorithm = none): the agents estimate neither m nor J")
    for name, col, tcol in (("J", "J", "inertia"), ("m", "m", "mass")):
        if no_dynamics or true[name] is None:
            continue
        rel = distributed_rel_errors(run, col, tcol)
        finite = None if rel is None else np.abs(rel[np.isfinite(rel)])
        if finite is None or finite.size == 0:
            why.append(f"{name}: no agent has a final estimate")
            continue
        dist = float(np.median(finite))
        ratio[f"{name}_dist_rel"] = dist
        cen = central[f"{name}_rel"]
        if cen is not None and central[f"{name}_ci95"]:
            ratio[f"{name}_over_ci95"] = dist / (central[f"{name}_ci95"] / true[name])
        if cen is None:
            why.append(f"{name}: no centralized error ({'fit failed' if fit is None else 'not identifiable'})")
        elif cen == 0:
            why.append(f"{name}: the centralized error is exactly zero")
        else:
            ratio[name] = dist / abs(cen)
    ratio["reason"] = "; ".join(dict.fromkeys(why)) or None
    return {"centralized": central, "distributed_over_centralized": ratio}
