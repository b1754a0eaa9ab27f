"""The compiled core's three speed numbers (issue 22) for two source trees in one run, interleaved.

    OPENBLAS_NUM_THREADS=1 python bench/core_speed.py BASE [--reps 2] [--duration 20] [--plant-duration 120]
        [--json FILE]

BASE is another source tree (a worktree of main, or ``git archive main agents coload config net simulator hinf``
unpacked); "here" is the tree this file is in. Every measurement runs in a fresh process per tree with
``PYTHONPATH=TREE`` (the worker mode of this file: it imports the tree's packages, and only the measuring
functions from here), the two trees back to back, their order swapped every repetition, so that both see
the same machine load; each number is the best of ``--reps``. Each process first loads the tree's kernels
(``agents.kernels.warm()``, from numba's cache; compiled once per tree before the first repetition), as the
engines' parents do: the in-process CLI run does not, and would pay that load inside its timed loop.

Columns (a row per tree, then here / base):
  x real     (a) paper-fig4, n = 10, the whole of Algorithm 1 (120 s simulated; ``--real-duration``), in process as
             ``coload run paper-fig4 --engine inproc --no-report --no-batch-fit --quiet`` runs it (recording
             included): simulated seconds per wall second, summary.json's sim_s / wall_s. Best: the highest.
  x task     (a') the same run as a campaign's worker runs it (coload.analysis.campaign.run_task: recorded, scored,
             the run directory packed, without the CSV tables a campaign does not keep), after a short one
             (a worker's imports): simulated seconds per wall second of the whole task. Best: the highest.
  step5 us,  (b) the engine's own ``agent_step_us`` (time inside the team's step per agent per tick) on the
  step40 us  campaign scenario at n = 5 and n = 40 (bench/agent_step.py's ``one``: paper-fig4 resized, sigma
             0.3, seed 12345), ``--duration`` simulated seconds. Best: the lowest of each.
  40/5       (b) step40 / step5: what grows with n (a line graph: <= 2 neighbours per agent whatever n).
  plant %    (c) the plant's share of the wall time (measure + apply_and_step over the whole loop) of
             paper-fig4, n = 10, ``--plant-duration`` s, nothing recorded (bench/plant_share.py's ``one``),
             from the repetition with the lowest wall time.
  warm s     the kernels' cache load of the x-real process (not in any other column).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
PKGS = ("agents", "coload", "config", "net", "simulator", "hinf")
COLUMNS = ("x real", "x task", "step5 us", "step40 us", "40/5", "plant %", "warm s")


# ------------------------------------------------------------------------ worker: one measurement, one tree
def _warm() -> float:
    import time

    t0 = time.perf_counter()
    if importlib.util.find_spec("agents.kernels") is not None:
        import agents.kernels

        agents.kernels.warm()
    return time.perf_counter() - t0


def _bench_module(name: str):  # noqa: ANN202
    """bench/NAME.py of this tree, whose imports of the project's packages resolve to the measured tree."""
    spec = importlib.util.spec_from_file_location(f"core_speed_{name}", HERE / "bench" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _check_tree(tree: Path) -> None:
    """Every module of the project's packages came from ``tree`` (not from this one, nor the editable install)."""
    stray = [m.__name__ for m in list(sys.modules.values()) if m.__name__.split(".")[0] in PKGS
             and getattr(m, "__file__", None) and not Path(m.__file__).resolve().is_relative_to(tree)]
    if stray:
        raise RuntimeError(f"modules not from {tree}: {stray[:5]}")


def worker(kind: str, tree: Path, duration: float) -> dict:
    if kind == "real":
        warm = _warm()
        from coload import cli

        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "run"
            cli.main(["run", "paper-fig4", "--engine", "inproc", "--no-report", "--no-batch-fit", "--quiet",
                      "--out", str(out), *([] if duration == 120.0 else ["--set", f"duration={duration}"])])
            s = json.loads((out / "summary.json").read_text())
        _check_tree(tree)
        return {"x real": s["sim_s"] / s["wall_s"], "warm s": warm}
    _warm()
    if kind == "task":
        import time

        from coload.analysis.campaign import run_task
        from config.loader import load_scenario

        scenario = load_scenario("paper-fig4", ["record.batch_fit=false", f"duration={duration}"])
        run_task(load_scenario("paper-fig4", ["record.batch_fit=false", "duration=5"]))  # a worker's imports
        t0 = time.perf_counter()
        files = run_task(scenario)
        wall = time.perf_counter() - t0
        _check_tree(tree)
        return {"x task": json.loads(files["summary.json"])["sim_s"] / wall}
    if kind == "step":
        one = _bench_module("agent_step").one
        res = {f"step{n} us": one(n, duration, False)[0] for n in (5, 40)}
    else:
        # plant_share puts this tree first on sys.path when it loads: the measured tree's modules go first
        import agents.rigid_filter  # noqa: F401
        import coload.runs.engine  # noqa: F401
        import coload.runs.orchestrate  # noqa: F401
        import config.loader  # noqa: F401
        import simulator.plant  # noqa: F401

        path = list(sys.path)
        mod = _bench_module("plant_share")
        sys.path[:] = path  # and the imports the run makes later still find the measured tree
        t = mod.one(10, duration)
        res = {"plant %": 100.0 * (t["measure"] + t["apply"]) / t["wall"], "plant wall s": t["wall"]}
    _check_tree(tree)
    return res


# ------------------------------------------------------------------------ parent: the trees interleaved
def measure(tree: Path, kind: str, duration: float) -> dict:
    argv = [sys.executable, str(Path(__file__).resolve()), "--worker", kind, "--tree", str(tree),
            "--duration", str(duration)]
    env = dict(os.environ, PYTHONPATH=str(tree), OPENBLAS_NUM_THREADS="1")
    done = subprocess.run(argv, cwd=tree, env=env, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"{kind} in {tree}: exit {done.returncode}\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def best(runs: list[dict]) -> dict:
    """The best of the repetitions, per number (module docstring)."""
    out = {"x real": max(r["x real"] for r in runs), "x task": max(r["x task"] for r in runs)}
    out["warm s"] = next(r["warm s"] for r in runs if r["x real"] == out["x real"])
    out["step5 us"] = min(r["step5 us"] for r in runs)
    out["step40 us"] = min(r["step40 us"] for r in runs)
    out["40/5"] = out["step40 us"] / out["step5 us"]
    out["plant %"] = min(runs, key=lambda r: r["plant wall s"])["plant %"]
    return out


def table(res: dict[str, dict]) -> str:
    ratio = {c: res["here"][c] / res["base"][c] if res["base"][c] else float("nan") for c in COLUMNS}
    digits = {"x real": 2, "x task": 2, "step5 us": 1, "step40 us": 1, "40/5": 2, "plant %": 1, "warm s": 2}
    lines = [f"{'':>12}" + "".join(f"{c:>11}" for c in COLUMNS)]
    for name, row in (("base", res["base"]), ("here", res["here"]), ("here / base", ratio)):
        lines.append(f"{name:>12}" + "".join(f"{row[c]:>11.{3 if name == 'here / base' else digits[c]}f}"
                                             for c in COLUMNS))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("base", nargs="?", type=Path, help="the other source tree")
    ap.add_argument("--reps", type=int, default=2, help="repetitions per tree; the best counts (default 2)")
    ap.add_argument("--duration", type=float, default=20.0, help="simulated s of the step runs (b) (default 20)")
    ap.add_argument("--plant-duration", type=float, default=120.0, help="simulated s of the plant run (c)")
    ap.add_argument("--real-duration", type=float, default=120.0, help="simulated s of the x-real run (a)")
    ap.add_argument("--json", help="also write the results (every repetition, and the best) here; - : stdout")
    ap.add_argument("--worker", choices=("real", "task", "step", "plant"), help=argparse.SUPPRESS)
    ap.add_argument("--tree", type=Path, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.worker:
        print(json.dumps(worker(a.worker, a.tree.resolve(), a.duration)))
        return 0
    if a.base is None or not (a.base / "agents").is_dir():
        ap.error("BASE must be a source tree of this project (with agents/)")
    trees = {"base": a.base.resolve(), "here": HERE}
    for tree in trees.values():  # compiles a cold cache outside the timed runs
        subprocess.run([sys.executable, "-c", "import agents.kernels as k; k.warm()"], cwd=tree, check=True,
                       env=dict(os.environ, PYTHONPATH=str(tree)))
    print(f"load average {os.getloadavg()[0]:.1f}; base {trees['base']}, here {HERE}", flush=True)
    runs: dict[str, list[dict]] = {name: [] for name in trees}
    for rep in range(a.reps):
        order = ("base", "here") if rep % 2 == 0 else ("here", "base")
        row = {name: {} for name in trees}
        for kind, duration in (("real", a.real_duration), ("task", a.real_duration), ("step", a.duration),
                               ("plant", a.plant_duration)):
            for name in order:
                row[name].update(measure(trees[name], kind, duration))
        for name in trees:
            runs[name].append(row[name])
        print(f"rep {rep + 1}: " + ", ".join(f"{n} x real {row[n]['x real']:.2f}" for n in order), flush=True)
    res = {name: best(r) for name, r in runs.items()}
    print(table(res))
    out = {"base": str(trees["base"]), "here": str(HERE), "reps": a.reps, "real_duration": a.real_duration,
           "duration": a.duration, "plant_duration": a.plant_duration, "best": res, "runs": runs}
    if a.json == "-":
        print(json.dumps(out))
    elif a.json:
        Path(a.json).write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
