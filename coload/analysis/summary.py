"""Completes a finished run's summary.json with what is computed from its files: the error metrics,
the agents' estimate trust (docs/estimate-trust.md), their innovation monitors' counts
(docs/innovation-monitor.md), the online detection's switches (docs/online-detection.md) and the
centralized batch-fit yardstick (docs/run-directory.md, docs/batch-fit.md).

The recorder only records; every engine calls :func:`complete_summary` once the run directory is
closed.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from agents.rigid_filter import EFFECTS  # bit k of eff_on is the filter's effect k
from coload.analysis import yardstick
from coload.analysis.metrics import final_errors, last_finite
from coload.provenance import versions
from coload.rundir import format as fmt
from coload.rundir.recorder import write_summary
from config.scenario import Scenario


def complete_summary(
    run_dir: Path, scenario: Scenario, summary: dict[str, Any], held: fmt.RunData | None = None
) -> dict[str, Any]:
    """Adds ``errors`` (and, with ``record.batch_fit``, the centralized blocks) and ``versions`` to
    ``summary`` and rewrites summary.json. The tables are read from ``run_dir``, or are ``held`` (the
    recorder's, in memory: ``Recorder.held``). A run too short to score still keeps its summary, with the reason."""
    run = None
    try:
        run = fmt.read_run(run_dir) if held is None else held
        summary["errors"] = final_errors(run)
        trust = trust_block(run)
        if trust:
            summary["trust"] = trust
            for name, block in trust.items():
                if block["untrusted_agents"]:
                    summary.setdefault("warnings", []).append(
                        f"{name} untrusted at agents {block['untrusted_agents']}: fresh neighbour states down to "
                        f"{block['fresh_min']:.0%} in one of its stages (docs/estimate-trust.md)")
        monitor = monitor_block(run)
        if monitor:
            summary["monitor"] = monitor
        effects = effects_block(run)
        if effects:
            summary["effects"] = effects
            # every switch, withdrawal and ruling-out the team agreed online is an event of the run, beside
            # the partitions
            events = summary.get("events", []) + [
                {"tick": e["tick"], "t": e["tick"] * scenario.dt, "event": e["event"], "effect": e["effect"],
                 "statistic": e["statistic"], "agents": e["agents"]} for e in effects["events"] if e["tick"] >= 0]
            summary["events"] = sorted(events, key=lambda e: e["tick"])
    except (ValueError, OSError) as exc:
        summary["errors"] = {}
        summary.setdefault("warnings", []).append(f"errors not computed: {exc}")
    if scenario.record.batch_fit:
        summary.update(_centralized(run))
    summary["versions"] = versions()
    write_summary(Path(run_dir), summary)
    return summary


def _centralized(run: fmt.RunData | None) -> dict[str, Any]:
    """The batch-fit yardstick blocks (coload.analysis.yardstick.centralized_blocks); whatever goes wrong, the run
    still gets its summary, with null blocks and the reason."""
    try:
        if run is None:
            raise ValueError("the run directory could not be read")
        return yardstick.centralized_blocks(run)
    except Exception as exc:  # noqa: BLE001  the yardstick must never cost the run its summary
        reason = f"batch fit not run: {type(exc).__name__}: {exc}"
        return {"centralized": {**dict.fromkeys(yardstick.CENTRAL_KEYS), "flags": [], "reason": reason},
                "distributed_over_centralized": {**dict.fromkeys(yardstick.RATIO_KEYS), "reason": reason}}


def trust_block(run: fmt.RunData | None) -> dict[str, Any]:
    """The agents' final trust in their m and J estimates (the ``*_trusted``, ``*_fresh``, ``*_sd`` columns
    of estimates.csv, last row each agent reported): per estimate, whether every agent trusts it, the
    untrusted agents, the poorest fresh fraction and the largest sd. Empty for a run without those columns
    (an older run, a run without the dynamical phase) or before any agent judged."""
    est = None if run is None else run.estimates
    out: dict[str, Any] = {}
    if est is None or len(est.t) == 0:
        return out
    for name in ("m", "J"):
        cols = [f"{name}_trusted", f"{name}_fresh", f"{name}_sd"]
        if not all(est.has(c) for c in cols):
            continue
        flag, fresh, sd = (last_finite(est.columns[c])[0] for c in cols)
        judged = np.isfinite(flag)
        if not judged.any():
            continue
        out[name] = {
            "trusted": bool(np.all(flag[judged] == 1.0)),
            "untrusted_agents": [int(i) for i in np.flatnonzero(flag == 0.0)],
            "fresh_min": _finite_or_none(np.nanmin(fresh) if np.isfinite(fresh).any() else math.nan),
            "sd_max": _finite_or_none(np.nanmax(sd) if np.isfinite(sd).any() else math.nan),
            "fresh": [_finite_or_none(v) for v in fresh],
            "sd": [_finite_or_none(v) for v in sd],
        }
    return out


def monitor_block(run: fmt.RunData | None) -> dict[str, Any]:
    """The agents' innovation monitors at the end (``mon_windows``, ``mon_alarms`` of estimates.csv): windows
    tested and windows that alarmed, in total and per agent, and the first time each agent's count of alarms
    was seen above 0 (None: never). Empty for a run without those columns or before any window."""
    est = None if run is None else run.estimates
    if est is None or len(est.t) == 0 or not (est.has("mon_windows") and est.has("mon_alarms")):
        return {}
    windows = last_finite(est.columns["mon_windows"])[0]
    alarms = last_finite(est.columns["mon_alarms"])[0]
    if not np.isfinite(windows).any():
        return {}
    first = []
    col = est.columns["mon_alarms"]
    for i in range(col.shape[1]):
        hit = np.flatnonzero(col[:, i] > 0.0)
        first.append(float(est.t[hit[0]]) if hit.size else None)
    return {
        "windows": int(np.nansum(windows)),
        "alarms": int(np.nansum(alarms)),
        "per_agent": {"windows": [_int_or_none(v) for v in windows], "alarms": [_int_or_none(v) for v in alarms],
                      "first_alarm_t": first},
    }


def effects_block(run: fmt.RunData | None) -> dict[str, Any]:
    """The online detection's decisions (``eff_*`` columns, docs/online-detection.md): every switch and every
    withdrawal the team agreed as an event (``effect_switch`` or ``effect_withdrawn``: an ``eff_on`` bit set or
    cleared) and every candidate it ruled out before any switch (``effect_ruled_out``: an ``eff_out`` bit set
    while its ``eff_on`` bit is clear); tick, effect, pooled statistic, the agents that applied it; the effects
    on at the end, and the windows judged ``unexplained`` (the largest count over the agents). Empty without
    those columns (a run without online detection)."""
    est = None if run is None else run.estimates
    if est is None or len(est.t) == 0 or not all(est.has(c) for c in ("eff_on", "eff_tick", "eff_z")):
        return {}
    on, tick, z = (est.columns[c] for c in ("eff_on", "eff_tick", "eff_z"))
    if not np.isfinite(on).any():
        return {}
    out = est.columns["eff_out"] if est.has("eff_out") else np.zeros_like(on)
    events: dict[tuple[int, str], dict[str, Any]] = {}
    for i in range(on.shape[1]):
        prev = prev_out = 0
        for r in np.flatnonzero(np.isfinite(on[:, i])):
            cur, cur_out = int(on[r, i]), int(out[r, i]) if np.isfinite(out[r, i]) else 0
            # a candidate ruled out before any switch: its eff_out bit set while its eff_on bit is clear (a
            # withdrawal sets the eff_out bit of an effect that was on)
            ruled = cur_out & ~prev_out & ~prev & ~cur
            for kind, bits in (("effect_switch", cur & ~prev), ("effect_withdrawn", prev & ~cur),
                               ("effect_ruled_out", ruled)):
                for k, name in enumerate(EFFECTS):
                    if (bits >> k) & 1:
                        ev = events.setdefault((int(tick[r, i]), name), {
                            "event": kind, "tick": int(tick[r, i]), "effect": name,
                            "statistic": _finite_or_none(z[r, i]), "agents": []})
                        ev["agents"].append(i)
            prev, prev_out = cur, cur_out
    final = last_finite(on)[0]
    unexplained = last_finite(est.columns["eff_unexplained"])[0] if est.has("eff_unexplained") else final * math.nan
    names = sorted({name for v in final if math.isfinite(v) for k, name in enumerate(EFFECTS) if (int(v) >> k) & 1})
    return {
        "events": sorted(events.values(), key=lambda e: (e["tick"], e["effect"])),
        "on": names,
        "agree": len({v for v in final if math.isfinite(v)}) <= 1,
        "unexplained_windows": _int_or_none(float(np.nanmax(unexplained))) if np.isfinite(unexplained).any() else None,
    }


def _int_or_none(v: float) -> int | None:
    return int(v) if math.isfinite(v) else None


def _finite_or_none(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None
