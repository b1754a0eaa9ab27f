"""The one interface daemons talk through (principle 2); Zenoh and in-memory implement it.

As in httpx, the transport is passed in: a daemon never opens a socket itself, so the same daemon
code runs over :class:`net.zenoh_transport.ZenohTransport` (real processes) and
:class:`net.memory.MemoryTransport` (one process: the daemons themselves, in fast tests; campaigns
use the in-process engine, ``coload.runs.engine``, which calls the agents' cores directly).

Threading contract, for every implementation: callbacks (``on_sample``, ``on_change``) run on the
asyncio loop the transport was created with, never on a network thread and never synchronously
inside :meth:`Transport.publish`; after a subscription's ``close()`` returns, its callback is not
called again. Payloads are opaque bytes here; :mod:`net.schema` gives them meaning.
"""

from __future__ import annotations

import asyncio
from abc import ABC, abstractmethod
from typing import Callable, Protocol

OnSample = Callable[[str, bytes], None]
"""``on_sample(key, payload)``: one received sample on a concrete key."""
OnAliveChange = Callable[[str, bool], None]
"""``on_change(key, alive)``: a liveliness token appeared (True) or disappeared (False)."""


class Subscription(Protocol):
    """Handle of a subscription, liveliness token or watcher; ``close()`` is idempotent."""

    def close(self) -> None: ...


class Transport(ABC):
    """Publish/subscribe of opaque payloads plus liveliness, bound to one asyncio loop."""

    @abstractmethod
    def publish(self, key: str, payload: bytes) -> None:
        """Send ``payload`` on the concrete ``key`` (no wildcards). Never calls back synchronously."""

    @abstractmethod
    def subscribe(self, key_expr: str, on_sample: OnSample) -> Subscription:
        """Call ``on_sample(key, payload)`` on the loop thread for every sample matching ``key_expr``."""

    @abstractmethod
    def declare_alive(self, key: str) -> Subscription:
        """Declare a liveliness token on ``key``; ``close()`` (or closing the transport) withdraws it."""

    @abstractmethod
    def watch_alive(self, key_expr: str, on_change: OnAliveChange) -> Subscription:
        """Report tokens matching ``key_expr`` as they appear and disappear, on the loop thread.

        Tokens already alive when the watch starts are reported too (``alive=True``), so a daemon
        that starts last still learns who is there.
        """

    @abstractmethod
    async def wait_subscribed(self, key: str, timeout: float) -> bool:
        """Wait until at least one subscriber matches ``key`` (or ``timeout`` s); True if one does.

        Lets a publisher wait for its audience instead of sleeping before the first publish.
        """

    @abstractmethod
    def close(self) -> None:
        """Close every subscription and token of this transport (watchers elsewhere see them go)."""

    @property
    @abstractmethod
    def loop(self) -> asyncio.AbstractEventLoop:
        """The loop on which callbacks run."""

    def __enter__(self) -> Transport:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class _Closable:
    """A subscription handle: a flag checked before every delivery plus an undeclare action."""

    __slots__ = ("closed", "_on_close")

    def __init__(self, on_close: Callable[[], None] | None = None) -> None:
        self.closed = False
        self._on_close = on_close

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        if self._on_close is not None:
            on_close, self._on_close = self._on_close, None
            on_close()


class _Handles:
    """The open handles of one transport, so that closing the transport closes them all."""

    __slots__ = ("_open",)

    def __init__(self) -> None:
        self._open: set[_Closable] = set()

    def track(self, h: _Closable, undeclare: Callable[[], None]) -> _Closable:
        """Registers ``h``; closing it runs ``undeclare`` once and forgets it."""

        def on_close() -> None:
            self._open.discard(h)
            undeclare()

        h._on_close = on_close
        self._open.add(h)
        return h

    def close_all(self) -> None:
        for h in list(self._open):
            h.close()
