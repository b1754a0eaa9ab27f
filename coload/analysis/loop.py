"""``coload loop``'s comparison: which named effects the agents can estimate online, and the before/after
table, Markdown and figure of a loop (docs/loop.md).

Pure: the runs (:class:`coload.rundir.format.RunData` with their summaries), the diagnosis (its JSON dict,
``ident.report.Diagnosis.as_dict``) and the scenario are arguments; the command does the I/O.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, get_args

import numpy as np

from coload.analysis.metrics import last_finite
from coload.rundir.format import RunData
from config.agent_params import DynamicsSpec
from config.scenario import Scenario
from ident.model import EFFECTS


def _online_effects() -> tuple[str, ...]:
    # the names DynamicsSpec.estimate_effects accepts (tuple[Literal[...], ...]): what the agents' filters
    # can carry is declared once, in config
    literal = get_args(DynamicsSpec.model_fields["estimate_effects"].annotation)[0]
    return tuple(get_args(literal))


ONLINE_EFFECTS: tuple[str, ...] = _online_effects()
"""Effects of ``coload diagnose``'s vocabulary that the agents can estimate online (``dynamics.estimate_effects``)."""

ESTIMATE_COLUMN: dict[str, str] = {"viscous_friction": "b", "rotational_damping": "c", "coulomb_friction": "fc",
                                   "force_bias": "fb"}
"""The estimates.csv column that holds each online effect's value after the averaging consensus (a vector
effect's: the columns COLUMN_x, COLUMN_y); an online effect without one is reported as "not recorded"."""

MONITOR_TESTS = 5  # the innovation monitor's p-values per window: an alarm is any below alpha / 5
P_FLOOR = 1e-20  # the figure's lowest p-value


@dataclass(frozen=True)
class Plan:
    """What the loop does after the diagnosis: ``online`` (re-run with these in ``dynamics.estimate_effects``,
    in :data:`ONLINE_EFFECTS`' order) when ``rerun``, else ``reason`` says why not; ``offline`` the named
    effects the agents cannot estimate (the diagnosis's ``effects`` entries)."""

    online: tuple[str, ...]
    offline: tuple[dict[str, Any], ...]
    rerun: bool
    reason: str


def plan(diagnosis: dict[str, Any], before_effects: Sequence[str]) -> Plan:
    """Split the diagnosis's named effects into online-capable and offline-only and decide on the re-run.
    ``before_effects``: the before run's ``dynamics.estimate_effects``."""
    named = list(diagnosis.get("effects") or [])
    online = tuple(n for n in ONLINE_EFFECTS if n in {e["name"] for e in named})
    offline = tuple(e for e in named if e["name"] not in ONLINE_EFFECTS)
    if not named:
        if diagnosis.get("unexplained"):
            reason = ("the diagnosis found a structured residual that no candidate explains (unexplained): "
                      "nothing to estimate online, no re-run")
        else:
            reason = "the diagnosis named no effect (the nominal model fits the recording): no re-run"
        return Plan((), offline, False, reason)
    if not online:
        names = ", ".join(e["name"] for e in offline)
        return Plan((), offline, False, f"named {names}: outside the agents' online vocabulary "
                                        f"({', '.join(ONLINE_EFFECTS)}), offline only: no re-run")
    if set(online) == set(before_effects):
        return Plan(online, offline, False, f"the before run already estimates {', '.join(online)} online: no re-run")
    return Plan(online, offline, True, f"re-run with dynamics.estimate_effects = {list(online)}")


def plant_truth(scenario: Scenario) -> dict[str, float | list[float]]:
    """Each effect's true value in the simulated plant (``[plant]``; 0 where absent), in the diagnosis's
    names and units. The delay is the whole ticks the plant applies."""
    p = scenario.plant
    return {
        "viscous_friction": p.friction.viscous, "coulomb_friction": p.friction.coulomb,
        "rotational_damping": p.friction.rotational,
        "measurement_delay": round(p.sensor.delay / scenario.dt) * scenario.dt,
        "force_bias": [float(v) for v in p.external_force], "velocity_bias": [float(v) for v in p.sensor.velocity_bias],
    }  # fmt: skip


def _f(x: Any) -> float | None:
    """JSON-safe float (NaN, inf and None become None)."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def _team(run: RunData, col: str) -> float | None:
    """Mean over agents of each agent's last reported value of ``col``; None without one."""
    est = run.estimates
    if est is None or not est.has(col):
        return None
    last = last_finite(est.columns[col])[0]
    return _f(np.mean(last[np.isfinite(last)])) if np.isfinite(last).any() else None


def _vec_side(run: RunData, col: str, truth: Sequence[float] | None) -> tuple[list[float] | None, float | None]:
    """A vector effect's team value (the mean over agents of each component's last value) and the RMS over
    agents of |x_i - truth| / |truth|; None where not recorded."""
    est = run.estimates
    cols = (f"{col}_x", f"{col}_y")
    if est is None or not all(est.has(c) for c in cols):
        return None, None
    last = np.column_stack([last_finite(est.columns[c])[0] for c in cols])
    ok = np.isfinite(last).all(axis=1)
    if not ok.any():
        return None, None
    value = [float(v) for v in np.mean(last[ok], axis=0)]
    t = np.asarray(truth, float) if truth is not None else None
    if t is None or t.shape != (2,) or not np.hypot(*t) > 0 or not ok.all():
        return value, None
    return value, _f(np.sqrt(np.mean(np.sum((last - t) ** 2, axis=1)) / np.sum(t * t)))


def _rel_rms(run: RunData, col: str, truth: float) -> float | None:
    """RMS over agents of the final (x_i - truth) / truth (summary.json's ``b_rel``, ``c_rel`` form)."""
    est = run.estimates
    if est is None or not est.has(col) or not truth > 0:
        return None
    last = last_finite(est.columns[col])[0]
    return _f(np.sqrt(np.mean(((last - truth) / truth) ** 2))) if np.isfinite(last).all() else None


def monitor_windows(run: RunData) -> tuple[np.ndarray, np.ndarray]:
    """The innovation monitor's persistence p-value per completed window (every agent's), with the time
    it was first reported: the rows where an agent's ``mon_windows`` count rises. Empty without the columns."""
    est = run.estimates
    if est is None or not (est.has("mon_windows") and est.has("mon_p_white")):
        return np.zeros(0), np.zeros(0)
    t, p = [], []
    wins, pw = est.columns["mon_windows"], est.columns["mon_p_white"]
    for i in range(wins.shape[1]):
        w = np.where(np.isfinite(wins[:, i]), wins[:, i], 0.0)
        rose = np.flatnonzero(np.diff(w, prepend=0.0) > 0)
        t.extend(est.t[rose])
        p.extend(pw[rose, i])
    order = np.argsort(t, kind="stable")
    return np.asarray(t, dtype=float)[order], np.asarray(p, dtype=float)[order]


def run_side(run: RunData, summary: dict[str, Any], truth: dict[str, Any], effects: Sequence[str]) -> dict[str, Any]:
    """One run's row of the table: the team's m and J (mean of the agents' final estimates; errors as
    summary.json's ``m_rel``, ``J_rel``: RMS over agents), its online effects' values, the innovation
    monitor's counts and the Algorithm 1 finish time."""
    errors = summary.get("errors") or {}
    mon = summary.get("monitor") or {}
    _, p_white = monitor_windows(run)
    p_white = p_white[np.isfinite(p_white)]
    out: dict[str, Any] = {
        "engine": summary.get("engine"), "estimate_effects": list(effects),
        "m": _team(run, "m"), "m_rel": _f(errors.get("m_rel")),
        "J": _team(run, "J"), "J_rel": _f(errors.get("J_rel")),
        "finished_s": _f(errors.get("finished_s")),
        "filter_restarts": errors.get("filter_restarts"),
        "monitor": {"windows": mon.get("windows"), "alarms": mon.get("alarms"),
                    "alarm_rate": _f(mon["alarms"] / mon["windows"]) if mon.get("windows") else None,
                    "p_white_median": _f(np.median(p_white)) if p_white.size else None},
        "effects": {},
    }  # fmt: skip
    for name in effects:
        col = ESTIMATE_COLUMN.get(name)
        true = truth.get(name)
        if col and isinstance(true, list):  # a vector effect (force_bias): fb_x, fb_y
            value, rel = _vec_side(run, col, true)
        else:
            value = _team(run, col) if col else None
            rel = _rel_rms(run, col, true) if col and isinstance(true, (int, float)) else None
        out["effects"][name] = {"column": col, "value": value, "rel_err": rel}
    return out


def _offline_model(rep: dict[str, Any]) -> dict[str, Any]:
    keys = ("effects", "m", "J", "m_rel_err", "J_rel_err", "residual_rms", "residual_over_floor", "whiteness_p")
    return {k: rep.get(k) for k in keys}


def compare(*, source: dict[str, Any], diagnosis: dict[str, Any], the_plan: Plan, scenario: Scenario,
            before: dict[str, Any], after: dict[str, Any] | None, wall_s: dict[str, float]) -> dict[str, Any]:
    """loop.json: the input, the diagnosis's verdict, the plan, both runs' rows (:func:`run_side`), the
    offline residual before (nominal model) and after (with the named effects) on the before run's
    recording, the truth and the times."""
    truth = plant_truth(scenario)
    named = {e["name"]: e for e in diagnosis.get("effects") or []}
    effects = []
    for name in sorted(set(named) | set(before["effects"]) | set((after or {}).get("effects", {})),
                       key=lambda n: list(truth).index(n) if n in truth else len(truth)):
        e = named.get(name, {})
        effects.append({
            "name": name, "unit": e.get("unit") or (EFFECTS[name][0] if name in EFFECTS else None),
            "truth": truth.get(name),
            "named": name in named, "online": name in ONLINE_EFFECTS,
            "offline": e.get("value"), "offline_ci95": e.get("ci95"),
            "before": before["effects"].get(name), "after": (after or {}).get("effects", {}).get(name),
        })  # fmt: skip
    return {
        "input": source,
        "diagnosis": {"file": "diagnosis.json", "named": list(named), "unexplained": bool(diagnosis.get("unexplained")),
                      "ambiguous": diagnosis.get("ambiguous") or [], "warnings": diagnosis.get("warnings") or []},
        "online": list(the_plan.online), "offline_only": [e["name"] for e in the_plan.offline],
        "rerun": the_plan.rerun, "reason": the_plan.reason,
        "truth": {"m": _f(scenario.load.mass), "J": _f(scenario.load.inertia), **truth},
        "before": before, "after": after, "effects": effects,
        "residual_offline": {"before": _offline_model(diagnosis.get("nominal") or {}),
                             "after": _offline_model(diagnosis.get("augmented") or {})},
        "wall_s": wall_s,
    }  # fmt: skip


# --- Markdown ----------------------------------------------------------------------------------------------
def _num(x: Any, spec: str = ".4g") -> str:
    if x is None:
        return "-"
    if isinstance(x, (list, tuple)):
        return "[" + ", ".join(_num(v, spec) for v in x) + "]"
    return format(float(x), spec)


def _pct(x: Any, signed: bool = False) -> str:
    return "-" if x is None else f"{100 * float(x):{'+' if signed else ''}.3g} %"


def _off(value: Any, rel: Any = None) -> str:
    return f"{_num(value)} ({_pct(rel)} off)" if rel is not None else _num(value)


def _mon(side: dict[str, Any]) -> str:
    m = side["monitor"]
    if not m.get("windows"):
        return "-"
    return (f"{m['alarms']} / {m['windows']} windows alarm ({_pct(m['alarm_rate'])}), "
            f"median whiteness p {_num(m['p_white_median'], '.2g')}")


def markdown(loop: dict[str, Any]) -> str:
    """loop.md: what ran, the verdict, and one before/after table."""
    src, before, after = loop["input"], loop["before"], loop["after"]
    head = [f"# coload loop: {src['scenario']}, seed {src['seed']} ({src['engine']})", "",
            f"- before: `{src['before_dir']}` ({'run by the loop' if src['kind'] == 'scenario' else 'given'}; "
            f"`dynamics.estimate_effects` = {before['estimate_effects'] or 'none'})",
            f"- offline diagnosis of before (`diagnosis.json`): named {', '.join(loop['diagnosis']['named']) or 'none'}"
            + ("; **unexplained**" if loop["diagnosis"]["unexplained"] else "")
            + (f"; not separable: {loop['diagnosis']['ambiguous']}" if loop["diagnosis"]["ambiguous"] else ""),
            f"- online: {', '.join(loop['online']) or 'none'}; offline only: {', '.join(loop['offline_only']) or 'none'}",
            f"- {'after: `after` (same scenario and seed), ' if loop['rerun'] else ''}{loop['reason']}", ""]
    truth, res = loop["truth"], loop["residual_offline"]
    rows = ["| quantity | truth | before: agents | offline diagnosis of before: nominal -> with the named effects "
            "| after: agents |", "|---|---|---|---|---|"]
    aft = after or {}
    no_after = "(no re-run)"
    for q, unit in (("m", "kg"), ("J", "kg m^2")):
        offline = (f"{_num(res['before'][q])} ({_pct(res['before'][f'{q}_rel_err'], True)}) -> "
                   f"{_num(res['after'][q])} ({_pct(res['after'][f'{q}_rel_err'], True)})")
        rows.append(f"| {q} ({unit}) | {_num(truth[q])} | {_off(before[q], before[f'{q}_rel'])} | {offline} | "
                    f"{_off(aft.get(q), aft.get(f'{q}_rel')) if after else no_after} |")
    for e in loop["effects"]:
        unit = f" ({e['unit']})" if e["unit"] else ""
        offline = (f"{_num(e['offline'])} +- {_num(e['offline_ci95'], '.2g')}" if e["named"] else "not named")
        if not e["online"]:
            offline += ", offline only"

        def agents(side: dict[str, Any] | None, missing: str) -> str:
            if side is None:
                return missing
            return _off(side["value"], side["rel_err"]) if side["value"] is not None else "not recorded"

        rows.append(f"| {e['name']}{unit} | {_num(e['truth'])} | {agents(e['before'], 'not estimated')} | {offline} | "
                    f"{agents(e['after'], 'not estimated' if after else no_after)} |")
    rb, ra = res["before"], res["after"]
    rows.append(f"| residual (x noise floor), Ljung-Box p | 1, p > 0.01 | - | "
                f"{_num(rb['residual_over_floor'])}, p {_num(rb['whiteness_p'], '.2g')} -> "
                f"{_num(ra['residual_over_floor'])}, p {_num(ra['whiteness_p'], '.2g')} | - |")
    rows.append(f"| agents' innovation monitor | no alarm | {_mon(before)} | - | {_mon(after) if after else no_after} |")
    rows.append(f"| Algorithm 1 done at (s) | - | {_num(before['finished_s'])} | - | "
                f"{_num(aft.get('finished_s')) if after else no_after} |")
    w = loop["wall_s"]
    tail = ["", "Errors: m, J of the agents are the RMS over agents of the final relative error (summary.json's "
            "`m_rel`, `J_rel`); values are the mean over agents of the final estimates. Offline: the diagnosis's "
            "fit of the before run's recording (signed errors against truth). Monitor: windows of every agent "
            "(docs/innovation-monitor.md).", "",
            "Wall time: " + ", ".join(f"{k.replace('_', ' ')} {v:.1f} s" for k, v in w.items()), ""]
    return "\n".join(head + rows + tail)


# --- figure ------------------------------------------------------------------------------------------------
def final_per_agent(run: RunData, col: str, truth_col: str) -> tuple[np.ndarray, float | None]:
    """Each agent's |x_i - x| / x of its last reported ``col`` against the truth at that time (NaN for an
    agent without one), and the first time any agent reported it (the end of its stage)."""
    est, tr = run.estimates, run.truth
    if est is None or tr is None or not est.has(col) or truth_col not in tr.columns:
        return np.zeros(0), None
    true = tr.columns[truth_col][run.truth_index(est.t)]
    rel = np.abs(est.columns[col] - true[:, None]) / true[:, None]
    seen = np.isfinite(rel).any(axis=1)
    return last_finite(rel)[0], (float(est.t[np.argmax(seen)]) if seen.any() else None)


def draw_loop(fig: Any, before: RunData, after: RunData | None, residual: dict[str, Any] | None,
              alpha: float, title: str = "") -> None:
    """The loop figure into ``fig``: each agent's final m and J relative error before (red) and after (blue)
    (the agents report m and J once their stage ends: a time axis would show one step); the agents'
    innovation monitor's whiteness p per window with its alarm level ``alpha`` / 5; the offline residual's
    autocorrelation (diagnosis ``residual`` panels) with the nominal and with the named effects, and the
    white-noise 95 % band. Axes labelled ``m``, ``J``, ``monitor``, ``acf``."""
    axes = fig.subplots(2, 2)
    runs = [("before", before, "tab:red")] + ([("after", after, "tab:blue")] if after is not None else [])
    for ax, (col, tcol) in zip(axes[0], (("m", "mass"), ("J", "inertia"))):
        ax.set_label(col)
        for k, (name, run, color) in enumerate(runs):
            rel, t0 = final_per_agent(run, col, tcol)
            if np.isfinite(rel).any():
                x = np.arange(len(rel)) + (0.12 if k else -0.12)
                when = f", reported from {t0:.1f} s" if t0 is not None else ""
                ax.semilogy(x, rel, "o", color=color, ms=5, label=f"{name}{when}")
        ax.axhline(0.01, color="k", ls=":", lw=0.7, label="1 %")
        ax.set_xlabel("agent")
        ax.set_ylabel(f"{col}: final |relative error|", fontsize=8)
        ax.legend(fontsize=8)
    ax = axes[1, 0]
    ax.set_label("monitor")
    for name, run, color in runs:
        t, p = monitor_windows(run)
        if t.size:
            # p underflows to 0 on a badly wrong model: drawn at the panel's floor
            ax.semilogy(t, np.clip(p, P_FLOOR, 1.0), "o", ms=3, color=color, alpha=0.6, label=name)
    ax.axhline(alpha / MONITOR_TESTS, color="k", ls="--", lw=0.8, label=f"alarm level {alpha}/{MONITOR_TESTS}")
    ax.set_xlabel("t (s)")
    ax.set_ylim(P_FLOOR / 3, 3.0)
    ax.set_ylabel(f"innovation monitor: whiteness p per window (floor {P_FLOOR:g})", fontsize=8)
    ax.legend(fontsize=8)
    ax = axes[1, 1]
    ax.set_label("acf")
    if residual is not None:
        lags = int(residual["lags"])
        lag_t = np.arange(1, lags + 1) * float(residual["block_s"])
        styles = ("-", "--", ":")
        for key, color in (("nominal", "tab:red"), ("augmented", "tab:blue")):
            m = residual[key]
            for j, mode in enumerate(residual["modes"]):
                acf = np.array([np.nan if v is None else v for v in m["acf"][j]], dtype=float)
                who = ", ".join(m["effects"]) or "nominal"
                ax.plot(lag_t, acf, styles[j % 3], marker="o", ms=2, color=color, lw=0.8, label=f"{who}: {mode}")
        b = max(residual["bound"])
        ax.axhspan(-b, b, color="0.85", zorder=0, label="white 95 %")
        ax.set_xlabel("lag (s)")
        ax.set_ylabel("offline residual of before: autocorrelation", fontsize=8)
        ax.legend(fontsize=6)
    if title:
        fig.suptitle(title, fontsize=10)
