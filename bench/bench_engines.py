"""Engine speed, measured in one run: ratios, not thresholds.

    python bench/bench_engines.py [--duration 20] [--zenoh-duration 10]

Prints simulated seconds per wall second for the in-process engine and for a lockstep run over Zenoh
(router, simulator and 10 agents as separate processes), both on paper-fig4, and the mean cost of one
agent step at n = 40 over n = 5 (contact spacing kept as in paper-fig4 by scaling the load with n).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from coload.runs.engine import run_inproc  # noqa: E402
from coload.runs.orchestrate import run_processes  # noqa: E402
from config.loader import load_scenario  # noqa: E402

KIN = 'dynamics.algorithm="none"'  # engine speed of the kinematic phase, as the documented numbers
FIG4 = ROOT / "config" / "scenarios" / "paper-fig4.toml"


def scaled(n: int, duration: float) -> list[str]:
    """paper-fig4 with n agents: the rectangle grows with n so neighbour spacing stays ~1.2 m."""
    s = n / 10
    w, h, m = 4.0 * s, 2.2 * s, 5.0 * n
    inertia = m * (w * w + h * h) / 12
    return [f"n={n}", f"duration={duration}", f"load.width={w}", f"load.height={h}", f"load.mass={m}",
            f"load.inertia={inertia}", "record.every_ticks=1000000"]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=20.0, help="simulated seconds for the in-process runs")
    ap.add_argument("--zenoh-duration", type=float, default=10.0, help="simulated seconds for the Zenoh run")
    args = ap.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        sc = load_scenario(FIG4, [f"duration={args.duration}", KIN])
        rec = run_inproc(sc, tmp / "inproc")
        bare = run_inproc(load_scenario(FIG4, [f"duration={args.duration}", "record.every_ticks=1000000", KIN]), None)
        zsc = load_scenario(FIG4, [f"duration={args.zenoh_duration}", KIN])
        zen = run_processes(zsc, tmp / "zenoh", quiet=True)
        if zen is None:
            print("zenoh run failed", file=sys.stderr)
            return 1
        step = {}
        for n in (5, 40):
            s = run_inproc(load_scenario(FIG4, [*scaled(n, min(args.duration, 10.0)), KIN]), None)
            step[n] = s["agent_step_us"]

    rows = [
        ("in-process, n=10, recording (samples every tick, estimates 10 Hz)", rec["sim_s"] / rec["wall_s"], "x real time"),
        ("in-process, n=10, no recording", bare["sim_s"] / bare["wall_s"], "x real time"),
        ("Zenoh lockstep, n=10, 12 processes", zen["sim_s"] / zen["wall_s"], "x real time"),
        ("in-process over Zenoh (same scenario)", (rec["sim_s"] / rec["wall_s"]) / (zen["sim_s"] / zen["wall_s"]), "ratio"),
        ("agent step, n=5", step[5], "us"),
        ("agent step, n=40", step[40], "us"),
        ("agent step n=40 over n=5", step[40] / step[5], "ratio"),
    ]
    width = max(len(r[0]) for r in rows)
    for name, value, unit in rows:
        print(f"{name:<{width}}  {value:10.2f}  {unit}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
