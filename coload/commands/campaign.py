"""``coload campaign``: the Monte Carlo grid, locally or on a Dask cluster."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from coload.commands.common import (
    check_law,
)
from config.loader import load_scenario


def cmd_campaign(args: argparse.Namespace) -> int:
    from coload.analysis import campaign as cp
    from coload.runs.orchestrate import ProgressBar
    from coload.runs.sweep import ExecutorError, parse_executor

    overrides = list(args.overrides) + ([f"duration={args.duration}"] if args.duration is not None else [])
    overrides += ["record.batch_fit=true"] if args.batch_fit else []
    if args.stop_after_done < 0:
        print(f"coload campaign: --stop-after-done: must be >= 0 s (got {args.stop_after_done})", file=sys.stderr)
        return 2
    overrides += [] if args.to_end else [f"stop_after_done_s={args.stop_after_done}"]
    if args.table:
        return _campaign_table(args.out)
    base = load_scenario(args.scenario or cp.DEFAULT_BASE, overrides)
    check_law(base, args.scenario or cp.DEFAULT_BASE, range(base.n))
    try:
        ns = cp.parse_list(args.ns, int, "--n")
        sigmas = cp.parse_list(args.sigmas, float, "--sigma")
        negative = [x for x in sigmas if not x >= 0]
        if negative:
            raise ValueError(f"--sigma: a noise level must be >= 0 m/s (got {negative[0]:g})")
        if args.jobs < 1:
            raise ValueError(f"--jobs: must be at least 1 (got {args.jobs})")
        parse_executor(args.executor)
        runs = cp.plan(base, args.out, ns, sigmas, args.runs_per_cell, args.seed0)
    except ValueError as exc:
        print(f"coload campaign: {exc}", file=sys.stderr)
        return 2
    print(cp.geometry_table(base, ns))
    if args.plan:
        print(f"{len(runs)} runs ({len(ns)} n x {len(sigmas)} sigma x {args.runs_per_cell}), "
              f"{runs[0].scenario.duration:g} s simulated each")
        return 0
    try:
        result = cp.run_campaign(runs, args.out, jobs=args.jobs, keep_data=args.keep_data, executor=args.executor,
                                 progress=ProgressBar("campaign", args.quiet, unit="run"))
    except ExecutorError as exc:  # the executor cannot be used: nothing was run or written
        print(f"coload campaign: {exc}", file=sys.stderr)
        return 2
    print(cp.cell_table(result.rows))
    rate = f", {result.runs_per_min:.1f} runs/min" if result.runs_per_min else ""
    print(f"{result.planned} runs planned: {result.reused} finished before, {result.ran} run now, "
          f"{len(result.failed)} failed; {result.wall_s:.1f} s wall{rate}")
    if result.total_ran > result.ran:
        print(f"over every invocation on {args.out}: {result.total_ran} runs in {result.total_wall_s:.0f} s wall "
              f"({60.0 * result.total_ran / max(result.total_wall_s, 1e-9):.1f} runs/min; {cp.LOG_NAME})")
    for name, err in result.failed:
        print(f"coload campaign: run {name} failed: {err}", file=sys.stderr)
    print(f"table: {args.out / cp.CSV_NAME}")
    for path in result.plots:
        print(f"plot: {path}")
    return 1 if result.failed else 0


def _campaign_table(out: Path) -> int:
    from coload.analysis import campaign as cp

    csv_path = out / cp.CSV_NAME
    try:
        rows = cp.read_csv(csv_path)
    except FileNotFoundError:
        print(f"coload campaign: {csv_path}: no such file (no run of this campaign has finished yet, "
              f"or --out is not a campaign directory)", file=sys.stderr)
        return 2
    except ValueError as exc:
        print(f"coload campaign: {exc}", file=sys.stderr)
        return 2
    print(cp.digest(rows, out / cp.LOG_NAME))
    for path in cp.plot_campaign(rows, out) if rows else []:
        print(f"plot: {path}")
    return 0
