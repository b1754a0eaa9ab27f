"""``coload diagnose``: the entry points on recording directories (docs/diagnose.md).

:func:`diagnose_dir` reads a recording (:mod:`ident.recording`), diagnoses it (:mod:`ident.select`)
and, with ``validate``, predicts another recording of the same plant with the nominal and the
augmented model. Presentation is in :mod:`ident.report`.
"""

from __future__ import annotations

import sys
import time
import warnings
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from statistics import NormalDist

import numpy as np

from ident.change import diagnose_sides, drift_hint
from ident.fit import states_of, window_valid
from ident.frames import frame_check, to_world, velocities_to_world, velocity_frame_check
from ident.glitches import GLITCH_FLOORS, force_spikes, spike_response
from ident.model import EFFECTS, PER_AGENT, PLANAR, VECTOR_EFFECTS
from ident.offsets import (
    drift_text,
    drifting_agent,
    offset_as_external_force,
    offsets_drift,
    offsets_together,
    unname_drifting,
)
from ident.prepare import without_glitches
from ident.recording import Recording, RecordingError, agent_period
from ident.recording import read_recording as _read
from ident.report import (
    Diagnosis,
    ModelReport,
    draw_residuals,
    format_diagnosis,
    plot_diagnosis,
    residual_panels,
)
from ident.saturation import at_limit, saturated, saturation_warning, without_limits
from ident.select import DiagnoseError, DiagnoseOptions, diagnose, predict
from ident.stats import Z95, autocorrelation, block_average, ljung_box
from ident.vscale import agents_off, rescaled, scale_check

Z999 = NormalDist().inv_cdf(0.9995)  # the two-sided 99.9 % quantile
CANDIDATES: dict[str, tuple[int, str, str]] = {
    name: (2 if name in VECTOR_EFFECTS or name in PLANAR else 3 if name == "sensor_offset_body"
           else -1 if name in PER_AGENT else 1, unit, sig)
    for name, (unit, sig) in EFFECTS.items()
}
"""name -> (number of parameters on a planar load, -1 for n - 1: one per agent but the reference; unit, the
signature shown in the cross-correlation)."""
MIN_STAMPS = 50
FRAME_WINDOW_S = 1.0  # the robot-frame check's windows (s)
HALF_SAMPLE_TOL = 0.2  # a delay within 2 ci95 or this share of half a sample period of it is the hold's


def read_recording(path: str | Path) -> Recording:
    """Read a recording directory; malformed input raises :class:`DiagnoseError` (file, line, field)."""
    try:
        rec = _read(path)
    except RecordingError as exc:
        raise DiagnoseError(str(exc)) from None
    if rec.T < MIN_STAMPS:
        raise DiagnoseError(f"{Path(path) / 'samples.csv'}: too short: {rec.T} stamps, need at least {MIN_STAMPS}")
    return rec


def diagnose_dir(path: str | Path, *, options: DiagnoseOptions | None = None,
                 progress: Callable[[str], None] | None = None,
                 validate: str | Path | None = None, keep_spikes: str | None = None) -> Diagnosis:  # fmt: skip
    """Read a recording directory and diagnose it; with ``validate`` (another recording directory) also
    report the models' errors on it (``Diagnosis.validation``). Force spikes (:func:`ident.glitches.force_spikes`)
    are left out unless the motion follows them; ``keep_spikes``: the reason they are kept (the second pass)."""
    rec = raw = read_recording(path)
    other = read_recording(validate) if validate is not None else None
    flags = dep = None
    if rec.vel is not None:  # each agent's own samples: an interpolated row is no evidence
        logged = rec.wrench_logged[..., None] if rec.wrench_logged is not None else True
        flags, dep = force_spikes(rec.t, np.where(logged, rec.wrench[..., :2], np.nan))
    if flags is not None and flags.any() and keep_spikes is None:
        w = rec.wrench.copy()
        w[..., :2] -= dep  # each spike replaced by the line through its neighbours
        rec = raw = replace(rec, wrench=w)
    found = saturated(rec)
    hit = at_limit(rec, found)
    hit_share = float(hit.mean())
    rec, left_out = without_limits(rec, hit)
    with warnings.catch_warnings():
        # a stamp where no agent has a value is NaN by design; numpy's warning about it says nothing to a user
        warnings.filterwarnings("ignore", "Mean of empty slice", RuntimeWarning)
        rec, vframes = _robot_velocity_frames(rec, options or DiagnoseOptions(), progress)
        rec, vscale = _velocity_scales(rec, options or DiagnoseOptions(), progress)
        raw = rec  # the forces' check turns from the velocities in the world frame
        rec, frames = _robot_frames(rec, options or DiagnoseOptions(), progress)
        result = diagnose(rec, options=options, progress=progress, clock=time.perf_counter)
        if frames is not None and frames["robot_frame"]:
            # the kinematics' angle is the start's (a few % of the rotation off): the fitted model's angle
            # turns the forces again, and the recording is diagnosed once more
            angle = fitted_angle(result)
            if angle is not None:
                rec, frames = _robot_frames(raw, options or DiagnoseOptions(), progress, angle)
                result = diagnose(rec, options=options, progress=progress, clock=time.perf_counter)
        if _sign_reversed(result):
            # the load accelerates against the logged force, far beyond what friction holding it could do: the
            # forces (and torques) are logged with the opposite sign. The nominal fit cannot tell (its 1/m takes
            # the sign), the effects can (friction opposes the motion, not the logged force): diagnosed again
            # with the wrench turned round
            a, ha = result.fits["nominal"].inverse("m")
            rec = replace(rec, wrench=-rec.wrench)
            result = diagnose(rec, options=options, progress=progress, clock=time.perf_counter)
            result.effects.insert(0, {"name": "force_sign_reversed", "value": -1.0, "unit": "-", "ci95": 0.0,
                                      "kind": "logger"})  # fmt: skip
            result.warnings.insert(0, f"force_sign_reversed: the load accelerates against the logged forces (1/m "
                                      f"{a:.4g} +- {ha:.2g} 1/kg as logged): every agent's force and torque is "
                                      "logged with the opposite sign (or its velocities are); diagnosed with the "
                                      "wrench turned round")  # fmt: skip
        held = _half_sample_delay(result, rec)
        if held is not None:
            if progress is not None:
                progress(f"a delay of {held}: refitting with the wrench held between samples")
            rec.hold, rec.hold_source = "zoh", "inferred: a delay of half a sample period"
            alt = diagnose(rec, options=options, progress=progress, clock=time.perf_counter)
            if alt.unexplained and not result.unexplained:
                rec.hold, rec.hold_source = "cubic", "default"
            else:
                alt.warnings.insert(0, f"run.toml has no input_hold, and with the wrench taken as smooth the data "
                                       f"show a delay of {held}: what holding each sample until the next does. "
                                       "Read as held (input_hold = \"zoh\"); declare input_hold = \"cubic\" in "
                                       "run.toml if the wrench is smooth and the delay is real")
                result = alt
    result.model["hold_source"] = rec.hold_source
    result.saturation = found
    if found:
        result.warnings.insert(0, saturation_warning(found, left_out, hit_share))
    if vframes is not None:
        result.velocity_frames = vframes
        if vframes["robot_frame"]:
            n = len(vframes["phi_deg"])
            result.effects.insert(0, {"name": "robot_frame_velocities", "value": vframes["phi_deg"], "unit": "deg",
                                      "ci95": [None] * n, "agents": list(range(n)), "reference": None,
                                      "frame": "relative to agent 0's", "kind": "logger"})  # fmt: skip
            result.warnings.insert(0, "robot_frame_velocities: the velocities are logged in each robot's own frame, "
                                      "turning with the load (the rigid body's kinematics fit "
                                      f"{vframes['rss_world'] / vframes['rss_robot']:.3g} x better in them; t "
                                      f"{vframes['t']:.3g} over {vframes['windows']} windows, p {vframes['p']:.2g}): "
                                      "turned to the world frame before the fit, each by the load's angle from "
                                      "their own kinematics plus its mounting angle relative to agent 0 (value, "
                                      "deg), and the team by the angle the forces' direction gives")  # fmt: skip
    drift = offsets_drift(result, options or DiagnoseOptions())
    alpha = (options or DiagnoseOptions()).alpha
    who = drifting_agent(drift[1], result.problem, alpha) if drift is not None else None
    if who is not None and not who["p_constant"] < alpha:
        # read as per-robot offsets (their sum and moment) the windows agree: the form fitted (a body-frame
        # offset for world-frame ones) changes with the angles each quarter covers, the offsets do not drift
        result.warnings.append("the offsets fitted to each quarter of the recording apart differ, but read as force "
                               "offsets of each robot's own (their sum and moment) the windows agree (p "
                               f"{who['p_constant']:.2g}): the offsets do not drift; the form fitted stands in for "
                               "offsets of each robot's own")
        drift = None
    if drift is not None:
        unname_drifting(result, drift[0])
        if who is not None:
            result.offset_drift = who
            result.warnings.append(drift_text(who))
    else:
        offsets_together(result)
        offset_as_external_force(result)
    if vscale is not None and vscale["scaled"]:
        off = vscale["agents"]
        result.effects.insert(0, {"name": "velocity_scale", "value": vscale["scales"], "unit": "-",
                                  "ci95": vscale["ci95"], "agents": off, "reference": None,
                                  "frame": "relative to the team's median agent", "kind": "logger"})  # fmt: skip
        result.warnings.insert(0, "velocity_scale: agent(s) " + ", ".join(
            f"{j} log {vscale['scales'][j]:.4g} +- {vscale['ci95'][j]:.2g} x" for j in off) + " the velocity the "
            "others' rigid-body motion gives at their contacts (a wheel radius or an odometry gain off; the "
            f"kinematics' remainder {vscale['rss_one'] / vscale['rss_scaled']:.3g} x lower with a scale per agent, "
            f"F {vscale['F']:.3g}, p {vscale['p']:.2g}, and then {vscale['over_noise']:.3g} x the agents' own "
            "noise): their velocities divided by it before the fit. A gain on an actuator leaves the kinematics "
            "rigid; a scale common to every agent is m and J's and invisible here")
    if frames is not None:
        result.frames = frames
        if frames["robot_frame"]:
            n = len(frames["phi_deg"])
            result.effects.insert(0, {"name": "robot_frame_forces", "value": frames["phi_deg"], "unit": "deg",
                                      "ci95": frames["phi_ci95_deg"], "agents": list(range(n)), "reference": None,
                                      "kind": "logger"})  # fmt: skip
            result.warnings.insert(0, "robot_frame_forces: the forces are logged in each robot's own frame, "
                                      "turning with the load (equation error "
                                      f"{frames['rss_world'] / frames['rss_robot']:.3g} x lower with them turned "
                                      f"by the load's angle; t {frames['t']:.3g} over {frames['windows']} windows, "
                                      f"p {frames['p']:.2g}): turned to the world frame before the fit, each by the "
                                      "load's angle (the kinematics', then the fitted model's) plus its mounting "
                                      "angle (value, deg)")
    result.change = diagnose_sides(rec, result, options, progress)
    ch = result.change
    if ch and not ch["found"] and "before" in ch:
        sides = "; ".join(f"{k} p {ch[k]['whiteness_p']:.2g}" for k in ("before", "after") if "whiteness_p" in ch[k])
        result.warnings.append(f"a change of the load between {ch['window'][0]:.4g} and {ch['window'][1]:.4g} s was "
                               f"tried and not kept: the sides' residuals stay structured ({sides})")
        hint = drift_hint(ch.get("m_per_part", []))
        if hint:
            result.warnings.append(hint)
    if ch and ch["found"]:
        if result.effects:
            # named on a structured residual (the 90 % rule, or a random force's walk) by one model over a
            # recording that two models explain: each side's diagnosis names its own (a per-agent gain
            # follows a change of m in part where the agents push differently before and after it)
            result.warnings.append(f"{', '.join(e['name'] for e in result.effects)}: named by one model over the "
                                   "whole recording, whose residual stays structured; superseded by the change: "
                                   "each side names its own effects (see change)")  # fmt: skip
            if result.random_force is not None:
                walk = "the residual drifts as a random walk"
                result.warnings = [w for w in result.warnings if not w.startswith(walk)]
            result.effects, result.augmented, result.random_force = [], result.nominal, None
            result.fits["augmented"] = result.fits["nominal"]
        result.unexplained = False
        result.warnings = [w for w in result.warnings if not w.startswith("unexplained:")]
        result.warnings.append(f"the residual of one model over the whole recording is structured, and a change of "
                               f"the load between {ch['window'][0]:.4g} and {ch['window'][1]:.4g} s explains it: "
                               "each side is explained by its own model (see change)")
    if flags is not None and flags.any():
        if keep_spikes is None:
            why = _spikes_followed(rec, result, flags, dep, options or DiagnoseOptions())
            if why.startswith("kept"):
                if progress is not None:
                    progress("the motion follows the force spikes: diagnosed again with them as logged")
                return diagnose_dir(path, options=options, progress=progress, validate=validate, keep_spikes=why)
        k, i = np.nonzero(flags)
        result.warnings.insert(0, f"{k.size} force samples ({100 * k.size / flags.size:.2g} %) are more than "
                                  f"{GLITCH_FLOORS:g} noise floors of their agent's force off the cubic through their "
                                  f"neighbours (agents {sorted(set(i.tolist()))}, the first at t = "
                                  f"{rec.t0 + rec.t[k.min()]:.6g} s): {keep_spikes or why}")
    if other is not None:
        if other.hold_source == "default" and other.hold != rec.hold:
            other.hold, other.hold_source = rec.hold, f"as {path}"  # the same plant's wrench varies alike
        if progress is not None:
            progress(f"predicting {validate} with the nominal and the augmented model")
        try:
            result.validation = {"recording": str(validate), **predict(result, other, options)}
        except ValueError as exc:
            raise DiagnoseError(f"{validate}: cannot predict it with this model: {exc}") from None
    return result


def _spikes_followed(rec: Recording, result: Diagnosis, flags: np.ndarray, dep: np.ndarray,
                     opt: DiagnoseOptions) -> str:
    """Whether the velocities follow the force spikes as the fitted model says a real force would
    (:func:`ident.glitches.spike_response`, one-sided tests at the selection's level): the verdict's text,
    starting "kept" (they follow, and do not fall short of it) or "left out" (they do not follow, or the
    motion cannot tell)."""
    fit = result.fits.get("augmented")
    if fit is None:
        return "left out, each replaced by the line through its neighbours (no model to test them with)"
    inv_m = fit.inverse("m")[0]
    inv_J = fit.inverse("J")[0] if fit.lay.rotation else 0.0
    arms = None
    angle = fitted_angle(result)
    if angle is not None and angle[0].size == rec.T:
        r = fit.g[: 2 * rec.n].reshape(rec.n, 2)
        c, s = np.cos(angle[0])[:, None], np.sin(angle[0])[:, None]
        arms = np.stack((c * r[:, 0] - s * r[:, 1], s * r[:, 0] + c * r[:, 1]), axis=-1)
    vel = without_glitches(rec, []).vel
    beta, se, used = spike_response(rec.t, vel, flags, dep, inv_m, inv_J, arms)
    if not used or not np.isfinite(se) or se <= 0:
        return ("left out, each replaced by the line through its neighbours: the motion around them cannot be "
                "measured (too close to an end or to a gap)")
    p1 = float(NormalDist().cdf((beta - 1.0) / se))  # that the load feels them as logged
    p0 = float(NormalDist().cdf(-beta / se))  # that it does not feel them
    seen = (f"the velocities across {used} of them jump {beta:.2g} +- {Z95 * se:.2g} x what the fitted model "
            f"predicts for a real force (1: the load feels them, p {p1:.2g}; 0: it does not, p {p0:.2g})")
    if p0 < opt.alpha and p1 >= opt.alpha:
        return f"kept as logged: {seen}: knocks the load felt"
    # a glitch of the log, as a velocity's, unless the motion shows it; one too small to move the load
    # measurably is left out as well: what it would add is below what the data resolve
    why = "spikes of the force log" if p1 < opt.alpha else "too small for the motion to tell"
    return f"left out, each replaced by the line through its neighbours: {seen}: {why}"


def fitted_angle(result: Diagnosis) -> tuple[np.ndarray, np.ndarray] | None:
    """The final model's angle and rate at every stamp of the recording, or None when the fit left windows out
    (a long recording fitted in part)."""
    pb, fit = result.problem, result.fits.get("augmented")
    if pb is None or fit is None or not fit.lay.rotation:
        return None
    valid = window_valid(pb)
    st = states_of(pb, fit)[valid]
    if st.shape[0] != pb.win.u_t.size:
        return None
    return st[:, 3], st[:, 2]


def _check_window(rec: Recording, opt: DiagnoseOptions) -> float:
    """The frame checks' window (s): at most ``FRAME_WINDOW_S``, at most the fit's."""
    # windows of 1 s are the checks' units (their t-test has one degree of freedom per window less one): the
    # fit's 2.5 s windows leave a 10 s recording 3, where no t-test reaches the selection's level
    return min(FRAME_WINDOW_S, opt.fit.window_stamps * agent_period(rec))


def _robot_frames(rec: Recording, opt: DiagnoseOptions, progress, angle=None) -> tuple[Recording, dict | None]:
    """The robot-frame check (:mod:`ident.frames`) at the family-wise level of the selection; the recording
    turned to the world frame when its forces are in the robots' frames, else as it is."""
    fc = frame_check(rec, _check_window(rec, opt), opt.fit.gap_factor, angle)
    if fc is None:
        return rec, None
    out = fc.summary(opt.alpha) | {"phi_ci95_deg": np.degrees(fc.phi_ci95).tolist()}
    if not out["robot_frame"]:
        return rec, out
    if progress is not None:
        progress(f"forces logged in the robots' own frames (equation error {fc.rss_world / fc.rss_robot:.3g} x lower "
                 f"turned with the load, p {fc.p:.2g}): turned to the world frame")
    return to_world(rec, fc.theta, fc.phi), out


def _sign_reversed(result: Diagnosis) -> bool:
    """Is the nominal fit's 1/m negative beyond its own 99.9 % interval? Friction that holds a creeping load
    leaves 1/m near zero either way; a clearly negative one is a force logged with the opposite sign."""
    fit = result.fits.get("nominal")
    if fit is None:
        return False
    a, ha = fit.inverse("m")
    return a + ha / Z95 * Z999 < 0.0  # the 95 % half-width widened to 99.9 %


def _robot_velocity_frames(rec: Recording, opt: DiagnoseOptions, progress) -> tuple[Recording, dict | None]:
    """The velocities' frame check (:func:`ident.frames.velocity_frame_check`) at the selection's family-wise
    level; the recording with its velocities turned to the world frame when they are in the robots' frames."""
    vc = velocity_frame_check(rec, _check_window(rec, opt), opt.alpha)
    if vc is None:
        return rec, None
    # (alpha is NaN where the check does not pass: the angles are read only then)
    out = vc.summary(opt.alpha) | {"alpha_deg": float(np.degrees(vc.alpha))}
    if not out["robot_frame"]:
        return rec, out
    if progress is not None:
        progress(f"velocities logged in the robots' own frames (kinematics {vc.rss_world / vc.rss_robot:.3g} x better "
                 f"in them, p {vc.p:.2g}): turned to the world frame")
    return velocities_to_world(rec, vc), out


def _velocity_scales(rec: Recording, opt: DiagnoseOptions, progress) -> tuple[Recording, dict | None]:
    """The velocity-scale check (:mod:`ident.vscale`) at the selection's family-wise level, its remainder at most
    ``opt.restart_misfit`` x the agents' own noise (a fault the scales only partly take up leaves more: a clock
    off); the recording with the agents off rescaled when it passes."""
    sc = scale_check(rec)
    if sc is None:
        return rec, None
    out = sc.summary(opt.alpha, opt.restart_misfit) | {"agents": agents_off(sc, opt.alpha)}
    if not out["scaled"] or not out["agents"]:
        out["scaled"] = False
        return rec, out
    if progress is not None:
        progress(f"agent(s) {out['agents']} log their velocity at scale(s) "
                 f"{[round(sc.scales[j], 4) for j in out['agents']]} of the others' kinematics: rescaled")
    return rescaled(rec, sc, out["agents"]), out


def sample_period(rec: Recording) -> float:
    """The median interval between an agent's own measured samples (agents may log on their own clocks)."""
    meas = rec.vel if rec.vel is not None else rec.pos
    gaps = [np.diff(rec.t[~np.isnan(meas[:, i]).all(axis=1)]) for i in range(rec.n)]
    return float(np.median(np.concatenate(gaps)))


def _half_sample_delay(result: Diagnosis, rec: Recording) -> str | None:
    """The named delay as text when it is half a sample period, as holding a smooth-taken wrench looks, on a
    recording whose run.toml does not say how the wrench varies; None otherwise."""
    if rec.hold_source != "default" or rec.hold != "cubic":
        return None
    d = next((e for e in result.effects if e["name"] == "measurement_delay"), None)
    if d is None:
        return None
    half = 0.5 * sample_period(rec)
    ci = d.get("ci95") or 0.0
    if abs(d["value"] - half) > max(2.0 * ci, HALF_SAMPLE_TOL * half):
        return None
    return f"{d['value'] * 1e3:.3g} +- {ci * 1e3:.2g} ms (half the sample period is {half * 1e3:.3g} ms)"


def stderr_progress(prefix: str = "coload diagnose") -> Callable[[str], None]:
    """Progress lines on stderr with the elapsed time."""
    t0 = time.perf_counter()

    def say(msg: str) -> None:
        print(f"{prefix} [{time.perf_counter() - t0:6.1f} s] {msg}", file=sys.stderr, flush=True)

    return say


__all__ = [
    "CANDIDATES", "DiagnoseError", "DiagnoseOptions", "Diagnosis", "ModelReport", "Z95", "autocorrelation",
    "block_average", "diagnose", "diagnose_dir", "draw_residuals", "format_diagnosis", "ljung_box",
    "plot_diagnosis", "read_recording", "residual_panels", "stderr_progress",
]  # fmt: skip
