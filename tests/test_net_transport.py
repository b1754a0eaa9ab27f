"""Transport contract suite, run against every implementation (in-memory and real Zenoh).

The Zenoh half is real: an embedded router in its own OS process on a free loopback port, client
sessions connected to it, and, for crash/hang detection, a peer in yet another process that is
SIGKILLed or SIGSTOPped. Waits are on futures with timeouts, never sleeps.
"""

from __future__ import annotations

import asyncio
import os
import select
import signal
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Awaitable, Callable, Iterator
from pathlib import Path

import pytest

from net import keys
from net.memory import MemoryBus, MemoryTransport
from net.transport import Transport
from net.zenoh_transport import ZenohTransport, free_tcp_port, zenoh_config

REPO = Path(__file__).resolve().parents[1]
NODE = REPO / "tests" / "net_helpers" / "zenoh_node.py"
LEASE_MS = 1000
TIMEOUT = 10.0


# ---------------------------------------------------------------------------------------------
# Helper processes


def _spawn(*args: str) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        [sys.executable, str(NODE), *args],
        cwd=REPO,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )


def _wait_ready(proc: subprocess.Popen[bytes], timeout: float = 20.0) -> None:
    """Block until the helper prints READY (it does so once its session is up)."""
    assert proc.stdout is not None
    fd = proc.stdout.fileno()
    buf = b""
    deadline = time.monotonic() + timeout
    while b"READY" not in buf:
        left = deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError(f"helper not ready after {timeout} s: {buf!r}")
        r, _, _ = select.select([fd], [], [], left)
        if r:
            chunk = os.read(fd, 4096)
            if not chunk:
                err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
                raise RuntimeError(f"helper exited ({proc.wait()}) before READY: {err}")
            buf += chunk


def _stop(proc: subprocess.Popen[bytes]) -> None:
    """Terminate (then kill) a helper and reap it, whatever state it is in."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGCONT)  # in case a test stopped it
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5)
    for f in (proc.stdout, proc.stderr):
        if f is not None:
            f.close()


@pytest.fixture(scope="module")
def router() -> Iterator[str]:
    """A Zenoh router in its own process on a free loopback port; yields its endpoint."""
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    proc = _spawn("router", "--listen", endpoint, "--lease-ms", str(LEASE_MS))
    try:
        _wait_ready(proc)
        yield endpoint
    finally:
        _stop(proc)


# ---------------------------------------------------------------------------------------------
# Implementations under test


class _MemoryImpl:
    def __init__(self) -> None:
        self.bus: MemoryBus | None = None

    def make(self) -> Transport:
        if self.bus is None:
            self.bus = MemoryBus(asyncio.get_running_loop())
        return MemoryTransport(self.bus)


class _ZenohImpl:
    def __init__(self, endpoint: str) -> None:
        self.endpoint = endpoint

    def make(self) -> Transport:
        conf = zenoh_config("client", connect=[self.endpoint], lease_ms=LEASE_MS)
        return ZenohTransport(conf, asyncio.get_running_loop())


@pytest.fixture(
    params=[pytest.param("memory"), pytest.param("zenoh", marks=pytest.mark.zenoh)],
)
def impl(request: pytest.FixtureRequest) -> _MemoryImpl | _ZenohImpl:
    if request.param == "memory":
        return _MemoryImpl()
    return _ZenohImpl(request.getfixturevalue("router"))


def run(body: Callable[[Callable[[], Transport]], Awaitable[None]], impl: _MemoryImpl | _ZenohImpl) -> None:
    """Run ``body(make)`` on a fresh loop; every transport it makes is closed afterwards."""

    async def main() -> None:
        made: list[Transport] = []

        def make() -> Transport:
            t = impl.make()
            made.append(t)
            return t

        try:
            await asyncio.wait_for(body(make), 60)
        finally:
            for t in made:
                t.close()

    asyncio.run(main())


def _run_name() -> str:
    return f"t{uuid.uuid4().hex[:10]}"


class Inbox:
    """Collects (key, value) pairs on the loop and lets a test await a condition on them."""

    def __init__(self) -> None:
        self.items: list[tuple[str, object]] = []
        self.threads: set[int] = set()
        self._changed = asyncio.Event()

    def __call__(self, key: str, value: object) -> None:
        self.threads.add(threading.get_ident())
        self.items.append((key, value))
        self._changed.set()

    async def until(self, cond: Callable[[list[tuple[str, object]]], bool], timeout: float = TIMEOUT) -> None:
        async def loop() -> None:
            while not cond(self.items):
                self._changed.clear()
                await self._changed.wait()

        await asyncio.wait_for(loop(), timeout)


# ---------------------------------------------------------------------------------------------
# Contract


def test_pubsub_delivers_later_on_the_loop_thread(impl: _MemoryImpl | _ZenohImpl) -> None:
    async def body(make: Callable[[], Transport]) -> None:
        run_ = _run_name()
        a, b = make(), make()
        key = keys.state(run_, 3)
        inbox = Inbox()
        in_publish = False

        def on_sample(k: str, p: bytes) -> None:
            assert not in_publish, "callback ran synchronously inside publish"
            inbox(k, p)

        b.subscribe(key, on_sample)
        assert await a.wait_subscribed(key, TIMEOUT)  # before a's own subscription matches too
        a.subscribe(key, on_sample)  # local delivery must follow the same rules
        in_publish = True
        a.publish(key, b"\x01\x02")
        in_publish = False
        await inbox.until(lambda items: len(items) == 2)
        assert inbox.items == [(key, b"\x01\x02")] * 2
        assert all(isinstance(p, bytes) for _, p in inbox.items)
        assert inbox.threads == {threading.get_ident()}

    run(body, impl)


def test_order_is_preserved_per_publisher(impl: _MemoryImpl | _ZenohImpl) -> None:
    async def body(make: Callable[[], Transport]) -> None:
        run_ = _run_name()
        a, b = make(), make()
        key = keys.state(run_, 0)
        inbox = Inbox()
        b.subscribe(key, inbox)
        assert await a.wait_subscribed(key, TIMEOUT)
        sent = [i.to_bytes(2, "big") for i in range(200)]
        for p in sent:
            a.publish(key, p)
        await inbox.until(lambda items: len(items) == len(sent))
        assert [p for _, p in inbox.items] == sent

    run(body, impl)


def test_a_raising_callback_does_not_strand_the_samples_behind_it(impl: _MemoryImpl | _ZenohImpl) -> None:
    # Zenoh hands samples over in bursts (one loop wake-up per burst): an exception in one delivery
    # goes to the loop's exception handler and the rest of the burst is still delivered, in order.
    async def body(make: Callable[[], Transport]) -> None:
        run_ = _run_name()
        a, b = make(), make()
        key = keys.state(run_, 5)
        inbox = Inbox()
        errors: list[BaseException | None] = []
        asyncio.get_running_loop().set_exception_handler(lambda _loop, ctx: errors.append(ctx.get("exception")))

        def on_sample(k: str, p: bytes) -> None:
            if p == b"bad":
                raise RuntimeError("handler bug")
            inbox(k, p)

        b.subscribe(key, on_sample)
        assert await a.wait_subscribed(key, TIMEOUT)
        sent = [b"1", b"bad", b"2", b"bad", b"3"]
        for p in sent:
            a.publish(key, p)
        await inbox.until(lambda items: len(items) == 3)
        assert [p for _, p in inbox.items] == [b"1", b"2", b"3"]
        assert len(errors) == 2 and all(isinstance(e, RuntimeError) for e in errors)

    run(body, impl)


def test_wildcards_match_one_chunk_and_many(impl: _MemoryImpl | _ZenohImpl) -> None:
    async def body(make: Callable[[], Transport]) -> None:
        run_, other = _run_name(), _run_name()
        a, b = make(), make()
        one, many = Inbox(), Inbox()
        b.subscribe(keys.agent_all(run_, "estimate"), one)
        b.subscribe(keys.run_all(run_), many)
        sentinel = keys.estimate(run_, 99)
        assert await a.wait_subscribed(sentinel, TIMEOUT)
        # `many` alone matches a state key: without this, `a` may not know of `many` yet when it
        # publishes s1 (matching `sentinel` only proves that `one` is known), and s1 goes nowhere
        assert await a.wait_subscribed(keys.state(run_, 1), TIMEOUT)
        a.publish(keys.state(run_, 1), b"s1")  # not an estimate: only `many`
        a.publish(keys.estimate(other, 1), b"x")  # another run: nobody
        a.publish(keys.estimate(run_, 1), b"e1")
        a.publish(keys.estimate(run_, 2), b"e2")
        a.publish(sentinel, b"end")  # same publisher session: arrives after the others
        await one.until(lambda items: (sentinel, b"end") in items)
        await many.until(lambda items: (sentinel, b"end") in items)
        assert one.items == [(keys.estimate(run_, 1), b"e1"), (keys.estimate(run_, 2), b"e2"), (sentinel, b"end")]
        assert [k for k, _ in many.items] == [
            keys.state(run_, 1), keys.estimate(run_, 1), keys.estimate(run_, 2), sentinel,
        ]

    run(body, impl)


def test_closed_subscription_gets_nothing_more(impl: _MemoryImpl | _ZenohImpl) -> None:
    async def body(make: Callable[[], Transport]) -> None:
        run_ = _run_name()
        a, b = make(), make()
        key = keys.state(run_, 5)
        closed, open_ = Inbox(), Inbox()
        sub = b.subscribe(key, closed)
        b.subscribe(key, open_)
        assert await a.wait_subscribed(key, TIMEOUT)
        a.publish(key, b"1")
        await closed.until(lambda items: len(items) == 1)
        await open_.until(lambda items: len(items) == 1)
        a.publish(key, b"2")  # may be queued on the loop already when we close: must not run
        sub.close()
        sub.close()  # idempotent
        a.publish(key, b"3")
        await open_.until(lambda items: len(items) == 3)
        assert closed.items == [(key, b"1")]

    run(body, impl)


def test_liveliness_appear_disappear_and_history(impl: _MemoryImpl | _ZenohImpl) -> None:
    async def body(make: Callable[[], Transport]) -> None:
        run_ = _run_name()
        watcher, early, late = make(), make(), make()
        k_sim, k_agent = keys.alive(run_, "sim", 0), keys.alive(run_, "agent", 4)
        early.declare_alive(k_sim)
        # Let the token reach the network before watching: the watch must report it as history.
        probe = Inbox()
        watcher.watch_alive(keys.alive_all(run_, "sim"), probe)
        await probe.until(lambda items: (k_sim, True) in items)

        seen = Inbox()
        watcher.watch_alive(keys.alive_all(run_), seen)
        await seen.until(lambda items: (k_sim, True) in items)  # history

        token = late.declare_alive(k_agent)
        await seen.until(lambda items: (k_agent, True) in items)
        own = keys.alive(run_, "recorder", 0)
        own_token = watcher.declare_alive(own)  # a watcher sees its own endpoint's tokens too
        await seen.until(lambda items: (own, True) in items)
        own_token.close()
        await seen.until(lambda items: (own, False) in items)
        token.close()
        await seen.until(lambda items: (k_agent, False) in items)
        early.close()  # closing the transport withdraws its tokens
        await seen.until(lambda items: (k_sim, False) in items)
        assert seen.threads == {threading.get_ident()}
        assert (keys.alive(run_, "agent", 4), True) not in probe.items  # role filter

    run(body, impl)


def test_closed_transport_refuses_work(impl: _MemoryImpl | _ZenohImpl) -> None:
    async def body(make: Callable[[], Transport]) -> None:
        t = make()
        t.close()
        t.close()  # idempotent
        with pytest.raises(RuntimeError):
            t.publish(keys.state(_run_name(), 0), b"x")
        with pytest.raises(RuntimeError):
            t.subscribe("coload/**", lambda k, p: None)

    run(body, impl)


def test_wait_subscribed_times_out_without_audience(impl: _MemoryImpl | _ZenohImpl) -> None:
    async def body(make: Callable[[], Transport]) -> None:
        t = make()
        t0 = time.monotonic()
        assert not await t.wait_subscribed(keys.state(_run_name(), 0), 0.3)
        assert time.monotonic() - t0 >= 0.25

    run(body, impl)


# ---------------------------------------------------------------------------------------------
# Zenoh only: other processes crashing and hanging


def _watch_foreign_token(router: str, sig: signal.Signals) -> float:
    """Start a peer process holding a token, send it ``sig``; return seconds until the watcher saw it go."""
    run_ = _run_name()
    key = keys.alive(run_, "agent", 7)
    proc = _spawn("token", "--connect", router, "--key", key, "--lease-ms", str(LEASE_MS))
    try:
        _wait_ready(proc)

        async def main() -> float:
            t = ZenohTransport(zenoh_config("client", connect=[router], lease_ms=LEASE_MS))
            try:
                seen = Inbox()
                t.watch_alive(keys.alive_all(run_), seen)
                await seen.until(lambda items: (key, True) in items)
                t0 = time.monotonic()
                proc.send_signal(sig)
                await seen.until(lambda items: (key, False) in items, timeout=5 * LEASE_MS / 1000)
                return time.monotonic() - t0
            finally:
                t.close()

        return asyncio.run(main())
    finally:
        proc.kill()
        _stop(proc)


@pytest.mark.zenoh
def test_killed_peer_process_is_seen_dead(router: str) -> None:
    latency = _watch_foreign_token(router, signal.SIGKILL)
    print(f"SIGKILL -> alive=False after {latency * 1000:.0f} ms")
    assert latency < LEASE_MS / 1000 + 1.0


@pytest.mark.zenoh
def test_hung_peer_process_is_seen_dead_after_its_lease(router: str) -> None:
    latency = _watch_foreign_token(router, signal.SIGSTOP)
    print(f"SIGSTOP -> alive=False after {latency * 1000:.0f} ms (lease {LEASE_MS} ms)")
    assert latency < 2 * LEASE_MS / 1000 + 1.0


@pytest.mark.zenoh
def test_router_process_is_reaped(router: str) -> None:
    """Sanity: the fixture's router is a separate, live process (and the fixture reaps it)."""
    async def main() -> None:
        t = ZenohTransport(zenoh_config("client", connect=[router]))
        try:
            assert t.session.info.routers_zid(), "client session has no router"
        finally:
            t.close()

    asyncio.run(main())
