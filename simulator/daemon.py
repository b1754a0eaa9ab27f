"""The simulator daemon: the plant behind a transport, writing the run through the recorder it is handed.

Lockstep: the simulator is the clock. It publishes tick k's measurements, waits for the wrench of
every live agent for tick k (a timeout is counted, the missing wrench taken as zero), then steps.
Real time: it steps at wall-clock rate and applies each agent's latest wrench.
It records samples, truth and every agent's published estimates into the run directory.

Restart: the daemon keeps a journal in the run directory (``sim.journal``, JSON lines, one write per
tick: the wrenches it applied, plus every estimate it recorded and every event, liveliness change and
drop count). Killed and started again with the same run name and scenario, it replays the journal:
the plant is stepped again with the journaled wrenches and the sensor RNG draws again, so plant,
noise and recorded tables are exactly where they were, and the run goes on from the first tick it
had not finished. The agents, which noticed it leave through its liveliness token, wait for it and
re-send their last wrench and estimate when it is back. The journal is deleted once summary.json is
written. (The plant is *re-created*, not re-estimated: the load does not jump, so the agents' estimates
stay valid.)
"""

from __future__ import annotations

import asyncio
import base64
import hashlib
import json
import logging
import math
import struct
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

from config.loader import dump_scenario
from config.scenario import Scenario
from net import keys
from net.link import partition_events
from net.messages import AgentReport, Control, Estimate, LoadPose, Measurement, Wrench
from net.schema import FirstDrops, decode, decode_counted, encode
from net.transport import Transport
from simulator.plant import Plant, sensor_rng
from simulator.stop import done_stop

log = logging.getLogger("coload.sim")

ZERO_WRENCH = (0.0, 0.0, 0.0)



class RunRecorder(Protocol):
    """What the daemon writes the run through (coload.rundir.recorder.Recorder is the one the
    application hands in): the tables as the run goes, and where the restart journal lives."""

    journal_path: Path

    def keeps(self, tick: int) -> bool: ...
    def estimate(self, est: Estimate) -> None: ...
    def truth(self, row: Any) -> None: ...
    def samples(self, tick: int, meas: Any, applied: Any) -> None: ...
    def abort(self, reason: str) -> None: ...
    def close(self, summary: dict[str, Any]) -> dict[str, Any]: ...


_JOURNAL_VERSION = 1


def _resolve(fut: asyncio.Future[bool], met: bool) -> None:
    if not fut.done():
        fut.set_result(met)


class SimDaemon:
    def __init__(
        self,
        scenario: Scenario,
        transport: Transport,
        run: str,
        recorder: RunRecorder,
        progress: Callable[[int, int], None] | None = None,
        engine: str = "zenoh",
    ) -> None:
        self.scenario = scenario
        self.transport = transport
        self.run_name = run
        self.progress = progress
        self.engine = engine  # what summary.json calls the transport this daemon runs on
        self.n = scenario.n
        self.plant = Plant(scenario)
        self.rng = sensor_rng(scenario.seed)
        self.recorder = recorder
        self.journal_path = recorder.journal_path
        self.alive: set[int] = set()
        self.drops: Counter[str] = Counter()
        self.said = FirstDrops(log, "simulator")  # the first drop of each kind and reason, in the log
        self.wrench_timeouts = 0
        self.events: list[dict[str, Any]] = []
        self.reports: dict[int, AgentReport] = {}
        self.last_estimate: list[int] = [-1] * self.n  # tick of the last estimate recorded per agent
        self.last_wrench: list[int] = [-1] * self.n  # tick of the last wrench accepted per agent
        self._partition_events = partition_events(scenario)  # recorded as their tick comes
        self.tick = 0
        # ticks the run lasts: the scenario's, or fewer once every agent is done (stop_after_done_s)
        self._stop = done_stop(scenario)
        self.ended = False  # 'done' published: reports are expected from now on
        self.started = False  # 'start' published: agents that come and go from now on are events
        self.wrenches: dict[int, tuple[float, float, float]] = {}  # of self.tick; emptied after each step
        self.latest: list[tuple[float, float, float]] = [ZERO_WRENCH] * self.n
        self._subs: list = []
        # the one thing the run waits for (all agents up, tick k's wrenches, the reports): its
        # condition and a future that the input completing it resolves (no task, no Event round
        # trip per input); None when nobody waits
        self._waiting: tuple[Callable[[], bool], asyncio.Future[None]] | None = None
        # keys built and parsed once: agent keys of this run -> agent id (anything else is parsed)
        self._meas_keys = [keys.meas(run, i) for i in range(self.n)]
        self._agent_ids = {keys.agent(run, i, kind): (i, kind) for i in range(self.n)
                           for kind in ("wrench", "estimate", "report")}
        self._meas_out: list[bytes] | None = None  # lockstep: this tick's measurements while its wrenches are awaited
        # restart: the journal, what it said was alive, and the tick the run resumed at (-1: not resumed)
        self._journal = None
        self._journal_drops: dict[str, int] = {}
        self._wfmt = f"<{3 * self.n}d"
        self._expected_alive: set[int] = set()
        self._seen: set[int] = set()  # agents seen alive in this run (by token or wrench)
        names = getattr(recorder, "estimate_names", None)  # the columns of estimates.csv
        self._columns = None if names is None else frozenset(names)
        self.resumed_at = -1
        self.scenario_hash = hashlib.sha256(dump_scenario(scenario).encode()).hexdigest()

    # ---- inputs ----------------------------------------------------------------------------
    def _decode(self, payload: bytes, kind: type, key: str = ""):
        return decode_counted(payload, kind, self.drops, None, self.said, key)

    def _agent_of(self, key: str, kind: str) -> int | None:
        """The agent whose ``kind`` key ``key`` is; None (counted) for a put on a wider key expression
        (``wrong_key``) or for an agent this run does not have (``unknown_sender``)."""
        known = self._agent_ids.get(key)
        if known is not None and known[1] == kind:
            return known[0]
        parsed = keys.parse_agent_key(key)
        if parsed is None or parsed.run != self.run_name or parsed.kind != kind:
            self.drops[keys.WRONG_KEY] += 1
            self.said.drop(kind, keys.WRONG_KEY, f"a put on {key}, taken only on an agent's exact {kind} key")
            return None
        self.drops["unknown_sender"] += 1
        self.said.drop(kind, "unknown_sender", f"agent {parsed.agent} is not in this run (0..{self.n - 1})", key)
        return None

    def _on_alive(self, key: str, alive: bool) -> None:
        parsed = keys.parse_alive(key)
        if parsed is None or parsed[1] != "agent" or not 0 <= parsed[2] < self.n:
            return
        self._set_alive(parsed[2], alive, by_token=True)

    def _set_alive(self, i: int, alive: bool, by_token: bool) -> None:
        """Agent ``i`` came (its liveliness token, or a wrench of the current tick) or went (its token).

        A joiner's token and its first wrench come on different subscriptions, each called back on a
        thread of its own: the wrench can come first, and the agent is up from that wrench's tick.
        Only an agent never seen in this run comes by a wrench: a wrench in flight from one that went
        can arrive after its token's withdrawal, and must not make the run wait for it again.
        """
        if alive:
            self._seen.add(i)
        was = i in self.alive
        (self.alive.add if alive else self.alive.discard)(i)
        if was != alive and (self.started or self.resumed_at >= 0) and not self.ended:  # not start-up, not shutdown
            if alive and i in self._expected_alive:
                self._expected_alive.discard(i)  # alive before the restart: found again, not an event
            else:
                self._event("agent_up" if alive else "agent_down", agent=i)
                log.info("agent %d %s at tick %d", i, "up" if alive else "down", self.tick)
            self._write_journal({"alive": sorted(self.alive)})
            if alive and by_token and self._meas_out is not None:
                # it (re)appeared while this tick's wrenches are awaited: it may have subscribed after
                # its measurement went out, and would otherwise make the tick wait for nothing
                self.transport.publish(self._meas_keys[i], self._meas_out[i])
        self._poke()

    def _first_wrench(self, i: int) -> None:
        """Agent ``i``'s wrench is taken: if the run has never seen it, this is its arrival (see _set_alive)."""
        if i not in self._seen and i not in self._expected_alive:
            self._set_alive(i, True, by_token=False)

    def _event(self, event: str, **fields: Any) -> None:
        ev = {"tick": self.tick, "t": self.tick * self.scenario.dt, "event": event, **fields}
        self.events.append(ev)
        self._write_journal({"ev": ev})

    def _on_wrench(self, key: str, payload: bytes) -> None:
        i = self._agent_of(key, "wrench")
        w = self._decode(payload, Wrench, key) if i is not None else None
        if w is None:
            return
        if w.agent != i:
            self.drops["spoofed_sender"] += 1
            self.said.drop("wrench", "spoofed_sender", f"agent {w.agent} on agent {i}'s key", key)
            return
        if self.scenario.mode == "realtime":
            # the newest wrench holds; an older one (a replay, a reordered copy) or one from a tick
            # not yet simulated (a forgery) must not replace it
            if w.tick <= self.last_wrench[i]:
                self.drops["duplicate" if w.tick == self.last_wrench[i] else "stale"] += 1
                return
            if w.tick > self.tick + 1:
                self.drops["future"] += 1
                return
            self._first_wrench(i)
            self.latest[i] = (w.fx, w.fy, w.tau)
            self.last_wrench[i] = w.tick
            return
        if w.tick != self.tick:
            if w.tick == self.last_wrench[i] or w.tick == self.resumed_at - 1:
                # an agent that lost the simulator re-sends its last wrench when it is back
                self.drops["resent"] += 1
            else:
                self.drops["stale" if w.tick < self.tick else "future"] += 1
            return
        if i in self.wrenches:
            self.drops["duplicate"] += 1  # first one wins: a replay cannot overwrite the genuine wrench
            return
        self._first_wrench(i)
        self.wrenches[i] = (w.fx, w.fy, w.tau)
        self.last_wrench[i] = w.tick
        self._poke()

    def _have_wrenches(self) -> bool:
        return self.alive <= self.wrenches.keys()

    def _on_estimate(self, key: str, payload: bytes) -> None:
        i = self._agent_of(key, "estimate")
        est = self._decode(payload, Estimate, key) if i is not None else None
        if est is None:
            return
        if est.agent != i:
            self.drops["spoofed_sender"] += 1
            self.said.drop("estimate", "spoofed_sender", f"agent {est.agent} on agent {i}'s key", key)
            return
        # an agent publishes an estimate once per recorded tick, after stepping it (so never for a
        # tick the simulator has not reached): anything else would write a forged row
        if est.tick <= self.last_estimate[i]:
            # an agent that lost the simulator re-sends its last estimate, which may be here already
            self.drops["resent" if est.tick == self.last_estimate[i] else "stale"] += 1
            return
        if est.tick > self.tick:
            self.drops["future"] += 1
            return
        if not self.recorder.keeps(est.tick):
            self.drops["off_grid"] += 1
            return
        if self._columns is not None and not self._columns.issuperset(est.values):
            unknown = sorted(set(est.values) - self._columns)
            log.warning("agent %d's estimate of tick %d has values estimates.csv has no column for: %s; they are "
                        "not recorded, the others are (the columns: net/vocabulary.py ESTIMATE_NAMES; said once)",
                        i, est.tick, ", ".join(unknown[:8]))
            self._columns = None  # said once
        self._take_estimate(est)
        self._write_journal({"e": base64.b64encode(payload).decode("ascii")})

    def _take_estimate(self, est: Estimate) -> None:
        """A valid estimate, live or replayed from the journal: recorded, and seen by the early-end rule."""
        self.last_estimate[est.agent] = est.tick
        self.recorder.estimate(est)
        if self._stop is not None:
            self._stop.see(est.tick, est.agent, est.values.get("phase", math.nan))

    def _on_report(self, key: str, payload: bytes) -> None:
        i = self._agent_of(key, "report")
        rep = self._decode(payload, AgentReport, key) if i is not None else None
        if rep is None:
            return
        if rep.agent != i:
            self.drops["spoofed_sender"] += 1
            self.said.drop("report", "spoofed_sender", f"agent {rep.agent} on agent {i}'s key", key)
            return
        if not self.ended:
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
                fut.set_result(True)

    async def _wait_for(self, cond: Callable[[], bool], timeout: float) -> bool:
        """Waits until ``cond()`` holds, re-checked on every input; False on timeout.

        One future per wait, resolved by the input that makes ``cond`` true; the timeout is a
        ``call_later`` on the loop, cancelled when the future resolves first. The answer is the
        future's: an input that lands between its resolution and this coroutine's resumption (an
        agent appearing, say) does not turn a met condition into a timeout.
        """
        if cond():
            return True
        loop = asyncio.get_running_loop()
        fut = loop.create_future()
        self._waiting = (cond, fut)
        timer = loop.call_later(timeout, _resolve, fut, False)
        try:
            met = await fut
        finally:
            timer.cancel()
            self._waiting = None
        return met or cond()

    def _publish_control(self, kind: str, tick: int) -> None:
        self.transport.publish(keys.sim_control(self.run_name), encode(Control(kind, tick, self.scenario.ticks)))

    # ---- restart journal -------------------------------------------------------------------
    def _write_journal(self, record: dict[str, Any]) -> None:
        if self._journal is not None:
            self._journal.write((json.dumps(record, separators=(",", ":")) + "\n").encode())

    def _journal_tick(self, k: int, applied: list[tuple[float, float, float]], timeout: bool) -> None:
        """One unbuffered write per tick, before the plant steps: a killed daemon loses nothing it
        applied (the OS keeps what was written)."""
        if self._journal is None:
            return
        # the wrenches as little-endian doubles in hex: exact, and ~10x cheaper than float reprs
        w = struct.pack(self._wfmt, *(x for wr in applied for x in wr)).hex()
        extra = ',"to":1' if timeout else ""
        if self.drops != self._journal_drops:
            self._journal_drops = dict(self.drops)
            extra += ',"drops":' + json.dumps(self._journal_drops, separators=(",", ":"))
        self._journal.write(f'{{"k":{k},"w":"{w}"{extra}}}\n'.encode())

    def _read_journal(self) -> list[dict[str, Any]] | None:
        """The records of a journal left by this run (same run name and scenario), else None."""
        path = self.journal_path
        try:
            raw = path.read_bytes()
        except OSError:
            return None
        records: list[dict[str, Any]] = []
        good = 0
        for line in raw.split(b"\n"):
            try:
                records.append(json.loads(line))
            except ValueError:
                break  # a line cut by the kill, or the end
            good += len(line) + 1
        if not records or records[0].get("journal") != _JOURNAL_VERSION:
            return None
        head = records[0]
        if head.get("run") != self.run_name or head.get("scenario") != self.scenario_hash:
            log.warning("%s is from another run or scenario: starting afresh", path)
            return None
        if good < len(raw):
            with path.open("r+b") as f:
                f.truncate(good)  # drop the cut line: appends go after the last whole record
        return records[1:]

    def _resume(self, records: list[dict[str, Any]]) -> None:
        """Replays the journal: plant, sensor noise, tables and counters as they were when it died."""
        alive: set[int] = set()
        for rec in records:
            if "k" in rec:
                k = rec["k"]
                if k != self.tick:
                    raise RuntimeError(f"{self.journal_path.name}: tick {k} follows tick {self.tick - 1}")
                meas = self.plant.measure(self.rng).tolist()
                self.recorder.truth(self.plant.truth())
                flat = struct.unpack(self._wfmt, bytes.fromhex(rec["w"]))
                applied = [flat[3 * i:3 * i + 3] for i in range(self.n)]
                self.recorder.samples(k, meas, applied)
                self.plant.apply_and_step(applied)
                self.latest = list(applied)
                self.wrench_timeouts += rec.get("to", 0)
                if "drops" in rec:
                    self.drops = Counter(rec["drops"])
                self.tick = k + 1
            elif "e" in rec:
                est = decode(base64.b64decode(rec["e"]), Estimate)
                self._take_estimate(est)
            elif "ev" in rec:
                self.events.append(rec["ev"])
            elif "alive" in rec:
                alive = set(rec["alive"])
        self._journal_drops = dict(self.drops)
        self._expected_alive = alive
        self.resumed_at = self.tick
        # those recorded before it died are in self.events already (journaled as they came)
        self._partition_events = [e for e in self._partition_events if e not in self.events]

    def _open_journal(self, records: list[dict[str, Any]] | None) -> None:
        path = self.journal_path
        if records is None:
            self._journal = path.open("wb", buffering=0)
            self._write_journal({"journal": _JOURNAL_VERSION, "run": self.run_name, "scenario": self.scenario_hash})
        else:
            self._journal = path.open("ab", buffering=0)

    def _close_journal(self, completed: bool) -> None:
        if self._journal is not None:
            self._journal.close()
            self._journal = None
            if completed:
                (self.journal_path).unlink(missing_ok=True)

    async def run(self) -> dict[str, Any]:
        records = self._read_journal()
        down_s = None
        if records is not None:
            down_s = max(0.0, time.time() - (self.journal_path).stat().st_mtime)
            self._resume(records)  # before subscribing: inputs then meet the resumed tick
            log.warning("restarted: resuming run %s at tick %d (replayed from %s)", self.run_name, self.tick,
                        self.journal_path.name)
        self._open_journal(records)
        if records is not None:
            self._event("sim_restart", replayed_ticks=self.tick, down_s=round(down_s, 3))
        t, run = self.transport, self.run_name
        self._subs += [
            t.subscribe(keys.agent_all(run, "wrench"), self._on_wrench),
            t.subscribe(keys.agent_all(run, "estimate"), self._on_estimate),
            t.subscribe(keys.agent_all(run, "report"), self._on_report),
            t.watch_alive(keys.alive_all(run), self._on_alive),
            t.declare_alive(keys.alive(run, "sim", 0)),
        ]
        completed = False
        try:
            summary = await self._run()
            completed = True
            return summary
        except BaseException as exc:  # cancelled (SIGTERM, Ctrl-C) or failed: keep the tables, say so
            self.recorder.abort(type(exc).__name__)
            raise
        finally:
            for s in reversed(self._subs):
                s.close()
            self._subs.clear()
            self._close_journal(completed)

    async def _run(self) -> dict[str, Any]:
        sc = self.scenario
        start = self.tick
        if self.resumed_at < 0:
            log.info("waiting for %d agents (run %s)", self.n, self.run_name)
            if not await self._wait_for(lambda: len(self.alive) == self.n, sc.timing.startup_timeout_s):
                missing = sorted(set(range(self.n)) - self.alive)
                log.warning("starting without agents %s", missing)
                self._event("start_without", agents=missing)
            self._write_journal({"alive": sorted(self.alive)})
            self._publish_control("start", 0)
            self.started = True  # from here an agent that appears (also during tick 0) is an event
        else:
            expected = set(self._expected_alive)
            if not await self._wait_for(lambda: not self._expected_alive, sc.timing.sim_restart_wait_s):
                for i in sorted(self._expected_alive):
                    log.warning("agent %d did not come back after the restart", i)
                    self._event("agent_down", agent=i)
            self._expected_alive.clear()
            log.info("resuming at tick %d with agents %s (before: %s)", self.tick, sorted(self.alive), sorted(expected))
        t_begin = time.perf_counter()
        wall0 = t_begin - start * sc.dt  # real time: tick k is due at wall0 + k dt (resumed: from now on)
        ticks = sc.ticks
        report_every = max(1, ticks // 100)
        pevents = self._partition_events
        stop = self._stop
        every, pose_key = sc.record.every_ticks, keys.sim_pose(self.run_name)
        for k in range(start, ticks):
            if stop is not None and k >= stop.end:
                break
            self.tick = k
            while pevents and pevents[0]["tick"] <= k:
                ev = pevents.pop(0)
                self.events.append(ev)
                self._write_journal({"ev": ev})
                log.info("tick %d: %s %d", k, ev["event"], ev["partition"])
            if sc.mode == "realtime":
                lag = wall0 + k * sc.dt - time.perf_counter()
                if lag > 0:
                    await asyncio.sleep(lag)
            meas = self.plant.measure(self.rng).tolist()
            publish, meas_keys = self.transport.publish, self._meas_keys
            out = [encode(Measurement(k, i, vx, vy)) for i, (vx, vy) in enumerate(meas)]
            for i in range(self.n):
                publish(meas_keys[i], out[i])
            # recorded once the measurements are out: the agents are busy with them meanwhile
            truth = self.plant.truth()
            self.recorder.truth(truth)
            if k % every == 0:
                publish(pose_key, encode(LoadPose(k, truth.x, truth.y, truth.angle, truth.pg[0], truth.pg[1],
                                                  tuple(c for xy in truth.zi for c in xy))))
            got = True
            if sc.mode == "lockstep":
                self._meas_out = out
                got = await self._wait_for(self._have_wrenches, sc.timing.wrench_timeout_s)
                self._meas_out = None
                if not got:
                    self.wrench_timeouts += 1
                    log.warning("tick %d: no wrench from %s", k, sorted(self.alive - self.wrenches.keys()))
                applied = [self.wrenches.get(i, ZERO_WRENCH) for i in range(self.n)]
            else:
                await asyncio.sleep(0)  # let arrived wrenches in
                applied = list(self.latest)
            self._journal_tick(k, applied, not got)
            self.recorder.samples(k, meas, applied)
            self.plant.apply_and_step(applied)
            self.wrenches = {}
            self.tick = k + 1  # inputs from now on are for the next tick
            if k % report_every == 0 or k == ticks - 1:
                self._publish_control("progress", k + 1)
                if self.progress is not None:
                    self.progress(k + 1, ticks)
        wall = time.perf_counter() - t_begin
        ticks = self.tick  # the scenario's, or stop.end (the estimate that set it is a tick old, after_ticks before)
        self.ended = True
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
            "sim_s": self.tick * self.scenario.dt,
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
