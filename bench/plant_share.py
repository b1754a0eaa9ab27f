"""The plant's share of an in-process run: its step and measurement against all the agent steps.

    OPENBLAS_NUM_THREADS=1 python bench/plant_share.py [--n 10 40] [--duration 60]

Runs paper-fig4 in process (the whole Algorithm 1; the load scaled with n as bench/bench_engines.py
does; nothing recorded) with timers around ``Plant.measure`` and ``Plant.apply_and_step`` (the wrench
reduction and the closed-form step, which equals pymunk's bit for bit: tests/test_plant.py); the agents'
time is the engine's own counter (``agent_step_us``), and of it the filter's (``RigidEKF.update`` +
``predict``, timed). Prints per tick (us): the plant's parts, the sum of the agent steps, the rest of the
engine loop (link delivery, wrench list), their shares of the wall time, and simulated seconds per wall
second. Docs: docs/agent-step.md, "Choosing the fast core: measured".
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from agents.rigid_filter import RigidEKF  # noqa: E402
from bench.bench_engines import FIG4, scaled  # noqa: E402
from coload.runs.engine import run_inproc  # noqa: E402
from config.loader import load_scenario  # noqa: E402
from simulator.plant import Plant  # noqa: E402


def one(n: int, duration: float) -> dict:
    t = {"measure": 0.0, "apply": 0.0, "filter": 0.0}
    clock = time.perf_counter
    plain_m, plain_a = Plant.measure, Plant.apply_and_step

    def measure(self, rng):  # noqa: ANN001, ANN202
        c0 = clock()
        out = plain_m(self, rng)
        t["measure"] += clock() - c0
        return out

    def apply_and_step(self, wrenches):  # noqa: ANN001, ANN202
        c0 = clock()
        plain_a(self, wrenches)
        t["apply"] += clock() - c0

    plain_u, plain_p = RigidEKF.update, RigidEKF.predict

    def update(self, *args):  # noqa: ANN001, ANN202
        c0 = clock()
        plain_u(self, *args)
        t["filter"] += clock() - c0

    def predict(self, *args):  # noqa: ANN001, ANN202
        c0 = clock()
        plain_p(self, *args)
        t["filter"] += clock() - c0

    Plant.measure, Plant.apply_and_step = measure, apply_and_step
    RigidEKF.update, RigidEKF.predict = update, predict
    try:
        s = run_inproc(load_scenario(FIG4, scaled(n, duration)), None)
    finally:
        Plant.measure, Plant.apply_and_step = plain_m, plain_a
        RigidEKF.update, RigidEKF.predict = plain_u, plain_p
    ticks = round(s["sim_s"] / 0.01)
    agents = s["agent_step_us"] * n * ticks * 1e-6
    t["agents"] = agents
    t["wall"] = s["wall_s"]
    t["ticks"] = ticks
    t["rt"] = s["sim_s"] / t["wall"]
    return t


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, nargs="+", default=[10, 40], help="team sizes")
    ap.add_argument("--duration", type=float, default=60.0, help="simulated seconds")
    a = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.1f}")
    print(f"{'n':>3} {'measure':>8} {'apply':>8} {'agents':>9} {'(filter)':>9} {'rest':>8} {'wall':>9} "
          f"{'plant %':>8} {'agents %':>8} {'x real':>7}   (us per tick)")
    for n in a.n:
        t = one(n, a.duration)
        k = t["ticks"]
        us = {key: 1e6 * t[key] / k for key in ("measure", "apply", "agents", "filter", "wall")}
        plant = us["measure"] + us["apply"]
        rest = us["wall"] - plant - us["agents"]
        print(f"{n:>3} {us['measure']:>8.1f} {us['apply']:>8.1f} {us['agents']:>9.1f} {us['filter']:>9.1f} "
              f"{rest:>8.1f} {us['wall']:>9.1f} {100 * plant / us['wall']:>8.1f} "
              f"{100 * us['agents'] / us['wall']:>8.1f} {t['rt']:>7.1f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
