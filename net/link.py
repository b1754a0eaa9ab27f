"""Link fault model: what happens to each message on one directed link, decided at the receiver.

A :class:`LinkModel` owns the random stream of one directed link (sender -> receiver), seeded from
(run seed, sender, receiver) only. It is consulted once per message, in send order, and says after
which delays the copies arrive (none: lost; two: duplicated). Partitions (``LinkSpec.partitions``)
cut a link over time windows: a message sent at a tick inside a window that cuts this link is lost,
and :meth:`LinkModel.partitioned` says so, so that callers count it apart from random loss (a window
with ``drop = "stale_age"`` models states that arrive too old to use: :meth:`LinkModel.stale` says
so, and they are counted as ``stale_age``). Because the draws depend on nothing
but the seed and the message's rank on that link, the in-process engine and the Zenoh daemons see
the same faults for the same seed, whatever the wall-clock timing (principles 2 and 3).

:class:`DelayLine` is the lockstep receive buffer both engines use, so that their inboxes are equal
message for message; :class:`LinkStats` is the per-link counter block written to ``summary.json``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from heapq import heappop as _heappop
from heapq import heappush as _heappush
from typing import Final, Generic, Literal, TypeVar

import numpy as np

from config.scenario import AgentView, LinkSpec, Scenario

STREAM_ID: Final = 0x11C4
"""Fourth word of every link RNG seed: keeps link streams apart from other users of the run seed."""

_BLOCK: Final = 256
"""Messages whose uniforms are drawn in one numpy call (speed only: the stream is the same)."""
_U_PER_MSG: Final = 5
"""Uniforms consumed per message, whatever the spec: [chain step, loss, duplicate, jitter 1, jitter 2].

A fixed count keeps the draws of message k independent of the spec, so that e.g. turning on
duplication does not change which messages are lost.
"""

Mode = Literal["lockstep", "realtime"]
T = TypeVar("T")


class LinkModel:
    """Delay, jitter, loss (none / Bernoulli / Gilbert-Elliott) and duplication of one directed link.

    Parameters: ``spec`` the fault parameters; ``seed`` the run seed; ``sender``/``receiver`` the
    agent ids of the link's ends; ``mode`` selects delays in whole ticks (``lockstep``:
    ``delay_ticks`` + uniform integer jitter in [0, ``jitter_ticks``]) or in seconds (``realtime``:
    ``delay_s`` + uniform [0, ``jitter_s``)). The Gilbert-Elliott chain starts in a state drawn from
    its stationary distribution and steps once per message, after that message's loss draw.
    """

    __slots__ = (
        "_bad",
        "_fate",
        "_fixed",
        "_k",
        "_last_tick",
        "_rng",
        "_stale",
        "_u",
        "_windows",
        "mode",
        "receiver",
        "sender",
        "spec",
    )

    def __init__(
        self, spec: LinkSpec, seed: int, sender: int, receiver: int, mode: Mode = "lockstep",
        dt: float | None = None,
    ) -> None:
        if mode not in ("lockstep", "realtime"):
            raise ValueError(f"mode must be 'lockstep' or 'realtime': {mode!r}")
        if min(seed, sender, receiver) < 0:
            raise ValueError("seed, sender and receiver must be non-negative")
        self.spec = spec
        self.mode: Mode = mode
        self.sender = sender
        self.receiver = receiver
        self._rng = np.random.default_rng([seed, sender, receiver, STREAM_ID])
        self._u = np.empty((0, _U_PER_MSG))
        self._k = 0
        self._last_tick = -1
        loss = spec.loss
        u0 = float(self._rng.random())  # drawn for every model, so streams line up across specs
        total = loss.p_good_to_bad + loss.p_bad_to_good
        pi_bad = loss.p_good_to_bad / total if total > 0 else 0.0
        self._bad = loss.model == "gilbert_elliott" and u0 < pi_bad
        # a link without loss, jitter or duplication has one fate: skip the draws on the hot path
        jitter = spec.jitter_ticks if mode == "lockstep" else spec.jitter_s
        faultless = loss.model == "none" and spec.duplicate == 0 and jitter == 0
        # partition windows of this link, as half-open tick ranges [t0, t1) of the send tick
        self._windows = partition_windows(spec, dt, sender, receiver)
        self._stale = partition_windows(spec, dt, sender, receiver, "stale_age")
        # _fate: the one fate of an otherwise faultless link (no draws); _fixed: the same when no
        # partition touches the link either (then deliveries() is a constant)
        self._fate = (self._delay(0.0),) if faultless else None
        self._fixed = self._fate if not self._windows else None

    def _next_uniforms(self) -> np.ndarray:
        if self._k == len(self._u):
            self._u = self._rng.random((_BLOCK, _U_PER_MSG))
            self._k = 0
        u = self._u[self._k]
        self._k += 1
        return u

    def deliveries(self, tick: int) -> tuple[int, ...] | tuple[float, ...]:
        """Fate of the next message sent on this link (sent at ``tick``): one delay per delivered copy.

        ``()`` = lost, ``(d,)`` = delivered once after ``d``, ``(d1, d2)`` = duplicated. Delays are
        ints (ticks) in lockstep mode and floats (seconds) in realtime mode. Must be called exactly
        once per message, in send order; ``tick`` must not decrease.
        """
        if tick < self._last_tick:
            raise ValueError(f"link {self.sender}->{self.receiver}: tick {tick} after {self._last_tick}")
        self._last_tick = tick
        if self._fixed is not None:
            return self._fixed
        if self._fate is not None:  # faultless but partitioned at times: no draws, as without partitions
            return () if self.partitioned(tick) else self._fate
        u_step, u_loss, u_dup, u_j1, u_j2 = self._next_uniforms().tolist()
        loss = self.spec.loss
        if loss.model == "bernoulli":
            lost = u_loss < loss.p
        elif loss.model == "gilbert_elliott":
            lost = u_loss < (loss.loss_bad if self._bad else loss.loss_good)
            self._bad = (u_step >= loss.p_bad_to_good) if self._bad else (u_step < loss.p_good_to_bad)
        else:
            lost = False
        # the draws above are made whatever the partition schedule, so that a partition changes
        # the fate of the messages in its window only
        if lost or (self._windows and self.partitioned(tick)):
            return ()
        if u_dup < self.spec.duplicate:
            return (self._delay(u_j1), self._delay(u_j2))
        return (self._delay(u_j1),)

    def _delay(self, u: float) -> int | float:
        s = self.spec
        if self.mode == "lockstep":
            return s.delay_ticks + min(int(u * (s.jitter_ticks + 1)), s.jitter_ticks)
        return s.delay_s + u * s.jitter_s

    @property
    def longest_delay(self) -> int | float:
        """The largest delay :meth:`deliveries` can draw (delay + the whole jitter)."""
        return self._delay(1.0)

    def partitioned(self, tick: int) -> bool:
        """True if a message sent at ``tick`` on this link falls in a partition window that cuts it."""
        for t0, t1 in self._windows:
            if t0 <= tick < t1:
                return True
        return False

    def stale(self, tick: int) -> bool:
        """True if a message sent at ``tick`` falls in a ``stale_age`` window of this link (lost as too old)."""
        for t0, t1 in self._stale:
            if t0 <= tick < t1:
                return True
        return False

    @property
    def fixed_delays(self) -> tuple[int, ...] | tuple[float, ...] | None:
        """The one fate of every message on a link without loss, jitter or duplication, else None.

        For that link :meth:`deliveries` always returns this and draws nothing, so a caller may use
        it instead (the in-process engine's fast path).
        """
        return self._fixed

    @property
    def in_bad_state(self) -> bool:
        """Gilbert-Elliott state before the next message (always False for other loss models)."""
        return self._bad


@dataclass
class LinkStats:
    """Message counters of one directed link, filled by the engines, written to summary.json.

    ``sent``: messages offered to the link; ``delivered``: copies handed to the receiver (duplicates
    included); ``dropped``: messages lost by the fault model; ``duplicated``: extra copies;
    ``late``: copies that arrived after the receiver had moved past their tick; ``malformed``:
    payloads rejected by :func:`net.schema.decode`; ``partitioned``: messages lost because a partition
    cut the link when they were sent (not counted in ``dropped``, which is random loss only);
    ``stale_age``: messages of a ``drop = "stale_age"`` window, modelled as arriving too old to be used.
    """

    sent: int = 0
    delivered: int = 0
    dropped: int = 0
    duplicated: int = 0
    late: int = 0
    malformed: int = 0
    partitioned: int = 0
    stale_age: int = 0

    def count_lost(self, link: LinkModel, send_tick: int) -> None:
        """A message the link did not deliver: cut by a partition, or lost at random."""
        if link.partitioned(send_tick):
            if link.stale(send_tick):
                self.stale_age += 1
            else:
                self.partitioned += 1
        else:
            self.dropped += 1

    def as_dict(self) -> dict[str, int]:
        return asdict(self)

    def __add__(self, other: LinkStats) -> LinkStats:
        return LinkStats(**{k: v + getattr(other, k) for k, v in asdict(self).items()})


class DelayLine(Generic[T]):
    """Lockstep receive buffer: messages wait here until their delivery tick.

    :meth:`pop_due` returns due messages in an order that depends only on the messages, not on the
    order they were pushed in: (deliver tick, sender, send tick, copy index), then push order for the
    (unexpected) case of two messages from one sender for one tick. The Zenoh daemon pushes as
    samples arrive and the in-process engine pushes in agent order; both pop the same inbox.
    """

    __slots__ = ("_heap", "_seq")

    def __init__(self) -> None:
        self._heap: list[tuple[int, int, int, int, int, T]] = []
        self._seq = 0

    def push(self, deliver_tick: int, sender: int, send_tick: int, copy: int, msg: T) -> None:
        _heappush(self._heap, (deliver_tick, sender, send_tick, copy, self._seq, msg))
        self._seq += 1

    def offer(self, link: LinkModel, send_tick: int, msg: T, stats: LinkStats | None = None) -> int:
        """Pass ``msg`` (sent at ``send_tick``) through ``link`` and buffer its copies.

        A copy with delay d is due at ``send_tick + d``. Returns the number of copies buffered and
        counts sent / dropped / duplicated in ``stats`` (``delivered`` is counted by :meth:`pop_due`'s
        caller, who knows whether the copy was still useful).
        """
        if link.mode != "lockstep":
            raise ValueError("DelayLine is for lockstep links (delays in ticks)")
        delays = link.deliveries(send_tick)
        for copy, d in enumerate(delays):
            self.push(send_tick + int(d), link.sender, send_tick, copy, msg)
        if stats is not None:
            stats.sent += 1
            if not delays:
                stats.count_lost(link, send_tick)
            stats.duplicated += max(0, len(delays) - 1)
        return len(delays)

    def pop_due(self, tick: int) -> list[T]:
        """Remove and return every message whose delivery tick is ``<= tick``, in deterministic order."""
        heap = self._heap
        if not heap or heap[0][0] > tick:
            return []
        out: list[T] = []
        while heap and heap[0][0] <= tick:
            out.append(_heappop(heap)[5])
        return out

    def next_due(self) -> int | None:
        """Delivery tick of the earliest buffered message, or None if empty."""
        return self._heap[0][0] if self._heap else None

    def __len__(self) -> int:
        return len(self._heap)


def deliver_tick(tick: int, delay: float, dt: float, mode: str) -> int:
    """Tick at which a message sent at ``tick`` with link delay ``delay`` is in the receiver's inbox.

    A message sent during tick k is first usable at k + 1; lockstep delays are whole ticks,
    real-time delays are seconds.
    """
    if mode == "lockstep":
        return tick + 1 + int(delay)
    return tick + 1 + int(delay // dt)


def receive_through(link: LinkModel, stats: LinkStats, line: DelayLine, sender: int, tick: int, msg: object,
                    dt: float, mode: str, next_tick: int) -> None:
    """A daemon's receive side of one directed link: the sender's message of ``tick`` goes through the
    link's fault model (the daemons apply it where the in-process engine applies it on send), is
    counted, and waits in ``line`` for its delivery tick(s); a copy due before ``next_tick`` is late."""
    stats.sent += 1
    delays = link.deliveries(tick)
    if not delays:
        stats.count_lost(link, tick)
    for copy, d in enumerate(delays):
        due = deliver_tick(tick, d, dt, mode)
        if due < next_tick:
            stats.late += 1
        line.push(due, sender, tick, copy, msg)
    stats.delivered += len(delays)
    stats.duplicated += max(0, len(delays) - 1)


def window_ticks(start: float, end: float, dt: float) -> tuple[int, int]:
    """A partition window [start, end) in seconds as the half-open range of send ticks it covers.

    Tick k is sent at time k * dt; it is in the window if start <= k * dt < end (up to rounding of
    the bounds to whole ticks, so that every engine agrees on the same ticks).
    """
    return round(start / dt), round(end / dt)


def partition_windows(spec: LinkSpec, dt: float | None, sender: int, receiver: int,
                      drop: str | None = None) -> tuple[tuple[int, int], ...]:
    """The send-tick windows during which the link ``sender -> receiver`` is cut (``drop``: only the
    windows of that kind, ``partitioned`` or ``stale_age``)."""
    parts = [p for p in spec.partitions if p.cuts(sender, receiver) and drop in (None, p.drop)]
    if not parts:
        return ()
    if dt is None or dt <= 0:
        raise ValueError("a link with partitions needs the tick length dt")
    return tuple(window_ticks(p.start, p.end, dt) for p in parts)


def partition_events(scenario: Scenario) -> list[dict]:
    """The summary events of the scenario's partition schedule, in tick order.

    One ``partition_start`` (with the undirected graph edges it cuts) and one ``partition_end`` per
    partition whose tick falls inside the run; both engines record exactly these.
    """
    edges = scenario.edges()
    events = []
    for p, part in enumerate(scenario.link.partitions):
        t0, t1 = window_ticks(part.start, part.end, scenario.dt)
        cut = [[i, j] for i, j in edges if part.cuts(i, j)]
        for tick, kind in ((t0, "partition_start"), (t1, "partition_end")):
            if tick < scenario.ticks:
                ev = {"tick": tick, "t": tick * scenario.dt, "event": kind, "partition": p}
                if kind == "partition_start":
                    ev["cut"] = cut
                    if part.drop != "partitioned":
                        ev["drop"] = part.drop
                events.append(ev)
    events.sort(key=lambda e: (e["tick"], e["partition"], e["event"] == "partition_start"))
    return events


def build_in_links(view: AgentView, mode: str | None = None) -> dict[int, LinkModel]:
    """The fault models of every link that ends at agent ``view.agent``, keyed by sender, partitions
    included.

    Both engines build their links here (it passes the tick length, which partition windows need).
    """
    mode = mode or view.mode
    return {
        sender: LinkModel(view.link, view.seed, sender, view.agent, mode, view.dt)  # type: ignore[arg-type]
        for sender in view.neighbours
    }
