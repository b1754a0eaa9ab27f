"""The named constant offsets checked: do they drift over the recording, and what do they identify together.

:func:`offsets_drift` refits the named force and torque offsets to each quarter of the recording apart;
:func:`offsets_together` reports the robots' sum (and the moment) where force_sensor_offset stands beside a
force_bias in the model, as per-robot offsets of their own give.
"""

from __future__ import annotations

import numpy as np
from scipy import stats as sst

from ident.fit import lm_fit, subset
from ident.report import Diagnosis
from ident.select import DiagnoseOptions
from ident.stats import Z95


OFFSETS = ("force_bias", "force_sensor_offset", "sensor_offset_body", "torque_bias")
PARTS = 4  # runs of windows the named offsets are fitted to apart


def offsets_drift(result: Diagnosis, opt: DiagnoseOptions) -> str | None:
    """The named constant offsets (force and torque biases, sensor offsets) refitted to each of ``PARTS`` runs
    of consecutive windows apart (the final model, its other parameters free too): where their values differ
    between the runs beyond their intervals (the chi-square of the runs about their weighted mean, every
    offset's components pooled, at the selection's level) the offsets are not constant: the text of the finding
    with the runs' values, or None (also where the final model's residual is above ``opt.restart_misfit`` x the
    noise floor: the test is not made)."""
    fit, pb = result.fits.get("augmented"), result.problem
    named = [e["name"] for e in result.effects if e["name"] in OFFSETS]
    if fit is None or pb is None or not named or pb.win.S < 2 * PARTS:
        return None
    if fit.sigma2 > opt.restart_misfit**2:
        # the quarters' intervals hold where the model explains the data to the noise; a misfit far above the
        # floor (a real machine's dynamics outside the vocabulary) moves every quarter's offset with it
        return None
    vals, ses, spans = [], [], []
    for idx in np.array_split(np.arange(pb.win.S), PARTS):
        f = lm_fit(subset(pb, idx), fit.lay, fit.g, fit.x[idx], max_iter=15)
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
            "changes during the run (thermal drift) is outside the vocabulary: the constant offsets are not named")


def unname_drifting(result: Diagnosis, text: str) -> None:
    """Constant offsets that drift are not named: the diagnosis falls back to the nominal model, unexplained."""
    result.warnings.append(text)
    result.warnings.append("unexplained: the offsets named on the whole recording differ from quarter to quarter; "
                           "m, J and their 95 % intervals are the nominal model's, which the data reject: they hold "
                           "only as far as that model does")
    walk = "the residual drifts as a random walk"
    result.warnings = [w for w in result.warnings if not w.startswith(walk)]
    for c in result.candidates:
        c["accepted"] = False
    result.effects = [e for e in result.effects if e.get("kind") == "logger"]
    result.augmented, result.random_force, result.unexplained = result.nominal, None, True
    result.fits["augmented"] = result.fits["nominal"]


def offsets_together(result: Diagnosis) -> None:
    """force_sensor_offset named beside force_bias in the model (named, or left ambiguous): what the data
    identify is the offsets' sum over the robots (their force on the load) and the moment about the contacts
    that turns with the load; robots whose
    offsets differ give both, and the model's split (one offset on every robot plus a bias) is not theirs. The
    sum, with its 95 % half-widths, is added to force_sensor_offset's entry and said in a warning."""
    names = {e["name"]: e for e in result.effects}
    fit = result.fits.get("augmented")
    # force_bias in the model counts too where it is not named (ambiguous with velocity_bias beside friction)
    if fit is None or "force_sensor_offset" not in names or "force_bias" not in fit.lay.effects:
        return
    lay = fit.lay
    n = lay.n
    b, o = lay.slot("force_bias"), lay.slot("force_sensor_offset")
    # the logged forces read n o - b too high in sum (the model gives the load b - n o more than logged)
    k = np.r_[-np.ones(b.stop - b.start), n * np.ones(o.stop - o.start)]
    idx = np.r_[np.arange(b.start, b.stop), np.arange(o.start, o.stop)]
    na = b.stop - b.start
    val, half = [], []
    for c in range(na):
        sel = np.array([c, na + c])
        w = k[sel]
        val.append(float(w @ fit.g[idx[sel]]))
        half.append(float(Z95 * np.sqrt(max(w @ fit.cov[np.ix_(idx[sel], idx[sel])] @ w, 0.0))))
    it = iter(zip(val, half))
    pairs = [next(it) if on else (None, None) for on in lay.axes]
    names["force_sensor_offset"]["sum_over_robots"] = [p[0] for p in pairs]
    names["force_sensor_offset"]["sum_over_robots_ci95"] = [p[1] for p in pairs]
    txt = ", ".join(f"{v:.3g} +- {h:.2g}" for v, h in pairs if v is not None)
    result.warnings.append(f"force_bias and force_sensor_offset together: the robots' logged forces read ({txt}) N "
                           "too high in sum (n x force_sensor_offset - force_bias), with a moment about the "
                           "contacts that turns with the load: what force sensors with offsets of their own give. "
                           "The data identify that sum and that moment, not each robot's offset: the same offset on "
                           "every robot plus a bias is the model's reading of them, not a correction for each sensor")
