"""The innovation monitor's false-alarm rate on clean runs and its alarms under undeclared effects.

    python bench/innovation_monitor.py [--seeds 1-10] [--jobs 1] [--effects clean,viscous,...]

In-process engine, quick.toml (n = 5, line, sigma 0.1) with short stages (kinematic settle 3 s, m 4 s,
J 4 s; done at ~26 s) run on to 40 s, monitor windows of 2.5 s (~9-11 per agent). Every window's five
p-values are read back from estimates.csv (each window appears there: estimates are kept every 10
ticks, windows are 250), so the alarm rate is given for several levels alpha from the same runs: a
window alarms when some p-value is below alpha / 5. Effects the agents are not told of: viscous
friction 5 N s/m (m / b = 10 s), Coulomb friction 5 N, rotational damping 8.69 N m s (J / c = 10 s).
For each: windows, the alarm rate at alpha = 0.01 and 0.05, the share of windows where each test
alone is below 0.01 / 5, and the first alarm time (median over seeds and agents).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from coload.rundir import format as fmt  # noqa: E402
from coload.runs.engine import run_inproc  # noqa: E402
from config.loader import load_scenario  # noqa: E402
from seed_list import parse_seeds  # noqa: E402  (bench/ is the script's own directory)

QUICK = ROOT / "config" / "scenarios" / "quick.toml"
SHORT = ['dynamics.algorithm="sequential"', "dynamics.kin_settle_s=3", "dynamics.m_excite_s=4",
         "dynamics.j_excite_s=4", "duration=40", "dynamics.monitor_window_s=2.5"]
EFFECTS = {
    "clean": [],
    "viscous": ["plant.friction={viscous=5.0}"],
    "coulomb": ["plant.friction={coulomb=5.0}"],
    "rotational": ["plant.friction={rotational=8.69}"],
}
P_NAMES = ("mon_p_white", "mon_p_vc", "mon_p_sgn", "mon_p_om", "mon_p_f")


def one(effect: str, seed: int) -> tuple[np.ndarray, float]:
    """Every window's p-values (rows) and the agent step cost (us)."""
    sc = load_scenario(QUICK, [*SHORT, f"seed={seed}", *EFFECTS[effect]])
    with tempfile.TemporaryDirectory() as d:
        s = run_inproc(sc, Path(d) / "run")
        c = fmt.read_run(Path(d) / "run").estimates.columns
    t = np.arange(len(c["phase"])) * sc.record.every_ticks * sc.dt
    rows = []
    for a in range(sc.n):
        w = c["mon_windows"][:, a]
        for i in range(1, len(w)):
            if w[i] == w[i] and not (w[i - 1] == w[i]):
                rows.append([c[n][i, a] for n in P_NAMES] + [t[i], a])
    return np.array(rows), s["agent_step_us"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="1-10", help="seeds, a range A-B or a comma list (default 1-10)")
    ap.add_argument("--jobs", type=int, default=1, help="parallel runs (default 1)")
    ap.add_argument("--effects", default=",".join(EFFECTS), help="comma-separated, of: " + ", ".join(EFFECTS))
    a = ap.parse_args()
    seeds = parse_seeds(a.seeds)
    effects = a.effects.split(",")
    bad = [e for e in effects if e not in EFFECTS]
    if bad:
        ap.error(f"unknown effect {bad[0]!r}: expected one of {', '.join(EFFECTS)}")
    jobs = [(e, s) for e in effects for s in seeds]
    with ProcessPoolExecutor(a.jobs) as ex:
        out = list(ex.map(one, *zip(*jobs)))
    print(f"seeds {seeds[0]}..{seeds[-1]} ({len(seeds)})")
    print("| plant | windows | alarm rate alpha 0.01 | alarm rate alpha 0.05 | white | v_C | sign v_C | omega q_perp "
          "| own force | first alarm (s, median) | step (us, median) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for e in effects:
        res = [r for (ee, _), r in zip(jobs, out) if ee == e]
        p = np.concatenate([r[0] for r in res])
        pmin = np.nanmin(p[:, :5], axis=1)
        lvl = 0.01 / 5
        firsts = []
        for rows, _ in res:
            for ag in np.unique(rows[:, 6]):
                mine = rows[rows[:, 6] == ag]
                hit = mine[np.nanmin(mine[:, :5], axis=1) < lvl]
                if len(hit):
                    firsts.append(float(hit[0, 5]))
        tests = " | ".join(f"{np.mean(p[:, k] < lvl):.3f}" for k in range(5))
        first = f"{statistics.median(firsts):.1f} ({len(firsts)} agents)" if firsts else "-"
        print(f"| {e} | {len(p)} | {np.mean(pmin < 0.01 / 5):.3f} | {np.mean(pmin < 0.05 / 5):.3f} | {tests} "
              f"| {first} | {statistics.median(r[1] for r in res):.0f} |")


if __name__ == "__main__":
    main()
