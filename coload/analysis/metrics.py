"""Estimation-error metrics of a run (paper 000, Sec. VIII-A) as pure functions on arrays.

The array functions (:func:`eerd`, :func:`eec`, ...) know nothing about files, so they can be tested
on hand-made numbers and reused by campaigns; :func:`error_series` and :func:`final_errors` apply
them to a :class:`~coload.rundir.format.RunData` and produce the ``errors`` block of summary.json.
Every key of that block is defined in ``docs/run-directory.md``.

Conventions
-----------
* ``truth_zi`` has shape (T, n, 2): z_i = p_Ci - p_G; hence z_ij = z_i - z_j = p_Ci - p_Cj.
* Estimates are NaN where an agent reported nothing. Time series are computed on what was reported,
  and sums over agents propagate NaN (a sum with a missing term is unknown, and a gap in a plot is
  more honest than a stale estimate of a rotating vector). Final values use each agent's last
  report, judged against the truth at the time it was made (:func:`last_finite`).
* On edge (i, j) both ends estimate the relative position: i holds z_ij_hat, j holds z_ji_hat.
  EERD's edge term is the mean of |z_ij - z_ij_hat|^2 over the ends that reported (j's estimate
  enters as -z_ji_hat). When both ends agree this is exactly the paper's sum over i < j, and it does
  not depend on how agents happen to be numbered when they disagree.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from coload.rundir.format import RunData

Edge = tuple[int, int]

CONVERGED_FRACTION = 0.01
"""EERD counts as converged below this fraction of its initial value (the 1 % line of the report)."""


# --- array helpers -------------------------------------------------------------------------------
def hold_last(values: np.ndarray) -> np.ndarray:
    """Forward-fill NaNs along axis 0 (time), per column: a silent agent's last estimate still stands.

    For arrays with trailing vector axes (e.g. (T, n, 2)) a row counts as missing if any component is.
    """
    values = np.asarray(values, dtype=float)
    if values.shape[0] == 0:
        return values.copy()
    flat = values.reshape(values.shape[0], -1)
    if values.ndim >= 3:
        vec = values.shape[-1]
        missing = np.isnan(flat.reshape(flat.shape[0], -1, vec)).any(axis=2)
        missing = np.repeat(missing, vec, axis=1)
    else:
        missing = np.isnan(flat)
    idx = np.where(~missing, np.arange(flat.shape[0])[:, None], 0)
    np.maximum.accumulate(idx, axis=0, out=idx)
    filled = flat[idx, np.arange(flat.shape[1])[None, :]]
    # rows before the first report stay NaN
    never = np.logical_and.accumulate(missing, axis=0)
    filled[never] = np.nan
    return filled.reshape(values.shape)


def _check_times(times: np.ndarray, *arrays: np.ndarray) -> int:
    t = len(times)
    for a in arrays:
        if a.shape[0] != t:
            raise ValueError(f"array with {a.shape[0]} rows does not match {t} times")
    return t


def true_pairs(truth_zi: np.ndarray, edges: Sequence[Edge]) -> np.ndarray:
    """z_ij = z_i - z_j for each edge, shape (T, E, 2)."""
    truth_zi = np.asarray(truth_zi, dtype=float)
    if not edges:
        return np.zeros((truth_zi.shape[0], 0, 2))
    i = np.array([e[0] for e in edges])
    j = np.array([e[1] for e in edges])
    return truth_zi[:, i] - truth_zi[:, j]


def _sq(v: np.ndarray) -> np.ndarray:
    return np.sum(np.square(v), axis=-1)


def edge_errors(
    times: np.ndarray,
    truth_zi: np.ndarray,
    est_pairs: Mapping[Edge, np.ndarray],
    edges: Sequence[Edge],
) -> np.ndarray:
    """|z_ij - z_ij_hat|^2 per edge, shape (T, E): mean over the two ends that reported, NaN if neither did."""
    z = true_pairs(truth_zi, edges)
    _check_times(times, z)
    out = np.full((len(times), len(edges)), np.nan)
    nan2 = np.full((len(times), 2), np.nan)
    for k, (i, j) in enumerate(edges):
        from_i = np.asarray(est_pairs.get((i, j), nan2), dtype=float)
        from_j = -np.asarray(est_pairs.get((j, i), nan2), dtype=float)
        _check_times(times, from_i, from_j)
        both = np.stack([_sq(z[:, k] - from_i), _sq(z[:, k] - from_j)], axis=1)
        have = ~np.isnan(both)
        count = have.sum(axis=1)
        total = np.where(have, both, 0.0).sum(axis=1)
        out[:, k] = np.where(count > 0, total / np.maximum(count, 1), np.nan)
    return out


def eerd(
    times: np.ndarray,
    truth_zi: np.ndarray,
    est_pairs: Mapping[Edge, np.ndarray],
    edges: Sequence[Edge],
) -> np.ndarray:
    """EERD(t) = sum over edges i<j of |z_ij(t) - z_ij_hat(t)|^2 (m^2), shape (T,).

    ``est_pairs[(i, j)]`` is agent i's estimate of z_ij, shape (T, 2), NaN where absent. NaN at a time
    where some edge has no estimate from either end.
    """
    return edge_errors(times, truth_zi, est_pairs, edges).sum(axis=1)


def eerd_reference(truth_zi: np.ndarray, edges: Sequence[Edge]) -> np.ndarray:
    """EERD with all estimates at zero, i.e. sum over edges of |z_ij|^2 (m^2): what EERD is at t = 0."""
    return _sq(true_pairs(truth_zi, edges)).sum(axis=1)


def eerd_per_agent(
    times: np.ndarray,
    truth_zi: np.ndarray,
    est_pairs: Mapping[Edge, np.ndarray],
    edges: Sequence[Edge],
    n: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Agent i's own share: sum over its neighbours j of |z_ij - z_ij_hat (held by i)|^2, and its reference.

    Returns ``(share, reference)``, both (T, n); reference is the same sum with zero estimates. An agent
    without edges has share and reference 0.
    """
    truth_zi = np.asarray(truth_zi, dtype=float)
    _check_times(times, truth_zi)
    share = np.zeros((len(times), n))
    ref = np.zeros((len(times), n))
    nan2 = np.full((len(times), 2), np.nan)
    for a, b in edges:
        for i, j in ((a, b), (b, a)):
            z = truth_zi[:, i] - truth_zi[:, j]
            est = np.asarray(est_pairs.get((i, j), nan2), dtype=float)
            share[:, i] += _sq(z - est)
            ref[:, i] += _sq(z)
    return share, ref


def zi_error(truth_zi: np.ndarray, est_zi: np.ndarray) -> np.ndarray:
    """|z_i_hat - z_i| per agent (m), shape (T, n); NaN where the agent did not report."""
    return np.sqrt(_sq(np.asarray(est_zi, dtype=float) - np.asarray(truth_zi, dtype=float)))


def eec(times: np.ndarray, truth_zi: np.ndarray, est_zi: np.ndarray) -> np.ndarray:
    """EEC(t) = sum_i |z_i(t) - z_i_hat(t)|^2 (m^2), shape (T,)."""
    est_zi = np.asarray(est_zi, dtype=float)
    _check_times(times, est_zi, np.asarray(truth_zi))
    return np.sum(np.square(zi_error(truth_zi, est_zi)), axis=1)


def omega_error(truth_omega: np.ndarray, est_omega: np.ndarray) -> np.ndarray:
    """omega_hat - omega per agent (rad/s), shape (T, n); truth_omega has shape (T,)."""
    return np.asarray(est_omega, dtype=float) - np.asarray(truth_omega, dtype=float)[:, None]


def time_to_converge(
    times: np.ndarray,
    values: np.ndarray,
    initial: float | None = None,
    fraction: float = CONVERGED_FRACTION,
) -> float | None:
    """First time after which ``values`` stay below ``fraction * initial`` until the end (None if never).

    ``initial`` defaults to the first finite value. NaN samples (unknown) are skipped rather than
    counted as excursions, so a gap in the recording does not reset convergence.
    """
    times = np.asarray(times, dtype=float)
    values = np.asarray(values, dtype=float)
    ok = np.isfinite(values)
    times, values = times[ok], values[ok]
    if len(values) == 0:
        return None
    if initial is None:
        initial = float(values[0])
    threshold = fraction * initial
    above = np.flatnonzero(values >= threshold)
    if len(above) == 0:
        return float(times[0])
    last = int(above[-1])
    if last == len(values) - 1:
        return None
    return float(times[last + 1])


# --- applied to a run ----------------------------------------------------------------------------
def last_finite(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per column of a (T, n[, d]) array: the last row where it is finite, and that row's index (-1 if none).

    Final errors judge each agent's last estimate against the truth *at the time it was made*: a crashed
    agent's stale estimate of a rotating vector compared with today's truth would measure the
    rotation, not the estimator.
    """
    values = np.asarray(values, dtype=float)
    ok = np.isfinite(values) if values.ndim == 2 else np.isfinite(values).all(axis=-1)
    rows = np.arange(values.shape[0])[:, None]
    idx = np.where(ok, rows, -1).max(axis=0) if values.shape[0] else np.full(ok.shape[1:], -1)
    cols = np.arange(values.shape[1])
    picked = values[np.maximum(idx, 0), cols]
    picked[idx < 0] = np.nan
    return picked, idx


@dataclass(frozen=True)
class ErrorSeries:
    """Error time series of a run, aligned with truth; shared by :func:`final_errors` and the report.

    Series are computed on what agents actually reported (NaN where they did not). Arrays named for
    the estimates grid have ``len(est_t)`` rows; those for the pairs grid ``len(pair_t)`` rows.
    """

    est_t: np.ndarray
    truth_est_idx: np.ndarray  # (K,) truth row of each estimate time
    pair_t: np.ndarray | None = None
    eerd: np.ndarray | None = None  # (P,)
    eerd_ref: np.ndarray | None = None  # (P,) EERD with zero estimates
    edge_err: np.ndarray | None = None  # (P, E) per-edge squared error
    eerd_agent: np.ndarray | None = None  # (P, n) each agent's own share
    eerd_agent_ref: np.ndarray | None = None  # (P, n)
    eec: np.ndarray | None = None  # (K,)
    zi_err: np.ndarray | None = None  # (K, n)
    omega_true: np.ndarray | None = None  # (K,)
    omega_hat: np.ndarray | None = None  # (K, n)
    omega_err: np.ndarray | None = None  # (K, n)


def _vec(table_cols: Mapping[str, np.ndarray], x: str, y: str) -> np.ndarray:
    return np.stack([table_cols[x], table_cols[y]], axis=-1)


def error_series(run: RunData) -> ErrorSeries:
    """Compute every error time series the run's files allow (requires truth and estimates)."""
    if run.truth is None or run.estimates is None:
        raise ValueError(f"{run.path}: error metrics need truth.csv and estimates.csv")
    est = run.estimates
    ti = run.truth_index(est.t)
    truth_zi_e = run.truth.zi[ti]
    kw: dict[str, Any] = {}
    if run.pairs is not None:
        pair_t = run.pairs.t
        truth_zi_p = run.truth.zi[run.truth_index(pair_t)]
        edge_err = edge_errors(pair_t, truth_zi_p, run.pairs.zij, run.edges)
        share, share_ref = eerd_per_agent(pair_t, truth_zi_p, run.pairs.zij, run.edges, run.n)
        kw.update(
            pair_t=pair_t,
            edge_err=edge_err,
            eerd=edge_err.sum(axis=1),
            eerd_ref=eerd_reference(truth_zi_p, run.edges),
            eerd_agent=share,
            eerd_agent_ref=share_ref,
        )
    if est.has("zi_x", "zi_y"):
        zi_hat = _vec(est.columns, "zi_x", "zi_y")
        kw.update(zi_err=zi_error(truth_zi_e, zi_hat), eec=eec(est.t, truth_zi_e, zi_hat))
    if est.has("omega") and "omega" in run.truth.columns:
        omega_true = run.truth.columns["omega"][ti]
        kw.update(
            omega_true=omega_true,
            omega_hat=est.columns["omega"],
            omega_err=omega_error(omega_true, est.columns["omega"]),
        )
    return ErrorSeries(est_t=est.t, truth_est_idx=ti, **kw)


def _num(x: Any) -> float | None:
    """JSON-safe float: NaN/inf become None (strict JSON has no NaN)."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def _rms(values: np.ndarray) -> float | None:
    """Root mean square over the finite entries; None when there are none."""
    values = np.asarray(values, dtype=float)
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return None
    return float(np.sqrt(np.mean(np.square(finite))))


def _rms_all(values: np.ndarray) -> float | None:
    """RMS over agents that must all be known: one agent without any estimate makes it None."""
    values = np.asarray(values, dtype=float)
    return _rms(values) if values.size and np.all(np.isfinite(values)) else None


def _ratio(num: float | None, den: float | None) -> float | None:
    if num is None or den is None or not den > 0:
        return None
    return _num(num / den)


def final_errors(run: RunData, window_s: float = 20.0) -> dict[str, Any]:
    """The ``errors`` block of summary.json (keys defined in docs/run-directory.md).

    "Final" is each agent's last reported estimate (at the last recorded time for a live agent),
    judged against the truth at the time it was reported. "Window" quantities use every estimate
    reported in the last ``window_s`` seconds of the recording.
    """
    s = error_series(run)
    est, truth = run.estimates, run.truth
    assert est is not None and truth is not None  # checked by error_series
    n = run.n
    out: dict[str, Any] = {}
    if len(s.est_t) == 0:
        return out
    t_end = float(s.est_t[-1])
    window = s.est_t >= t_end - window_s
    out["t_final"] = t_end
    out["window_s"] = float(window_s)

    if s.zi_err is not None:
        final, _ = last_finite(s.zi_err)
        out["zi_rms"] = _rms_all(final)
        out["zi_rms_window"] = _rms(s.zi_err[window])
        out["zi_err_per_agent"] = [_num(v) for v in final]
        out["eec_final"] = _num(np.sum(np.square(final)))

    if s.omega_err is not None:
        out["omega_rms"] = _rms(s.omega_err[window])
        out["omega_rms_per_agent"] = [_rms(s.omega_err[window, i]) for i in range(n)]

    if s.pair_t is not None and len(s.pair_t):
        assert s.edge_err is not None and s.eerd is not None and s.eerd_ref is not None
        assert s.eerd_agent is not None and s.eerd_agent_ref is not None
        initial = _num(s.eerd_ref[0])
        final_eerd = _num(np.sum(last_finite(s.edge_err)[0])) if run.edges else 0.0
        out["eerd_initial"] = initial
        out["eerd_final"] = final_eerd
        out["eerd_ratio"] = _ratio(final_eerd, initial)
        out["eerd_converge_s"] = time_to_converge(s.pair_t, s.eerd, initial) if initial else None
        share, _ = last_finite(s.eerd_agent)
        out["eerd_ratio_per_agent"] = [_ratio(_num(share[i]), _num(s.eerd_agent_ref[0, i])) for i in range(n)]

    if est.has("phase"):
        # Algorithm 1 done (stage 6, net.vocabulary.DONE) at every agent: the first recorded time
        # from which all agents report it; None if the run ended before
        done = np.all(est.columns["phase"] == 6.0, axis=1)
        out["finished_s"] = float(s.est_t[int(np.argmax(done))]) if done.any() else None

    if est.has("filter_restarts") and np.isfinite(est.columns["filter_restarts"]).any():
        # restarts of the dynamical phase's filters by their lock check, summed over the agents (0 in a
        # run where every filter stayed consistent: agents/dynamic_phase.py, DynamicsSpec.lock_nis)
        last, _ = last_finite(est.columns["filter_restarts"])
        out["filter_restarts"] = int(np.nansum(last))

    tcol = truth.columns
    ti = s.truth_est_idx
    # J_local/m_local: each agent's own least-squares estimate before the averaging consensus
    # (paper 000, Fig. 8 "before"); the per-agent lists keep the sign, for box plots over agents.
    for col, tname, key in (("J", "inertia", "J_rel"), ("m", "mass", "m_rel"),
                            ("J_local", "inertia", "J_local_rel"), ("m_local", "mass", "m_local_rel")):
        if est.has(col) and tname in tcol:
            true = tcol[tname][ti]
            rel, _ = last_finite((est.columns[col] - true[:, None]) / true[:, None])
            out[key] = _rms_all(rel)
            if col.endswith("_local"):
                out[f"{key}_per_agent"] = [_num(v) for v in rel]
    # augmented model (DynamicsSpec.estimate_effects): b and c against the plant's friction, which is
    # constant over a run and recorded in run.toml ([plant.friction] viscous, rotational; 0 when absent)
    fr = run.config.get("plant", {}).get("friction", {}) if isinstance(run.config.get("plant"), dict) else {}
    for col, tname in (("b", "viscous"), ("c", "rotational"), ("b_local", "viscous"), ("c_local", "rotational")):
        if est.has(col) and np.isfinite(est.columns[col]).any():
            true_v = float(fr.get(tname, 0.0)) if isinstance(fr, dict) else 0.0
            final, _ = last_finite(est.columns[col])
            if not col.endswith("_local"):
                out[f"{col}_true"] = true_v
                out[f"{col}_final"] = [_num(v) for v in final]
            out[f"{col}_err"] = _rms_all(final - true_v)
            if true_v > 0.0:
                out[f"{col}_rel"] = _rms_all((final - true_v) / true_v)
    # a constant external force (force_bias): fb against the plant's external_force (world frame, N)
    if est.has("fb_x", "fb_y") and np.isfinite(est.columns["fb_x"]).any():
        plant = run.config.get("plant")
        ext = plant.get("external_force", [0.0, 0.0]) if isinstance(plant, dict) else [0.0, 0.0]
        true_f = np.array([float(v) for v in ext]) if len(ext) == 2 else np.zeros(2)
        final = np.stack([last_finite(est.columns[c])[0] for c in ("fb_x", "fb_y")], axis=1)
        out["fb_true"] = [float(v) for v in true_f]
        out["fb_final"] = [[_num(v) for v in row] for row in final]
        err = np.sqrt(np.sum((final - true_f) ** 2, axis=1))
        out["fb_err"] = _rms_all(err)
        if np.hypot(*true_f) > 0.0:
            out["fb_rel"] = _rms_all(err / np.hypot(*true_f))
    if est.has("zc_x", "zc_y") and "zc_x" in tcol and "zc_y" in tcol:
        true_zc = np.stack([tcol["zc_x"][ti], tcol["zc_y"][ti]], axis=1)[:, None, :]
        err, _ = last_finite(np.sqrt(_sq(_vec(est.columns, "zc_x", "zc_y") - true_zc)))
        out["zC_rms"] = _rms_all(err)
    if est.has("vc_x", "vc_y") and "vc_x" in tcol and "vc_y" in tcol:
        true_vc = np.stack([tcol["vc_x"][ti], tcol["vc_y"][ti]], axis=1)[:, None, :]
        err = np.sqrt(_sq(_vec(est.columns, "vc_x", "vc_y") - true_vc))
        out["vC_rms"] = _rms(err[window])
    return out
