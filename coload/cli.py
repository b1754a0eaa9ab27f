"""The ``coload`` command line: builds finished configs and hands them to the daemons and engines."""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import os
import signal
import sys
import threading
from collections.abc import Sequence
from pathlib import Path

from config.loader import ScenarioError, load_scenario

EXAMPLES = """examples:
  coload run config/scenarios/paper-fig4.toml                  # router, simulator, 10 agents as processes
  coload run config/scenarios/paper-fig4.toml --engine inproc  # the same in one process
  coload run config/scenarios/quick.toml --set noise.sigma_v=0.1 --seed 3 --out runs/q3
  coload report runs/q3
  # by hand, in separate terminals:
  coload router --listen tcp/127.0.0.1:7447
  coload sim config/scenarios/quick.toml --connect tcp/127.0.0.1:7447 --run demo --out runs/demo
  coload agent --id 0 config/scenarios/quick.toml --connect tcp/127.0.0.1:7447 --run demo
"""


def _add_scenario_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", type=Path,
                   help="scenario TOML file, a run directory (its run.toml) or a bundled scenario's name "
                        "(paper-fig4, paper-fig5, paper-fig9, quick, ...)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scenario field, dotted key, TOML value (repeatable), e.g. noise.sigma_v=0.1")
    p.add_argument("--seed", type=int, help="run seed (overrides the scenario's)")
    p.add_argument("--mode", choices=["lockstep", "realtime"], help="time mode (overrides the scenario's)")


def _add_zenoh_args(p: argparse.ArgumentParser, router: bool = False) -> None:
    g = p.add_argument_group("zenoh")
    g.add_argument("--connect", action="append", metavar="ENDPOINT",
                   help="endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)"
                        + ("; other routers of a mesh" if router else ""))
    g.add_argument("--listen", action="append", metavar="ENDPOINT",
                   help="endpoint to listen on (repeatable)"
                        + ("; default tcp/127.0.0.1:7447, or with --zenoh-config the file's listen.endpoints"
                           if router else ""))
    if not router:
        g.add_argument("--zenoh-mode", choices=["client", "peer", "router"],
                       help="Zenoh session mode (default: client, or a mode other than peer that the "
                            "--zenoh-config file sets)")
    g.add_argument("--zenoh-config", type=Path, metavar="FILE",
                   help="a Zenoh JSON5 config file (TLS, lease, ...); its mode and endpoints are kept unless "
                        "given here; multicast scouting stays off")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="coload",
        description="Teams of robots that move an unknown load together and learn it as they go.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("run", help="run a scenario: router, simulator and agents as processes, or in-process",
                       description="Run a scenario end to end and leave a run directory.")
    _add_scenario_args(p)
    p.add_argument("--engine", choices=["zenoh", "inproc"], default="zenoh",
                   help="zenoh: an embedded router, the simulator and one daemon per agent as separate OS "
                        "processes; inproc: everything in this process with the in-memory link model")
    p.add_argument("--out", type=Path,
                   help="run directory (default: runs/NAME-seedS-DATE); a previous run in it is replaced, and said")
    p.add_argument("--listen", metavar="ENDPOINT",
                   help="zenoh engine: the embedded router's endpoint, for clients that watch or join the run "
                        "(docs/wire.md), e.g. tcp/127.0.0.1:7447 (default: a free loopback port; printed)")
    p.add_argument("--no-report", action="store_true", help="do not draw report.png at the end")
    p.add_argument("--no-batch-fit", action="store_true",
                   help="skip the centralized batch fit of samples.csv at the end (summary.json then has no "
                        "'centralized' and 'distributed_over_centralized' blocks; saves ~1/3 to 1x the run's CPU)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")

    p = sub.add_parser("sim", help="run the simulator daemon (the plant and the recorder)",
                       description="Run the simulator daemon; it records the run directory.")
    _add_scenario_args(p)
    _add_zenoh_args(p)
    p.add_argument("--run", required=True, help="run name: the key-expression namespace shared by all daemons")
    p.add_argument("--out", type=Path, required=True, help="run directory to write")

    p = sub.add_parser("agent", help="run one agent daemon", description="Run the daemon of one agent.")
    p.add_argument("--id", type=int, required=True, help="agent id (0..n-1)")
    _add_scenario_args(p)
    _add_zenoh_args(p)
    p.add_argument("--run", required=True, help="run name: the key-expression namespace shared by all daemons")

    p = sub.add_parser("router", help="run an embedded Zenoh router",
                       description="Run a Zenoh router in this process (nothing to install).")
    _add_zenoh_args(p, router=True)

    p = sub.add_parser("compose", help="write a docker-compose file: router, simulator and N agents",
                       description="Write a docker-compose file for one run (one image, explicit endpoints, "
                                   "liveliness health checks).")
    p.add_argument("--agents", type=int, required=True, help="number of agent services")
    p.add_argument("--scenario", default="config/scenarios/paper-fig4.toml",
                   help="scenario path inside the image (default: %(default)s); n is set to --agents")
    p.add_argument("--run", default="compose", help="run name (key-expression namespace)")
    p.add_argument("--out", type=Path, default=Path("docker/compose.yaml"), help="file to write (default: %(default)s)")

    p = sub.add_parser("alive", help="health check: exit 0 if the router answers (and a liveliness token matches)",
                       description="Exit 0 if a client session opens on --connect and, with --key, a liveliness "
                                   "token matching the key expression is alive; exit 1 otherwise.")
    p.add_argument("--connect", action="append", required=True, metavar="ENDPOINT", help="router endpoint")
    p.add_argument("--key", help="liveliness key expression, e.g. coload/RUN/alive/agent/3")
    p.add_argument("--timeout", type=float, default=2.0, help="seconds to wait for the token (default: %(default)s)")

    p = sub.add_parser("observer", help="immersion-and-invariance speed observer (paper 004)",
                       description="Speed observer for Euler-Lagrange robots from joint positions only (paper 004).")
    osub = p.add_subparsers(dest="observer_command", required=True, metavar="ACTION")
    q = osub.add_parser("run", help="integrate a robot and its observer; draw observer.png",
                        description="Integrate the robot and the observer of a scenario (e.g. "
                                    "config/observers/ii-two-link.toml); write observer.png and summary.json.")
    q.add_argument("scenario", type=Path, help="observer scenario TOML")
    q.add_argument("--out", type=Path, required=True, help="output directory")
    q.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scenario field (dotted key, TOML value; repeatable)")

    p = sub.add_parser("arms", help="agents that are two-link arms with encoders only (paper 004 observer in the loop)",
                       description="Agents that are planar two-link arms on fixed bases, holding the load through "
                                   "pivots, with joint encoders and wrist force sensors but no speed sensor (issue 7).")
    asub = p.add_subparsers(dest="arms_command", required=True, metavar="ACTION")
    q = asub.add_parser("run", help="arm agents vs velocity-measuring agents on the same load; comparison report",
                        description="Run a scenario with an [arms] section (e.g. config/scenarios/arms-rocking.toml) "
                                    "twice in-process on the same load and seed: arm agents (speed observer + "
                                    "Jacobian) and velocity-measuring agents. Writes OUT/observer/ and "
                                    "OUT/velocity/ (run directories), OUT/comparison.json and OUT/comparison.png, "
                                    "and prints the comparison table. See docs/speed-observer.md.")
    _add_scenario_args(q)
    q.add_argument("--out", type=Path, required=True, help="output directory")
    q.add_argument("--no-batch-fit", action="store_true",
                   help="skip the centralized batch fit of m and J on each run's samples.csv")
    q.add_argument("--quiet", action="store_true", help="no progress bar")

    p = sub.add_parser("hinf", help="cooperative H-infinity estimation from relative measurements (paper 003)",
                       description="Cooperative H-infinity estimators and synchronization controllers (paper 003).")
    hsub = p.add_subparsers(dest="hinf_command", required=True, metavar="ACTION")
    q = hsub.add_parser("design", help="solve the LMIs of a spec: gains, gamma, centralized bound, kappa/theta",
                        description="Check detectability per strongly connected component, solve the coupled "
                                    "LMIs (6)-(7) minimising gamma, compute the centralized bound and the "
                                    "synchronization design (Theorem 3); e.g. config/hinf/sec5-cyclic.toml.")
    q.add_argument("spec", type=Path, help="design spec (TOML)")
    q.add_argument("--out", type=Path, help="write the gains and results here (JSON)")
    q = hsub.add_parser("run", help="design, then run the estimators (4) and controllers (10)-(11) as daemons",
                        description="Design the spec, then simulate its [run] section: a simulator integrates "
                                    "the LTI agents, one estimator-controller daemon per agent exchanges "
                                    "estimates with its neighbours (zenoh: router, simulator and daemons as OS "
                                    "processes; inproc: one process, lockstep). Writes RUN_DIR/summary.json "
                                    "(errors, decay vs alpha, energy gain vs gamma, synchronization) and hinf.png.")
    q.add_argument("spec", type=Path, help="spec (TOML) with an optional [run] section")
    q.add_argument("--out", type=Path, required=True, help="run directory to write")
    q.add_argument("--engine", choices=["zenoh", "inproc"], default="zenoh",
                   help="zenoh: separate processes over an embedded router; inproc: this process (lockstep)")
    q.add_argument("--mode", choices=["lockstep", "realtime"], help="time mode (overrides run.mode)")
    q.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a spec field, dotted key, TOML value (repeatable), e.g. run.duration=10")
    q.add_argument("--quiet", action="store_true", help="no progress bar")
    for action, what in (("sim", "the LTI simulator daemon (it records RUN_DIR)"),
                         ("agent", "one estimator-controller daemon")):
        q = hsub.add_parser(action, help=f"run {what}; started by `coload hinf run`",
                            description=f"Run {what} of a run directory prepared by `coload hinf run` "
                                        "(it reads RUN_DIR/spec.json and RUN_DIR/design.json).")
        if action == "agent":
            q.add_argument("--id", type=int, required=True, help="agent index (0..N-1, spec order)")
        q.add_argument("run_dir", type=Path, help="prepared run directory")
        _add_zenoh_args(q)
        q.add_argument("--run", required=True, help="run name: the key-expression namespace shared by all daemons")

    p = sub.add_parser("campaign", help="paper 000's Monte Carlo grid (Fig. 7/8) on the in-process engine",
                       description="Run the (n, sigma) grid of paper 000's appendix B: m = 5n, the load scaled so "
                                   "the contact spacing stays that of the base, line graph, independent seeds; "
                                   "in parallel worker processes, resumable (finished runs are kept). Writes "
                                   "OUT/campaign.csv, OUT/campaign.png (and campaign-consensus.png once the "
                                   "agents estimate J and m) and a run directory per run in OUT/runs/. "
                                   "Geometry and columns: docs/campaign.md.")
    p.add_argument("scenario", type=Path, nargs="?",
                   help="base scenario, resized per n (default: the bundled config/scenarios/paper-fig4.toml)")
    p.add_argument("--out", type=Path, required=True, help="campaign directory (re-use it to resume)")
    p.add_argument("--n", dest="ns", default=",".join(map(str, (5, 8, 11, 14, 17, 20))), metavar="LIST",
                   help="team sizes, comma-separated (default: the paper's %(default)s)")
    p.add_argument("--sigma", dest="sigmas", default="0.1,0.2,0.3,0.4,0.5,0.6,0.7,0.8,0.9,1.0", metavar="LIST",
                   help="velocity-noise levels in m/s, comma-separated (default: the paper's %(default)s)")
    p.add_argument("--runs-per-cell", type=int, default=50, metavar="K",
                   help="independent runs per (n, sigma) (default: the paper's %(default)s)")
    p.add_argument("--duration", type=float, metavar="S", help="simulated time per run (s; default: the base's)")
    p.add_argument("--jobs", type=int, default=os.cpu_count() or 1, metavar="J",
                   help="worker processes (default: the number of CPUs, %(default)s)")
    p.add_argument("--seed0", type=int, default=0, metavar="N",
                   help="campaign seed: each run's seed derives from (N, n, sigma, run index) (default: %(default)s)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a field of the base scenario (dotted key, TOML value; repeatable)")
    p.add_argument("--keep-data", action="store_true",
                   help="keep every run's CSV tables (default: only run.toml and summary.json; a run is "
                        "reproduced exactly by `coload run OUT/runs/NAME/run.toml --engine inproc`)")
    p.add_argument("--batch-fit", action="store_true",
                   help="fit the centralized batch estimator in every run (columns central_*, dist_over_central_*; "
                        "about doubles each run's CPU, see docs/campaign.md)")
    p.add_argument("--stop-after-done", type=float, default=2.0, metavar="S",
                   help="end each run S seconds after its agents agreed they are done (scenario field "
                        "stop_after_done_s; the duration stays the cap; default: %(default)s)")
    p.add_argument("--to-end", action="store_true",
                   help="run every run its whole duration (no early end; the braking phase is simulated too)")
    p.add_argument("--plan", action="store_true", help="print the geometry table and the number of runs, run nothing")
    p.add_argument("--table", action="store_true",
                   help="print the grid tables (median and 90th percentile of the RE of J and m, finish time) "
                        "of the runs OUT holds now, the wall time over every invocation, and redraw the "
                        "plots; run nothing (safe while another invocation works on OUT)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")

    p = sub.add_parser("report", help="draw report.png for a run directory and print its summary table",
                       description="Draw report.png (true vs estimated quantities) and print a summary table; "
                                   "with RUN_DIR/diagnosis.json (see --diagnose) also residual.png, the residual "
                                   "before/after the diagnosed effects and its autocorrelation with bounds.")
    p.add_argument("run_dir", type=Path, help="a run directory")
    p.add_argument("--out", type=Path, help="PNG path (default: RUN_DIR/report.png)")
    p.add_argument("--diagnose", action="store_true",
                   help="first run coload diagnose on the run's samples.csv and write RUN_DIR/diagnosis.json; with a "
                        "diagnosis.json the report also draws RUN_DIR/residual.png (residual before/after, "
                        "autocorrelation with bounds)")

    p = sub.add_parser("diagnose", help="find the effect the nominal model lacks in a recording (samples.csv + run.toml)",
                       description="Fit the nominal rigid-body model to a recording, test its residual (whiteness, "
                                   "signatures), select missing effects from a candidate library, re-fit and report "
                                   "before and after (docs/diagnose.md).")
    p.add_argument("recording", type=Path, help="directory with run.toml (n; dt, edges, input_hold optional) and "
                   "samples.csv (t, agent, vx,vy and/or x,y, fx, fy, tau)")
    p.add_argument("--json", type=Path, metavar="FILE", help="write the diagnosis as JSON (schema in docs/diagnose.md)")
    p.add_argument("--plot", action="store_true",
                   help="draw RECORDING/diagnose.png: residual before/after and its autocorrelation with bounds")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")
    p.add_argument("--validate", type=Path, metavar="OTHER",
                   help="also predict the recording OTHER (same plant) with the nominal and the augmented model and "
                        "report both errors")

    p = sub.add_parser("import", help="convert a dataset into a recording (measured-data format)",
                       description="Write a recording directory (run.toml + samples.csv) from a published dataset "
                                   "(docs/diagnose.md, 'EMPS').")
    isub = p.add_subparsers(dest="format", required=True)
    q = isub.add_parser("emps", help="the EMPS benchmark's .mat file: one agent, position x = qm, fx = gtau * vir",
                        description="Import DATA_EMPS.mat or DATA_EMPS_PULSES.mat (Janot, Gautier, Brunot 2019).")
    q.add_argument("file", type=Path, help="the .mat file")
    q.add_argument("--out", type=Path, required=True, metavar="DIR", help="recording directory to write")
    return parser


def _scenario(args: argparse.Namespace):
    overrides = list(args.overrides)
    if args.seed is not None:
        overrides.append(f"seed={args.seed}")
    if args.mode is not None:
        overrides.append(f'mode="{args.mode}"')
    return load_scenario(args.scenario, overrides)


def _check_law(scenario, source: str, agents: Sequence[int]) -> None:
    """The user's control law, imported and built for ``agents`` before any process or run starts, so that
    a bad one is one scenario error (ScenarioError) rather than a failure per daemon or per run."""
    if not scenario.control.law:
        return
    from agents.factory import build_law
    from agents.laws import ControlLawError

    try:
        for i in agents:
            build_law(scenario, i)
    except ControlLawError as exc:
        raise ScenarioError(str(source), None, "control.law", str(exc).removeprefix("control.law ")) from None


def _zenoh_conf(args: argparse.Namespace):
    from net.zenoh_transport import zenoh_config

    return zenoh_config(mode=args.zenoh_mode, connect=args.connect, listen=args.listen,
                        config_file=args.zenoh_config, mode_if_unset="client")


class DaemonStartError(Exception):
    """A daemon could not start: no router, a bad endpoint or config, an agent id the scenario lacks."""


async def _serve(coro_factory, transport_factory):
    """Runs a daemon until it finishes or SIGINT/SIGTERM arrive. What fails before the daemon runs
    (opening the session, building the daemon) is a :class:`DaemonStartError`, not a traceback."""
    from net.zenoh_transport import zenoh_error_text

    loop = asyncio.get_running_loop()
    try:
        transport = transport_factory(loop)
    except Exception as exc:  # zenoh.ZError: nothing listens at the endpoint, a bad locator, ...
        raise DaemonStartError(f"cannot open the Zenoh session ({zenoh_error_text(exc)}); is the router "
                               f"running and --connect its endpoint?") from None
    try:
        coro = coro_factory(transport)
    except ValueError as exc:
        transport.close()
        raise DaemonStartError(str(exc)) from None
    task = asyncio.ensure_future(coro)
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, task.cancel)
    try:
        return await task
    except asyncio.CancelledError:
        return None
    finally:
        transport.close()


def _run_daemon(name: str, args: argparse.Namespace, coro_factory):
    """Opens the daemon's Zenoh session and runs it; start-up errors are one line on stderr, exit 2."""
    from net.zenoh_transport import ZenohTransport

    try:
        conf = _zenoh_conf(args)
    except ValueError as exc:  # a bad --zenoh-config file
        print(f"coload {name}: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    try:
        return asyncio.run(_serve(coro_factory, lambda loop: ZenohTransport(conf, loop)))
    except DaemonStartError as exc:  # only what failed before the daemon ran; later errors keep their traceback
        print(f"coload {name}: {exc}", file=sys.stderr)
        raise SystemExit(2) from None


def cmd_agent(args: argparse.Namespace) -> int:
    from agents.daemon import AgentDaemon

    scenario = _scenario(args)
    if not 0 <= args.id < scenario.n:
        print(f"coload agent: --id {args.id} is not an agent of {scenario.name} (0..{scenario.n - 1})",
              file=sys.stderr)
        return 2
    _check_law(scenario, args.scenario, [args.id])
    daemon: list[AgentDaemon] = []

    def build(t):
        daemon.append(AgentDaemon(scenario, args.id, t, args.run))
        return daemon[0].run()

    report = _run_daemon("agent", args, build)
    if daemon and daemon[0].failed:
        print(f"coload agent: {daemon[0].failed}", file=sys.stderr)
        return 1
    if report is None:
        return 130
    return 1 if daemon[0].gave_up else 0


def cmd_sim(args: argparse.Namespace) -> int:
    from coload.analysis.summary import complete_summary
    from coload.rundir.recorder import Recorder
    from net.vocabulary import ESTIMATE_NAMES
    from simulator.daemon import SimDaemon

    scenario = _scenario(args)
    summary = _run_daemon("sim", args, lambda t: SimDaemon(
        scenario, t, args.run, Recorder(args.out, scenario, ESTIMATE_NAMES)).run())
    if summary is None:
        return 130
    complete_summary(args.out, scenario, summary)
    print(f"run directory: {args.out}")
    return 0


def cmd_router(args: argparse.Namespace) -> int:
    from net.zenoh_transport import run_router, zenoh_error_text

    listen = args.listen or (None if args.zenoh_config else ["tcp/127.0.0.1:7447"])
    try:
        return run_router(listen, config_file=args.zenoh_config, connect=args.connect)
    except ValueError as exc:
        print(f"coload router: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # zenoh.ZError: the port is taken, a bad locator
        print(f"coload router: cannot listen on {' '.join(listen or ['the config file endpoints'])} "
              f"({zenoh_error_text(exc)})", file=sys.stderr)
        return 2


def cmd_report(args: argparse.Namespace) -> int:
    from coload.analysis.report import make_report
    from coload.rundir.format import INTERRUPTED_JSON

    if not args.run_dir.is_dir():
        print(f"coload report: {args.run_dir}: not a directory", file=sys.stderr)
        return 2
    try:
        path, table = make_report(args.run_dir, args.out)
    except ValueError as exc:  # RunFormatError; a recording without truth.csv/estimates.csv
        print(f"coload report: {exc}", file=sys.stderr)
        if not args.diagnose:
            return 2
        print("coload report: no report.png; diagnosing the recording", file=sys.stderr)
    else:
        print(table)
        print(f"report: {path}")
    stopped = args.run_dir / INTERRUPTED_JSON
    if stopped.exists():
        try:
            info = json.loads(stopped.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            info = {}
        print(f"coload report: this run was stopped at t = {info.get('t', '?')} s of {info.get('duration', '?')} s "
              f"({info.get('reason', '?')}); its tables end there", file=sys.stderr)
    from coload.analysis.report import residual_figure, write_diagnosis
    from ident.diagnose import DiagnoseError, stderr_progress

    try:
        if args.diagnose:
            print(f"diagnosis: {write_diagnosis(args.run_dir, stderr_progress('coload report --diagnose'))}")
        residual = residual_figure(args.run_dir)
    except (DiagnoseError, ValueError) as exc:
        print(f"coload report: {exc}", file=sys.stderr)
        return 2
    if residual is not None:
        print(f"residual: {residual}")
    return 0


def cmd_diagnose(args: argparse.Namespace) -> int:
    from ident.diagnose import (
        DiagnoseError,
        diagnose_dir,
        format_diagnosis,
        plot_diagnosis,
        stderr_progress,
    )

    try:
        result = diagnose_dir(args.recording, progress=None if args.quiet else stderr_progress(),
                              validate=args.validate)
    except DiagnoseError as exc:
        print(f"coload diagnose: {exc}", file=sys.stderr)
        return 2
    print(format_diagnosis(result))
    if args.json:
        args.json.write_text(json.dumps(result.as_dict(), indent=2) + "\n", encoding="utf-8")
        print(f"json: {args.json}")
    if args.plot:
        print(f"plot: {plot_diagnosis(result, args.recording / 'diagnose.png')}")
    return 0


def cmd_import(args: argparse.Namespace) -> int:
    from ident.emps import import_emps
    from ident.recording import RecordingError

    try:
        out = import_emps(args.file, args.out)
    except RecordingError as exc:
        print(f"coload import: {exc}", file=sys.stderr)
        return 2
    print(f"recording: {out}")
    return 0


def cmd_compose(args: argparse.Namespace) -> int:
    from coload.runs.compose import write_compose

    try:
        path = write_compose(args.out, args.agents, args.scenario, args.run)
    except ValueError as exc:
        print(f"coload compose: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {path}: docker compose -f {path} up --build")
    return 0


def cmd_alive(args: argparse.Namespace) -> int:
    from coload.runs.compose import check_alive

    return 0 if check_alive(args.connect, args.key, args.timeout) else 1


def cmd_observer(args: argparse.Namespace) -> int:
    from coload.runs.observer_run import ObserverScenarioError, run_observer_cli

    try:
        summary = run_observer_cli(args.scenario, args.out, list(args.overrides))
    except ObserverScenarioError as exc:
        print(f"coload observer run: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(summary, indent=2, default=str))
    print(f"plot: {args.out / 'observer.png'}")
    return 0


def cmd_arms(args: argparse.Namespace) -> int:
    from coload.runs.arm_run import run_arms_cli
    from simulator.arms import ArmSetupError

    scenario = _scenario(args)
    try:
        _, table = run_arms_cli(scenario, args.out, batch_fit=not args.no_batch_fit, quiet=args.quiet)
    except (ArmSetupError, ValueError) as exc:
        print(f"coload arms run: {args.scenario}: {exc}", file=sys.stderr)
        return 2
    print(table)
    print(f"runs: {args.out / 'observer'}, {args.out / 'velocity'}; comparison: {args.out / 'comparison.png'}")
    return 0


def cmd_hinf(args: argparse.Namespace) -> int:
    from hinf import SpecError, design_cli
    from hinf.design import HinfDesignError

    if args.hinf_command != "design":
        return cmd_hinf_runtime(args)
    try:
        result = design_cli(args.spec, args.out)
    except (SpecError, HinfDesignError) as exc:
        print(f"coload hinf design: {exc}", file=sys.stderr)
        return 2
    keys = ("gamma", "gamma_centralized", "gamma_centralized_alpha", "realised_norm", "error_decay_rate")
    shown = {k: result[k] for k in keys if k in result}
    sync = result.get("sync") or {}
    shown.update({k: sync[k] for k in ("kappa", "theta") if k in sync})
    print(json.dumps(shown, indent=2, default=str))
    if args.out:
        print(f"gains and results: {args.out}")
    return 0


def cmd_campaign(args: argparse.Namespace) -> int:
    from coload.analysis import campaign as cp
    from coload.runs.orchestrate import ProgressBar

    overrides = list(args.overrides) + ([f"duration={args.duration}"] if args.duration is not None else [])
    overrides += ["record.batch_fit=true"] if args.batch_fit else []
    if args.stop_after_done < 0:
        print(f"coload campaign: --stop-after-done: must be >= 0 s (got {args.stop_after_done})", file=sys.stderr)
        return 2
    overrides += [] if args.to_end else [f"stop_after_done_s={args.stop_after_done}"]
    if args.table:
        return _campaign_table(args.out)
    base = load_scenario(args.scenario or cp.DEFAULT_BASE, overrides)
    _check_law(base, args.scenario or cp.DEFAULT_BASE, range(base.n))
    try:
        ns = cp.parse_list(args.ns, int, "--n")
        sigmas = cp.parse_list(args.sigmas, float, "--sigma")
        if args.jobs < 1:
            raise ValueError(f"--jobs: must be at least 1 (got {args.jobs})")
        runs = cp.plan(base, args.out, ns, sigmas, args.runs_per_cell, args.seed0)
    except ValueError as exc:
        print(f"coload campaign: {exc}", file=sys.stderr)
        return 2
    print(cp.geometry_table(base, ns))
    if args.plan:
        print(f"{len(runs)} runs ({len(ns)} n x {len(sigmas)} sigma x {args.runs_per_cell}), "
              f"{runs[0].scenario.duration:g} s simulated each")
        return 0
    result = cp.run_campaign(runs, args.out, jobs=args.jobs, progress=ProgressBar("campaign", args.quiet, unit="run"),
                             keep_data=args.keep_data)
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


def cmd_hinf_runtime(args: argparse.Namespace) -> int:
    """`coload hinf run|sim|agent`: the paper-003 runtime (hinf.daemon)."""
    from coload.runs.hinf_run import run_cli
    from hinf import SpecError
    from hinf.design import HinfDesignError

    if args.hinf_command == "run":
        try:
            s = run_cli(args.spec, args.out, args.engine, args.mode, args.overrides, args.quiet, args.verbose)
        except (SpecError, HinfDesignError) as exc:
            print(f"coload hinf run: {exc}", file=sys.stderr)
            return 2
        if s is None:
            return 1
        en, de = s["energy"], s["decay"]
        print(json.dumps({"gamma": en["gamma"], "empirical_gain": en["empirical_gain"],
                          "sampled_norm": en["sampled_norm"], "continuous_norm": en["continuous_norm"],
                          "alpha": de["alpha"], "V_rate_fit": de["V_rate_fit"],
                          "alpha_bound_holds": de["alpha_bound_holds"],
                          "own_error_final": {k: v["own_final"] for k, v in s["errors"].items()},
                          "y_spread": [s["sync"]["y_spread_initial"], s["sync"]["y_spread_final"]]}, indent=2))
        print(f"run directory: {args.out} (summary.json, hinf.png)")
        return 0
    from hinf.daemon import HinfAgentDaemon, HinfSimDaemon
    from hinf.report import finish_run, load_run_dir

    try:
        setup = load_run_dir(args.run_dir)
    except SpecError as exc:
        print(f"coload hinf {args.hinf_command}: {exc}", file=sys.stderr)
        return 2
    if args.hinf_command == "agent":
        rep = _run_daemon("hinf agent", args, lambda t: HinfAgentDaemon(setup, args.id, t, args.run).run())
        return 0 if rep is not None else 130
    res = _run_daemon("hinf sim", args, lambda t: HinfSimDaemon(setup, t, args.run).run())
    if res is None:
        return 130
    trace, info = res
    finish_run(args.run_dir, setup, trace, {**info, "engine": "zenoh"})
    print(f"run directory: {args.run_dir}")
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    from coload.runs.orchestrate import (
        default_run_dir,
        prepare_run_dir,
        run_inproc_cli,
        run_processes,
    )

    # the batch-fit yardstick (record.batch_fit) is on for every `coload run` unless --no-batch-fit
    args.overrides = ["record.batch_fit=true", *args.overrides, *(["record.batch_fit=false"] if args.no_batch_fit else [])]
    scenario = _scenario(args)
    _check_law(scenario, args.scenario, range(scenario.n))
    run_dir = args.out or default_run_dir(scenario)
    if args.listen and args.engine != "zenoh":
        print("coload run: --listen is for --engine zenoh (the in-process engine has no router)", file=sys.stderr)
        return 2
    try:
        note = prepare_run_dir(run_dir)
    except ValueError as exc:
        print(f"coload run: {exc}", file=sys.stderr)
        return 2
    if note:
        print(f"coload run: {note}", file=sys.stderr)
    if args.engine == "inproc":
        summary = run_inproc_cli(scenario, run_dir, quiet=args.quiet)
    else:
        summary = run_processes(scenario, run_dir, quiet=args.quiet, verbose=args.verbose, listen=args.listen)
    if summary is None:
        return 1
    if not args.no_report:
        from coload.analysis.report import make_report

        path, table = make_report(run_dir)
        print(table)
        print(f"report: {path}")
    else:
        from coload.analysis.report import centralized_lines

        for line in centralized_lines(summary):
            print(line)
    print(f"run directory: {run_dir}")
    failed = summary.get("failed_members")
    if failed:
        print(f"coload run: {', '.join(failed)} failed during the run and the run went on without them "
              f"(logs in {run_dir / 'logs'}); first: {next(iter(failed.values()))}", file=sys.stderr)
        return 1
    return 0


COMMANDS = {"run": cmd_run, "sim": cmd_sim, "agent": cmd_agent, "router": cmd_router, "report": cmd_report,
            "compose": cmd_compose, "alive": cmd_alive, "campaign": cmd_campaign, "observer": cmd_observer, "hinf": cmd_hinf,
            "arms": cmd_arms, "diagnose": cmd_diagnose, "import": cmd_import}


def main(argv: Sequence[str] | None = None) -> int:
    from agents.laws import ControlLawError
    from coload.runs.orchestrate import (
        Terminated,
        check_terminated,
        terminate_on_sigterm,
    )

    parent = os.environ.pop("COLOAD_PARENT_PID", None)  # popped: not inherited by our own children
    if parent is not None:
        from coload.runs.orchestrate import die_with_parent

        die_with_parent(int(parent))
    args = build_parser().parse_args(argv)
    level = [logging.WARNING, logging.INFO, logging.DEBUG][min(args.verbose, 2)]
    daemon = args.command in ("sim", "agent", "router") or getattr(args, "hinf_command", None) in ("sim", "agent")
    if daemon:
        level = min(level, logging.INFO)
    logging.basicConfig(level=level, format=f"%(asctime)s {args.command}[{os.getpid()}] %(levelname)s %(message)s")
    previous = None
    if not daemon and threading.current_thread() is threading.main_thread():
        previous = terminate_on_sigterm()  # daemons handle SIGTERM in their own loops
    try:
        code = COMMANDS[args.command](args)
        if previous is not None:
            check_terminated()  # a SIGTERM that a library call swallowed: still a stop
        return code
    except ScenarioError as exc:
        print(f"coload {args.command}: {exc}", file=sys.stderr)
        return 2
    except ControlLawError as exc:  # the user's law failed while running (it was built and checked before)
        print(f"coload {args.command}: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"coload {args.command}: interrupted", file=sys.stderr)
        return 130
    except Terminated:
        print(f"coload {args.command}: terminated (SIGTERM)", file=sys.stderr)
        return 143
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":
    sys.exit(main())
