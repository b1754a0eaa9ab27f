"""The byte gate of the compiled-core port: the same runs on two source trees, outputs compared byte for byte.

    git worktree add /tmp/base main          # or: mkdir B && git archive main | tar -x -C B
    python bench/port_ab.py /tmp/base [--case NAME ...] [--jobs 2] [--keep DIR]

Runs every gate case (``--list``) with ``coload run CASE --engine inproc`` once in BASE and once in this
tree (each run imports its own tree's packages), then compares ``estimates.csv, pairs.csv, samples.csv,
truth.csv`` byte for byte and ``summary.json`` without its timings and versions. A case that differs is followed by the
largest relative difference of each numeric column of estimates.csv and the rows where the stage column
first differs, so that a last-bit change (expected from a slice that reorders arithmetic) is told from a
moved decision (docs/fast-core-plan.md, section 4 rule b). Exit status 0 when every case is identical, 1
otherwise. Prints the wall time of each side: not a speed measurement (bench/agent_step_ab.py is).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
FILES = ("estimates.csv", "pairs.csv", "samples.csv", "truth.csv")
TIMINGS = ("wall_s", "agent_step_us", "sim_per_wall", "wall_per_tick_us", "versions")  # and the commit

# name -> (scenario, overrides): each case reaches a part of the agent the others do not
CASES: dict[str, tuple[str, list[str]]] = {
    "quick": ("quick", []),
    "dyn": ("quick-dynamics", []),
    "dyn-faulty": ("quick-dynamics", ["link.delay_ticks=2", "link.jitter_ticks=3", 'link.loss.model="bernoulli"',
                                      "link.loss.p=0.2", "link.duplicate=0.1"]),
    "dyn-online": ("quick-dynamics", ["plant.friction.viscous=5", "dynamics.online_detection=true"]),
    "friction-online": ("friction-online", ["duration=60"]),
    "fig9": ("paper-fig9", ["duration=60"]),
    "dyn-noisy": ("quick-dynamics", ["noise.sigma_v=0.8"]),
}


def run_case(tree: Path, case: str, out: Path) -> float:
    scenario, sets = CASES[case]
    argv = [sys.executable, "-m", "coload.cli", "run", scenario, "--engine", "inproc", "--no-report",
            "--no-batch-fit", "--quiet", "--out", str(out)]
    for s in sets:
        argv += ["--set", s]
    env = dict(os.environ, PYTHONPATH=str(tree), OPENBLAS_NUM_THREADS="1")
    t0 = time.perf_counter()
    done = subprocess.run(argv, cwd=tree, env=env, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"{case} in {tree}: exit {done.returncode}\n{done.stderr[-2000:]}")
    return time.perf_counter() - t0


def _summary(path: Path) -> dict:
    data = json.loads(path.read_text())

    def strip(d):
        if isinstance(d, dict):
            return {k: strip(v) for k, v in d.items() if k not in TIMINGS}
        return d
    return strip(data)


def _floats(row: dict) -> dict[str, float]:
    out = {}
    for k, v in row.items():
        try:
            out[k] = float(v)
        except (TypeError, ValueError):
            pass
    return out


def explain(a: Path, b: Path) -> list[str]:
    """What differs in estimates.csv: per column the largest relative difference, the first stage change."""
    with open(a, newline="") as fa, open(b, newline="") as fb:
        ra, rb = list(csv.DictReader(fa)), list(csv.DictReader(fb))
    lines = []
    if len(ra) != len(rb):
        lines.append(f"    estimates.csv: {len(ra)} rows in base, {len(rb)} here")
    worst: dict[str, float] = {}
    stage_at = None
    for x, y in zip(ra, rb):
        if stage_at is None and x.get("stage") != y.get("stage"):
            stage_at = (x.get("tick"), x.get("agent"), x.get("stage"), y.get("stage"))
        fx, fy = _floats(x), _floats(y)
        for k in fx.keys() & fy.keys():
            u, v = fx[k], fy[k]
            if math.isnan(u) and math.isnan(v) or u == v:
                continue
            d = abs(u - v) / max(abs(u), abs(v), 1e-300) if math.isfinite(u) and math.isfinite(v) else math.inf
            worst[k] = max(worst.get(k, 0.0), d)
    for k, d in sorted(worst.items(), key=lambda kv: -kv[1]):
        lines.append(f"    {k}: max relative difference {d:.3g}")
    if stage_at:
        tick, agent, was, now = stage_at
        lines.append(f"    first stage difference: tick {tick} agent {agent}: {was} -> {now}")
    return lines


def compare(base: Path, mine: Path) -> list[str]:
    diffs = []
    for name in FILES:
        pa, pb = base / name, mine / name
        if pa.exists() != pb.exists():
            diffs.append(f"  {name}: present on one side only")
        elif pa.exists() and pa.read_bytes() != pb.read_bytes():
            diffs.append(f"  {name}: differs")
            if name == "estimates.csv":
                diffs += explain(pa, pb)
    if _summary(base / "summary.json") != _summary(mine / "summary.json"):
        diffs.append("  summary.json: differs (timings aside)")
    return diffs


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("base", nargs="?", type=Path, help="the other source tree (e.g. a worktree of main)")
    ap.add_argument("--case", action="append", choices=sorted(CASES), help="run only these cases (repeatable)")
    ap.add_argument("--jobs", type=int, default=2, help="runs at once (default 2)")
    ap.add_argument("--keep", type=Path, help="keep the run directories here")
    ap.add_argument("--list", action="store_true", help="print the gate cases and exit")
    args = ap.parse_args(argv)
    if args.list or args.base is None:
        for name, (sc, sets) in CASES.items():
            print(f"{name}: {sc} {' '.join('--set ' + s for s in sets)}")
        return 0 if args.list else 2
    base = args.base.resolve()
    if not (base / "agents").is_dir():
        print(f"port_ab: {base} is not a source tree of this project (no agents/)", file=sys.stderr)
        return 2
    cases = args.case or list(CASES)
    root = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="port_ab-"))
    jobs = [(tree, side, case) for case in cases for tree, side in ((base, "base"), (HERE, "here"))]
    with ThreadPoolExecutor(max(1, args.jobs)) as pool:
        walls = dict(zip([(s, c) for _, s, c in jobs],
                         pool.map(lambda j: run_case(j[0], j[2], root / j[2] / j[1]), jobs)))
    bad = 0
    for case in cases:
        diffs = compare(root / case / "base", root / case / "here")
        state = "identical" if not diffs else "DIFFERS"
        bad += bool(diffs)
        print(f"{case}: {state} (wall base {walls['base', case]:.1f} s, here {walls['here', case]:.1f} s)")
        for line in diffs:
            print(line)
    if not args.keep:
        shutil.rmtree(root, ignore_errors=True)
    print(f"{len(cases) - bad} of {len(cases)} cases identical")
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
