"""Daemons of the paper-003 runtime: the LTI simulator and one estimator-controller per agent.

They own no maths (``hinf.runtime`` does): they decode and validate what arrives (a bad message is
dropped and counted by reason, never raised), pass neighbour states through the receive-side link
model and a ``DelayLine`` exactly as ``runtime.run_inproc`` does, and step the pure cores.

Lockstep: the simulator is the clock. It publishes z^(k)(t) to every estimator, waits for every live
estimator's u_k(t) (a timeout is counted and the last u_k held), records, then steps the plant. An
estimator steps tick t once it has z^(k)(t) and its live in-neighbours' states sent at t - 1 (a
timeout is counted; the neighbour's last data is held), and sends u_k(t + 1) at once (it depends on
the prior estimate only), so the simulator usually has it before it publishes z(t + 1). Real time:
the simulator steps at wall-clock rate and applies the newest u_k(t') with t' <= t (held if
u_k(t) is missing, counted); an estimator steps as soon as z arrives, with what it has.

Key expressions (``net.keys``): coload/{run}/hinf/{k}/meas|input|state|report, coload/{run}/hinf/control,
liveliness coload/{run}/alive/hinf/{k} and coload/{run}/alive/hinfsim/0.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import Counter
from collections.abc import Callable
from typing import Any

import numpy as np

from net import keys
from net.hinf_messages import HinfInput, HinfMeas, HinfState
from net.link import DelayLine, LinkStats, receive_through
from net.messages import AgentReport, Control
from net.neighbour_wait import MAX_TICK_LEAD, NeighbourWait
from net.schema import FirstDrops, decode_counted, encode
from net.transport import Transport

from .runtime import (
    EstimatorCore,
    PlantCore,
    Setup,
    Trace,
    TraceWriter,
    in_links,
)

log = logging.getLogger("coload.hinf")


def _resolve(fut: asyncio.Future[None]) -> None:
    if not fut.done():
        fut.set_result(None)


class _Waiter:
    """One condition at a time, re-checked by :meth:`poke` on every input; a future per wait."""

    def __init__(self) -> None:
        self._waiting: tuple[Callable[[], bool], asyncio.Future[None]] | None = None

    def poke(self) -> None:
        if self._waiting is not None:
            cond, fut = self._waiting
            if not fut.done() and cond():
                fut.set_result(None)

    async def wait_for(self, cond: Callable[[], bool], timeout: float) -> bool:
        if cond():
            return True
        loop = asyncio.get_running_loop()
        fut = loop.create_future()
        self._waiting = (cond, fut)
        timer = loop.call_later(max(0.0, timeout), _resolve, fut)
        try:
            await fut
        finally:
            timer.cancel()
            self._waiting = None
        return cond()


# ----------------------------------------------------------------------------- simulator


class HinfSimDaemon:
    """The N LTI agents behind a transport; records a :class:`runtime.Trace`."""

    def __init__(self, setup: Setup, transport: Transport, run: str,
                 progress: Callable[[int, int], None] | None = None) -> None:
        self.setup = setup
        self.transport = transport
        self.run_name = run
        self.progress = progress
        self.N = setup.N
        self.mode = setup.spec.run.mode
        self.plant = PlantCore(setup)
        self.rec = TraceWriter(setup)
        self.alive: set[int] = set()
        self.drops: Counter[str] = Counter()
        self.said = FirstDrops(log, "hinf simulator")  # the first drop of each kind and reason, in the log
        self.input_timeouts = 0
        self.reports: dict[int, AgentReport] = {}
        self.tick = 0
        self.by_tick: dict[int, dict[int, HinfInput]] = {}  # inputs of this tick and the next
        self.stale_u = 0  # realtime: (tick, agent) pairs where u_k(t) was missing and the last one held
        self.late_inputs = 0  # inputs that arrived after their tick was stepped
        self.last_u = [setup.input_law(k, np.zeros(setup.net.n[k]), setup.zeta0[k]) for k in range(self.N)]
        self.waiter = _Waiter()
        self._subs: list = []
        self._ids = {keys.hinf(run, k, kind): (k, kind) for k in range(self.N) for kind in ("input", "report")}
        self._meas_keys = [keys.hinf(run, k, "meas") for k in range(self.N)]
        self.wall_s = 0.0

    def _agent_of(self, key: str, kind: str) -> int | None:
        """The estimator whose ``kind`` key ``key`` is; None (counted) for a put on a wider key
        expression (``wrong_key``) or an estimator this run does not have (``unknown_sender``)."""
        known = self._ids.get(key)
        if known is not None and known[1] == kind:
            return known[0]
        parsed = keys.parse_hinf_key(key)
        self.drops["unknown_sender" if parsed is not None and parsed.kind == kind else keys.WRONG_KEY] += 1
        return None

    def _decode(self, payload: bytes, kind: type, key: str = ""):
        return decode_counted(payload, kind, self.drops, None, self.said, key)

    def _on_alive(self, key: str, alive: bool) -> None:
        parsed = keys.parse_alive(key)
        if parsed is None or parsed[1] != "hinf" or not 0 <= parsed[2] < self.N:
            return
        (self.alive.add if alive else self.alive.discard)(parsed[2])
        self.waiter.poke()

    def _on_input(self, key: str, payload: bytes) -> None:
        k = self._agent_of(key, "input")
        msg = self._decode(payload, HinfInput, key) if k is not None else None
        if msg is None:
            return
        s = self.setup
        if msg.agent != k:
            self.drops["spoofed_sender"] += 1
            return
        if (len(msg.u) != s.B[k].shape[1] or len(msg.xhat) != s.locs[k].sigma or len(msg.zeta) != s.nu):
            self.drops["bad_shape"] += 1
            return
        if msg.tick > self.tick + 1 or msg.tick >= self.setup.ticks:
            self.drops["future"] += 1
            return
        if msg.tick < self.tick:
            # too late to be applied (real time): recorded if its row is still empty, never applied
            self.late_inputs += 1
            if not self.rec.trace.got[msg.tick, k]:
                self.rec.input(msg)
            return
        slot = self.by_tick.setdefault(msg.tick, {})
        if k in slot:
            self.drops["duplicate"] += 1  # first one wins: a replay cannot overwrite the genuine input
            return
        slot[k] = msg
        self.rec.input(msg)
        self.waiter.poke()

    def _on_report(self, key: str, payload: bytes) -> None:
        k = self._agent_of(key, "report")
        rep = self._decode(payload, AgentReport, key) if k is not None else None
        if rep is None:
            return
        if rep.agent != k:
            self.drops["spoofed_sender"] += 1
            return
        if self.tick < self.setup.ticks:
            self.drops["early"] += 1
            return
        self.reports.setdefault(k, rep)
        self.waiter.poke()

    def _control(self, kind: str, tick: int) -> None:
        self.transport.publish(keys.hinf_control(self.run_name), encode(Control(kind, tick, self.setup.ticks)))

    async def run(self) -> tuple[Trace, dict[str, Any]]:
        t, run = self.transport, self.run_name
        self._subs += [
            t.subscribe(keys.hinf_all(run, "input"), self._on_input),
            t.subscribe(keys.hinf_all(run, "report"), self._on_report),
            t.watch_alive(keys.alive_all(run, "hinf"), self._on_alive),
            t.declare_alive(keys.alive(run, "hinfsim", 0)),
        ]
        try:
            return await self._run()
        finally:
            for s in reversed(self._subs):
                s.close()
            self._subs.clear()

    async def _run(self) -> tuple[Trace, dict[str, Any]]:
        s, run = self.setup, self.setup.spec.run
        events: list[dict[str, Any]] = []
        if not await self.waiter.wait_for(lambda: len(self.alive) == self.N, run.timing.startup_timeout_s):
            missing = sorted(set(range(self.N)) - self.alive)
            log.warning("starting without estimators %s", missing)
            events.append({"tick": 0, "event": "start_without", "agents": missing})
        self._control("start", 0)
        ticks, dt = s.ticks, s.dt
        every = max(1, ticks // 100)
        wall0 = time.perf_counter()
        lockstep = self.mode == "lockstep"
        for k in range(ticks):
            if not lockstep:
                lag = wall0 + k * dt - time.perf_counter()
                if lag > 0:
                    await asyncio.sleep(lag)
            self.tick = k
            self.by_tick.pop(k - 1, None)
            now = self.by_tick.setdefault(k, {})
            zs = self.plant.measure(k)
            self.rec.truth(k, self.plant)
            for i, z in enumerate(zs):
                self.transport.publish(self._meas_keys[i], encode(HinfMeas(k, i, z)))
            if lockstep:
                if not await self.waiter.wait_for(lambda now=now: self.alive <= now.keys(), run.timing.input_timeout_s):
                    self.input_timeouts += 1
                    log.warning("tick %d: no input from %s", k, sorted(self.alive - now.keys()))
            else:
                await self.waiter.wait_for(lambda now=now: len(now) == self.N, wall0 + (k + 1) * dt - time.perf_counter())
                self.stale_u += self.N - len(now)
            for i, m in now.items():
                self.last_u[i] = np.asarray(m.u)
            self.rec.applied(k, self.last_u)
            self.plant.step(self.last_u)
            if k % every == 0 or k == ticks - 1:
                self._control("progress", k + 1)
                if self.progress is not None:
                    self.progress(k + 1, ticks)
        self.wall_s = time.perf_counter() - wall0
        self.tick = ticks
        self._control("done", ticks)
        expected = set(self.alive)
        if not await self.waiter.wait_for(lambda: expected <= self.reports.keys(), run.timing.startup_timeout_s):
            log.warning("no end-of-run report from estimators %s", sorted(expected - self.reports.keys()))
        return self.rec.trace, self._info(events)

    def _info(self, events: list[dict[str, Any]]) -> dict[str, Any]:
        links: dict[str, dict[str, int]] = {}
        drops: Counter[str] = Counter({f"sim:{r}": c for r, c in self.drops.items()})
        timeouts = 0
        held = {}
        rejoined = {}  # estimators that came back from a gap in their measurements (count of gaps)
        for k, rep in sorted(self.reports.items()):
            for j, c in sorted(rep.links.items()):
                links[f"{j}->{k}"] = dict(c)
            held[str(k)] = rep.drops.get("_held", 0)
            if rep.drops.get("_rejoined"):
                rejoined[str(k)] = rep.drops["_rejoined"]
            drops.update({f"{k}:{r}": c for r, c in rep.drops.items() if not r.startswith("_")})
            timeouts += rep.timeouts
        return {"links": dict(sorted(links.items())), "drops": dict(sorted(drops.items())),
                "timeouts": {"input": self.input_timeouts, "neighbour": timeouts}, "held": held,
                "rejoined": rejoined,
                "stale_u": self.stale_u, "late_inputs": self.late_inputs,
                "events": events, "agents_reported": sorted(self.reports), "wall_s": self.wall_s}


# ----------------------------------------------------------------------------- estimator


class HinfAgentDaemon:
    """Estimator-controller k: schedules one :class:`runtime.EstimatorCore` over a transport."""

    def __init__(self, setup: Setup, k: int, transport: Transport, run: str) -> None:
        if not 0 <= k < setup.N:
            raise ValueError(f"--id {k} is not an agent of this spec (0..{setup.N - 1})")
        self.setup, self.id, self.transport, self.run_name = setup, k, transport, run
        self.mode = setup.spec.run.mode
        self.core = EstimatorCore(setup, k)
        self.nbrs = setup.nbrs(k)
        self.links = in_links(setup, k, self.mode)
        self.stats = {j: LinkStats() for j in self.nbrs}
        self.line: DelayLine = DelayLine()
        self.drops: Counter[str] = Counter()
        self.said = FirstDrops(log, f"hinf estimator {k}")  # the first drop of each kind and reason, in the log
        self.timeouts = 0
        self.next_tick = 0
        self.last_meas = -1
        self.last_z: tuple[float, ...] | None = None
        self.pending: dict[int, tuple[float, ...]] = {}
        self._held: HinfMeas | None = None  # lockstep: a measurement past a gap, until the next confirms it
        self.rejoins = 0  # lockstep gaps this estimator came back from
        # the in-neighbours' last states, which of them a lockstep step waits for, the end-of-run gate;
        # a neighbour that skipped ticks is back only at a tick this estimator has reached
        self.wait = NeighbourWait(self.nbrs, self.mode, self._report_and_end, lead=0)
        self.done = asyncio.Event()
        self._timer: asyncio.TimerHandle | None = None
        self._subs: list = []
        self._k_input = keys.hinf(run, k, "input")
        self._k_state = keys.hinf(run, k, "state")
        self._k_meas = keys.hinf(run, k, "meas")
        self._k_control = keys.hinf_control(run)
        self._state_keys = {keys.hinf(run, j, "state"): j for j in self.nbrs}
        self.nz = setup.net.r * len(self.nbrs)
        self.ticks_stepped = 0
        self.sent_input = -1  # tick of the last input message published

    def start(self) -> None:
        t, run, k = self.transport, self.run_name, self.id
        self._subs.append(t.subscribe(keys.hinf(run, k, "meas"), self._on_meas))
        for j in self.nbrs:
            self._subs.append(t.subscribe(keys.hinf(run, j, "state"), self._on_state))
        self._subs.append(t.subscribe(keys.hinf_control(run), self._on_control))
        self._subs.append(t.watch_alive(keys.alive_all(run, "hinf"), self._on_alive))
        self._subs.append(t.declare_alive(keys.alive(run, "hinf", k)))
        log.info("estimator %d up: in-neighbours %s, mode %s", k, self.nbrs, self.mode)

    async def run(self) -> AgentReport:
        self.start()
        try:
            await self.done.wait()
        finally:
            if self._timer is not None:
                self._timer.cancel()
            self.wait.finish.cancel()
            for s in reversed(self._subs):
                s.close()
            self._subs.clear()
        return self.report()

    def report(self) -> AgentReport:
        drops = dict(self.drops)
        drops["_held"] = self.core.held  # ticks stepped with some neighbour's data held (not a drop)
        if self.rejoins:
            drops["_rejoined"] = self.rejoins  # gaps in the measurements this estimator came back from
        return AgentReport(self.id, {j: s.as_dict() for j, s in self.stats.items()}, drops, self.timeouts,
                           self.ticks_stepped)

    def _decode(self, payload: bytes, kind: type, link: int | None = None, key: str = ""):
        return decode_counted(payload, kind, self.drops, None if link is None else self.stats[link], self.said, key)

    def _on_alive(self, key: str, alive: bool) -> None:
        parsed = keys.parse_alive(key)
        if parsed is None or alive or not self.wait.gone(parsed[2]):
            return  # back in with its next message
        self._try_step()
        self.wait.check_finish()

    def _on_control(self, key: str, payload: bytes) -> None:
        if key != self._k_control:
            self.drops[keys.WRONG_KEY] += 1  # a put on a wider key expression: not the simulator's
            return
        msg = self._decode(payload, Control, key=key)
        if msg is None:
            return
        if msg.ticks != self.setup.ticks:
            self.drops["bad_control"] += 1
            return
        if msg.kind == "done" and msg.tick == msg.ticks:
            self.wait.done(msg.tick)

    def _report_and_end(self) -> None:
        self.transport.publish(keys.hinf(self.run_name, self.id, "report"), encode(self.report()))
        self.done.set()

    def _on_meas(self, key: str, payload: bytes) -> None:
        if key != self._k_meas:
            self.drops[keys.WRONG_KEY] += 1  # a put on a wider key expression: not the simulator's
            return
        m = self._decode(payload, HinfMeas, key=key)
        if m is None:
            return
        if m.agent != self.id:
            self.drops["wrong_agent"] += 1
            return
        if len(m.z) != self.nz:
            self.drops["bad_shape"] += 1
            return
        if m.tick <= self.last_meas or m.tick < self.next_tick:
            self.drops["stale"] += 1
            return
        if self.last_meas >= 0 and m.tick > self.next_tick + MAX_TICK_LEAD:
            self.drops["future"] += 1  # (a restarted estimator's first measurement may be far ahead)
            return
        if self.mode == "lockstep" and m.tick != self.last_meas + 1:
            # the lockstep simulator never skips a tick: either the run went on without this estimator
            # (a lost connection, a restart) or the message is forged. Hold it; the next measurement
            # right after it confirms the gap, and the estimator rejoins the run there
            held = self._held
            if held is None or m.tick != held.tick + 1:
                if held is not None:
                    self.drops["future"] += 1  # the one held before was not confirmed
                self._held = m
                return
            self._held = None
            self._rejoin(held)
        elif self._held is not None and self._held.tick <= m.tick:
            self.drops["future"] += 1  # the stream went on without a gap: the held one was not ours
            self._held = None
        self.last_meas = m.tick
        if self.mode == "realtime":
            self._skip_to(m)  # act on the newest data
        self.pending[m.tick] = m.z
        self._try_step()

    def _rejoin(self, m: HinfMeas) -> None:
        """Come back at ``m.tick`` after a gap: the missed ticks are stepped with the last z held (as in
        real time; neither inputs nor states are published for them: the run has moved on), then
        ``m`` is this tick's data."""
        log.warning("estimator %d: measurements %d..%d missed; rejoining the run at tick %d", self.id,
                    self.last_meas + 1, m.tick - 1, m.tick)
        self.rejoins += 1
        self.pending.clear()
        self._skip_to(m)
        self.last_meas = m.tick
        self.pending[m.tick] = m.z

    def _skip_to(self, m: HinfMeas) -> None:
        """Step the ticks before ``m.tick`` that never got a measurement with the last z held (``m.z``
        if there is none yet), publishing nothing for them."""
        z_hold = self.last_z if self.last_z is not None else m.z
        for t in range(self.next_tick, m.tick):
            self._step(t, z_hold, publish=False)

    def _on_state(self, key: str, payload: bytes) -> None:
        sender = self._state_keys.get(key)
        if sender is None:
            self.drops[keys.WRONG_KEY] += 1  # a put on a wider key expression (hinf/*/state)
            return
        msg = self._decode(payload, HinfState, link=sender, key=key)
        if msg is None:
            return
        s = self.setup
        if msg.sender != sender:
            self.drops["spoofed_sender"] += 1
            return
        if len(msg.xhat) != s.net.n[sender] or len(msg.u) != s.B[sender].shape[1] or len(msg.zeta) != s.nu:
            self.drops["bad_shape"] += 1
            self.stats[sender].malformed += 1
            return
        refused = self.wait.admit(sender, msg.tick, self.next_tick)
        if refused is not None:
            self.drops[refused] += 1
            return
        receive_through(self.links[sender], self.stats[sender], self.line, sender, msg.tick, msg, s.dt, self.mode,
                        self.next_tick)
        self._try_step()
        self.wait.check_finish()

    def _try_step(self) -> None:
        while self.next_tick in self.pending:
            t = self.next_tick
            if not self.wait.ready(t):
                if self._timer is None:
                    self._timer = asyncio.get_running_loop().call_later(
                        self.setup.spec.run.timing.neighbour_timeout_s, self._on_timeout, t)
                return
            self._step(t, self.pending.pop(t))

    def _on_timeout(self, t: int) -> None:
        self._timer = None
        if self.next_tick != t:
            return
        missing = self.wait.stop_waiting(t)  # back in once they speak again
        log.warning("estimator %d: tick %d: no state from %s in time; holding their last data", self.id, t, missing)
        self.timeouts += 1
        self._try_step()

    def _step(self, t: int, z: tuple[float, ...], publish: bool = True) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        pub = self.transport.publish
        if publish and self.sent_input < t:  # tick 0, or ticks skipped in real time
            pub(self._k_input, encode(self.core.input_msg(t)))
        inp, st = self.core.step(t, z, self.line.pop_due(t))
        self.last_z = z
        if publish and inp.tick < self.setup.ticks:
            pub(self._k_input, encode(inp))  # first: the simulator waits for it
            self.sent_input = inp.tick
        if publish:  # a re-stepped (skipped) tick's state is history the neighbours have no use for
            pub(self._k_state, encode(st))
        self.next_tick = t + 1
        self.ticks_stepped += 1


# ----------------------------------------------------------------------------- running them


async def run_daemons_in_memory(setup: Setup, run: str = "hinf-mem") -> tuple[Trace, dict[str, Any]]:
    """Simulator and estimators on the in-memory transport in this loop: the daemons' code paths
    (codec, link model, lockstep waits) without sockets; the fast way to test them."""
    from net.memory import MemoryBus, MemoryTransport

    loop = asyncio.get_running_loop()
    bus = MemoryBus()
    ts = [MemoryTransport(bus, loop) for _ in range(setup.N + 1)]
    agents = [HinfAgentDaemon(setup, k, ts[k], run) for k in range(setup.N)]
    tasks = [asyncio.ensure_future(a.run()) for a in agents]
    try:
        trace, info = await HinfSimDaemon(setup, ts[-1], run).run()
        await asyncio.wait_for(asyncio.gather(*tasks), 10.0)
    finally:
        for t in tasks:
            t.cancel()
        for t in ts:
            t.close()
    return trace, info
