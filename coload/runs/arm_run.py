"""``coload arms run``: paper-000 agents that are two-link arms, against velocity-measuring agents.

Two in-process runs on the same load, seed, arms, motion plan and link model:

* ``observer``: each agent reads joint encoders (+ noise) and its wrist force sensor (+ noise); its
  paper-004 speed observer gives the joint speeds and the Jacobian the contact velocity that goes
  into the unchanged ``AgentCore.step`` (agents/arm.py);
* ``velocity``: the same arms, but each agent measures its contact-point velocity directly with the
  plant's sensor (true velocity + N(0, noise.sigma_v^2)), as in every other coload run.

Both write an ordinary run directory (``samples.csv`` holds the velocity the agent used and the
wrist force it applied, tau = 0: a pivot passes no torque), plus ``arms.csv`` (per recorded tick and
agent: observer estimates next to the truth) and an ``arms`` block in summary.json. The comparison
(``comparison.json``, ``comparison.png``, a printed table) puts side by side: each agent's contact-speed
error, the kinematic estimates of paper 000 (z_ij via EERD, z_i, omega) and, from each run's
samples.csv, the centralized batch fit's m and J (the agents' own dynamical phase is not in AgentCore yet).

Messages between agents go through the link model of ``net/link.py`` exactly as in
``coload.runs.engine.run_inproc`` (its ``LinkNetwork``: a DelayLine per receiver).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from agents.arm import ArmFrontEnd, MotionPlan, Tracking, make_observer
from agents.factory import build_agent
from coload.analysis.summary import complete_summary
from coload.rundir.recorder import Recorder
from coload.runs.engine import LinkNetwork, base_summary
from config.scenario import Scenario
from net.vocabulary import ESTIMATE_NAMES
from simulator.arms import ArmPlant
from simulator.plant import sensor_rng

Progress = Callable[[int, int], None]
SENSINGS = ("observer", "velocity")
ARMS_CSV = "arms.csv"
ARMS_HEADER = ["t", "agent", "vx_hat", "vy_hat", "vx_true", "vy_true", "qd1_hat", "qd2_hat", "qd1", "qd2", "r",
               "fx", "fy", "track_err"]
_ARM_STREAM = 0x41524D53  # "ARMS": encoder and force-sensor noise, independent of the velocity-sensor stream
SETTLE_S = 1.0  # contact-speed error statistics "after settling" use t >= this (s)
SETTLE_FRACTION = 0.05  # settle time: |error| stays below this fraction of its initial value


def arm_rng(seed: int) -> np.random.Generator:
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence(seed, spawn_key=(_ARM_STREAM,))))


def agent_scenario(scenario: Scenario, sensing: str) -> Scenario:
    """The scenario the AgentCores are built from: arm agents assume the observer's error level."""
    if sensing != "observer":
        return scenario
    assert scenario.arms is not None
    est = scenario.estimator.model_copy(update={"sigma_v": scenario.arms.sigma_v_assumed})
    return scenario.model_copy(update={"estimator": est})


def speed_error_stats(t: np.ndarray, err: np.ndarray) -> dict[str, Any]:
    """Per-agent statistics of the contact-speed error norm ``err`` (T, n) sampled at times ``t``."""
    after = t >= SETTLE_S
    out: dict[str, Any] = {"rms_after": [], "max_after": [], "initial": [], "settle_s": []}
    for i in range(err.shape[1]):
        e = err[:, i]
        out["rms_after"].append(float(np.sqrt(np.mean(e[after] ** 2))) if after.any() else None)
        out["max_after"].append(float(e[after].max()) if after.any() else None)
        e0 = float(e[0])
        out["initial"].append(e0)
        settle = None
        if e0 > 0:
            above = np.flatnonzero(e >= SETTLE_FRACTION * e0)
            if len(above) == 0:
                settle = float(t[0])
            elif above[-1] < len(e) - 1:
                settle = float(t[above[-1] + 1])
        out["settle_s"].append(settle)
    return out


def run_arms(scenario: Scenario, run_dir: Path | None, sensing: str = "observer",
             progress: Progress | None = None) -> dict[str, Any]:
    """One arm run (see the module docstring); writes ``run_dir`` when given and returns the summary."""
    if sensing not in SENSINGS:
        raise ValueError(f"sensing must be one of {SENSINGS}, got {sensing!r}")
    spec = scenario.arms
    if spec is None:
        raise ValueError("arms: the scenario has no [arms] section (see config/scenarios/arms-rocking.toml)")
    if scenario.mode != "lockstep":
        raise ValueError("mode: arm runs are lockstep only")
    n, dt, ticks = scenario.n, scenario.dt, scenario.ticks
    ap = ArmPlant(scenario)
    plant = ap.plant
    vel_rng = sensor_rng(scenario.seed)
    noise_rng = arm_rng(scenario.seed)
    agents = [build_agent(agent_scenario(scenario, sensing).agent_view(i)) for i in range(n)]

    q_true = ap.angles()
    q_meas = q_true + noise_rng.normal(0.0, spec.encoder_sigma, size=(n, 2))
    contacts0 = np.array([ap.bases[i] + ap.model.tip(q_meas[i]) for i in range(n)])
    mo = spec.motion
    # the rotation centre every arm agrees on: the contacts' centroid at start-up (in a lab, one
    # average consensus over the graph; here the engine computes it from the agents' own encoders)
    plan = MotionPlan(tuple(contacts0.mean(axis=0)), mo.amplitude, mo.period, mo.ramp, mo.shift, mo.shift_period, mo.shift_angle)
    tracking = Tracking(mo.kp, mo.kd)
    ob = spec.observer
    fronts = []
    for i in range(n):
        observer = None
        if sensing == "observer":
            observer = make_observer(ap.model, ob.k1, ob.k2, ob.k3, ob.c_r, ob.nodes, seed=scenario.seed + i)
        fronts.append(ArmFrontEnd(ap.model, ap.bases[i], plan, tracking, dt, q_meas[i], observer,
                                  x0_hat=ob.initial_error if observer is not None else (0.0, 0.0),
                                  r0=ob.r0, substeps=ob.substeps))

    net = LinkNetwork(scenario, "lockstep")
    rec = Recorder(run_dir, scenario, ESTIMATE_NAMES) if run_dir is not None else None
    arms_rows: list[str] = []

    err = np.zeros((ticks, n))  # |sensed - true| contact velocity per tick and agent (m/s)
    track = np.zeros((ticks, n))  # |p_ref - p| grasp-point tracking error (m)
    f_meas = np.zeros((n, 2))  # wrist force over the previous interval (none before the first step)
    wall0 = time.perf_counter()
    report_every = max(1, ticks // 100)
    for k in range(ticks):
        v_true = np.asarray(plant.velocities())
        if k > 0:
            q_true = ap.angles()
            q_meas = q_true + noise_rng.normal(0.0, spec.encoder_sigma, size=(n, 2))
        if sensing == "observer":
            if k == 0:
                v = np.array([ap.model.jacobian(q_meas[i]) @ fronts[i].x_hat for i in range(n)])
            else:
                v = np.array([fronts[i].sense(q_meas[i], f_meas[i])[0] for i in range(n)])
        else:
            v = np.asarray(plant.measure(vel_rng))
        err[k] = np.hypot(*(v - v_true).T)
        keep = rec is not None and rec.keeps(k)
        if keep:
            rec.truth(plant.truth())  # type: ignore[union-attr]
        u = np.zeros((n, 2))
        for i in range(n):
            res = agents[i].step(k, float(v[i, 0]), float(v[i, 1]), net.pops[i](k))
            w = res.wrench
            net.send(i, k, res.state)
            u[i], _ = fronts[i].command(k, q_meas[i], v[i], (w.fx, w.fy))
            p = ap.bases[i] + ap.model.tip(q_meas[i])
            track[k, i] = float(np.hypot(*(plan.reference(k * dt, fronts[i].p0)[0] - p)))
            if keep:
                rec.estimate(res.estimate)  # type: ignore[union-attr]
        ap.step(u)
        f_meas = ap.forces + noise_rng.normal(0.0, spec.force_sigma, size=(n, 2))
        if rec is not None:
            rec.samples(k, [tuple(x) for x in v.tolist()], [(float(fx), float(fy), 0.0) for fx, fy in f_meas])
            if keep:
                qd = ap.joint_speeds()  # after the step; the row is about tick k, close enough for plots
                for i in range(n):
                    fe = fronts[i]
                    xh = fe.x_hat if sensing == "observer" else (math.nan, math.nan)
                    r = fe.state.r if fe.state is not None else math.nan
                    arms_rows.append(",".join(repr(float(x)) for x in (
                        k * dt, i, v[i, 0], v[i, 1], v_true[i, 0], v_true[i, 1], xh[0], xh[1], qd[i, 0], qd[i, 1], r,
                        f_meas[i, 0], f_meas[i, 1], track[k, i])))
        if progress is not None and (k % report_every == 0 or k == ticks - 1):
            progress(k + 1, ticks)
    wall = time.perf_counter() - wall0
    t = np.arange(ticks) * dt
    arms_summary: dict[str, Any] = {
        "sensing": sensing,
        "contact_speed_error": speed_error_stats(t, err),
        "tracking_rms_m": float(np.sqrt(np.mean(track[t >= SETTLE_S] ** 2))) if ticks * dt > SETTLE_S else None,
        "bases": ap.bases.tolist(),
        "plan_centre": list(plan.centre),
        "sigma_v_agents": agents[0].sigma_v,
    }
    summary = base_summary("arms-inproc", scenario, "lockstep", ticks, wall, net.close(ticks))
    summary["arms"] = arms_summary
    if rec is not None:
        assert run_dir is not None
        (Path(run_dir) / ARMS_CSV).write_text(",".join(ARMS_HEADER) + "\n" + "\n".join(arms_rows) + "\n", encoding="utf-8")
        summary = complete_summary(run_dir, scenario, rec.close(summary))
    summary["_err_series"] = (t, err)  # for the comparison plot; dropped before anything is written
    return summary


# --------------------------------------------------------------------------------------------------
# comparison


def _batch(run_dir: Path) -> dict[str, Any]:
    """m and J from the centralized batch fit of the run's samples.csv, with relative errors."""
    from coload.analysis.yardstick import fit_run_dir
    from coload.rundir.format import read_run
    from ident.batch_fit import BatchFitError

    try:
        fit = fit_run_dir(run_dir)
    except (BatchFitError, ValueError, np.linalg.LinAlgError) as exc:
        return {"error": str(exc)}
    truth = read_run(run_dir).truth
    assert truth is not None
    m_true = float(truth.columns["mass"][0])
    j_true = float(truth.columns["inertia"][0])

    def rel(p, true):
        return None if not math.isfinite(p.raw) else (p.raw - true) / true

    return {"m": fit.m.raw, "m_ci95": fit.m.ci95, "m_rel": rel(fit.m, m_true), "J": fit.J.raw, "J_ci95": fit.J.ci95,
            "J_rel": rel(fit.J, j_true), "residual_rms": fit.residual_rms, "wall_s": fit.wall_s,
            "warnings": list(fit.warnings)}


def compare(out: Path, summaries: dict[str, dict[str, Any]], batch: dict[str, dict[str, Any]] | None) -> dict[str, Any]:
    """The comparison block: per sensing, contact-speed error and the paper-000 estimates' errors."""
    comp: dict[str, Any] = {"runs": {}}
    for sensing, s in summaries.items():
        e = s.get("errors", {})
        cse = s["arms"]["contact_speed_error"]
        comp["runs"][sensing] = {
            "dir": sensing,
            "contact_speed_rms_after": cse["rms_after"],
            "contact_speed_max_after": cse["max_after"],
            "contact_speed_settle_s": cse["settle_s"],
            "tracking_rms_m": s["arms"]["tracking_rms_m"],
            "eerd_ratio": e.get("eerd_ratio"),
            "eerd_converge_s": e.get("eerd_converge_s"),
            "zi_rms": e.get("zi_rms"),
            "omega_rms": e.get("omega_rms"),
            "wall_s": s["wall_s"],
            "batch_fit": (batch or {}).get(sensing),
        }
    return comp


def _f(x: Any, spec: str = ".3g") -> str:
    if x is None:
        return "-"
    if isinstance(x, float) and not math.isfinite(x):
        return "nan"
    return format(x, spec)


def comparison_table(comp: dict[str, Any]) -> str:
    runs = comp["runs"]
    names = list(runs)
    n = len(runs[names[0]]["contact_speed_rms_after"])
    lines = [f"contact-speed error |v_used - v_true| after {SETTLE_S:g} s (m/s), per agent:",
             f"{'agent':>6} " + " ".join(f"{nm + ' rms':>14} {nm + ' max':>14}" for nm in names)
             + f" {'observer settle (s)':>20}"]
    for i in range(n):
        row = f"{i:>6} " + " ".join(f"{_f(runs[nm]['contact_speed_rms_after'][i]):>14} "
                                    f"{_f(runs[nm]['contact_speed_max_after'][i]):>14}" for nm in names)
        settle = runs.get("observer", {}).get("contact_speed_settle_s", [None] * n)[i]
        lines.append(row + f" {_f(settle):>20}")
    lines.append("")
    lines.append("paper-000 estimates (final / last 20 s) and batch fit of samples.csv:")
    lines.append(f"{'quantity':<34}" + "".join(f"{nm:>16}" for nm in names))
    rows = [
        ("grasp tracking RMS (m)", lambda r: r["tracking_rms_m"]),
        ("EERD final / initial", lambda r: r["eerd_ratio"]),
        ("EERD < 1 % from (s)", lambda r: r["eerd_converge_s"]),
        ("z_i RMS (m)", lambda r: r["zi_rms"]),
        ("omega RMS, last 20 s (rad/s)", lambda r: r["omega_rms"]),
        ("batch fit m error (%)", lambda r: None if not r["batch_fit"] or r["batch_fit"].get("m_rel") is None
         else 100 * r["batch_fit"]["m_rel"]),
        ("batch fit J error (%)", lambda r: None if not r["batch_fit"] or r["batch_fit"].get("J_rel") is None
         else 100 * r["batch_fit"]["J_rel"]),
        ("wall time (s)", lambda r: r["wall_s"]),
    ]
    for label, get in rows:
        lines.append(f"{label:<34}" + "".join(f"{_f(get(runs[nm])):>16}" for nm in names))
    return "\n".join(lines)


def comparison_figure(out: Path, err_series: dict[str, tuple[np.ndarray, np.ndarray]]) -> Path:
    """comparison.png: contact-speed error, omega, EERD and z_i error of both runs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from coload.analysis.metrics import error_series
    from coload.rundir.format import read_run

    fig, axes = plt.subplots(2, 2, figsize=(13, 8.5), constrained_layout=True)
    colors = {"observer": "tab:blue", "velocity": "tab:orange"}
    ax = axes[0, 0]
    for name, (t, err) in err_series.items():
        ax.semilogy(t, np.sqrt(np.mean(err**2, axis=1)) + 1e-12, color=colors[name], lw=0.8,
                    label=f"{name}: RMS over agents")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("|v_used - v_true| (m/s)")
    ax.set_title("contact-point speed error")
    ax.legend(fontsize=8)
    for name in err_series:
        run = read_run(out / name)
        s = error_series(run)
        c = colors[name]
        if s.omega_hat is not None:
            axes[0, 1].plot(s.est_t, np.nanmean(s.omega_hat, axis=1), color=c, lw=0.9, label=f"{name}: mean omega_hat")
        if s.eerd is not None:
            axes[1, 0].semilogy(s.pair_t, s.eerd + 1e-16, color=c, lw=0.9, label=name)
        if s.zi_err is not None:
            axes[1, 1].plot(s.est_t, np.sqrt(np.nanmean(s.zi_err**2, axis=1)), color=c, lw=0.9, label=name)
        if name == "observer" and s.omega_true is not None:
            axes[0, 1].plot(s.est_t, s.omega_true, color="k", lw=0.7, ls="--", label="true omega")
    axes[0, 1].set(xlabel="t (s)", ylabel="rad/s", title="omega: truth and estimates (rocking motion)")
    axes[1, 0].set(xlabel="t (s)", ylabel="m^2", title="EERD (sum over edges |z_ij - z_ij_hat|^2)")
    axes[1, 1].set(xlabel="t (s)", ylabel="m", title="z_i error, RMS over agents")
    for a in (axes[0, 1], axes[1, 0], axes[1, 1]):
        a.legend(fontsize=8)
    path = out / "comparison.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def run_arms_cli(scenario: Scenario, out: Path, *, batch_fit: bool = True, quiet: bool = False,
                 sensings: tuple[str, ...] = SENSINGS) -> tuple[dict[str, Any], str]:
    """Both runs into ``out/observer`` and ``out/velocity``, then comparison.json/png; returns (comparison, table)."""
    from coload.runs.orchestrate import ProgressBar

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    summaries: dict[str, dict[str, Any]] = {}
    series: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for sensing in sensings:
        s = run_arms(scenario, out / sensing, sensing, progress=ProgressBar(f"{scenario.name} ({sensing})", quiet))
        series[sensing] = s.pop("_err_series")
        summaries[sensing] = s
    batch = {name: _batch(out / name) for name in sensings} if batch_fit else None
    comp = compare(out, summaries, batch)
    comp["scenario"] = scenario.name
    comp["seed"] = scenario.seed
    comp["png"] = str(comparison_figure(out, series).name)
    (out / "comparison.json").write_text(json.dumps(comp, indent=2) + "\n", encoding="utf-8")
    return comp, comparison_table(comp)


__all__ = ["ARMS_CSV", "SENSINGS", "compare", "comparison_table", "run_arms", "run_arms_cli", "speed_error_stats"]
