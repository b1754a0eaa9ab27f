"""``coload run`` and ``coload view``: a whole team end to end, and the live view."""

from __future__ import annotations

import argparse
import asyncio
import sys

from coload.commands.common import (
    check_law,
    run_daemon,
    scenario_of,
)
from coload.extras import require


def cmd_run(args: argparse.Namespace) -> int:
    from coload.runs.orchestrate import (
        default_run_dir,
        prepare_run_dir,
        run_inproc_cli,
        run_processes,
    )

    # the batch-fit yardstick (record.batch_fit) is on for every `coload run` unless --no-batch-fit
    args.overrides = ["record.batch_fit=true", *args.overrides, *(["record.batch_fit=false"] if args.no_batch_fit else [])]
    scenario = scenario_of(args)
    check_law(scenario, args.scenario, range(scenario.n))
    run_dir = args.out or default_run_dir(scenario)
    if args.listen and args.engine != "zenoh":
        print("coload run: --listen is for --engine zenoh (the in-process engine has no router)", file=sys.stderr)
        return 2
    if args.view is not None and args.engine != "zenoh":
        print("coload run: --view is for --engine zenoh (the live view listens on the run's router)", file=sys.stderr)
        return 2
    if args.secure and args.engine != "zenoh":
        print("coload run: --secure is for --engine zenoh (the in-process engine has no network)", file=sys.stderr)
        return 2
    if args.secure and args.listen and not args.listen.startswith("tls/"):
        print(f"coload run: --secure needs a tls/ endpoint (--listen {args.listen})", file=sys.stderr)
        return 2
    view = _start_view(scenario, args.view) if args.view is not None else None
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
        try:
            summary = run_processes(scenario, run_dir, quiet=args.quiet, verbose=args.verbose, listen=args.listen,
                                    secure=args.secure,
                                    on_router=view.attach_to(run_dir / "keys" if args.secure else None)
                                    if view else None)
        finally:
            if view:
                view.close()
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
    if "agents_reported" in summary:
        silent = sorted(set(range(scenario.n)) - set(summary["agents_reported"]))
        if silent:
            print(f"coload run: agents {', '.join(map(str, silent))} did not report at the end "
                  f"(logs in {run_dir / 'logs'})", file=sys.stderr)
            return 1
    return 0


class _RunView:
    """`coload run --view`: the Foxglove server from the start, the Zenoh watcher once the router listens."""

    def __init__(self, scenario, port: int) -> None:
        from coload.viz.live import FoxgloveSink, LiveScene
        from coload.viz.scene import outline_body

        self.scene = LiveScene(scenario.n, scenario.dt, outline_body(scenario))
        self.sink = FoxgloveSink(scenario.n, "127.0.0.1", port)
        self.thread = None

    def attach_to(self, tls_dir):
        """The router callback: with ``tls_dir`` (a secure run's keys) the watcher holds the monitor's
        certificate, read-only: it may hear the load's pose, the estimates and the control notices."""
        return lambda endpoint, run: self.attach(endpoint, run, tls_dir)

    def attach(self, endpoint: str, run: str, tls_dir=None) -> None:
        import json

        from coload.viz.live import ViewThread
        from net import access_policy
        from net.zenoh_transport import zenoh_config

        conf = zenoh_config(mode="client", connect=[endpoint])
        if tls_dir is not None:
            conf.insert_json5("transport/link/tls", json.dumps(access_policy.tls_block(tls_dir, access_policy.MONITOR)))
        self.thread = ViewThread(conf, run, self.scene, self.sink)
        self.thread.start()

    def close(self) -> None:
        if self.thread is not None:
            self.thread.stop()
            c = self.thread.counts
            print(f"coload run: live view sent {c.get('pose', 0)} poses and {c.get('estimate', 0)} estimates"
                  + (f" (stopped: {self.thread.error})" if self.thread.error else ""), file=sys.stderr)
        self.sink.close()


def _start_view(scenario, port: int) -> _RunView:
    require("viz", "foxglove")
    try:
        view = _RunView(scenario, port)
    except RuntimeError as exc:  # the port is taken
        print(f"coload run: --view {port}: cannot serve there ({exc})", file=sys.stderr)
        raise SystemExit(2) from None
    print(f"coload run: live view on ws://127.0.0.1:{view.sink.port} (Foxglove: Open connection, Foxglove "
          f"WebSocket)", file=sys.stderr, flush=True)
    return view


def cmd_view(args: argparse.Namespace) -> int:
    """`coload view`: a live team's pose and estimates to Foxglove until the run's done notice or Ctrl-C."""
    from coload.viz.live import FoxgloveSink, LiveScene, watch
    from coload.viz.scene import outline_body

    require("viz", "foxglove")
    scenario = scenario_of(args)
    scene = LiveScene(scenario.n, scenario.dt, outline_body(scenario))
    try:
        sink = FoxgloveSink(scenario.n, args.host, args.port)
    except RuntimeError as exc:
        print(f"coload view: --port {args.port}: cannot serve there ({exc})", file=sys.stderr)
        return 2
    print(f"coload view: ws://{args.host}:{sink.port} (Foxglove: Open connection, Foxglove WebSocket); "
          f"watching run {args.run}", file=sys.stderr, flush=True)

    def build(transport):
        stop = asyncio.Event()
        return watch(transport, args.run, scene, sink.log, stop)

    try:
        counts = run_daemon("view", args, build, "monitor")
    finally:
        sink.close()
    if counts is None:
        return 130
    print(f"coload view: {counts['pose']} poses, {counts['estimate']} estimates, {counts['dropped']} dropped")
    return 0
