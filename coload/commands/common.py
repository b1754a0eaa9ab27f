"""What every command handler shares: the scenario, output-path checks, a daemon's Zenoh session."""

from __future__ import annotations

import argparse
import asyncio
import os
import signal
import sys
from collections.abc import Sequence
from pathlib import Path

from config.loader import ScenarioError, load_scenario

VIEW_PORT = 8765  # Foxglove's default WebSocket port


def writable(flag: str, path: Path) -> str | None:
    """Why ``path`` (given as ``flag``) cannot be written, checked before any work; None if it can be."""
    where = f"{flag} {path}: cannot write there"
    if path.is_dir():
        return f"{where}: it is a directory"
    parent = path.parent
    if not parent.is_dir():
        return f"{where}: no directory {parent}"
    if not os.access(parent, os.W_OK | os.X_OK) or (path.exists() and not os.access(path, os.W_OK)):
        return f"{where}: permission denied"
    return None


def refuse_unwritable(command: str, *outputs: tuple[str, Path | None]) -> bool:
    """Print the one line for the first output that cannot be written; True if there was one."""
    for flag, path in outputs:
        problem = writable(flag, path) if path is not None else None
        if problem:
            print(f"coload {command}: {problem}", file=sys.stderr)
            return True
    return False


def scenario_of(args: argparse.Namespace):
    overrides = list(args.overrides)
    if args.seed is not None:
        overrides.append(f"seed={args.seed}")
    if args.mode is not None:
        overrides.append(f'mode="{args.mode}"')
    return load_scenario(args.scenario, overrides)


def check_law(scenario, source: str, agents: Sequence[int]) -> None:
    """The user's control law, imported and built for ``agents`` before any process or run starts, so that
    a bad one is one scenario error (ScenarioError) rather than a failure per daemon or per run."""
    if not scenario.control.law:
        return
    from agents.factory import build_law
    from agents.laws import ControlLawError

    try:
        for i in agents:
            build_law(scenario.agent_view(i))
    except ControlLawError as exc:
        raise ScenarioError(str(source), None, "control.law", str(exc).removeprefix("control.law ")) from None


def zenoh_conf_of(args: argparse.Namespace, role: str):
    from coload.zenoh_flags import zenoh_conf

    return zenoh_conf(args, role)


class DaemonStartError(Exception):
    """A daemon could not start: no router, a bad endpoint or config, an agent id the scenario lacks."""


async def serve(coro_factory, transport_factory):
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


def run_daemon(name: str, args: argparse.Namespace, coro_factory, role: str):
    """Opens the daemon's Zenoh session and runs it; start-up errors are one line on stderr, exit 2."""
    from net.zenoh_transport import ZenohTransport

    try:
        conf = zenoh_conf_of(args, role)
    except ValueError as exc:  # a bad config file, --cfg or --tls-dir
        print(f"coload {name}: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    try:
        return asyncio.run(serve(coro_factory, lambda loop: ZenohTransport(conf, loop)))
    except DaemonStartError as exc:  # only what failed before the daemon ran; later errors keep their traceback
        print(f"coload {name}: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
