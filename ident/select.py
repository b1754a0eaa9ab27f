"""``coload diagnose``: trace the residual of the nominal rigid-body model to the effects it lacks.

Pure core: :func:`diagnose` takes a :class:`ident.recording.Recording` and returns a
:class:`ident.report.Diagnosis`. Steps (docs/diagnose.md, "Method"): noise floor from the data;
nominal fit (:mod:`ident.fit`); score tests of every candidate effect; forward selection by nested
F-test and BIC; an effect is named only if the final residual is white, or (real data with dynamics
outside any model) if the named effects remove nearly all of the nominal model's excess residual.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ident import stats
from ident.fit import (
    Fit,
    FitError,
    FitOptions,
    Lin,
    NoiseAR,
    Problem,
    correlated,
    differenced,
    fit_robust,
    initial_guess,
    linearise,
    lm_fit,
    make_problem,
    normal_equations,
    refit_states,
    states_of,
    subset,
    window_valid,
)
from ident.model import EFFECTS, MIRRORS, NONNEGATIVE, PER_AGENT, PLANAR, TIMING, VECTOR_EFFECTS, Layout, expand
from ident.prepare import (
    RUN,
    agent_floors,
    correlated_velocities,
    differenced_velocities,
    noise_floor,
    spread_windows,
    usable_floor,
    without_glitches,
)
from ident.random_force import (
    fit_random_force,
    rigid_modes,
    robust_covariance,
    robust_wald,
    significant_walk,
    walk_values,
    walk_warning,
)
from ident.recording import Recording, agent_period
from ident.report import Diagnosis, ModelReport
from ident.timing import FORCE_LAG, at_bound, force_lag_shape, lag_text

Z95 = stats.Z95


class DiagnoseError(ValueError):
    """The recording cannot be diagnosed; the message says why."""


@dataclass(frozen=True)
class DiagnoseOptions:
    """Thresholds of the selection; the defaults are the documented ones (docs/diagnose.md)."""

    alpha: float = 1e-3  # family-wise level of the nested F-tests (Bonferroni over the candidates left)
    alpha_white: float = 0.01  # Ljung-Box level: a residual with p above it counts as white
    lags: int = 20  # Ljung-Box lags (of the block-averaged series)
    block_s: float = 0.1  # block length (s) in front of Ljung-Box
    ambiguous_bic: float = 10.0  # two substitutes closer than this in BIC cannot be told apart
    holdout: float = 0.25  # trailing share of the recording held out for the prediction error
    restart_misfit: float = 1.3  # a candidate's fit above this x the noise floor also starts from the kinematics
    max_effects: int = 3
    max_fits: int = 3  # candidates fitted per round: those with the strongest score tests
    explained: float = 0.9  # share of the nominal excess residual the effects must remove when not white
    max_samples: int = 150_000  # windows x stamps x agents fitted at most (0: all): runs of windows spread out
    candidates: tuple[str, ...] = tuple(EFFECTS)
    fit: FitOptions = FitOptions()


def _channels(pb: Problem, fit: Fit) -> dict[str, np.ndarray]:
    """Unweighted residual per channel, (S, L, n, 2)."""
    w = pb.win
    out = {}
    k = 0
    for name, y, sig in (("vel", w.vel, pb.sigma_v), ("pos", w.pos, pb.sigma_p)):
        if y is not None:
            size = y[..., 0].size // w.S * 2
            out[name] = fit.res[:, k : k + size].reshape(w.S, w.L, w.n, 2) * sig
            k += size
    return out


def residual_modes(pb: Problem, fit: Fit, res: np.ndarray | None = None, theta: np.ndarray | None = None) -> np.ndarray:
    """(T, K) rigid-body modes of the weighted residual ``res`` (default: the fit's) per stamp: per channel
    the agents' mean x, mean y (active axes) and, with rotation, the rotation; NaN where nothing was measured."""
    w = pb.win
    lay = fit.lay
    if theta is None:
        theta = states_of(pb, fit)[..., 3]
    res = fit.res if res is None else res
    valid = window_valid(pb)
    cols = []
    k = 0
    for name, mask in (("vel", w.vmask), ("pos", w.pmask)):
        if mask is None:
            continue
        size = mask.size // w.S * 2
        e = res[:, k : k + size].reshape(w.S, w.L, w.n, 2)
        k += size
        new = rigid_modes(e, mask, lay, fit.g, theta, velocity=name == "vel")
        cols += new
    M = np.stack(cols, axis=-1)  # (S, L, K)
    return M[valid]


def whiteness(pb: Problem, fit: Fit, opt: DiagnoseOptions, modes: np.ndarray | None = None, draws: int = 100,
              theta: np.ndarray | None = None) -> float:
    """Ljung-Box p of the block-averaged residual modes. Each window's free start state removes part of
    a white residual, which leaves the residual slightly anti-correlated at lags within a window; that
    autocorrelation is measured on white noise projected the same way (``draws`` draws, a fixed seed)
    and subtracted (:func:`ident.stats.ljung_box`). ``theta``: the fit's body angle, when already simulated."""
    theta = states_of(pb, fit)[..., 3] if theta is None else theta
    modes = residual_modes(pb, fit, theta=theta) if modes is None else modes
    block = _block(pb, opt)
    lin = fit.lin if fit.lin is not None else linearise(pb, fit.lay, fit.g, fit.x, cols=np.zeros(0, int))
    mask = (lin.Jx != 0).any(axis=2) | (fit.res != 0)
    rng = np.random.default_rng(12345)
    Qs = [np.linalg.qr(lin.Jx[s][:, np.abs(lin.Jx[s]).sum(axis=0) > 0])[0] for s in range(pb.win.S)]
    acc = []
    for _ in range(draws):
        e = rng.standard_normal(fit.res.shape) * mask
        for s in range(pb.win.S):
            e[s] -= Qs[s] @ (Qs[s].T @ e[s])
        m = stats.block_average(residual_modes(pb, fit, res=e, theta=theta), block)
        acc.append([stats.autocorrelation(m[:, j], opt.lags) for j in range(m.shape[1])])
    center = np.mean(acc, axis=0)
    return stats.ljung_box(stats.block_average(modes, block), opt.lags, center, center_draws=draws)[2]


def _block(pb: Problem, opt: DiagnoseOptions) -> int:
    return max(1, round(opt.block_s / float(np.median(np.diff(pb.win.u_t)))))


@dataclass
class _Score:
    p: float
    logp: float
    half_width: float
    collinear: float
    corr: list[float]
    step: np.ndarray
    lm: float = 0.0  # the statistic itself: ranks candidates whose p-values underflow alike


def score(pb: Problem, fit: Fit, name: str) -> _Score:
    """Score test of adding ``name`` to ``fit``: the decrease of the residual one Gauss-Newton step of the
    augmented model promises, beyond the step without it, over sigma^2 ~ chi2(q)."""
    lay2 = fit.lay.with_effects(fit.lay.effects + (name,))
    g2 = expand(lay2, fit.g, fit.lay)
    sl = lay2.slot(name)
    q = sl.stop - sl.start
    eff_cols = np.arange(sl.start, sl.stop)
    le = linearise(pb, lay2, g2, fit.x, cols=eff_cols)
    old = fit.lin
    idx = np.array([i for i in range(lay2.G) if not (sl.start <= i < sl.stop)], int)
    Jg = le.Jg.copy()
    Jg[..., idx] = old.Jg
    Jcg = le.Jcg.copy()
    Jcg[:, idx] = old.Jcg
    lin2 = Lin(le.r, Jg, old.Jx, le.rc, Jcg, old.Jcx, old.Jcn)
    H, rhs = normal_equations(lin2)
    keep = np.ones(H.shape[0], bool)
    keep[eff_cols] = False
    d_full = np.linalg.lstsq(H, rhs, rcond=1e-13)[0]
    d_rest = np.linalg.lstsq(H[np.ix_(keep, keep)], rhs[keep], rcond=1e-13)[0]
    dec = float(rhs @ d_full - rhs[keep] @ d_rest)
    lm = max(dec, 0.0) / fit.sigma2
    p, logp = stats.score_test(lm, q)
    cov = np.linalg.pinv(H, rcond=1e-13, hermitian=True)
    ce = np.diag(cov)[eff_cols]
    raw = np.diag(H)[eff_cols]
    # the share of the candidate's information the model's own parameters already carry (Schur complement)
    Hoe = H[np.ix_(keep, eff_cols)]
    schur = H[np.ix_(eff_cols, eff_cols)] - Hoe.T @ np.linalg.lstsq(H[np.ix_(keep, keep)], Hoe, rcond=1e-13)[0]
    collinear = float(1.0 - (np.diag(schur) / np.maximum(raw, 1e-300)).min()) if np.all(raw > 0) else 1.0
    half = float(Z95 * np.sqrt(fit.sigma2 * np.clip(ce, 0, None)).max())
    rss0 = lin2.cost
    corr = [float(math.copysign(math.sqrt(max(dec, 0.0) / max(rss0, 1e-300) / q), v)) for v in d_full[eff_cols]]
    return _Score(p, logp, half, collinear, corr, d_full[eff_cols], lm / q)


def _reference(name: str, m: float, J: float, dt: float) -> float:
    """A realistic small magnitude of each effect; a candidate the data cannot resolve to this is 'not excited'."""
    mg = m * 9.81 if math.isfinite(m) and m > 0 else 500.0
    return {
        "viscous_friction": (m if math.isfinite(m) and m > 0 else 50.0) / 20.0,  # time constant m/b = 20 s
        "anisotropic_friction": (m if math.isfinite(m) and m > 0 else 50.0) / 20.0,
        "coulomb_friction": 0.005 * mg,
        "rotational_damping": (J if math.isfinite(J) and J > 0 else 100.0) / 20.0,
        "measurement_delay": max(0.02, 2 * dt),
        "force_sensor_lag": max(0.02, 2 * dt),  # force rows two samples or 20 ms late
        "force_sensor_lowpass": max(0.02, 2 * dt),  # a force sensor's filter of 20 ms
        "force_bias": 0.005 * mg,
        "torque_bias": 0.005 * mg * 0.2,  # half a percent of the weight at a 0.2 m arm
        "velocity_bias": 0.02,
        "sensor_offset_body": 0.005 * mg,
        "force_sensor_offset": 0.001 * mg,  # each agent's sensor: a force bias's share of a team of about five
        "agent_actuator_gain": 0.05,  # one actuator 5 % off the others
        "agent_clock_offset": max(0.02, 2 * dt),  # as the delay: a logger's clock two samples or 20 ms off
    }[name]


def _value(x: np.ndarray, lay: Layout, name: str, ci: bool = False) -> float | list:
    """A scalar, or for a vector effect [x, y] (None on an idle axis: not identifiable there), or for a
    per-agent effect one value per agent (the reference agent's exact: gain 1, clock offset 0; ``ci``:
    the 95 % half-widths, 0 at the reference)."""
    if name in PER_AGENT:
        full = np.zeros(lay.n)
        full[np.arange(lay.n) != lay.ref] = x
        if name == "agent_actuator_gain" and not ci:
            full += 1.0
        return full.tolist()
    if name == "sensor_offset_body":  # [Bx, By] in the load's frame (None on an idle axis), the torque
        return _value(x[:-1], lay, "force_bias") + [float(x[-1])]
    if name in PLANAR:
        return [float(v) for v in x]
    if name not in VECTOR_EFFECTS:
        return float(x[0])
    out: list = [None, None]
    k = 0
    for c in range(2):
        if lay.axes[c]:
            out[c] = float(x[k])
            k += 1
    return out


def _principal(d: np.ndarray, iso: float) -> dict[str, float]:
    """The friction's principal axes from D's (d1, d2) and the isotropic part ``iso`` (viscous_friction's
    value, 0 if not named): ``along`` acts along the axis at ``axis_deg`` in the load's frame at the model's
    angle 0, ``across`` perpendicular to it."""
    k = math.hypot(float(d[0]), float(d[1]))
    return {"axis_deg": math.degrees(0.5 * math.atan2(float(d[1]), float(d[0]))), "along": iso + k, "across": iso - k}


def _agents_off(val: list, ci: list, name: str) -> list[int]:
    """The agents whose per-agent value's 95 % interval excludes the reference's (gain 1, offset 0)."""
    ref = 1.0 if name == "agent_actuator_gain" else 0.0
    return [i for i, (v, h) in enumerate(zip(val, ci)) if abs(v - ref) > h]


FORCE_LIKE = ("viscous_friction", "anisotropic_friction", "coulomb_friction", "rotational_damping", "force_bias",
              "torque_bias", "force_sensor_offset", "sensor_offset_body")


def _regauge(pb: Problem, fit: Fit, say: Callable[[str], None]) -> Fit:
    """``fit`` with the per-agent effects relative to the agent at the team's median (of the gains if named,
    else of the clock offsets): when one agent is off, the others agree and the median is one of them, so m,
    J and the forces are those of the majority's actuators and clock (a team-wide gain is m/g and J/g, a
    team-wide clock offset no offset: the reference picks which agents are called right, nothing else).
    n = 2 has no majority: agent 0 stays the reference. The same model re-parametrised, refitted from the
    exact transform (the logged torque column is not per agent: refitted, not copied)."""
    lay = fit.lay
    if lay.n < 3:
        return fit
    key = "agent_actuator_gain" if "agent_actuator_gain" in lay.effects else "agent_clock_offset"
    full = lay.per_agent(fit.g, key)
    order = np.argsort(full)
    ref = int(order[(lay.n - 1) // 2])
    if ref == lay.ref:
        return fit
    lay2 = Layout(lay.n, lay.rotation, lay.axes, lay.positions, lay.effects, ref)
    g = fit.g.copy()
    others = np.arange(lay.n) != ref
    if "agent_actuator_gain" in lay.effects:
        gain = 1.0 + lay.per_agent(fit.g, "agent_actuator_gain")
        k = gain[ref]
        g[lay2.slot("agent_actuator_gain")] = gain[others] / k - 1.0
        g[lay.ia] *= k
        if lay.rotation:
            g[lay.ib] *= k
        for e in FORCE_LIKE:
            if e in lay.effects:
                g[lay.slot(e)] /= k
    if "agent_clock_offset" in lay.effects:
        off = lay.per_agent(fit.g, "agent_clock_offset")
        g[lay2.slot("agent_clock_offset")] = off[others] - off[ref]
    say(f"per-agent effects relative to agent {ref} (the team's median)")
    return lm_fit(pb, lay2, g, fit.x)


def _retimed(rec: Recording, offset: np.ndarray) -> Recording:
    """``rec`` with each agent's velocities moved to the time they were measured at: its row at stamp t holds
    the velocity at t - offset_i, so the velocity at t is its series read at t + offset_i (linear)."""
    vel = rec.vel.copy()
    for i, d in enumerate(offset):
        for c in range(2):
            y = rec.vel[:, i, c]
            ok = ~np.isnan(y)
            if d and ok.sum() >= 2:
                vel[:, i, c] = np.where(ok, np.interp(rec.t + d, rec.t[ok], y[ok], left=np.nan, right=np.nan), np.nan)
    return replace(rec, vel=vel)


def _rms(pb: Problem, fit_res: np.ndarray) -> dict[str, float]:
    """Unweighted residual RMS per channel, per measured component."""
    w = pb.win
    out = {}
    k = 0
    ax = int(sum(pb.base.axes))
    for name, y, mask, sig in (("vel", w.vel, w.vmask, pb.sigma_v), ("pos", w.pos, w.pmask, pb.sigma_p)):
        if y is not None:
            size = y[..., 0].size // w.S * 2
            e = fit_res[:, k : k + size].reshape(w.S, w.L, w.n, 2) * sig
            out[name] = math.sqrt(float((e * e).sum()) / max(int(mask.sum()) * ax, 1))
            k += size
    return out


def diagnose(rec: Recording, *, options: DiagnoseOptions | None = None, progress: Callable[[str], None] | None = None,
             clock: Callable[[], float] | None = None) -> Diagnosis:  # fmt: skip
    """Diagnose one recording. ``clock`` (e.g. ``time.perf_counter``) times it into ``wall_s`` (0 without)."""
    opt = options or DiagnoseOptions()
    unknown = [c for c in opt.candidates if c not in EFFECTS]
    if unknown:
        raise DiagnoseError(f"unknown candidate effect(s) {unknown}; known: {list(EFFECTS)}")
    say = progress or (lambda msg: None)
    t_start = clock() if clock is not None else 0.0
    warns = list(rec.warnings)
    lag1 = differenced_velocities(rec, warns)
    rec = without_glitches(rec, warns)  # before the floors: glitches inflate them
    # a filtered velocity's noise correlates in time (differenced positions' is the MA(1) above)
    corr = None if lag1 else correlated_velocities(rec, warns, opt.block_s, opt.lags)
    sv, sp = noise_floor(rec)
    sv_w, sp_w = usable_floor(sv, rec.vel), usable_floor(sp, rec.pos)
    per_agent = {}
    for key, data, unit in (("velocity", rec.vel, "m/s"), ("position", rec.pos, "m")):
        own = agent_floors(rec, data)
        if own is not None:
            per_agent[key] = own[:, 0].tolist()
            warns.append(f"the agents' {key} noise differs ({own.min():.3g} to {own.max():.3g} {unit}): each agent's "
                         "samples are weighted by its own noise floor")  # fmt: skip
            sv_w, sp_w = (own, sp_w) if key == "velocity" else (sv_w, own)
    dtm = agent_period(rec)  # as make_problem's windows
    fopt = opt.fit
    wlen = min(fopt.window_s, fopt.window_stamps * dtm)
    cs = fopt.coulomb_speed
    try:
        pb = make_problem(rec, sv_w, sp_w, fopt)
        try:
            g0, x0, w0 = initial_guess(pb, rec)
        except FitError as exc:
            if not pb.base.rotation:
                raise
            # the rotation is below the noise: the translation alone is fitted, J and the geometry are
            # reported as not identifiable rather than guessed
            warns.append(f"{exc}; the load is modelled without its rotation")
            pb = make_problem(rec, sv_w, sp_w, fopt, rotation=False)
            g0, x0, w0 = initial_guess(pb, rec)
    except FitError as exc:
        raise DiagnoseError(f"cannot identify the nominal model: {exc}") from None
    warns += w0
    if cs is None:  # the Coulomb term's smoothing speed: small against the typical speed of the load
        if rec.vel is not None:
            speed = float(np.sqrt(np.nanmean(np.nansum(rec.vel**2, axis=-1))))
        else:
            speed = float(np.sqrt(np.mean(np.sum(np.diff(np.nan_to_num(rec.pos[:, 0]), axis=0) ** 2, axis=-1)))) / dtm
        cs = max(0.005 * speed, 1e-6)
    pb = replace(pb, coulomb_speed=cs)
    if lag1:
        pb = differenced(pb, lag1)
    elif corr is not None and corr["modelled"]:
        pb = correlated(pb, NoiseAR(tuple(corr["partial"]), dtm, corr["tau_s"] if corr["order"] == 1 else 0.0))
    size = pb.win.S * pb.win.L * rec.n
    if opt.max_samples and size > opt.max_samples:
        idx = spread_windows(pb.win.S, max(8, opt.max_samples // (pb.win.L * rec.n)))
        warns.append(f"a long recording ({pb.win.S} windows of {wlen:.3g} s, {size} samples to simulate): the fit "
                     f"uses {idx.size} of its windows, in runs of {RUN} spread over it (at most {opt.max_samples} "
                     "samples; --max-samples 0 fits every window, at a cost that grows with the length)")
        pb, x0 = subset(pb, idx), x0[idx]
    base = pb.base
    say(f"{rec.T} stamps, n = {rec.n}, {pb.win.S} windows of {wlen:.3g} s; noise floor "
        + ", ".join(f"{k} {v:.3g}" for k, v in (("velocity (m/s)", sv), ("position (m)", sp)) if math.isfinite(v)))
    if not base.rotation and rec.n == 1:
        warns.append("one agent (n = 1): the load's rotation is not observed; J, the contact geometry and "
                     "rotational_damping are not identifiable from these data")  # fmt: skip
    if not all(base.axes):
        warns.append(f"axis {'y' if base.axes[0] else 'x'}: no force and no motion: left out of the model "
                     "(its components of force_bias and velocity_bias are not identifiable)")  # fmt: skip
    cands = [c for c in opt.candidates if (c not in ("rotational_damping", "torque_bias", "force_sensor_offset",
                                                     "sensor_offset_body")
                                           or base.rotation)
             and (c != "velocity_bias" or rec.vel is not None) and (c not in PER_AGENT or rec.n >= 2)
             and (c not in PLANAR or (base.rotation and all(base.axes)))]  # fmt: skip
    say("nominal model: fitting")
    nominal = fit_robust(pb, base, g0, x0)
    modes0 = residual_modes(pb, nominal)
    p_white0 = whiteness(pb, nominal, opt, modes0)
    mj0 = nominal.mj()
    say(f"nominal: m {mj0['m']:.4g} kg, J {mj0['J']:.4g} kg m^2, residual {math.sqrt(nominal.sigma2):.3g} x noise "
        f"floor, whiteness p {p_white0:.3g}")  # fmt: skip

    scores0 = {c: score(pb, nominal, c) for c in cands}
    signatures = [{"signature": EFFECTS[c][1], "candidate": c, "corr": sc.corr, "bound": Z95 / math.sqrt(nominal.N),
                   "score_p": sc.p} for c, sc in scores0.items()]  # fmt: skip
    for c, sc in scores0.items():
        ref = _reference(c, mj0["m"], mj0["J"], dtm)
        if sc.collinear > 1 - 1e-6:
            why = (" (a constant velocity offset is the initial velocity of each window as long as no velocity-"
                   "dependent force is in the model)") if c == "velocity_bias" else ""  # fmt: skip
            warns.append(f"{c}: not identifiable from these data: its signature lies in the span of the nominal "
                         f"parameters{why}")  # fmt: skip
        elif sc.half_width > ref:
            warns.append(f"{c}: not excited enough: the data resolve it only to +-{sc.half_width:.3g} "
                         f"{EFFECTS[c][0]}, more than a realistic {ref:.3g} {EFFECTS[c][0]}")  # fmt: skip

    current = nominal
    remaining = [c for c in cands if scores0[c].collinear <= 1 - 1e-6]
    # a candidate in the span of the model's parameters may leave it once an effect is added (a velocity
    # offset is a window's start velocity until a velocity-dependent force makes it a force c b): it is tried
    # again then, as a twin that can make another candidate ambiguous but is never named itself (what it
    # adds is what the named effect's form happens to allow, not evidence of its own)
    hidden = [c for c in cands if c not in remaining]
    twins: list[str] = []
    accepted: list[str] = []
    ambiguous: list[list[str]] = []
    table: dict[str, dict[str, Any]] = {}
    scores = scores0
    init = {"viscous_friction": 0.0, "coulomb_friction": 0.0}
    while remaining and len(accepted) < opt.max_effects:
        # the input's timing is one test (its signs and shapes share one score, each sign's fit sees half of it)
        alpha_k = opt.alpha / len({"timing" if c in TIMING else c for c in remaining})
        # far above the noise floor the score test, linearised at a poor fit, can miss the effect that
        # made the fit poor and misrank the rest: every candidate left is then fitted
        screened = current.sigma2 <= opt.restart_misfit**2
        structured = screened and (p_white0 if current is nominal else whiteness(pb, current, opt)) <= opt.alpha_white
        if structured and all(scores[c].p >= alpha_k for c in remaining):
            # a structured residual that no score test points at: the fit may have absorbed the effect
            # elsewhere (viscous friction named first, J ten times too large for a rotational damping), where
            # the linearised test is blind to it; every candidate left is then fitted
            screened = False
        order = sorted(remaining, key=lambda c: (scores[c].logp, -scores[c].lm))
        ranked = [c for c in order if scores[c].p < alpha_k or not screened]
        blind: list[str] = []
        if structured and screened:
            # the same blindness with another candidate's score passing in its place (a constant torque's
            # score takes up the damping's structure but its fit does not qualify): the rest are fitted after
            # it, as unscreened ones are, only when none of those the scores point at qualifies
            blind = [c for c in order if c not in ranked]
            ranked += blind
        trials: dict[str, tuple[Fit, float]] = {}
        eligible: list[str] = []
        extra = 0  # fits beyond the rounds of max_fits: a force lag's second shape
        for j, c in enumerate(ranked):
            if screened and j and (j - extra) % opt.max_fits == 0 and eligible:
                if not (c in FORCE_LAG and trials.keys() & set(FORCE_LAG)):
                    break  # fit the next strongest only when none of these qualifies
                extra += 1  # a force lag's two shapes are fitted side by side: the better one goes on
            lay = current.lay.with_effects(current.lay.effects + (c,))
            say(f"candidate {c} ({j + 1}/{len(ranked)}) on top of {list(current.lay.effects) or 'nominal'}")
            g = expand(lay, current.g, current.lay, init)
            sl = lay.slot(c)
            g[sl] = np.maximum(scores[c].step, lay.lower()[sl])  # the score test's Gauss-Newton step
            f = lm_fit(pb, lay, g, current.x)
            if f.sigma2 > opt.restart_misfit**2 or not screened or c in blind:
                # the model without the candidate may have moved far to make up for it (a large J for a
                # strong damping), and a fit from there can stop halfway
                f = _or_restarted(pb, rec, f)
            F, pF = stats.nested_f(current.rss, f.rss, lay.G - current.lay.G, f.N, f.P)
            st = states_of(pb, f)
            wp = whiteness(pb, f, opt, theta=st[..., 3])
            val, ci = f.param(c)
            table[c] = {"name": c, "unit": EFFECTS[c][0], "value": _value(val, f.lay, c),
                        "ci95": _value(ci, f.lay, c, ci=True),
                        "F": F, "p": pF, "delta_bic": f.bic - current.bic, "whiteness_p": wp,
                        "on_top_of": list(current.lay.effects)}  # fmt: skip
            if wp <= opt.alpha_white and pF < alpha_k:
                # a drifting residual makes the F-test see structure everywhere: the effect must also stand
                # against the random walk that an unmeasured random force leaves (ident/random_force.py)
                rf = fit_random_force(pb, f, st, alpha=opt.alpha, lags=opt.lags, block=_block(pb, opt))
                if rf.present:
                    pR = robust_wald(f, c, robust_covariance(pb, f, rf, st[..., 3]))
                    table[c]["p_with_random_force"] = pR
                    pF = max(pF, pR)
            trials[c] = (f, pF)
            eligible = sorted((c for c, (f, pF) in trials.items() if pF < alpha_k and f.bic < current.bic),
                              key=lambda c: trials[c][0].bic)  # fmt: skip
        primary = [c for c in eligible if c not in twins]
        if not primary:
            break
        best = primary[0]
        fb_ = trials[best][0]
        for c2 in [c for c in eligible if c != best]:
            if c2 == best or c2 not in remaining or trials[c2][0].bic - fb_.bic >= opt.ambiguous_bic:
                continue
            lay2 = fb_.lay.with_effects(fb_.lay.effects + (c2,))
            say(f"telling {best} from {c2}: joint fit")
            joint = lm_fit(pb, lay2, expand(lay2, fb_.g, fb_.lay), fb_.x)
            q = lay2.G - fb_.lay.G
            p1 = stats.nested_f(fb_.rss, joint.rss, q, joint.N, joint.P)[1]
            p2 = stats.nested_f(trials[c2][0].rss, joint.rss, lay2.G - trials[c2][0].lay.G, joint.N, joint.P)[1]
            if (p1 >= alpha_k or p2 >= alpha_k) and {best, c2} == set(FORCE_LAG):
                # the same lag of the logged force in two shapes: the better named (the shapes compared at the end)
                remaining.remove(c2)
                continue
            if (p1 >= alpha_k or p2 >= alpha_k) and {best, c2} == set(SAME_FORCE):
                # a common sensor offset is a force bias plus its torque about the contacts' centroid: where the
                # data do not resolve that torque (the centroid near the centre of mass) they see the force alone
                warns.append(f"force_bias and force_sensor_offset: the data do not resolve the offset's torque about "
                             f"the contacts' centroid (BIC within {abs(trials[c2][0].bic - fb_.bic):.1f}): named "
                             "force_bias, the force they see (a common sensor offset reads -1/n of it per robot)")
                if best == "force_sensor_offset":
                    best, fb_ = c2, trials[c2][0]
                    remaining.remove("force_sensor_offset")
                else:
                    remaining.remove(c2)
                continue
            if p1 >= alpha_k or p2 >= alpha_k:
                ambiguous.append([best, c2])
                warns.append(f"{best} and {c2}: the data cannot separate them (BIC within "
                             f"{trials[c2][0].bic - fb_.bic:.1f}, neither adds to the other); "
                             "naming neither")  # fmt: skip
                remaining.remove(c2)
        accepted.append(best)
        remaining.remove(best)
        if MIRRORS.get(best) in remaining:  # one shift of the input: its other sign adds nothing beside it
            remaining.remove(MIRRORS[best])
        current = fb_
        if best in PER_AGENT:
            current = _regauge(pb, current, say)
        if len(accepted) < opt.max_effects:
            back = {c: score(pb, current, c) for c in hidden}
            back = {c: sc for c, sc in back.items() if sc.collinear <= 1 - 1e-6}
            if back:
                say(f"{', '.join(back)}: identifiable beside {best}: a candidate again")
                warns = [w for w in warns if not any(w.startswith(f"{c}: not identifiable") for c in back)]
            hidden = [c for c in hidden if c not in back]
            remaining += list(back)
            twins += list(back)
            scores = {c: score(pb, current, c) for c in remaining if c not in back} | back
    if "coulomb_friction" in accepted and fopt.coulomb_speed is None:
        pb, current = _coulomb_speed(pb, current, say)
        cs = pb.coulomb_speed
        # with the smoothing fitted, an effect that only stood in for a too-sharp one no longer adds
        current = _drop_idle(pb, current, [c for c in accepted if c != "coulomb_friction"], accepted, table,
                             opt.alpha, say, lambda c: "coulomb_friction with its smoothing fitted",
                             "stood in for the Coulomb term's smoothing")
    # forward selection adds one effect at a time: one that stood in for part of a later one (a force bias for
    # the force of a sensor offset named after it) no longer adds to the rest
    current = _drop_idle(pb, current, list(accepted) if len(accepted) > 1 else [], accepted, table, opt.alpha, say,
                         lambda c: ", ".join(e for e in accepted if e != c),
                         "adds nothing beside the effects named after it")
    current, shape = force_lag_shape(pb, current, accepted, opt.alpha, say)
    _enter(table, current, accepted)  # the force lag's shape kept at the end, not fitted in a round
    for c in _unresolved_effects(current, accepted):
        # the effect acts through a 1/m (1/J) the data do not resolve from zero: they see only its product
        # with 1/m, so its value is not determined and it is not named (it stays in the candidates' table)
        what = "m" if c in TRANSLATION else "J"
        inv, half = current.inverse(what)
        warns.append(f"{c}: passes its F-test, but it acts through 1/{what}, which the data do not resolve from zero "
                     f"(1/{what} {inv:.3g} +- {half:.2g}): its value is not determined; not named")
        table[c]["unresolved"] = f"1/{what} not resolved"
        current = _without(pb, current, c)[0]
        accepted.remove(c)
    st1 = states_of(pb, current)
    theta_w = st1[..., 3]
    modes1 = residual_modes(pb, current, theta=theta_w)
    white = whiteness(pb, current, opt, modes1, theta=theta_w)
    excess0 = nominal.rss - nominal.N
    share = (nominal.rss - current.rss) / excess0 if excess0 > 0 else 0.0
    if white <= opt.alpha_white and share < opt.explained:
        alt = _robot_offsets(pb, rec, nominal, current, accepted, cands, opt, say)
        if alt is not None:
            before = list(accepted)
            current, accepted = alt
            _enter(table, current, accepted)
            st1 = states_of(pb, current)
            theta_w = st1[..., 3]
            modes1 = residual_modes(pb, current, theta=theta_w)
            white = whiteness(pb, current, opt, modes1, theta=theta_w)
            share = (nominal.rss - current.rss) / excess0 if excess0 > 0 else 0.0
            warns.append(f"the selection's {', '.join(before)} left a structured residual; with its offsets replaced "
                         "by force_bias and force_sensor_offset together the model is "
                         f"{', '.join(accepted)} (force offsets of each robot's own give the load a sum and a moment "
                         "that turns with it: four parameters, which the selection, adding one effect at a time, "
                         "took in other forms)")
    ambiguous_names = {c for pair in ambiguous for c in pair}
    friction_shape = None  # a named friction whose leftover depends on the speed
    walk = None if white > opt.alpha_white or pb.win.vel is None else significant_walk(
        pb, current, st1, alpha=opt.alpha, lags=opt.lags, block=_block(pb, opt))
    walk_white = walk is not None and walk.p_white > opt.alpha_white and walk.p_motion > opt.alpha_white
    # a walk fits part of any slow structure: it is reported only where it is all that is left
    walk_info = walk_values(walk, pb, current, dtm) if walk_white else None
    if walk_info is not None:
        warns.append(walk_warning(walk_info, walk))
    if accepted and (white > opt.alpha_white or share >= opt.explained or walk_white):
        unexplained = False
        named = [c for c in accepted if c not in ambiguous_names]
        final = current
        if white <= opt.alpha_white and not walk_white:
            # a share above 1 is a residual brought below the floor: its structure is at the noise's level
            removed = (f"{100 * share:.1f} % of the nominal model's excess residual: named; dynamics outside the "
                       "vocabulary remain" if share <= 1.0 else "all of the nominal model's excess residual: named; "
                       "what structure remains is at the noise's level (the sensors', or dynamics outside the "
                       "vocabulary)")
            warns.append(f"the residual with {', '.join(accepted)} is not white (Ljung-Box p {white:.2g}, "
                         f"{math.sqrt(current.sigma2):.3g} x the noise floor), but the effects remove {removed}")
            friction = [c for c in accepted if c in FRICTIONS]
            if friction and walk is not None and walk.p_motion <= opt.alpha_white:
                # the leftover force follows the speed: the friction named has the wrong shape, which the other
                # parameters absorb (a Stribeck friction read as Coulomb pulls m off by several of its
                # intervals); the values are that model's, as a rejected model's are
                friction_shape = {"p": walk.p_motion, "friction": friction}
                warns.append(f"{', '.join(friction)}: the friction's shape is outside the vocabulary: what the "
                             f"model leaves depends on the speed (p {walk.p_motion:.2g}; a friction stronger at "
                             "low speed, Stribeck or static friction, leaves this). m, J, the friction and their "
                             "95 % intervals are this model's, which the data reject: they hold only as far as "
                             "it does")
    elif not accepted and (white > opt.alpha_white or walk_white):
        unexplained, named, final = False, [], nominal
    else:
        unexplained, named, final = True, [], nominal
        # with nothing accepted every candidate was fitted and rejected: there is no share to report
        tried = (f"with {', '.join(accepted)} added, explaining {100 * share:.0f} % of the excess" if accepted else
                 "with no candidate kept")
        warns.append(f"unexplained: a structured residual remains (Ljung-Box p {white:.2g} {tried}; nominal p "
                     f"{p_white0:.2g}); no candidate effect "
                     f"explains it, so none is named; m, J and their 95 % intervals are the nominal model's, which "
                     f"the data reject: they hold only as far as that model does")  # fmt: skip
    if walk_white and final is current:
        final.cov = robust_covariance(pb, final, walk, theta_w)  # the ci95 reported include the walk
    for c in table:
        table[c]["accepted"] = c in named
    # a non-negative candidate the reported model would take below its bound 0 (its score test's step points
    # there, at the selection's level over the candidates left out): held at 0, the data point at the other sign.
    # Only on a white residual: a structured one (a real machine's misfit, a velocity noise filtered otherwise
    # than the whitening models) makes every score test's p far too small
    out = [c for c in cands if c not in final.lay.effects] if (white if final is current else p_white0) > \
        opt.alpha_white else []
    level = opt.alpha / max(len({"timing" if c in TIMING else c for c in out}), 1)
    for c in out:
        if c in NONNEGATIVE and not (c in TIMING and set(TIMING) & set(named)):
            sc = score(pb, final, c)
            if sc.step[0] < 0 and sc.p < level:
                warns.append(at_bound(c, sc.p))
                if c in table:
                    table[c]["at_bound_p"] = sc.p
    effects = []
    retimed: dict[str, float] = {}  # the velocity floor re-read with the clock offsets named
    for c in named:
        val, ci = final.param(c)
        effects.append({"name": c, "value": _value(val, final.lay, c), "unit": EFFECTS[c][0],
                        "ci95": _value(ci, final.lay, c, ci=True)})  # fmt: skip
        if c in PLANAR:
            effects[-1]["principal"] = _principal(val, final.param("viscous_friction")[0][0]
                                                  if "viscous_friction" in named else 0.0)
        if c in TIMING:
            warns.append(lag_text(c, float(val[0]), float(ci[0]), shape))
        if c in PER_AGENT:
            effects[-1]["reference"] = final.lay.ref
            effects[-1]["agents"] = _agents_off(effects[-1]["value"], effects[-1]["ci95"], c)
            if c == "agent_clock_offset" and rec.vel is not None and math.isfinite(sv):
                sv2 = noise_floor(_retimed(rec, np.asarray(effects[-1]["value"])))[0]
                retimed["velocity_retimed"] = sv2
                warns.append(f"agent_clock_offset: the noise floor ({sv:.3g} m/s) is read from the agents' relative "
                             f"velocities at common stamps, where an agent's offset counts as noise; with each "
                             f"agent's velocities re-timed by its offset it reads {sv2:.3g} m/s, and the residual "
                             f"is {final.over_floor * sv / sv2:.3g} x that")  # fmt: skip

    def report(f: Fit, pw: float, modes: np.ndarray) -> ModelReport:
        say(f"held-out error of {list(f.lay.effects) or 'nominal'}: fitting the first {1 - opt.holdout:.0%}")
        tcut = rec.t[0] + (1 - opt.holdout) * (rec.t[-1] - rec.t[0])
        head = np.flatnonzero(pb.t0 < tcut)
        tail = np.flatnonzero(pb.t0 >= tcut)
        held = math.nan
        if head.size >= 2 and tail.size >= 1:
            ph, pt = subset(pb, head), subset(pb, tail)
            fh = lm_fit(ph, f.lay, f.g, f.x[head], max_iter=10)
            xt = refit_states(pt, f.lay, fh.g, f.x[tail])
            res_t = pt.residual(fh.g[None], xt[None], f.lay)[0][0]
            held = next(iter(_rms(pt, res_t).values()))
        mj = f.mj()
        rms = _rms(pb, f.res)
        zc = tuple(f.g[: 2 * rec.n].reshape(rec.n, 2).mean(axis=0).tolist()) if f.lay.rotation else (math.nan, math.nan)
        rep = ModelReport(f.lay.effects, mj["m"], mj["m_ci95"], mj["J"], mj["J_ci95"], zc,
                          next(iter(rms.values())), pw, held, f.bic, residual_rms_pos=rms.get("pos"),
                          residual_over_floor=f.over_floor, modes=modes)  # fmt: skip
        if rec.truth:
            rep.m_rel_err = mj["m"] / rec.truth["m"] - 1
            rep.J_rel_err = mj["J"] / rec.truth["J"] - 1 if base.rotation else None
        return rep

    floors = {**{f"{k}_per_agent": v for k, v in per_agent.items()}, **retimed}
    if corr is not None:
        floors["velocity_correlation"] = corr
    # 1/m and 1/J are the fitted parameters: one not above its own 95 % half-width leaves m (J) unresolved
    # (a load that hardly moves under the applied force: friction holds it, or the push is too weak)
    resolved = {"m": False, "J": False}
    for name, on in (("m", True), ("J", base.rotation)):
        if not on:
            continue
        resolved[name] = _resolved(final, name)
        if not resolved[name]:
            inv, half = final.inverse(name)
            what = ("translation", "force", "kg") if name == "m" else ("rotation", "torque", "kg m^2")
            over = final.over_floor
            why = (f"the {what[0]} hardly answers the applied {what[1]} (friction holding the load, or too weak a "
                   "push)") if over < 2.0 else f"the model does not fit these data (residual {over:.3g} x the floor)"
            warns.append(f"{name} not resolved: the fit's 1/{name} is {inv:.3g} +- {half:.2g} 1/{what[2]} (95 %), not "
                         f"above zero: {why}")
    nominal_rep = report(nominal, p_white0, modes0)
    aug_rep = nominal_rep if final is nominal else report(final, white, modes1)
    block = _block(pb, opt)
    return Diagnosis(
        nominal=nominal_rep, augmented=aug_rep, effects=effects, unexplained=unexplained, warnings=warns,
        candidates=list(table.values()), signatures=signatures, ambiguous=ambiguous,
        noise_sigma=sv if math.isfinite(sv) else sp, wall_s=clock() - t_start if clock is not None else 0.0,
        truth=rec.truth, block_s=block * dtm, lags=opt.lags, noise_floor={"velocity": sv, "position": sp, **floors},
        identifiable={"m": resolved["m"], "J": resolved["J"], "geometry": base.rotation},
        model={"hold": rec.hold, "window_s": wlen, "coulomb_speed": cs, "integrator": "RK4",
               "max_step": pb.max_step,
               **({"friction_shape_outside": friction_shape} if friction_shape else {})},  # fmt: skip
        # the effects kept but not named on a structured residual: the offsets' drift check reads them
        fits={"nominal": nominal, "augmented": final} | ({"rejected": current} if unexplained and accepted else {}),
        problem=pb,
        random_force=walk_info if final is current else None,
    )  # fmt: skip


SAME_FORCE = ("force_bias", "force_sensor_offset")
FRICTIONS = ("viscous_friction", "anisotropic_friction", "coulomb_friction", "rotational_damping")
TRANSLATION = ("viscous_friction", "anisotropic_friction", "coulomb_friction", "force_bias", "force_sensor_offset",
               "sensor_offset_body")
ROTATION = ("rotational_damping", "torque_bias")


OFFSET_FORMS = ("force_bias", "force_sensor_offset", "sensor_offset_body", "torque_bias")
ROBOT_OFFSETS = SAME_FORCE  # the pair that spans per-robot offsets in the world frame


def _enter(table: dict, fit: Fit, accepted: list[str]) -> None:
    """The candidates' table entry of each effect of ``accepted`` that no round of the selection fitted (it came
    in at the end): its value and interval in ``fit``, on top of the other accepted effects."""
    for c in [c for c in accepted if c not in table]:
        val, ci = fit.param(c)
        table[c] = {"name": c, "unit": EFFECTS[c][0], "value": _value(val, fit.lay, c),
                    "ci95": _value(ci, fit.lay, c, ci=True), "on_top_of": [e for e in accepted if e != c]}


def _or_restarted(pb: Problem, rec: Recording, f: Fit) -> Fit:
    """``f``, or the same model fitted again from the kinematics' equation error (:func:`initial_guess`), whichever
    costs less: a fit started from another model's optimum can stop halfway."""
    try:
        g1, x1, _ = initial_guess(pb, rec, effects=f.lay.effects)
        f1 = lm_fit(pb, f.lay, g1, x1)
    except FitError:
        return f
    return f1 if f1.lin.cost < f.lin.cost else f


def _robot_offsets(pb: Problem, rec: Recording, nominal: Fit, fit: Fit, accepted: list[str], cands: list[str],
                   opt: DiagnoseOptions, say: Callable[[str], None]) -> tuple[Fit, list[str]] | None:
    """Per-robot force offsets in the world frame give the load their sum and a moment that turns with it:
    force_bias and force_sensor_offset together, four parameters. Forward selection adds one effect at a time
    and can take another offset's form first (sensor_offset_body under correlated velocity noise), leaving a
    structured residual. Where the selection's model holds an offset and is not explained, its offsets are
    replaced by the pair, the other effects that then add nothing at level ``opt.alpha`` (nested F-tests) are
    dropped, and the pair's model is returned with its effects when both of the pair add at that level, its
    BIC is the lower and its residual is white or explains ``opt.explained`` of the nominal model's excess;
    else None."""
    offs = [c for c in accepted if c in OFFSET_FORMS]
    if not offs or not pb.base.rotation or not set(ROBOT_OFFSETS) <= set(cands) or set(ROBOT_OFFSETS) <= set(offs):
        return None
    rest = [c for c in accepted if c not in OFFSET_FORMS]
    effs = rest + list(ROBOT_OFFSETS)
    lay = fit.lay.with_effects(tuple(effs))
    say(f"{', '.join(offs)}: refitted as per-robot force offsets (force_bias and force_sensor_offset)")
    alt = _or_restarted(pb, rec, lm_fit(pb, lay, expand(lay, fit.g, fit.lay), fit.x))
    for c in rest:  # an effect that stood in for the offsets' moment (a rotational damping) adds nothing now
        without, p = _without(pb, alt, c)
        if p >= opt.alpha:
            say(f"{c}: adds nothing beside the per-robot force offsets: dropped")
            alt, effs = without, [e for e in effs if e != c]
    if alt.bic >= fit.bic or any(_without(pb, alt, c)[1] >= opt.alpha for c in ROBOT_OFFSETS):
        return None
    excess0 = nominal.rss - nominal.N
    share = (nominal.rss - alt.rss) / excess0 if excess0 > 0 else 0.0
    if share < opt.explained and whiteness(pb, alt, opt) <= opt.alpha_white:
        return None
    return alt, effs


def _unresolved_effects(fit: Fit, accepted: list[str]) -> list[str]:
    """The accepted effects that act through a 1/m (translation's forces) or 1/J (rotation's torques) whose fitted
    value is not above its own 95 % half-width: the model sees only the effect times it."""
    out = []
    for group, name in ((TRANSLATION, "m"), (ROTATION, "J")):
        if name == "J" and not fit.lay.rotation:
            continue
        if not _resolved(fit, name):
            out += [c for c in accepted if c in group]
    return out


def _resolved(fit: Fit, name: str) -> bool:
    """Is the fitted 1/m (``name`` "m") or 1/J ("J") above its own 95 % half-width?"""
    inv, half = fit.inverse(name)
    return inv > half


def _without(pb: Problem, fit: Fit, name: str) -> tuple[Fit, float]:
    """``fit`` refitted without effect ``name``, and the nested F-test's p of what the effect adds."""
    lay = fit.lay.with_effects(tuple(e for e in fit.lay.effects if e != name))
    without = lm_fit(pb, lay, _drop(fit.g, fit.lay, name), fit.x)
    return without, stats.nested_f(without.rss, fit.rss, fit.lay.G - lay.G, fit.N, fit.P)[1]


def _drop_idle(pb: Problem, fit: Fit, cands: list[str], accepted: list[str], table: dict, alpha: float,
               say: Callable[[str], None], beside: Callable[[str], str], reason: str) -> Fit:
    """Each of ``cands`` refitted out of ``fit``: one whose F-test p is then at least ``alpha`` adds nothing
    beside the rest and is dropped from ``accepted`` (``reason`` in its ``table`` row). The fit without them."""
    for c in cands:
        without, p = _without(pb, fit, c)
        if p >= alpha:
            say(f"{c}: adds nothing beside {beside(c)}: dropped")
            accepted.remove(c)
            table[c]["dropped"] = reason
            fit = without
    return fit


def _drop(g: np.ndarray, lay: Layout, name: str) -> np.ndarray:
    """The global vector ``g`` of ``lay`` without effect ``name``'s slot."""
    keep = np.ones(g.size, bool)
    keep[lay.slot(name)] = False
    return g[keep]


def _coulomb_speed(pb: Problem, fit: Fit, say: Callable[[str], None], refine: int = 6) -> tuple[Problem, Fit]:
    """The Coulomb term's smoothing speed, fitted: the plant's is unknown (a tanh, a square root, a few cm/s
    or none), and one too sharp leaves a ramp near rest that viscous friction and a delay make up for.
    Doubled from the default while the residual falls, then a golden-section search on its logarithm
    within the last bracket (``refine`` fits)."""
    fits = {math.log(pb.coulomb_speed): (pb, fit)}

    def at(x: float) -> float:
        if x not in fits:
            near = fits[min(fits, key=lambda k: abs(k - x))][1]
            trial = replace(pb, coulomb_speed=math.exp(x))
            fits[x] = (trial, lm_fit(trial, fit.lay, near.g, near.x))
        return fits[x][1].rss

    x, step = math.log(pb.coulomb_speed), math.log(2.0)
    while at(x + step) < at(x) and x < math.log(pb.coulomb_speed) + 6 * step:
        x += step
    lo, hi = x - step, x + step
    gr = (math.sqrt(5.0) - 1.0) / 2.0
    c, d = hi - gr * (hi - lo), lo + gr * (hi - lo)
    for _ in range(refine):
        if at(c) < at(d):
            hi, d = d, c
            c = hi - gr * (hi - lo)
        else:
            lo, c = c, d
            d = lo + gr * (hi - lo)
    best = min(fits, key=lambda k: fits[k][1].rss)
    say(f"coulomb_friction: smoothing speed {math.exp(best):.3g} m/s")
    return fits[best]


def predict(diag: Diagnosis, rec: Recording, opt: DiagnoseOptions | None = None) -> dict[str, Any]:
    """Errors of the diagnosis' nominal and augmented models on another recording ``rec`` (same plant): the
    global parameters are kept, only each window's start state is fitted to ``rec``. The residual's
    whiteness and its ratio to the identification residual say whether ``rec`` holds something the models
    lack."""
    opt = opt or DiagnoseOptions()
    pb0 = diag.problem
    sv, sp = noise_floor(rec)
    tmp = make_problem(rec, pb0.sigma_v, pb0.sigma_p, opt.fit,
                       rotation=pb0.base.rotation)  # fmt: skip
    pb = replace(tmp, coulomb_speed=pb0.coulomb_speed, base=pb0.base, vel_ar=pb0.vel_ar)
    g_start, x_start, _ = initial_guess(pb, rec)
    out: dict[str, Any] = {"noise_floor": {"velocity": sv, "position": sp}}
    for key in ("nominal", "augmented"):
        f: Fit = diag.fits[key]
        x0 = x_start.copy()
        x = refit_states(pb, f.lay, f.g, x0, iters=4)
        res = pb.residual(f.g[None], x[None], f.lay)[0][0]
        rms = _rms(pb, res)
        fake = Fit(f.lay, f.g, x, f.cov, float((res * res).sum()), pb.N, res, 0)
        ident_rms = _rms(pb0, f.res)
        p = whiteness(pb, fake, opt)
        ch = next(iter(rms))
        out[key] = {"effects": list(f.lay.effects), "rms": rms[ch], "channel": ch, "whiteness_p": p,
                    "ratio_to_identification": rms[ch] / ident_rms[ch]}  # fmt: skip
    aug = out["augmented"]
    out["flagged"] = bool(aug["whiteness_p"] <= opt.alpha_white and aug["ratio_to_identification"] > 1.5)
    return out


__all__ = ["DiagnoseError", "DiagnoseOptions", "diagnose", "noise_floor", "predict", "residual_modes"]
