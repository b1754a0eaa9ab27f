"""Memory and overhead of the ``coload campaign`` driver over the paper's 3000-run grid.

Every run is a stand-in that returns at once what a real worker returns (run.toml, a summary.json
with every error key, logs/), so what is measured is the driver alone: planning, the sweep loop, writing
each run directory, the table and the log after every run. Prints the driver's resident memory
every 300 finished runs and its peak (the workers are other processes and not counted). The numbers in
docs/campaign.md come from

    python bench/bench_campaign_driver.py --executor local --jobs 2
    python bench/bench_campaign_driver.py --executor dask --jobs 2
"""

from __future__ import annotations

import argparse
import contextlib
import json
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from config.loader import dump_scenario, load_scenario
from coload.analysis import campaign as cp

EVERY = 300


def stand_in_task(scenario, keep_data: bool = False) -> dict[str, bytes]:
    """What run_task returns for this scenario, without running it: the errors block has every
    column a real run fills (values drawn from the run's seed) and per-agent lists as real ones do."""
    import numpy as np

    rng = np.random.default_rng(scenario.seed)
    errors: dict[str, object] = {key: float(rng.random()) for key in cp.ERROR_COLUMNS if key != "zi_rel"}
    for key in ("J_local_rel", "m_local_rel"):
        errors[f"{key}_per_agent"] = rng.random(scenario.n).tolist()
    summary = {"engine": "inproc", "scenario": scenario.name, "seed": scenario.seed, "wall_s": 0.0,
               "errors": errors, "finished_s": 82.0 + rng.random(), "agent_step_us": 100.0}
    return {"logs/": b"", "run.toml": dump_scenario(scenario).encode(),
            "summary.json": (json.dumps(summary, indent=2) + "\n").encode()}


def rss_mb() -> float:
    """The resident memory of this process now (MB, from /proc/self/statm)."""
    pages = int(Path("/proc/self/statm").read_text().split()[1])
    return pages * resource.getpagesize() / 1e6


@contextlib.contextmanager
def dask_cluster(tmp: Path, workers: int) -> Iterator[str]:
    """A Dask scheduler and ``workers`` single-threaded workers, each its own process on loopback (as
    `dask scheduler` and `dask worker` would start them): the driver's memory is then its own."""
    from distributed import Client

    info = tmp / "scheduler.json"
    procs = [subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
                               "--port", "0", "--no-dashboard", "--scheduler-file", str(info)],
                              stderr=subprocess.DEVNULL)]
    try:
        procs.append(subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", "--scheduler-file",
                                       str(info), "--nworkers", str(workers), "--nthreads", "1", "--no-dashboard"],
                                      stderr=subprocess.DEVNULL))
        with Client(scheduler_file=str(info), timeout=60) as client:
            client.wait_for_workers(workers, timeout=120)
            address = client.scheduler.address
        yield address.replace("tcp://", "dask://")
    finally:
        for proc in reversed(procs):
            proc.terminate()
            proc.wait(timeout=30)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--executor", choices=("local", "dask"), default="local",
                    help="the local process pool, or a Dask scheduler and --jobs workers started here (default: local)")
    ap.add_argument("--jobs", type=int, default=2, help="worker processes (default: %(default)s)")
    ap.add_argument("--runs-per-cell", type=int, default=cp.PAPER_RUNS_PER_CELL)
    args = ap.parse_args()

    t0 = time.perf_counter()
    start = rss_mb()
    base = load_scenario(cp.DEFAULT_BASE)
    with tempfile.TemporaryDirectory(prefix="bench-campaign-") as tmp:
        out = Path(tmp) / "camp"
        runs = cp.plan(base, out, cp.PAPER_N, cp.PAPER_SIGMA, args.runs_per_cell)
        planned = rss_mb()
        print(f"{len(runs)} runs planned in {time.perf_counter() - t0:.1f} s; driver RSS {start:.0f} MB at "
              f"start, {planned:.0f} MB with the plan")
        samples: list[tuple[int, float, float]] = []

        def progress(done: int, total: int, note: str = "") -> None:
            if done % EVERY == 0 and (not samples or samples[-1][0] != done):
                samples.append((done, rss_mb(), time.perf_counter() - t1))
                print(f"  {done:5d} runs: RSS {samples[-1][1]:6.1f} MB, {samples[-1][2]:6.1f} s  {note}", flush=True)

        executor = "local"
        with contextlib.ExitStack() as stack:
            if args.executor == "dask":
                executor = stack.enter_context(dask_cluster(Path(tmp), args.jobs))
            t1 = time.perf_counter()
            res = cp.run_campaign(runs, out, jobs=args.jobs, progress=progress, plots=False, executor=executor,
                                  task=stand_in_task)
        wall = time.perf_counter() - t1
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / 1e6
    first, last = samples[0][1], samples[-1][1]
    print(f"{res.ran} runs ({res.failed and len(res.failed) or 0} failed) in {wall:.1f} s "
          f"({1e3 * wall / max(1, res.ran):.1f} ms per run in the driver), executor {args.executor}")
    print(f"driver RSS after {samples[0][0]} runs {first:.1f} MB, after {samples[-1][0]} runs {last:.1f} MB "
          f"(+{last - first:.1f} MB); peak {peak:.1f} MB")


if __name__ == "__main__":
    main()
