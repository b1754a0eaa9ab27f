"""The simulator daemon: the plant behind a transport, and the run's recorder.

Lockstep: the simulator is the clock. It publishes tick k's measurements, waits for the wrench of
every live agent for tick k (a timeout is counted, the missing wrench taken as zero), then steps.
Real time: it steps at wall-clock rate and applies each agent's latest wrench.
It records samples, truth and every agent's published estimates into the run directory.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

from agents.agent import ESTIMATE_NAMES
from coload.recorder import Recorder
from config.scenario import Scenario
from net import keys
from net.link import partition_events
from net.messages import AgentReport, Control, Estimate, Measurement, Wrench
from net.schema import DecodeError, decode, encode
from net.transport import Transport
from simulator.plant import Plant, sensor_rng

log = logging.getLogger("coload.sim")

ZERO_WRENCH = (0.0, 0.0, 0.0)


def _resolve(fut: asyncio.Future[None]) -> None:
    if not fut.done():
        fut.set_result(None)


class SimDaemon:
    def __init__(
        self,
        scenario: Scenario,
        transport: Transport,
        run: str,
        run_dir: Path,
        progress: Callable[[int, int], None] | None = None,
        engine: str = "zenoh",
    ) -> None:
        self.scenario = scenario
        self.transport = transport
        self.run_name = run
        self.run_dir = Path(run_dir)
        self.progress = progress
        self.engine = engine  # what summary.json calls the transport this daemon runs on
        self.n = scenario.n
        self.plant = Plant(scenario)
        self.rng = sensor_rng(scenario.seed)
        self.recorder = Recorder(self.run_dir, scenario, ESTIMATE_NAMES)
        self.alive: set[int] = set()
        self.drops: Counter[str] = Counter()
        self.wrench_timeouts = 0
        self.events: list[dict[str, Any]] = []
        self.reports: dict[int, AgentReport] = {}
        self.last_estimate: list[int] = [-1] * self.n  # tick of the last estimate recorded per agent
        self._partition_events = partition_events(scenario)  # recorded as their tick comes
        self.tick = 0
        self.wrenches: dict[int, tuple[float, float, float]] = {}
        self.latest: list[tuple[float, float, float]] = [ZERO_WRENCH] * self.n
        self._subs: list = []
        # the one thing the run waits for (all agents up, tick k's wrenches, the reports): its
        # condition and a future that the input completing it resolves (no task, no Event round
        # trip per input); None when nobody waits
        self._waiting: tuple[Callable[[], bool], asyncio.Future[None]] | None = None
        # keys built and parsed once: agent keys of this run -> agent id (anything else is parsed)
        self._meas_keys = [keys.meas(run, i) for i in range(self.n)]
        self._agent_ids = {keys.agent(run, i, kind): i for i in range(self.n)
                           for kind in ("wrench", "estimate", "report")}

    # ---- inputs ----------------------------------------------------------------------------
    def _decode(self, payload: bytes, kind: type):
        try:
            return decode(payload, kind)
        except DecodeError as exc:
            self.drops[exc.reason] += 1
            return None

    def _agent_of(self, key: str) -> int | None:
        i = self._agent_ids.get(key)
        if i is not None:
            return i
        parsed = keys.parse_agent_key(key)
        if parsed is None or not 0 <= parsed[1] < self.n:
            self.drops["unknown_sender"] += 1
            return None
        return parsed[1]

    def _on_alive(self, key: str, alive: bool) -> None:
        parsed = keys.parse_alive(key)
        if parsed is None or parsed[1] != "agent" or not 0 <= parsed[2] < self.n:
            return
        i = parsed[2]
        was = i in self.alive
        (self.alive.add if alive else self.alive.discard)(i)
        if was != alive and 0 < self.tick < self.scenario.ticks:  # not start-up, not shutdown
            self.events.append({"tick": self.tick, "t": self.tick * self.scenario.dt,
                                "event": "agent_up" if alive else "agent_down", "agent": i})
            log.info("agent %d %s at tick %d", i, "up" if alive else "down", self.tick)
        self._poke()

    def _on_wrench(self, key: str, payload: bytes) -> None:
        i = self._agent_of(key)
        w = self._decode(payload, Wrench) if i is not None else None
        if w is None:
            return
        if w.agent != i:
            self.drops["spoofed_sender"] += 1
            return
        if self.scenario.mode == "realtime":
            self.latest[i] = (w.fx, w.fy, w.tau)
            return
        if w.tick != self.tick:
            self.drops["stale" if w.tick < self.tick else "future"] += 1
            return
        if i in self.wrenches:
            self.drops["duplicate"] += 1  # first one wins: a replay cannot overwrite the genuine wrench
            return
        self.wrenches[i] = (w.fx, w.fy, w.tau)
        self._poke()

    def _have_wrenches(self) -> bool:
        return self.alive <= self.wrenches.keys()

    def _on_estimate(self, key: str, payload: bytes) -> None:
        i = self._agent_of(key)
        est = self._decode(payload, Estimate) if i is not None else None
        if est is None:
            return
        if est.agent != i:
            self.drops["spoofed_sender"] += 1
            return
        # an agent publishes an estimate once per recorded tick, after stepping it (so never for a
        # tick the simulator has not reached): anything else would write a forged row
        if est.tick <= self.last_estimate[i]:
            self.drops["stale"] += 1
            return
        if est.tick > self.tick:
            self.drops["future"] += 1
            return
        if not self.recorder.keeps(est.tick):
            self.drops["off_grid"] += 1
            return
        self.last_estimate[i] = est.tick
        self.recorder.estimate(est)

    def _on_report(self, key: str, payload: bytes) -> None:
        i = self._agent_of(key)
        rep = self._decode(payload, AgentReport) if i is not None else None
        if rep is None:
            return
        if rep.agent != i:
            self.drops["spoofed_sender"] += 1
            return
        if self.tick < self.scenario.ticks:
            self.drops["early"] += 1  # agents report after the simulator's done notice only
            return
        if i in self.reports:
            self.drops["duplicate"] += 1
            return
        self.reports[i] = rep
        self._poke()

    def _poke(self) -> None:
        """Called by every input that can complete what the run waits for."""
        if self._waiting is not None:
            cond, fut = self._waiting
            if not fut.done() and cond():
                fut.set_result(None)

    async def _wait_for(self, cond: Callable[[], bool], timeout: float) -> bool:
        """Waits until ``cond()`` holds, re-checked on every input; False on timeout.

        One future per wait, resolved by the input that makes ``cond`` true; the timeout is a
        ``call_later`` on the loop, cancelled when the future resolves first.
        """
        if cond():
            return True
        loop = asyncio.get_running_loop()
        fut = loop.create_future()
        self._waiting = (cond, fut)
        timer = loop.call_later(timeout, _resolve, fut)
        try:
            await fut
        finally:
            timer.cancel()
            self._waiting = None
        return cond()

    def _publish_control(self, kind: str, tick: int) -> None:
        self.transport.publish(keys.sim_control(self.run_name), encode(Control(kind, tick, self.scenario.ticks)))

    async def run(self) -> dict[str, Any]:
        t, run = self.transport, self.run_name
        self._subs += [
            t.subscribe(keys.agent_all(run, "wrench"), self._on_wrench),
            t.subscribe(keys.agent_all(run, "estimate"), self._on_estimate),
            t.subscribe(keys.agent_all(run, "report"), self._on_report),
            t.watch_alive(keys.alive_all(run), self._on_alive),
            t.declare_alive(keys.alive(run, "sim", 0)),
        ]
        try:
            return await self._run()
        finally:
            for s in reversed(self._subs):
                s.close()
            self._subs.clear()

    async def _run(self) -> dict[str, Any]:
        sc = self.scenario
        log.info("waiting for %d agents (run %s)", self.n, self.run_name)
        if not await self._wait_for(lambda: len(self.alive) == self.n, sc.timing.startup_timeout_s):
            missing = sorted(set(range(self.n)) - self.alive)
            log.warning("starting without agents %s", missing)
            self.events.append({"tick": 0, "t": 0.0, "event": "start_without", "agents": missing})
        self._publish_control("start", 0)
        wall0 = time.perf_counter()
        ticks = sc.ticks
        report_every = max(1, ticks // 100)
        pevents = list(self._partition_events)
        for k in range(ticks):
            self.tick = k
            while pevents and pevents[0]["tick"] <= k:
                ev = pevents.pop(0)
                self.events.append(ev)
                log.info("tick %d: %s %d", k, ev["event"], ev["partition"])
            if sc.mode == "realtime":
                lag = wall0 + k * sc.dt - time.perf_counter()
                if lag > 0:
                    await asyncio.sleep(lag)
            meas = self.plant.measure(self.rng)
            self.wrenches = {}
            publish, meas_keys = self.transport.publish, self._meas_keys
            for i, (vx, vy) in enumerate(meas):
                publish(meas_keys[i], encode(Measurement(k, i, vx, vy)))
            # recorded once the measurements are out: the agents are busy with them meanwhile
            self.recorder.truth(self.plant.truth())
            if sc.mode == "lockstep":
                got = await self._wait_for(self._have_wrenches, sc.timing.wrench_timeout_s)
                if not got:
                    self.wrench_timeouts += 1
                    log.warning("tick %d: no wrench from %s", k, sorted(self.alive - self.wrenches.keys()))
                applied = [self.wrenches.get(i, ZERO_WRENCH) for i in range(self.n)]
            else:
                await asyncio.sleep(0)  # let arrived wrenches in
                applied = list(self.latest)
            self.recorder.samples(k, meas, applied)
            self.plant.apply_and_step(applied)
            if k % report_every == 0 or k == ticks - 1:
                self._publish_control("progress", k + 1)
                if self.progress is not None:
                    self.progress(k + 1, ticks)
        wall = time.perf_counter() - wall0
        self.tick = ticks
        self._publish_control("done", ticks)
        expected = set(self.alive)
        if not await self._wait_for(lambda: expected <= self.reports.keys(), sc.timing.startup_timeout_s):
            log.warning("no end-of-run report from agents %s", sorted(expected - self.reports.keys()))
        return self._finish(wall)

    def _finish(self, wall: float) -> dict[str, Any]:
        links: dict[str, dict[str, int]] = {}
        drops: Counter[str] = Counter(self.drops)
        agent_timeouts = 0
        for i, rep in sorted(self.reports.items()):
            for sender, counters in sorted(rep.links.items()):
                links[f"{sender}->{i}"] = dict(counters)
            drops.update(rep.drops)
            agent_timeouts += rep.timeouts
        summary: dict[str, Any] = {
            "engine": self.engine,
            "mode": self.scenario.mode,
            "sim_s": self.scenario.ticks * self.scenario.dt,
            "wall_s": wall,
            "seed": self.scenario.seed,
            "n": self.n,
            "scenario": self.scenario.name,
            "run": self.run_name,
            "links": dict(sorted(links.items())),
            "drops": dict(sorted(drops.items())),
            "timeouts": {"wrench": self.wrench_timeouts, "neighbour": agent_timeouts},
            "events": self.events,
            "agents_reported": sorted(self.reports),
        }
        return self.recorder.close(summary)
