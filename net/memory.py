"""In-process transport: a bus shared by endpoints on one asyncio loop.

For fast tests of the daemons (campaigns use ``coload.runs.engine`` instead, without daemons): no sockets, no threads, yet the same contract as Zenoh
(delivery later on the loop, never inside ``publish``; ``*``/``**`` key expressions; liveliness with
history, and tokens withdrawn when their endpoint closes, which is how a crash looks to the others).
All methods must be called on the bus's loop thread.
"""

from __future__ import annotations

import asyncio
from collections import defaultdict

from net.keys import key_matches
from net.transport import (
    OnAliveChange,
    OnSample,
    Subscription,
    Transport,
    _Closable,
    _Handles,
)


class _Sub(_Closable):
    __slots__ = ("key_expr", "callback")

    def __init__(self, key_expr: str, callback: OnSample | OnAliveChange) -> None:
        super().__init__()
        self.key_expr = key_expr
        self.callback = callback


class MemoryBus:
    """The shared medium: subscriptions, liveliness tokens and watchers of every endpoint."""

    def __init__(self, loop: asyncio.AbstractEventLoop | None = None) -> None:
        self.loop = loop if loop is not None else asyncio.get_running_loop()
        self._subs: list[_Sub] = []
        self._route: dict[str, list[_Sub]] = {}  # concrete key -> matching subs (cache)
        self._tokens: dict[str, int] = defaultdict(int)  # key -> number of live tokens
        self._watchers: list[_Sub] = []
        self._waiters: list[tuple[str, asyncio.Future[bool]]] = []
        self.published = 0
        """Samples published on the bus (for tests and campaign statistics)."""

    # -- pub/sub ---------------------------------------------------------------------------------
    def _add_sub(self, sub: _Sub) -> None:
        self._subs.append(sub)
        self._route.clear()
        for key, fut in self._waiters:
            if not fut.done() and key_matches(sub.key_expr, key):
                fut.set_result(True)
        self._waiters = [(k, f) for k, f in self._waiters if not f.done()]

    def _remove_sub(self, sub: _Sub) -> None:
        self._subs.remove(sub)
        self._route.clear()

    def _matching(self, key: str) -> list[_Sub]:
        subs = self._route.get(key)
        if subs is None:
            subs = self._route[key] = [s for s in self._subs if key_matches(s.key_expr, key)]
        return subs

    def _publish(self, key: str, payload: bytes) -> None:
        self.published += 1
        for sub in self._matching(key):
            self.loop.call_soon(_deliver, sub, key, payload)

    # -- liveliness ------------------------------------------------------------------------------
    def _token_up(self, key: str) -> None:
        self._tokens[key] += 1
        if self._tokens[key] == 1:
            self._notify(key, True)

    def _token_down(self, key: str) -> None:
        self._tokens[key] -= 1
        if self._tokens[key] == 0:
            del self._tokens[key]
            self._notify(key, False)

    def _notify(self, key: str, alive: bool) -> None:
        for w in self._watchers:
            if key_matches(w.key_expr, key):
                self.loop.call_soon(_deliver, w, key, alive)

    def _add_watcher(self, w: _Sub) -> None:
        self._watchers.append(w)
        for key in sorted(self._tokens):
            if key_matches(w.key_expr, key):
                self.loop.call_soon(_deliver, w, key, True)


def _deliver(sub: _Sub, key: str, arg: bytes | bool) -> None:
    if not sub.closed:
        sub.callback(key, arg)


class MemoryTransport(Transport):
    """One endpoint (one daemon) on a :class:`MemoryBus`."""

    def __init__(self, bus: MemoryBus, loop: asyncio.AbstractEventLoop | None = None) -> None:
        if loop is not None and loop is not bus.loop:
            raise ValueError("every MemoryTransport of a bus must use the bus's loop")
        self._bus = bus
        self._handles = _Handles()
        self._closed = False

    @property
    def loop(self) -> asyncio.AbstractEventLoop:
        return self._bus.loop

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError("transport is closed")

    def publish(self, key: str, payload: bytes) -> None:
        self._check_open()
        self._bus._publish(key, bytes(payload))

    def subscribe(self, key_expr: str, on_sample: OnSample) -> Subscription:
        self._check_open()
        sub = _Sub(key_expr, on_sample)
        self._bus._add_sub(sub)
        return self._handles.track(sub, lambda: self._bus._remove_sub(sub))

    def declare_alive(self, key: str) -> Subscription:
        self._check_open()
        self._bus._token_up(key)
        return self._handles.track(_Closable(), lambda: self._bus._token_down(key))

    def watch_alive(self, key_expr: str, on_change: OnAliveChange) -> Subscription:
        self._check_open()
        w = _Sub(key_expr, on_change)
        self._bus._add_watcher(w)
        return self._handles.track(w, lambda: self._bus._watchers.remove(w))

    async def wait_subscribed(self, key: str, timeout: float) -> bool:
        self._check_open()
        if self._bus._matching(key):
            return True
        fut: asyncio.Future[bool] = self.loop.create_future()
        self._bus._waiters.append((key, fut))
        try:
            return await asyncio.wait_for(fut, timeout)
        except asyncio.TimeoutError:
            return False

    def close(self) -> None:
        """Withdraw every subscription, watcher and token of this endpoint (as a crash would)."""
        if self._closed:
            return
        self._closed = True
        self._handles.close_all()
