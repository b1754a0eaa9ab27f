"""``coload loop``: run (or take) a run, diagnose it offline, re-run the same scenario and seed with the named
effects the agents can estimate online, and write one before/after table and figure (docs/loop.md).

Everything is written into a temporary directory next to ``--out`` and renamed into place at the end, so an
error or an interrupt leaves nothing half-written. ``--out`` must not exist, be empty, or hold a finished
loop (its loop.json), which is then replaced.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

from config.loader import ScenarioError, load_scenario
from config.scenario import Scenario

LOOP_JSON, LOOP_MD, LOOP_PNG, DIAGNOSIS = "loop.json", "loop.md", "loop.png", "diagnosis.json"


class LoopError(Exception):
    """Bad input or a failed step: one line for the user, exit status 2 (1 for a failed run)."""

    def __init__(self, msg: str, code: int = 2) -> None:
        super().__init__(msg)
        self.code = code


def _say(args: argparse.Namespace, msg: str) -> None:
    if not args.quiet:
        print(f"coload loop: {msg}", file=sys.stderr, flush=True)


def _check_out(out: Path, given_run: Path | None) -> bool:
    """Raises LoopError if ``out`` cannot take the loop; True if it holds a finished loop (to be replaced)."""
    if out.exists() and not out.is_dir():
        raise LoopError(f"--out {out}: exists and is not a directory")
    if given_run is not None:
        o, g = out.resolve(), given_run.resolve()
        if o == g or o in g.parents:
            raise LoopError(f"--out {out}: holds the input run {given_run}; choose another directory")
    parent = out.resolve().parent
    if not parent.is_dir() and not out.exists():
        try:
            parent.mkdir(parents=True)
        except OSError as exc:
            raise LoopError(f"--out {out}: cannot create {parent} ({exc.strerror})") from None
    if not os.access(parent, os.W_OK | os.X_OK):
        raise LoopError(f"--out {out}: cannot write in {parent}")
    if out.is_dir() and any(out.iterdir()):
        if (out / LOOP_JSON).is_file():
            return True
        raise LoopError(f"--out {out}: exists, is not empty and holds no finished loop ({LOOP_JSON}); "
                        f"choose another directory or remove it")
    return False


def _input(args: argparse.Namespace) -> tuple[Scenario, Path | None, list[str]]:
    """The before scenario, the given run directory (None for a scenario) and the overrides that make it."""
    src = Path(args.input)
    if src.is_dir():
        if not (src / "run.toml").is_file():
            raise LoopError(f"{src}: a directory without run.toml: give a scenario or a finished run directory")
        if not (src / "summary.json").is_file():
            raise LoopError(f"{src}: not a finished coload run (no summary.json); a lab recording cannot be "
                            f"re-run: use coload diagnose")
        if args.overrides or args.seed is not None:
            raise LoopError(f"{src}: --set and --seed are for a scenario; a run directory fixes both (its run.toml)")
        return load_scenario(src), src, []
    overrides = list(args.overrides) + ([f"seed={args.seed}"] if args.seed is not None else [])
    return load_scenario(src, overrides), None, overrides


def _run(args: argparse.Namespace, scenario: Scenario, run_dir: Path, label: str) -> dict:
    from coload.runs.orchestrate import run_inproc_cli, run_processes

    run_dir.mkdir()
    _say(args, f"{label}: {scenario.name}, seed {scenario.seed}, {args.engine} engine -> {run_dir.name}/")
    if args.engine == "inproc":
        summary = run_inproc_cli(scenario, run_dir, quiet=args.quiet)
    else:
        summary = run_processes(scenario, run_dir, quiet=args.quiet, verbose=args.verbose)
    if summary is None or summary.get("failed_members"):
        raise LoopError(f"the {label} run failed; nothing is kept (coload run of the same scenario keeps its "
                        f"logs)", code=1)
    return summary


def _loop(args: argparse.Namespace, work: Path, scenario: Scenario, given: Path | None, overrides: list[str]) -> None:
    """The whole loop into ``work``: the runs, diagnosis.json, loop.json, loop.md, loop.png."""
    from coload.analysis import loop as L
    from coload.rundir.format import read_run
    from ident.diagnose import DiagnoseError, diagnose_dir, stderr_progress

    t0 = time.perf_counter()
    wall: dict[str, float] = {}
    if given is None:
        _run(args, scenario, work / "before", "before")
        before_dir = work / "before"
        wall["before_run"] = time.perf_counter() - t0
    else:
        before_dir = given
        _say(args, f"before: {given} (given; not re-run)")
    t1 = time.perf_counter()
    _say(args, f"diagnosing {before_dir.name if given is None else before_dir} offline")
    try:
        diagnosis = diagnose_dir(before_dir, progress=None if args.quiet else stderr_progress("coload loop: diagnose"))
    except DiagnoseError as exc:
        raise LoopError(str(exc)) from None
    diag = diagnosis.as_dict()
    (work / DIAGNOSIS).write_text(json.dumps(diag, indent=1) + "\n", encoding="utf-8")
    wall["diagnosis"] = time.perf_counter() - t1
    the_plan = L.plan(diag, scenario.dynamics.estimate_effects)
    _say(args, f"named: {', '.join(e['name'] for e in diag['effects']) or 'none'}; {the_plan.reason}")
    after_run = after_summary = None
    if the_plan.rerun:
        t2 = time.perf_counter()
        # the before run's resolved run.toml: the same scenario and seed whatever the input was
        effects = json.dumps(list(the_plan.online))
        after_sc = load_scenario(before_dir, [f"dynamics.estimate_effects={effects}"])
        after_summary = _run(args, after_sc, work / "after", "after")
        after_run = read_run(work / "after")
        wall["after_run"] = time.perf_counter() - t2
    before_run = read_run(before_dir)
    truth = L.plant_truth(scenario)
    before = L.run_side(before_run, before_run.summary or {}, truth, scenario.dynamics.estimate_effects)
    after = (L.run_side(after_run, after_summary, truth, the_plan.online) if after_run is not None else None)
    wall["total"] = time.perf_counter() - t0
    source_info = {"kind": "scenario" if given is None else "run_dir", "given": str(args.input),
                   "scenario": scenario.name, "seed": scenario.seed, "engine": args.engine,
                   "overrides": overrides, "before_dir": "before" if given is None else str(given),
                   "after_dir": "after" if after is not None else None}  # fmt: skip
    loop = L.compare(source=source_info, diagnosis=diag, the_plan=the_plan, scenario=scenario,
                     before=before, after=after, wall_s=wall)
    (work / LOOP_JSON).write_text(json.dumps(loop, indent=1) + "\n", encoding="utf-8")
    (work / LOOP_MD).write_text(L.markdown(loop), encoding="utf-8")
    _figure(work / LOOP_PNG, before_run, after_run, diag.get("residual"), scenario, loop)


def _figure(path: Path, before_run, after_run, residual, scenario: Scenario, loop: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from coload.analysis.loop import draw_loop

    fig = plt.figure(figsize=(12, 8), layout="constrained")
    try:
        title = (f"coload loop: {scenario.name}, seed {scenario.seed}; named {', '.join(loop['diagnosis']['named']) or 'none'}"
                 f"; after: {', '.join(loop['online']) if loop['rerun'] else 'no re-run'}")
        draw_loop(fig, before_run, after_run, residual, scenario.dynamics.monitor_alpha, title)
        fig.savefig(path, dpi=90)
    finally:
        plt.close(fig)


def _install(work: Path, out: Path, replace: bool) -> None:
    """Renames the finished ``work`` to ``out`` (a finished loop there is moved aside first, then removed)."""
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(work, 0o777 & ~umask)  # mkdtemp's 0700 is for the unfinished state only
    old = None
    if replace:
        old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.resolve().parent))
        os.rename(out, old / "loop")
    elif out.is_dir():
        out.rmdir()  # empty (checked)
    os.rename(work, out)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def cmd_loop(args: argparse.Namespace) -> int:
    from coload.commands.common import check_law

    out = args.out
    try:
        scenario, given, overrides = _input(args)
        replace = _check_out(out, given)
        check_law(scenario, args.input, range(scenario.n))
    except (LoopError, ScenarioError) as exc:
        print(f"coload loop: {exc}", file=sys.stderr)
        return 2
    work = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.resolve().parent))
    try:
        _loop(args, work, scenario, given, overrides)
        if _check_out(out, given) != replace:
            raise LoopError(f"--out {out}: changed while the loop ran; the result is not installed")
        _install(work, out, replace)
    except (LoopError, ScenarioError) as exc:
        # the unfinished directory is removed: name its files relative to the loop (before/samples.csv)
        print(f"coload loop: {str(exc).replace(f'{work}{os.sep}', '')}", file=sys.stderr)
        return exc.code if isinstance(exc, LoopError) else 2
    finally:
        if work.exists():
            shutil.rmtree(work, ignore_errors=True)
    if replace:
        _say(args, f"{out} held a finished loop: replaced")
    print((out / LOOP_MD).read_text(encoding="utf-8"))
    print(f"loop: {out / LOOP_JSON}, {out / LOOP_MD}, {out / LOOP_PNG}")
    return 0
