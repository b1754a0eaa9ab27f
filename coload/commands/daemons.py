"""The team's processes and their set-up: agent, sim, router, alive, keys, compose."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from coload.commands.common import (
    check_law,
    run_daemon,
    scenario_of,
)
from config.loader import load_scenario


def cmd_agent(args: argparse.Namespace) -> int:
    from agents.daemon import AgentDaemon

    scenario = scenario_of(args)
    if not 0 <= args.id < scenario.n:
        print(f"coload agent: --id {args.id} is not an agent of {scenario.name} (0..{scenario.n - 1})",
              file=sys.stderr)
        return 2
    check_law(scenario, args.scenario, [args.id])
    from agents.kernels import warm

    warm()  # before the session opens: no tick of a realtime team waits on a compile or cache load
    daemon: list[AgentDaemon] = []

    def build(t):
        daemon.append(AgentDaemon(scenario.agent_view(args.id), t, args.run))
        return daemon[0].run()

    report = run_daemon("agent", args, build, f"agent-{args.id}")
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

    scenario = scenario_of(args)
    summary = run_daemon("sim", args, lambda t: SimDaemon(
        scenario, t, args.run, Recorder(args.out, scenario, ESTIMATE_NAMES)).run(), "sim")
    if summary is None:
        return 130
    complete_summary(args.out, scenario, summary)
    print(f"run directory: {args.out}")
    return 0


def cmd_router(args: argparse.Namespace) -> int:
    from coload.zenoh_flags import zenoh_conf
    from net.zenoh_transport import run_router, zenoh_error_text

    listen = args.listen
    try:
        conf = zenoh_conf(args, "router", mode="router", default_listen=["tcp/127.0.0.1:7447"])
        return run_router(None, config=conf)
    except ValueError as exc:
        print(f"coload router: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # zenoh.ZError: the port is taken, a bad locator
        print(f"coload router: cannot listen on {' '.join(listen or ['the config file endpoints'])} "
              f"({zenoh_error_text(exc)})", file=sys.stderr)
        return 2


def cmd_compose(args: argparse.Namespace) -> int:
    from coload.runs.compose import write_compose

    try:
        keys_dir = None
        if not args.insecure:
            keys_dir = "./keys"
            _compose_keys(args.out.parent / "keys", args)
        path = write_compose(args.out, args.agents, args.scenario, args.run, keys_dir=keys_dir)
    except ValueError as exc:
        print(f"coload compose: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {path}: docker compose -f {path} up --build")
    return 0


def _compose_keys(tls_dir: Path, args: argparse.Namespace) -> None:
    """The compose team's keys: made unless ``tls_dir`` holds this team's already."""
    import datetime as dt

    from coload.certificates import MANIFEST, init_team, load_team

    if args.agents < 2:
        raise ValueError(f"--agents must be at least 2, a team (got {args.agents})")
    if (tls_dir / MANIFEST).exists():
        team = load_team(tls_dir)
        if team.n != args.agents or team.run != args.run:
            raise ValueError(f"{tls_dir} holds the keys of another team ({team.n} agents, run {team.run}); "
                             "remove it or give another --out")
        return
    neighbours = load_scenario(args.scenario, [f"n={args.agents}"]).neighbours()
    init_team(tls_dir, neighbours, run=args.run, endpoint="tls/router:7447",
              now=dt.datetime.now(dt.timezone.utc))
    print(f"made the team's keys in {tls_dir}")


def cmd_alive(args: argparse.Namespace) -> int:
    from coload.runs.compose import check_alive
    from coload.zenoh_flags import zenoh_conf

    try:
        conf = zenoh_conf(args, "monitor", mode="client")
    except ValueError as exc:
        print(f"coload alive: {exc}", file=sys.stderr)
        return 2
    return 0 if check_alive(conf, args.key, args.timeout) else 1


def cmd_keys(args: argparse.Namespace) -> int:
    import datetime as dt

    from coload.certificates import KeysError, add_agent, init_team

    now = dt.datetime.now(dt.timezone.utc)
    try:
        if args.keys_command == "init":
            if args.agents < 1:
                raise KeysError(f"--agents must be at least 1 (got {args.agents})")
            if args.scenario is not None:
                neighbours = load_scenario(args.scenario, [f"n={args.agents}"]).neighbours()
            else:
                neighbours = [[j for j in range(args.agents) if j != i] for i in range(args.agents)]
            from coload.certificates import DEFAULT_HOSTS

            team = init_team(args.dir, neighbours, run=args.run, endpoint=args.endpoint,
                             hosts=args.host or DEFAULT_HOSTS, days=args.days, now=now)
            print(f"{args.dir}: a CA and keys for {', '.join(team.generations)} (valid {args.days:g} days)")
        else:
            neighbours = None
            if args.scenario is not None:
                sc = load_scenario(args.scenario)
                if args.agent >= sc.n:
                    sc = load_scenario(args.scenario, [f"n={args.agent + 1}"])
                neighbours = sc.neighbours()
            team = add_agent(args.dir, args.agent, neighbours=neighbours, now=now)
            role = f"agent-{args.agent}"
            print(f"{args.dir}: {role} generation {team.generations[role]}; restart the router to revoke the "
                  "older certificate")
    except (KeysError, ValueError) as exc:
        print(f"coload keys {args.keys_command}: {exc}", file=sys.stderr)
        return 2
    return 0
