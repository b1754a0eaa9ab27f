"""The real transport: Eclipse Zenoh (zenoh-python 1.x), plus config, router and port helpers.

Zenoh calls our callbacks on its own threads. They do the least possible there, copy the key and
payload out of the sample into an inbox drained on the asyncio loop, waking the loop with
``call_soon_threadsafe`` once per burst rather than once per sample; they never block and never call
Zenoh (principle 5). Liveliness tokens make a daemon visible while its session
lives: a clean close withdraws them at once, a killed process when the router sees its connection
drop, a hung one when its lease expires.

Configs are explicit: endpoints are listed, multicast scouting is off, nothing listens beyond the
endpoints given (coload runs on loopback or on the hosts named in the compose file).

Dead links (a cable pulled, a robot out of range): Zenoh sets ``SO_LINGER`` = 10 s on its TCP
sockets (a compile-time constant, no config key). When a lease expires on a link whose peer is
unreachable, the socket still holds unsent data, so closing it blocks the closing thread for 10 s;
a router closes on its RX runtime threads (two of them), so two dead links freeze the whole router
for 10 s (tests/test_netns.py, docs/faults.md; upstream eclipse-zenoh/zenoh#1101).
:class:`_LingerGuard` turns the linger off on this process's TCP sockets, so a close returns at once
and the kernel flushes or drops the data in the background. Every session and router opened here
runs it.
"""

from __future__ import annotations

import asyncio
import json
import os
import re
import signal
import socket
import stat
import struct
import threading
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Literal

import zenoh

from net.transport import OnAliveChange, OnSample, Subscription, Transport, _Closable, _Handles

Mode = Literal["peer", "client", "router"]

#: Reconnection to a lost router (client) or peer: first retry after 200 ms, then at most every 1 s
#: (Zenoh's default backs off to 4 s, too slow for a link that heals during a run).
RETRY = {"period_init_ms": 200, "period_max_ms": 1000, "period_increase_factor": 2}

_FD_DIR = "/proc/self/fd"
_NO_LINGER = struct.pack("ii", 0, 0)  # l_onoff = 0: close returns at once, the kernel finishes


def disable_linger_once(seen: set[int] | None = None) -> int:
    """Turn ``SO_LINGER`` off on every TCP socket of this process; returns how many were changed.

    Linux only (reads /proc/self/fd); elsewhere it does nothing. ``seen`` (socket inodes already
    handled) keeps repeated scans cheap. A socket is reached through a duplicate of its descriptor,
    so it shares the option with Zenoh's own descriptor; the duplicate is closed right away.
    """
    try:
        names = os.listdir(_FD_DIR)
    except OSError:
        return 0
    changed = 0
    for name in names:
        try:
            fd = int(name)
            st = os.fstat(fd)
        except (ValueError, OSError):
            continue  # closed since the listing
        if not stat.S_ISSOCK(st.st_mode) or (seen is not None and st.st_ino in seen):
            continue
        try:
            sock = socket.socket(fileno=os.dup(fd))
        except OSError:
            continue
        try:
            if sock.type == socket.SOCK_STREAM and sock.family in (socket.AF_INET, socket.AF_INET6):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, _NO_LINGER)
                changed += 1
            if seen is not None:
                seen.add(st.st_ino)
        except OSError:
            pass
        finally:
            sock.close()  # closes the duplicate only
    return changed


class _LingerGuard:
    """A background thread that runs :func:`disable_linger_once` every ``period`` s while at least
    one Zenoh session or router of this process is open (reference counted).

    Zenoh opens sockets on its own threads (accepts, reconnections), so they are found by polling;
    a scan of a daemon's ~20 descriptors costs tens of microseconds. Only a link that is opened and
    dies within one period keeps Zenoh's linger.
    """

    def __init__(self, period: float = 0.2) -> None:
        self.period = period
        self._lock = threading.Lock()
        self._users = 0
        self._stop: threading.Event | None = None

    def acquire(self) -> None:
        with self._lock:
            self._users += 1
            if self._stop is None:
                self._stop = threading.Event()
                threading.Thread(target=self._loop, args=(self._stop,), name="coload-linger",
                                 daemon=True).start()

    def release(self) -> None:
        with self._lock:
            self._users = max(0, self._users - 1)
            if self._users == 0 and self._stop is not None:
                self._stop.set()
                self._stop = None

    def _loop(self, stop: threading.Event) -> None:
        seen: set[int] = set()
        while True:
            disable_linger_once(seen)
            if stop.wait(self.period):
                return


_linger_guard = _LingerGuard()


def open_session(config: zenoh.Config) -> zenoh.Session:
    """``zenoh.open`` with the linger guard running for the session's life (see the module doc);
    close it with :func:`close_session`."""
    _linger_guard.acquire()
    try:
        session = zenoh.open(config)
    except BaseException:
        _linger_guard.release()
        raise
    disable_linger_once()  # the links opened by zenoh.open, without waiting for the first poll
    return session


def close_session(session: zenoh.Session) -> None:
    try:
        session.close()
    finally:
        _linger_guard.release()


def client_session(endpoint: str, tls: dict | None = None, timeout_ms: int = 20_000) -> zenoh.Session:
    """A client session on one endpoint, with a ``transport/link/tls`` block (``net.access_policy.tls_block``)
    when given; the connection attempt gives up after ``timeout_ms``. What a monitor or an outside
    client (the security tests' attacker) opens."""
    conf = zenoh_config(mode="client", connect=[endpoint])
    conf.insert_json5("connect/timeout_ms", str(timeout_ms))
    if tls is not None:
        conf.insert_json5("transport/link/tls", json.dumps(tls))
    return zenoh.open(conf)


def zenoh_config(
    mode: Mode | None = None,
    connect: Sequence[str] | None = None,
    listen: Sequence[str] | None = None,
    scouting: bool = False,
    lease_ms: int | None = None,
    config_file: str | Path | None = None,
    mode_if_unset: Mode = "peer",
) -> zenoh.Config:
    """Build a session config with explicit endpoints and, unless asked, no multicast scouting.

    ``connect``/``listen`` are Zenoh locators (``tcp/127.0.0.1:7447``); an empty ``listen`` means the
    session listens nowhere (Zenoh's default would be every interface). ``lease_ms`` shortens the
    lease after which a silent (hung, partitioned) session is declared dead; default 10 s.
    ``config_file`` (a Zenoh JSON5 config) is the base: its mode and endpoints stay unless ``mode``,
    ``connect`` or ``listen`` are given (``None``); without a file they default to a
    ``mode_if_unset`` session that connects to and listens on nothing; a file that does not name a
    mode gets ``mode_if_unset`` too, and one without listen endpoints listens nowhere. Multicast
    scouting is set either way (off unless ``scouting``): a daemon must not find peers its operator
    did not name.
    Clients and peers retry a lost connection after 200 ms, then every 1 s at most (:data:`RETRY`),
    unless the config file sets ``connect/retry`` itself.
    """
    if mode is not None and mode not in ("peer", "client", "router"):
        raise ValueError(f"mode must be peer, client or router: {mode!r}")
    if config_file is None:
        conf = zenoh.Config()
        mode, connect, listen = mode or mode_if_unset, connect or (), listen or ()
    else:
        try:
            conf = zenoh.Config.from_file(str(config_file))
        except Exception as exc:  # zenoh.ZError: the file is missing or not a valid config
            raise ValueError(f"{config_file}: not a usable Zenoh config ({zenoh_error_text(exc)})") from None
        text = Path(config_file).read_text(encoding="utf-8", errors="replace")
        if listen is None and not _file_sets(text, "listen"):
            listen = ()  # a file without listen endpoints: listen nowhere, not on every interface
        if mode is None and not _file_sets(text, "mode"):
            mode = mode_if_unset
    if mode is not None:
        conf.insert_json5("mode", json.dumps(mode))
    if connect is not None:
        conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    if listen is not None:
        conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    conf.insert_json5("scouting/multicast/enabled", json.dumps(bool(scouting)))
    if lease_ms is not None:
        if lease_ms <= 0:
            raise ValueError("lease_ms must be positive")
        conf.insert_json5("transport/link/tx/lease", json.dumps(int(lease_ms)))
    if json.loads(conf.get_json("mode")) != "router" and json.loads(conf.get_json("connect/retry")) is None:
        conf.insert_json5("connect/retry", json.dumps(RETRY))
    return conf


def zenoh_error_text(exc: BaseException) -> str:
    """A zenoh error's first line without its source location (zenoh appends ``at /path/file.rs:N``)."""
    return str(exc).splitlines()[0].split(" at /")[0] if str(exc) else type(exc).__name__


def _file_sets(text: str, key: str) -> bool:
    """Whether a JSON5 config text names ``key`` (quoted or not) anywhere: a file that writes
    ``mode: "peer"`` sets the mode, even to Zenoh's default."""
    return re.search(r"""(^|[{,\s])["']?%s["']?\s*:""" % re.escape(key), text) is not None


def router_config(
    listen: Sequence[str] | None, lease_ms: int | None = None, config_file: str | Path | None = None,
    connect: Sequence[str] | None = None,
) -> zenoh.Config:
    """A router's config: listening on ``listen`` (or the config file's endpoints) and connecting
    to ``connect`` (other routers of a mesh; or the file's). Never Zenoh's built-in listen
    endpoint, every interface: a file without endpoints needs ``listen``."""
    conf = zenoh_config("router", connect=connect, listen=listen, lease_ms=lease_ms, config_file=config_file)
    if not router_endpoints(conf):
        raise ValueError("a router needs at least one listen endpoint"
                         + (f" (--listen, or listen.endpoints in {config_file})" if config_file else ""))
    return conf


def router_endpoints(conf: zenoh.Config) -> list[str]:
    """The endpoints a (router) config listens on."""
    endpoints = json.loads(conf.get_json("listen/endpoints"))
    if isinstance(endpoints, dict):  # per-mode form {"router": [...], "peer": [...]}
        endpoints = endpoints.get("router", [])
    return [str(e) for e in endpoints or []]


def open_router(
    listen: Sequence[str] | None, lease_ms: int | None = None, config_file: str | Path | None = None,
    connect: Sequence[str] | None = None,
) -> zenoh.Session:
    """Open an embedded Zenoh router (see :func:`router_config`); the caller closes the session."""
    return open_session(router_config(listen, lease_ms, config_file, connect))


def _print_ready(listen: Sequence[str]) -> None:
    print("ready " + " ".join(listen), flush=True)


def run_router(
    listen: Sequence[str] | None,
    stop: threading.Event | None = None,
    lease_ms: int | None = None,
    on_ready: Callable[[], None] | None = None,
    config_file: str | Path | None = None,
    connect: Sequence[str] | None = None,
    config: zenoh.Config | None = None,
) -> int:
    """Run an embedded router until ``stop`` is set, or SIGTERM/SIGINT arrive; returns exit status 0.

    ``config``: a finished router config (TLS, access control, ...) instead of building one from
    ``listen``, ``lease_ms``, ``config_file`` and ``connect``.

    Meant to be the whole of a router process (``coload router``). Once the router listens,
    ``on_ready`` is called; by default it prints ``ready <endpoints>`` on stdout, the line a parent
    process waits for instead of sleeping. Without ``stop``, and on the main thread, SIGTERM and
    SIGINT close the router cleanly.
    """
    conf = router_config(listen, lease_ms, config_file, connect) if config is None else config
    if not router_endpoints(conf):
        raise ValueError("a router needs at least one listen endpoint (--listen, or listen.endpoints in its config)")
    session = open_session(conf)  # first: a router that cannot listen leaves the signal handlers alone
    if stop is None:
        stop = threading.Event()
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGTERM, signal.SIGINT):
                signal.signal(sig, lambda *_: stop.set())
    try:
        (on_ready or (lambda: _print_ready(router_endpoints(conf))))()
        while not stop.wait(1.0):  # a timed wait keeps the main thread responsive to signals
            pass
    finally:
        close_session(session)
    return 0


def free_tcp_port(host: str = "127.0.0.1") -> int:
    """A TCP port that was free on ``host`` a moment ago (the OS's pick), for tests and the CLI."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


class ZenohTransport(Transport):
    """A :class:`Transport` over one Zenoh session.

    Opening blocks briefly (a client connects to its router; it fails if none is reachable), so
    build it at daemon start-up. ``loop`` defaults to the running loop. Publishers are declared once
    per key and cached, reliable, congestion control BLOCK (lockstep equality with the in-process
    engine needs Zenoh itself never to drop: losses come from the link model only). ``express``
    (no batching) is off by default: an express put costs an order of magnitude more CPU than a
    batched one (docs/wire.md).
    """

    def __init__(
        self,
        config: zenoh.Config,
        loop: asyncio.AbstractEventLoop | None = None,
        *,
        express: bool = False,
    ) -> None:
        self._loop = loop if loop is not None else asyncio.get_running_loop()
        self._express = express
        self._session = open_session(config)
        self._pubs: dict[str, zenoh.Publisher] = {}
        self._handles = _Handles()
        self._closed = False
        # Samples handed over by Zenoh threads, drained on the loop thread. One loop wake-up
        # (call_soon_threadsafe, a self-pipe write) per burst, not per sample: ``_wake_pending`` is
        # set by the Zenoh thread that schedules the drain and cleared by the drain before it
        # empties the inbox, so a sample is never left behind without a drain scheduled.
        self._inbox: deque[tuple[_Closable, Callable[[str, object], None], str, object]] = deque()
        self._wake_pending = False

    @property
    def loop(self) -> asyncio.AbstractEventLoop:
        return self._loop

    @property
    def session(self) -> zenoh.Session:
        """The underlying session, for what the interface does not cover (admin space, info)."""
        return self._session

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError("transport is closed")

    def _handoff(self, h: _Closable, callback: Callable[[str, object], None], key: str, arg: object) -> None:
        """On a Zenoh thread: queue the delivery for the loop. Never blocks, never calls Zenoh.

        ``deque.append`` and the flag are safe under the GIL; the loop is woken only if no drain is
        already pending, so a burst of samples costs one wake-up.
        """
        self._inbox.append((h, callback, key, arg))
        if not self._wake_pending:
            self._wake_pending = True
            try:
                self._loop.call_soon_threadsafe(self._drain)
            except RuntimeError:
                # The loop is closed: the daemon is shutting down and nobody is listening any more.
                pass

    def _drain(self) -> None:
        """On the loop thread: deliver every queued sample, in arrival order."""
        self._wake_pending = False  # before draining: a sample queued from now on schedules a drain
        inbox = self._inbox
        while inbox:
            h, callback, key, arg = inbox.popleft()
            if h.closed:  # closed since the sample was queued
                continue
            try:
                callback(key, arg)
            except Exception as exc:  # one bad handler must not strand the samples behind it
                self._loop.call_exception_handler(
                    {"message": f"exception in a transport callback for {key}", "exception": exc})

    def _publisher(self, key: str) -> zenoh.Publisher:
        pub = self._pubs.get(key)
        if pub is None:
            pub = self._pubs[key] = self._session.declare_publisher(
                key,
                congestion_control=zenoh.CongestionControl.BLOCK,
                reliability=zenoh.Reliability.RELIABLE,
                express=self._express,
            )
        return pub

    def publish(self, key: str, payload: bytes) -> None:
        self._check_open()
        self._publisher(key).put(bytes(payload))

    def subscribe(self, key_expr: str, on_sample: OnSample) -> Subscription:
        self._check_open()
        h = _Closable()

        handoff = self._handoff

        def on_zenoh_sample(sample: zenoh.Sample) -> None:
            handoff(h, on_sample, str(sample.key_expr), sample.payload.to_bytes())

        # zenoh-python runs a plain callable on a Python thread of its own per subscriber (an
        # "indirect" callback): the Zenoh rx thread never waits for the GIL. Running it directly
        # on the rx thread (Callback(..., indirect=False)) saves that thread hop but makes the rx
        # thread take the GIL and build a fresh Python thread state per sample, for no gain on a
        # lockstep run (docs/wire.md), so the default stays.
        zsub = self._session.declare_subscriber(key_expr, on_zenoh_sample)
        # Gotcha: a subscriber declared with a callback lives on when its Python object is dropped;
        # only undeclare() (or closing the session) stops it.
        return self._handles.track(h, zsub.undeclare)

    def declare_alive(self, key: str) -> Subscription:
        self._check_open()
        token = self._session.liveliness().declare_token(key)
        return self._handles.track(_Closable(), token.undeclare)

    def watch_alive(self, key_expr: str, on_change: OnAliveChange) -> Subscription:
        self._check_open()
        h = _Closable()

        def on_zenoh_sample(sample: zenoh.Sample) -> None:
            self._handoff(h, on_change, str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)

        zsub = self._session.liveliness().declare_subscriber(key_expr, on_zenoh_sample, history=True)
        return self._handles.track(h, zsub.undeclare)

    async def wait_subscribed(self, key: str, timeout: float) -> bool:
        """Wait on the publisher's matching status (Zenoh knows when a subscriber matches)."""
        self._check_open()
        pub = self._publisher(key)
        if pub.matching_status.matching:
            return True
        fut: asyncio.Future[bool] = self._loop.create_future()

        def set_matched() -> None:
            if not fut.done():
                fut.set_result(True)

        def on_status(status: zenoh.MatchingStatus) -> None:
            if status.matching:
                try:
                    self._loop.call_soon_threadsafe(set_matched)
                except RuntimeError:
                    pass

        listener = pub.declare_matching_listener(on_status)
        try:
            if pub.matching_status.matching:  # matched between the first check and the listener
                return True
            return await asyncio.wait_for(fut, timeout)
        except asyncio.TimeoutError:
            return False
        finally:
            listener.undeclare()

    def close(self) -> None:
        """Undeclare everything, then close the session (its tokens vanish for every watcher)."""
        if self._closed:
            return
        self._closed = True
        self._handles.close_all()
        for pub in self._pubs.values():
            pub.undeclare()
        self._pubs.clear()
        close_session(self._session)
