"""``coload run``: starts the router, the simulator and the agents as OS processes, or runs in-process.

Every daemon reads the same resolved ``run.toml`` from the run directory, so they cannot disagree on
the scenario; their logs go to ``RUN_DIR/logs/``.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import re
import selectors
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

from config.loader import dump_scenario
from config.scenario import Scenario


class ProgressBar:
    """A one-line progress display on stderr (a line per 10 % when stderr is not a terminal)."""

    def __init__(self, label: str, quiet: bool = False, unit: str = "tick") -> None:
        self.label = label
        self.quiet = quiet
        self.unit = unit
        self.tty = sys.stderr.isatty()
        self.t0 = time.perf_counter()
        self._last_decile = -1

    def __call__(self, done: int, total: int, note: str = "") -> None:
        """``note``: shown after the count (a campaign's workers)."""
        if self.quiet or total <= 0:
            return
        note = f", {note}" if note else ""
        frac = done / total
        wall = time.perf_counter() - self.t0
        # remaining time at the pace so far: the number a user waiting on a long campaign wants
        eta = f", ~{wall * (total - done) / done:.0f}s left" if 0 < done < total else ""
        if self.tty:
            bar = "#" * int(30 * frac)
            sys.stderr.write(f"\r{self.label} [{bar:<30}] {100 * frac:5.1f}%  {self.unit} {done}/{total}{note}  "
                             f"{wall:6.1f}s wall{eta}   ")
            if done >= total:
                sys.stderr.write("\n")
            sys.stderr.flush()
        elif int(10 * frac) > self._last_decile:
            self._last_decile = int(10 * frac)
            print(f"{self.label}: {100 * frac:3.0f}% ({self.unit} {done}/{total}{note}, {wall:.1f}s wall{eta})",
                  file=sys.stderr, flush=True)


def default_run_dir(scenario: Scenario) -> Path:
    """runs/NAME-seedS-DATE, with -2, -3, ... if two runs start in the same second."""
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    base = Path("runs") / f"{scenario.name}-seed{scenario.seed}-{stamp}"
    path, k = base, 1
    while path.exists():
        k += 1
        path = base.with_name(f"{base.name}-{k}")
    return path


def prepare_run_dir(run_dir: Path) -> str | None:
    """Checks that ``run_dir`` can hold a run and clears a previous run's files from it (its tables,
    summary, report, diagnosis, restart journal: nothing of it may be read as the new run's, even if
    the new one fails before writing anything); returns a note saying so, or None. Raises ValueError
    naming the problem if the directory cannot be used."""
    from coload.rundir import format as fmt

    run_dir = Path(run_dir)
    if run_dir.exists() and not run_dir.is_dir():
        raise ValueError(f"--out {run_dir}: exists and is not a directory")
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(f"--out {run_dir}: cannot create it ({exc.strerror})") from None
    if not os.access(run_dir, os.W_OK):
        raise ValueError(f"--out {run_dir}: not writable")
    held = [name for name in (fmt.SUMMARY_JSON, fmt.INTERRUPTED_JSON, fmt.SAMPLES_CSV) if (run_dir / name).exists()]
    if not held:
        return None
    for name in (*fmt.DERIVED_FILES, fmt.SAMPLES_CSV, fmt.ESTIMATES_CSV, fmt.PAIRS_CSV, fmt.TRUTH_CSV, fmt.JOURNAL):
        (run_dir / name).unlink(missing_ok=True)
    return f"{run_dir} held a previous run ({', '.join(held)}): replaced"


def run_name_for(run_dir: Path) -> str:
    """A key-expression-safe namespace for this run."""
    base = re.sub(r"[^A-Za-z0-9_.-]+", "-", Path(run_dir).resolve().name).strip("-") or "run"
    return f"{base}-{os.getpid()}"


def run_inproc_cli(scenario: Scenario, run_dir: Path, quiet: bool = False) -> dict[str, Any]:
    from coload.runs.engine import run_inproc

    return run_inproc(scenario, run_dir, progress=ProgressBar(f"{scenario.name} (inproc)", quiet))


PARENT_ENV = "COLOAD_PARENT_PID"
"""Set for every child process a run starts: the pid of the ``coload`` process that supervises it."""


def die_with_parent(parent: int) -> None:
    """Ask the kernel to SIGTERM this process when its parent dies (Linux ``PR_SET_PDEATHSIG``), so
    that no daemon outlives a supervisor that was SIGKILLed; exit now if the parent is already gone."""
    if sys.platform.startswith("linux"):
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, int(signal.SIGTERM), 0, 0, 0)  # PR_SET_PDEATHSIG = 1
    if os.getppid() != parent:  # the parent died before the request took effect
        raise SystemExit(143)


class Terminated(BaseException):
    """SIGTERM, raised in the main thread of a supervising command (:func:`terminate_on_sigterm`) like
    Ctrl-C's KeyboardInterrupt, so that ``finally`` blocks stop the children. Not a KeyboardInterrupt:
    one raised inside a library call that runs Python code (zenoh's) makes the interpreter kill itself
    with SIGINT at exit."""


_starting = 0  # > 0 while a child is being started: a SIGTERM then waits until it is registered
_pending = False
_terminated = False  # a SIGTERM came: also for the supervision loops, in case a library swallowed the raise


def _on_sigterm(signum: int, frame: object) -> None:
    global _pending, _terminated
    _terminated = True
    if _starting:
        _pending = True
    else:
        raise Terminated


def check_terminated() -> None:
    """Raise :class:`Terminated` if a SIGTERM came: called by the supervision loops, because the
    raise of the handler can land inside a zenoh call that swallows it."""
    if _terminated:
        raise Terminated


def terminate_on_sigterm() -> Any:
    """Make SIGTERM raise :class:`Terminated` in the main thread; returns the previous handler."""
    global _pending, _terminated
    _pending = _terminated = False  # a fresh command (several may run in one process, e.g. tests)
    return signal.signal(signal.SIGTERM, _on_sigterm)


class _Children:
    """The processes of one run; all of them are stopped on exit, whatever happens."""

    def __init__(self, log_dir: Path) -> None:
        self.log_dir = log_dir
        self.procs: dict[str, subprocess.Popen] = {}
        self._logs: list[IO] = []

    def start(self, name: str, argv: list[str], pipe_stdout: bool = False) -> subprocess.Popen:
        """Starts and registers one child; a SIGTERM that arrives in between is raised after the
        registration, so that no child is forked without being stopped later."""
        global _starting, _pending
        _starting += 1
        try:
            return self._start(name, argv, pipe_stdout)
        finally:
            _starting -= 1
            if _pending and not _starting:
                _pending = False
                raise Terminated

    def _start(self, name: str, argv: list[str], pipe_stdout: bool) -> subprocess.Popen:
        log = (self.log_dir / f"{name}.log").open("w")
        self._logs.append(log)
        proc = subprocess.Popen(
            argv,
            stdout=subprocess.PIPE if pipe_stdout else log,
            stderr=log,
            stdin=subprocess.DEVNULL,
            # PARENT_ENV: the child dies with this process even if it is SIGKILLed (coload.cli.main)
            env={**os.environ, "PYTHONUNBUFFERED": "1", PARENT_ENV: str(os.getpid())},
        )
        self.procs[name] = proc
        return proc

    def crashed(self) -> list[str]:
        return [n for n, p in self.procs.items() if p.poll() not in (None, 0)]

    def stop(self, names: list[str] | None = None, grace: float = 5.0, let_finish: float = 0.0) -> None:
        """Gives the processes ``let_finish`` s to exit on their own, then SIGTERM, then SIGKILL."""
        procs = [self.procs[n] for n in (names or list(self.procs))]
        deadline = time.monotonic() + let_finish
        for p in procs:
            try:
                p.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass
        for p in procs:
            if p.poll() is None:
                p.terminate()
        deadline = time.monotonic() + grace
        for p in procs:
            try:
                p.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()

    def close(self) -> None:
        self.stop()
        for f in self._logs:
            f.close()


def _read_line(stream: IO[bytes], timeout: float) -> str | None:
    sel = selectors.DefaultSelector()
    sel.register(stream, selectors.EVENT_READ)
    try:
        if not sel.select(timeout):
            return None
        return stream.readline().decode(errors="replace").strip()
    finally:
        sel.close()


def start_router(children: _Children, py: list[str], endpoint: str, run_dir: Path, cmd: str,
                 tls_dir: Path | None = None) -> bool:
    """Starts the embedded router (with ``tls_dir``: mutual TLS and the team's access-control list) and
    waits (30 s) for its ``ready`` line; False, said on stderr, if not."""
    secure = ["--tls-dir", str(tls_dir)] if tls_dir is not None else []
    router = children.start("router", [*py, "router", "--listen", endpoint, *secure], pipe_stdout=True)
    line = _read_line(router.stdout, 30.0)
    if not line or not line.startswith("ready"):
        print(f"{cmd}: the router did not come up (see {run_dir / 'logs' / 'router.log'})", file=sys.stderr)
        return False
    return True


def watch_simulator(
    children: _Children, sim: subprocess.Popen, endpoint: str, control_key: str, ticks: int, budget: float,
    bar: ProgressBar, run_dir: Path, cmd: str, tls_dir: Path | None = None,
) -> bool:
    """Shows progress from the simulator's control messages until it exits.

    False (said on stderr) if the simulator crashed or the run exceeded ``budget`` seconds; a crashed
    member other than the simulator is reported and the run goes on without it.
    """
    import zenoh

    from net.messages import Control
    from net.schema import DecodeError, decode
    from net.zenoh_transport import zenoh_config

    progressed = threading.Event()
    state = {"tick": 0}

    def on_control(sample: Any) -> None:  # Zenoh thread: record and signal, nothing more
        try:
            msg = decode(sample.payload.to_bytes(), Control)
        except DecodeError:
            return
        state["tick"] = msg.tick
        if msg.kind == "done":
            state["end"] = msg.tick  # the run may end before its duration (stop_after_done_s)
        progressed.set()

    conf = zenoh_config(mode="client", connect=[endpoint], listen=[])
    if tls_dir is not None:  # the monitor's certificate: it may hear the control notices and estimates only
        from net import access_policy

        conf.insert_json5("transport/link/tls", json.dumps(access_policy.tls_block(tls_dir, access_policy.MONITOR)))
    with zenoh.open(conf) as session:
        session.declare_subscriber(control_key, on_control)
        deadline = time.monotonic() + budget
        said: set[str] = set()  # crashed members already reported: each is said once
        while sim.poll() is None:
            check_terminated()
            if progressed.wait(0.5):
                progressed.clear()
                bar(state["tick"], ticks)
            bad = [name for name in children.crashed() if name not in said]
            if bad:
                said.update(bad)
                print(f"{cmd}: {', '.join(bad)} exited with an error (logs in {run_dir / 'logs'})", file=sys.stderr)
                if "sim" in bad:
                    return False
            if time.monotonic() > deadline:
                print(f"{cmd}: the run exceeded its time budget; stopping", file=sys.stderr)
                return False
    end = state.get("end", ticks)
    bar(end, end)
    return True


def process_run(run_dir: Path, verbose: int = 0, listen: str | None = None) -> tuple[str, str, list[str], _Children]:
    """What every multi-process run starts from: ``run_dir/logs``, the embedded router's endpoint
    (``listen``, or a free loopback port), the run name (the key-expression namespace), the command
    that starts a ``coload`` child process and the supervisor of the children."""
    from net.zenoh_transport import free_tcp_port

    (run_dir / "logs").mkdir(parents=True, exist_ok=True)
    endpoint = listen or f"tcp/127.0.0.1:{free_tcp_port()}"
    py = [sys.executable, "-m", "coload"] + (["-v"] * verbose)
    return endpoint, run_name_for(run_dir), py, _Children(run_dir / "logs")


def secure_endpoint() -> str:
    """A free loopback ``tls/`` endpoint for a secure run's embedded router."""
    from net.zenoh_transport import free_tcp_port

    return f"tls/127.0.0.1:{free_tcp_port()}"


def make_run_keys(run_dir: Path, neighbours: list, run: str, endpoint: str) -> Path:
    """A secure run's own team in ``run_dir/keys``: a fresh CA (a previous run's keys are replaced),
    certificates valid one day for the router's host, the policy for ``run`` and ``neighbours``."""
    import shutil

    from coload.certificates import init_team

    tls_dir = run_dir / "keys"
    shutil.rmtree(tls_dir, ignore_errors=True)
    host = endpoint.split("/", 1)[1].rsplit(":", 1)[0].strip("[]")
    init_team(tls_dir, neighbours, run=run, endpoint=endpoint, hosts=sorted({"localhost", "127.0.0.1", host}),
              days=1.0, now=_dt.datetime.now(_dt.timezone.utc))
    return tls_dir


def run_processes(scenario: Scenario, run_dir: Path, quiet: bool = False, verbose: int = 0,
                  listen: str | None = None, secure: bool = False,
                  on_router: Callable[[str, str], Any] | None = None) -> dict[str, Any] | None:
    """The real thing: an embedded Zenoh router, the simulator and n agent daemons, each its own process.
    ``listen``: the router's endpoint, for clients of the run (docs/wire.md); default a free loopback port.
    ``secure``: a team's keys are made in ``run_dir/keys`` for this run (certificates valid one day),
    and every member speaks mutual TLS under the team's default-deny access-control list.
    ``on_router(endpoint, run)``: called once the router listens, before the simulator starts (a live view)."""
    from agents.kernels import warm
    from net import keys

    # the compiled core is compiled here once, so that the agent daemons only load its cache (an H-infinity
    # run, which shares process_run, steps none of it)
    warm()
    run_dir = Path(run_dir)
    if secure and listen is None:
        listen = secure_endpoint()
    endpoint, run, py, children = process_run(run_dir, verbose, listen)
    toml = run_dir / "run.toml"
    toml.write_text(dump_scenario(scenario), encoding="utf-8")
    tls_dir = make_run_keys(run_dir, scenario.neighbours(), run, endpoint) if secure else None
    bar = ProgressBar(f"{scenario.name} (zenoh, {scenario.n} agents)", quiet)
    try:
        if not start_router(children, py, endpoint, run_dir, "coload run", tls_dir):
            return None
        # what a client of the run needs (docs/wire.md): the router and the key space
        print(f"coload run: router {endpoint}, keys coload/{run}/**", file=sys.stderr, flush=True)
        if on_router is not None:
            on_router(endpoint, run)
        common = [str(toml), "--connect", endpoint, "--run", run,
                  *(["--tls-dir", str(tls_dir)] if tls_dir is not None else [])]
        sim = children.start("sim", [*py, "sim", *common, "--out", str(run_dir)])
        for i in range(scenario.n):
            children.start(f"agent-{i}", [*py, "agent", "--id", str(i), *common])
        # generous: start-up of n + 2 interpreters plus the run itself
        budget = 120.0 + scenario.timing.startup_timeout_s + 50.0 * scenario.duration
        if not watch_simulator(children, sim, endpoint, keys.sim_control(run), scenario.ticks, budget, bar,
                               run_dir, "coload run", tls_dir):
            return None
        check_terminated()  # a SIGTERM whose raise zenoh swallowed as the watch ended
        if sim.returncode != 0:
            print(f"coload run: the simulator failed (see {run_dir / 'logs' / 'sim.log'})", file=sys.stderr)
            return None
        agents = [n for n in children.procs if n.startswith("agent-")]
        children.stop(agents, let_finish=10.0)
        summary_path = run_dir / "summary.json"
        summary = json.loads(summary_path.read_text())
        # members that ended with an error status of their own (not our stop's signal): the run went on
        # without them, and the command says so in its exit status (cmd_run)
        failed = [n for n in agents if (children.procs[n].returncode or 0) > 0]
        if failed:
            summary["failed_members"] = {n: _last_line(run_dir / "logs" / f"{n}.log") for n in failed}
        return summary
    finally:
        children.close()


def _last_line(path: Path) -> str:
    """A member's last log line: its own one-line account of why it ended."""
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").strip().splitlines()
    except OSError:
        return ""
    return lines[-1] if lines else ""


async def run_daemons_in_memory(scenario: Scenario, run_dir: Path) -> dict[str, Any]:
    """The daemons themselves, on the in-memory transport, in one event loop.

    Same code paths as a Zenoh run (codec, link model, liveliness, lockstep waits), no sockets:
    the fast way to test the daemons.
    """
    import asyncio

    from agents.daemon import AgentDaemon
    from coload.analysis.summary import complete_summary
    from coload.rundir.recorder import Recorder
    from net.memory import MemoryBus, MemoryTransport
    from net.vocabulary import ESTIMATE_NAMES
    from simulator.daemon import SimDaemon

    loop = asyncio.get_running_loop()
    bus = MemoryBus()
    run = run_name_for(run_dir)
    transports = [MemoryTransport(bus, loop) for _ in range(scenario.n + 1)]
    agents = [AgentDaemon(scenario.agent_view(i), transports[i], run) for i in range(scenario.n)]
    agent_tasks = [asyncio.ensure_future(a.run()) for a in agents]
    try:
        recorder = Recorder(run_dir, scenario, ESTIMATE_NAMES)
        summary = await SimDaemon(scenario, transports[-1], run, recorder, engine="memory").run()
        await asyncio.wait_for(asyncio.gather(*agent_tasks), 10.0)
    finally:
        for t in agent_tasks:
            t.cancel()
        for t in transports:
            t.close()
    return complete_summary(run_dir, scenario, summary)
