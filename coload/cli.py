"""The ``coload`` command line: builds finished configs and hands them to the daemons and engines."""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import threading
from collections.abc import Sequence
from pathlib import Path

from coload.commands.analysis import cmd_diagnose, cmd_export, cmd_import, cmd_report
from coload.commands.campaign import cmd_campaign
from coload.commands.loop import cmd_loop
from coload.commands.common import VIEW_PORT, DaemonStartError, writable  # noqa: F401  (public names of the CLI)
from coload.commands.daemons import (
    cmd_agent,
    cmd_alive,
    cmd_compose,
    cmd_keys,
    cmd_router,
    cmd_sim,
)
from coload.commands.papers import cmd_arms, cmd_hinf, cmd_observer
from coload.commands.run import cmd_run, cmd_view
from coload.extras import ExtraMissing
from config.loader import ScenarioError

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
    from coload.zenoh_flags import add_zenoh_args

    add_zenoh_args(p, router=router)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="coload",
        description="Teams of robots that move an unknown load together and learn it as they go.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    parser.add_argument("--version", action="version", version=_version_line())
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("run", help="run a scenario: router, simulator and agents as processes, or in-process",
                       description="Run a scenario end to end and leave a run directory.")
    _add_scenario_args(p)
    p.add_argument("--engine", choices=["zenoh", "inproc"], default="zenoh",
                   help="zenoh: an embedded router, the simulator and one daemon per agent as separate OS "
                        "processes; inproc: everything in this process with the in-memory link model")
    p.add_argument("--out", type=Path,
                   help="run directory (default: runs/NAME-seedS-DATE); a previous run in it is replaced, and said")
    p.add_argument("-l", "--listen", metavar="ENDPOINT",
                   help="zenoh engine: the embedded router's endpoint, for clients that watch or join the run "
                        "(docs/wire.md), e.g. tcp/127.0.0.1:7447 (default: a free loopback port; printed)")
    p.add_argument("--secure", action="store_true",
                   help="zenoh engine: mutual TLS and a default-deny access-control list; the team's keys are "
                        "made in RUN_DIR/keys (docs/security.md)")
    p.add_argument("--no-report", action="store_true", help="do not draw report.png at the end")
    p.add_argument("--view", nargs="?", type=int, const=VIEW_PORT, metavar="PORT",
                   help=f"zenoh engine: stream the load, the contact points and the estimates live to Foxglove's "
                        f"WebSocket server on 127.0.0.1:PORT (default {VIEW_PORT}; Foxglove: open connection, "
                        f"Foxglove WebSocket); needs the viz extra. See docs/viewers.md")
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

    p = sub.add_parser("view", help="watch a live run in Foxglove (its load pose and estimates, from Zenoh)",
                       description="Subscribe to a run's load pose (coload/RUN/sim/pose) and estimates and "
                                   "stream them to Foxglove's WebSocket server until the run ends; the scenario "
                                   "gives the team size and the load's outline. Needs the viz extra. "
                                   "See docs/viewers.md.")
    _add_scenario_args(p)
    _add_zenoh_args(p)
    p.add_argument("--run", required=True, help="run name: the key-expression namespace of the run to watch")
    p.add_argument("--port", type=int, default=VIEW_PORT, help="Foxglove WebSocket port (default: %(default)s)")
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (default: %(default)s)")

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
    p.add_argument("--insecure", action="store_true",
                   help="plain TCP, no keys (default: mutual TLS and access control, with the team's keys made "
                        "in keys/ next to the compose file unless it holds them; docs/security.md)")

    p = sub.add_parser("alive", help="health check: exit 0 if the router answers (and a liveliness token matches)",
                       description="Exit 0 if a client session opens on --connect and, with --key, a liveliness "
                                   "token matching the key expression is alive; exit 1 otherwise. With "
                                   "--tls-dir it connects with the team's monitor certificate (read-only).")
    from coload.zenoh_flags import add_zenoh_args

    add_zenoh_args(p, mode=False)
    p.add_argument("--key", help="liveliness key expression, e.g. coload/RUN/alive/agent/3")
    p.add_argument("--timeout", type=float, default=2.0, help="seconds to wait for the token (default: %(default)s)")

    p = sub.add_parser("keys", help="a team's keys: a run CA and a certificate per role (docs/security.md)",
                       description="Make and renew the keys of a secure team: a CA, a key and certificate for the "
                                   "router, the simulator, the monitor (read-only) and each agent, and team.json, "
                                   "from which `--tls-dir DIR` builds each role's TLS settings and the router's "
                                   "default-deny access-control list.")
    ksub = p.add_subparsers(dest="keys_command", required=True, metavar="ACTION")
    q = ksub.add_parser("init", help="make a team's CA and every role's key and certificate",
                        description="Make DIR/ca.pem, DIR/ROLE.pem and DIR/ROLE.key for every role, and DIR/team.json.")
    q.add_argument("dir", type=Path, help="directory to write (must not hold a team)")
    q.add_argument("--agents", type=int, required=True, help="number of agents")
    q.add_argument("--scenario", type=Path,
                   help="scenario whose graph decides whose states each agent may hear (n set to --agents; "
                        "default: every agent hears every agent)")
    q.add_argument("--run", default="*", help="run name the policy is for (default: any run)")
    q.add_argument("--endpoint", default="tls/127.0.0.1:7447",
                   help="the router's endpoint, the default of every role (default: %(default)s)")
    q.add_argument("--host", action="append", metavar="NAME",
                   help="a name or address clients reach the router by (repeatable; default: localhost, "
                        "127.0.0.1, router)")
    q.add_argument("--days", type=float, default=30.0, help="certificate lifetime in days (default: %(default)s)")
    q = ksub.add_parser("add", help="issue an agent's certificate: a replacement (the old one is revoked) or a joiner",
                        description="Issue agent I's key and certificate under the next generation; the router's "
                                    "policy (rebuilt from team.json when it starts) names only the newest, so the "
                                    "replaced certificate may do nothing. For a new agent (I = n) give the grown "
                                    "team's --scenario. Restart the router to apply.")
    q.add_argument("dir", type=Path, help="a team's directory (coload keys init)")
    q.add_argument("--agent", type=int, required=True, help="agent id")
    q.add_argument("--scenario", type=Path, help="the grown team's scenario (its graph; n = I + 1 if larger)")

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
                                   "pivots, with joint encoders and wrist force sensors but no speed sensor.")
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
    q.add_argument("--secure", action="store_true",
                   help="zenoh engine: mutual TLS and a default-deny access-control list; the team's keys are "
                        "made in RUN_DIR/keys (docs/security.md)")
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
    p.add_argument("--executor", default="local", metavar="WHERE",
                   help="where the runs execute: 'local' (--jobs processes on this machine, the default) or "
                        "dask://HOST:PORT, the workers of a running Dask scheduler (needs the extra "
                        "coload[cluster]; --jobs is then ignored; docs/campaign.md)")
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
    p.add_argument("--max-samples", type=int, default=150_000, metavar="N",
                   help="fit at most N samples (windows x stamps x agents; default 150000: 2.5 min of 10 agents "
                        "at 100 Hz); a longer recording is fitted on runs of its windows spread over it; 0: all")
    p.add_argument("--validate", type=Path, metavar="OTHER",
                   help="also predict the recording OTHER (same plant) with the nominal and the augmented model and "
                        "report both errors")

    p = sub.add_parser("loop", help="run (or take) a run, diagnose it, re-run with the named effects estimated online",
                       description="Close the loop offline: run SCENARIO into OUT/before (or take a finished run "
                                   "directory as it is), diagnose it (coload diagnose), re-run the same scenario and "
                                   "seed with the named effects the agents can estimate online "
                                   "(dynamics.estimate_effects) into OUT/after, and write OUT/loop.json, OUT/loop.md "
                                   "(a before/after table) and OUT/loop.png. OUT must not exist, be empty or hold a "
                                   "finished loop (replaced); nothing is written until the loop is done "
                                   "(docs/loop.md).")
    p.add_argument("input", metavar="RUN_DIR_OR_SCENARIO",
                   help="a finished run directory (taken as 'before', not re-run), or a scenario TOML file or a "
                        "bundled scenario's name (run as it says)")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="loop directory to write")
    p.add_argument("--engine", choices=["zenoh", "inproc"], default="zenoh",
                   help="zenoh: router, simulator and agents as separate processes; inproc: one process")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="scenario override for both runs (dotted key, TOML value; repeatable); not with a run directory")
    p.add_argument("--seed", type=int, help="run seed for both runs (overrides the scenario's); not with a run directory")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")

    p = sub.add_parser("import", help="convert a dataset into a recording (measured-data format)",
                       description="Write a recording directory (run.toml + samples.csv) from a published dataset "
                                   "(docs/diagnose.md, 'EMPS').")
    isub = p.add_subparsers(dest="format", required=True)
    q = isub.add_parser("emps", help="the EMPS benchmark's .mat file: one agent, position x = qm, fx = gtau * vir",
                        description="Import DATA_EMPS.mat or DATA_EMPS_PULSES.mat (Janot, Gautier, Brunot 2019).")
    q.add_argument("file", type=Path, help="the .mat file")
    q.add_argument("--out", type=Path, required=True, metavar="DIR", help="recording directory to write")

    p = sub.add_parser("export", help="write a run directory in a standard viewer's format (MCAP: Foxglove, Rerun)",
                       description="Write a run directory as an MCAP file (JSON channels with Foxglove's schemas: "
                                   "the load's transform, pose and scene, each agent's estimates, the truth, the "
                                   "link statistics) for Foxglove or Rerun. Needs the viz extra: "
                                   "pip install 'coload[viz]'. See docs/viewers.md.")
    p.add_argument("run_dir", type=Path, help="a run directory")
    p.add_argument("--mcap", nargs="?", const="", metavar="FILE",
                   help="write an MCAP file (default FILE: RUN_DIR/run.mcap)")
    _add_verbose_after_command(sub)
    return parser


def _version_line() -> str:
    from coload.provenance import commit, version

    rev = commit()
    return f"coload {version('coload')}" + (f" (commit {rev})" if rev else "")


def _add_verbose_after_command(sub: argparse._SubParsersAction) -> None:
    """``-v`` after the command too (``coload run X -v``), on every command and action; counted with any
    given before it."""
    for p in sub.choices.values():
        p.add_argument("-v", "--verbose", action=_MoreVerbose, nargs=0, default=argparse.SUPPRESS,
                       help="more log output (-vv for debug)")
        for action in p._actions:
            if isinstance(action, argparse._SubParsersAction):
                _add_verbose_after_command(action)


class _MoreVerbose(argparse.Action):
    # a subcommand parses into a namespace of its own, copied over the top-level one afterwards: the count
    # goes in a separate field that main() adds to the top-level -v
    def __call__(self, parser, namespace, values, option_string=None):
        namespace.verbose_after = getattr(namespace, "verbose_after", 0) + 1


COMMANDS = {"run": cmd_run, "sim": cmd_sim, "agent": cmd_agent, "router": cmd_router, "report": cmd_report,
            "compose": cmd_compose, "alive": cmd_alive, "keys": cmd_keys, "campaign": cmd_campaign,
            "observer": cmd_observer, "hinf": cmd_hinf, "arms": cmd_arms, "diagnose": cmd_diagnose,
            "export": cmd_export, "view": cmd_view, "import": cmd_import, "loop": cmd_loop}


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
    args.verbose += getattr(args, "verbose_after", 0)
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
    except ExtraMissing as exc:
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
