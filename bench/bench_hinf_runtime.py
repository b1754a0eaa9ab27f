"""Speed of the paper-003 runtime: ticks per second of the in-process engine and of the daemons on the
in-memory transport, for the Sec. 5 example and a 20-agent ring of random heterogeneous agents.

    python bench/bench_hinf_runtime.py [--duration 10]

Prints measured numbers and the daemon/engine ratio (the cost of codec, link model and lockstep
waits); the Zenoh figure is in each run's summary.json (wall_s) of `coload hinf run`.
"""
from __future__ import annotations

import argparse
import asyncio
import time
import warnings
from pathlib import Path

import numpy as np

from hinf import design as D
from hinf import load_spec, parse_spec, run_design
from hinf import runtime as R
from hinf.daemon import run_daemons_in_memory
from hinf.spec import random_ring_spec

warnings.filterwarnings("ignore", message="Solution may be inaccurate")
EXAMPLE = Path(__file__).resolve().parents[1] / "config" / "hinf" / "sec5-cyclic.toml"


def _ring_setup(n: int, duration: float) -> R.Setup:
    """Estimation-only ring: gains from (6) directly (the centralized yardstick is skipped, it takes minutes)."""
    data = random_ring_spec(n, np.random.default_rng(0))
    data["run"] = {"duration": duration, "control": False}
    spec = parse_spec(data)
    est = D.design_estimators(D.network_from_spec(spec))
    design = {"gamma": est.gamma, "gains": [{"L": g.L.tolist(), "K": g.K.tolist(), "P": g.P.tolist()}
                                            for g in est.gains]}
    return R.build_setup(spec, design)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=10.0, help="simulated seconds per case (dt = 0.01)")
    a = ap.parse_args()
    spec = load_spec(EXAMPLE, [f"run.duration={a.duration}"])
    cases = [("sec5 sync (4 agents)", R.build_setup(spec, run_design(spec))),
             ("ring20 estimation", _ring_setup(20, a.duration))]
    print(f"{'case':24s} {'ticks':>6s} {'inproc ticks/s':>15s} {'daemons ticks/s':>16s} {'ratio':>6s}")
    for name, su in cases:
        t0 = time.perf_counter()
        ref, _ = R.run_inproc(su)
        t1 = time.perf_counter()
        got, _ = asyncio.run(run_daemons_in_memory(su))
        t2 = time.perf_counter()
        same = all(np.array_equal(v, got.arrays()[k], equal_nan=True) for k, v in ref.arrays().items())
        print(f"{name:24s} {su.ticks:6d} {su.ticks / (t1 - t0):15.0f} {su.ticks / (t2 - t1):16.0f} "
              f"{(t2 - t1) / (t1 - t0):6.2f}  {'equal' if same else 'DIFFERENT'}")


if __name__ == "__main__":
    main()
