"""Runs a paper-003 H-infinity team (``coload hinf run``): in this process, or as an embedded Zenoh
router, a simulator and one estimator daemon per agent, each its own OS process (docs/hinf.md).

Its run directory (docs/run-directory.md): spec.json and design.json (the inputs every daemon
reads), trace.csv (per tick: x, every local estimate xhat, zeta, u, xi, eta, got; see
hinf.runtime.Trace), summary.json and hinf.png."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from coload.rundir.series import read_series, write_series
from coload.runs.orchestrate import (
    ProgressBar,
    make_run_keys,
    process_run,
    secure_endpoint,
    start_router,
    watch_simulator,
)
from hinf import SpecError, load_spec, run_design
from hinf.report import json_default, load_run_dir, plot, prepare_run_dir, summarize
from hinf.runtime import TRACE_FIELDS, Setup, Trace, run_inproc
from net import keys


def run_cli(spec_path: Path, out: Path, engine: str = "zenoh", mode: str | None = None,
            overrides: list[str] | tuple[str, ...] = (), quiet: bool = False, verbose: int = 0,
            secure: bool = False) -> dict | None:
    """Design, then simulate the spec's [run]: ``zenoh`` = router, simulator and one estimator daemon per
    agent as OS processes; ``inproc`` = the same cores and link models in this process (lockstep only).
    ``secure``: mutual TLS and the default-deny access-control list (docs/security.md). Writes the
    run directory (see ``hinf.report``) and returns summary.json's content (None on failure).
    """
    spec = load_spec(spec_path, overrides)
    if mode is not None:
        spec = spec.model_copy(deep=True)
        spec.run.mode = mode  # type: ignore[assignment]
    if engine == "inproc" and spec.run.mode != "lockstep":
        raise SpecError("--engine inproc runs lockstep only; use --engine zenoh for --mode realtime")
    out = Path(out)
    prepare_run_dir(out, spec, run_design(spec, clock=time.perf_counter))
    setup = load_run_dir(out)  # what the daemons read: both engines start from the same floats
    if engine == "inproc":
        wall = time.perf_counter()
        trace, info = run_inproc(setup)
        info.update({"engine": "inproc", "wall_s": time.perf_counter() - wall})
        return finish_run(out, setup, trace, info)
    if not run_processes(setup, out, quiet=quiet, verbose=verbose, secure=secure):
        return None
    return json.loads((out / "summary.json").read_text())


def run_processes(setup: Setup, run_dir: Path, quiet: bool = False, verbose: int = 0, secure: bool = False) -> bool:
    """An embedded Zenoh router, the simulator and one estimator daemon per agent, each its own process.

    ``run_dir`` must already hold spec.json and design.json (``hinf.report.prepare_run_dir``); the
    simulator writes the rest. ``secure``: the team's keys are made in ``run_dir/keys`` (the spec's
    graph decides whose states each estimator may hear) and every member speaks mutual TLS under the
    access-control list. Returns True if the simulator finished.
    """
    run_dir = Path(run_dir)
    endpoint, run, py, children = process_run(run_dir, verbose, secure_endpoint() if secure else None)
    tls_dir = make_run_keys(run_dir, [setup.nbrs(k) for k in range(setup.N)], run, endpoint) if secure else None
    bar = ProgressBar(f"{setup.spec.name} (zenoh, {setup.N} estimators)", quiet)
    try:
        if not start_router(children, py, endpoint, run_dir, "coload hinf run", tls_dir):
            return False
        common = [str(run_dir), "--connect", endpoint, "--run", run,
                  *(["--tls-dir", str(tls_dir)] if tls_dir is not None else [])]
        sim = children.start("sim", [*py, "hinf", "sim", *common])
        for k in range(setup.N):
            children.start(f"estimator-{k}", [*py, "hinf", "agent", "--id", str(k), *common])
        run_spec = setup.spec.run
        budget = 120.0 + run_spec.timing.startup_timeout_s + 50.0 * run_spec.duration
        if not watch_simulator(children, sim, endpoint, keys.hinf_control(run), setup.ticks, budget, bar,
                               run_dir, "coload hinf run", tls_dir):
            return False
        children.stop([n for n in children.procs if n.startswith("estimator-")], let_finish=10.0)
        return sim.returncode == 0
    finally:
        children.close()


TRACE_CSV = "trace.csv"


def finish_run(run_dir: Path, setup: Setup, trace: Trace, info: dict, draw: bool = True) -> dict:
    """Write trace.csv, summary.json (and hinf.png); return the summary."""
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    arrays = trace.arrays()
    write_series(run_dir / TRACE_CSV, np.arange(len(arrays["x"])) * setup.spec.run.dt, arrays)
    summary = summarize(setup, trace, info)
    (run_dir / "summary.json").write_text(json.dumps(summary, indent=1, default=json_default) + "\n")
    if draw:
        plot(setup, trace, run_dir / "hinf.png")
    return summary


def load_trace(run_dir: Path) -> Trace:
    """The trace of a finished run directory, as the engine recorded it."""
    _, cols = read_series(Path(run_dir) / TRACE_CSV)
    return Trace(**{k: (cols[k].astype(bool) if k == "got" else cols[k]) for k in TRACE_FIELDS})
