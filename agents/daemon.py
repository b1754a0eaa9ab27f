"""The agent daemon: schedules one pure ``AgentCore`` over a transport.

It owns no estimation logic. Per tick it waits (lockstep) for its measurement and for the live
neighbours' previous-tick states, passes every neighbour message through the receive-side link
model into a ``DelayLine``, steps the core with what the line releases, and publishes the core's
state, wrench and estimate. Everything arriving from outside is decoded and validated here; a bad
message is dropped and counted by reason, never raised.
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections import Counter

from agents.factory import build_agent
from agents.laws import ControlLawError
from config.scenario import AgentView
from net import keys
from net.link import DelayLine, LinkStats, build_in_links, receive_through
from net.messages import AgentReport, Control, Measurement, StateMsg
from net.neighbour_wait import MAX_TICK_LEAD, NeighbourWait
from net.schema import FirstDrops, decode_counted, encode
from net.transport import Transport

log = logging.getLogger("coload.agent")

#: Real time: how far ahead a measurement or a neighbour's state may be. Two bounds, both must hold:
#: (1) ahead of the anchor by at most twice the wall-clock time since it plus the anchor's slack (a
#: simulator cannot run faster than the clock). The anchor is the simulator's start notice (tick 0,
#: slack START_SLACK_S: the notice may be handled late, after a stall of the agent's loop, with the
#: first measurements right behind it) or, for an agent that joins a running team, its first
#: measurement (slack REALTIME_LEAD_SLACK). It never moves, so a burst of forgeries cannot walk it
#: forward. (2) Once a measurement is accepted, ahead of it by at most 1.5 times the clock since it
#: plus REALTIME_LEAD_SLACK: one forgery far ahead is refused at once instead of making every genuine
#: message after it stale (an agent blinded, a link cut). A late joiner's first measurement is
#: trusted; keeping forged publishers out altogether is Zenoh access control's job (docs/security.md).
REALTIME_LEAD_SLACK = 50
START_SLACK_S = 2.0

# Lockstep tick discipline (validated here, at the edge, before a message reaches the core or
# consumes a link-model draw). The simulator publishes measurements tick after tick on one key, and a
# neighbour publishes its state tick after tick, and Zenoh delivers one publisher's samples in order
# and reliably (puts are RELIABLE + BLOCK). So in lockstep a genuine measurement is always the one
# after the last accepted one, and a genuine state is the one after the last accepted one from that
# neighbour -- or, after a neighbour restarted and jumped to the current tick, one no further ahead
# than our own next tick + 1. Anything else is replayed (``stale``) or ahead of time (``future``),
# and is dropped: before these rules, a state claiming a tick a few hundred ahead consumed a draw of
# the link model and made every genuine state of that neighbour look stale (a silent corruption).
# What no rule at the edge can catch is a well-formed forgery of exactly the next tick that arrives
# before the genuine message: that needs authenticated publishers (Zenoh access control / TLS).
#
# The simulator's liveliness token tells the agent when it lost the simulator (the simulator died,
# or this agent's own link went down) and when it is back. While it is gone a lockstep agent simply
# waits for its next measurement. When it comes back the agent re-publishes its last wrench and
# estimate (a restarted simulator resumes at the tick it had not finished and may have missed them),
# and takes the next measurement even if it skips ticks (the run went on while this agent was cut
# off): no rejoin_after_s hold then.


class AgentDaemon:
    def __init__(self, view: AgentView, transport: Transport, run: str) -> None:
        self.scenario = view  # what this agent knows of the scenario, nothing more
        self.id = agent_id = view.agent
        self.run_name = run
        self.transport = transport
        self.mode = view.mode
        self.core = build_agent(view)
        self.neighbours = list(view.neighbours)
        self.links = build_in_links(view)
        self.stats = {j: LinkStats() for j in self.neighbours}
        self.line = DelayLine()
        self.drops: Counter[str] = Counter()
        self.said = FirstDrops(log, f"agent {agent_id}")  # the first drop of each kind and reason, in the log
        self.timeouts = 0
        self.next_tick = 0  # the tick the core steps next
        self.last_meas = -1  # tick of the last accepted measurement
        self._anchor: tuple[int, float, float] | None = None  # real time: (tick, loop time, slack in ticks)
        self._last_meas_t = 0.0  # real time: loop time the last measurement was accepted
        self.seen_start = False  # the simulator's start notice arrived: we are in from tick 0
        self.pending_meas: dict[int, Measurement] = {}
        # the neighbours' last states, which of them a lockstep step waits for, the end-of-run gate; a
        # neighbour that skipped ticks comes back at most one tick past this agent's next (its state
        # of the tick this agent is about to step is fine)
        self.wait = NeighbourWait(self.neighbours, self.mode, self._report_and_end, lead=1)
        self.done = asyncio.Event()
        self._timer: asyncio.TimerHandle | None = None
        self._jump: Measurement | None = None  # lockstep: a measurement that skips ticks, held back
        self._jump_timer: asyncio.TimerHandle | None = None
        self._jump_base = -1  # last_meas when the skip was held back
        self._subs: list = []
        self._k_state = keys.state(run, agent_id)
        self._k_wrench = keys.wrench(run, agent_id)
        self._k_estimate = keys.estimate(run, agent_id)
        self._k_meas = keys.meas(run, agent_id)
        self._k_control = keys.sim_control(run)
        self._state_keys = {keys.state(run, j): j for j in self.neighbours}  # parsed once, not per sample
        self._record_every = view.record.every_ticks
        self.ticks_stepped = 0
        self.max_age_ticks = view.timing.max_age_s / view.dt
        self.sim_alive = False
        self._sim_lost = False  # the simulator's token went away after the run started; cleared by a measurement
        self._lost_timer: asyncio.TimerHandle | None = None  # gives up on a simulator gone too long
        self._tokenless = False  # measurements come, but the simulator's liveliness token was never seen
        self.gave_up = False  # ended because the simulator never came back
        self.failed: str | None = None  # ended because its step raised (a control law or a bug): the one-line cause
        self._resend: dict[str, bytes] = {}  # key -> last wrench / estimate published, re-sent to a returning simulator

    # ---- lifecycle -------------------------------------------------------------------------
    def start(self) -> None:
        t, run, i = self.transport, self.run_name, self.id
        self._subs.append(t.subscribe(self._k_meas, self._on_meas))
        for j in self.neighbours:
            self._subs.append(t.subscribe(keys.state(run, j), self._on_state))
        self._subs.append(t.subscribe(self._k_control, self._on_control))
        self._subs.append(t.watch_alive(keys.alive_all(run), self._on_alive))
        self._subs.append(t.declare_alive(keys.alive(run, "agent", i)))
        log.info("agent %d up: neighbours %s, mode %s", i, self.neighbours, self.mode)

    async def run(self) -> AgentReport:
        self.start()
        try:
            await self.done.wait()
        finally:
            self.stop()
        return self.report()

    def stop(self) -> None:
        for timer in (self._timer, self._jump_timer, self._lost_timer):
            if timer is not None:
                timer.cancel()
        self.wait.finish.cancel()
        for s in reversed(self._subs):
            s.close()
        self._subs.clear()

    def report(self) -> AgentReport:
        return AgentReport(
            agent=self.id,
            links={j: st.as_dict() for j, st in self.stats.items()},
            drops=dict(self.drops),
            timeouts=self.timeouts,
            ticks=self.ticks_stepped,
        )

    # ---- inputs ----------------------------------------------------------------------------
    def _decode(self, payload: bytes, kind: type, key: str, link: int | None = None):
        return decode_counted(payload, kind, self.drops, None if link is None else self.stats[link], self.said, key)

    def _on_alive(self, key: str, alive: bool) -> None:
        parsed = keys.parse_alive(key)
        if parsed is None:
            return
        _, role, ident = parsed
        if role == "sim":
            self._on_sim_alive(alive)
            return
        if alive or role != "agent" or not self.wait.gone(ident):
            return  # a neighbour that comes back is waited for again from its first message
        self._try_step()
        self.wait.check_finish()

    def _on_sim_alive(self, alive: bool) -> None:
        if alive == self.sim_alive:
            return
        self.sim_alive = alive
        if not alive:
            if self.done.is_set() or not (self.seen_start or self.ticks_stepped):
                return  # the run is over, or has not started
            self._sim_lost = True
            wait = self.scenario.timing.sim_lost_timeout_s
            log.warning("agent %d: the simulator is gone (next tick %d); waiting %g s for it", self.id,
                        self.next_tick, wait)
            self._lost_timer = asyncio.get_running_loop().call_later(wait, self._give_up)
            return
        if self._lost_timer is not None:
            self._lost_timer.cancel()
            self._lost_timer = None
        self._tokenless = False
        if self._sim_lost:
            log.info("agent %d: the simulator is back; re-sending the last wrench and estimate", self.id)
            for key, payload in self._resend.items():
                self.transport.publish(key, payload)

    def _on_control(self, key: str, payload: bytes) -> None:
        if key != self._k_control:
            self.drops[keys.WRONG_KEY] += 1  # a put on a wider key expression: not the simulator's
            self.said.drop("control", keys.WRONG_KEY, f"a put on {key}, taken only on {self._k_control}")
            return
        msg = self._decode(payload, Control, key)
        if msg is None:
            return
        # a run lasts its scenario's ticks, or fewer when it stops after done (stop_after_done_s)
        early_end = self.scenario.stop_after_done_s is not None
        if msg.ticks != self.scenario.ticks or (
                msg.kind == "done" and not (msg.tick == msg.ticks or (early_end and 0 < msg.tick < msg.ticks))):
            self.drops["bad_control"] += 1  # not this run's simulator (or a forgery): ignore it
            if msg.ticks != self.scenario.ticks:
                why = (f"{msg.kind!r} says the run has ticks={msg.ticks}; this agent's scenario has "
                       f"{self.scenario.ticks} (duration / dt): another run's notice, ignored")
            else:
                why = f"'done' at tick {msg.tick} before the run's last tick ({msg.ticks}): ignored"
            self.said.drop("control", "bad_control", why, key)
            return
        if msg.kind == "start":
            self.seen_start = True
            if self.mode == "realtime" and self._anchor is None:
                self._anchor = (0, self.transport.loop.time(), START_SLACK_S / self.scenario.dt)
        elif msg.kind == "done":
            self.wait.done(msg.tick)

    def _give_up(self) -> None:
        """The simulator stayed away for timing.sim_lost_timeout_s: report what this agent saw and end."""
        self._lost_timer = None
        if self.done.is_set():
            return
        log.error("agent %d: the simulator did not come back in %g s; giving up at tick %d", self.id,
                  self.scenario.timing.sim_lost_timeout_s, self.next_tick)
        self.gave_up = True
        self._report_and_end()

    def _report_and_end(self) -> None:
        self.transport.publish(keys.report(self.run_name, self.id), encode(self.report()))
        self.done.set()

    def _on_meas(self, key: str, payload: bytes) -> None:
        if key != self._k_meas:
            self.drops[keys.WRONG_KEY] += 1  # a put on a wider key expression: not the simulator's
            self.said.drop("meas", keys.WRONG_KEY, f"a put on {key}, taken only on {self._k_meas}")
            return
        m = self._decode(payload, Measurement, key)
        if m is None:
            return
        if m.agent != self.id:
            self.drops["wrong_agent"] += 1
            self.said.drop("meas", "wrong_agent", f"a measurement of agent {m.agent} on agent {self.id}'s key", key)
            return
        if m.tick == self.last_meas or m.tick in self.pending_meas:
            # the simulator re-sends the current measurement to an agent that (re)appears while it
            # waits for that tick's wrench; this agent may have had it already
            self.drops["duplicate"] += 1
            return
        if m.tick < self.last_meas or m.tick < self.next_tick:
            self.drops["stale"] += 1
            return
        if m.tick > self.next_tick + MAX_TICK_LEAD:
            self.drops["future"] += 1
            return
        if self.mode == "realtime":
            if self._anchor is None:
                self._anchor = (m.tick, self.transport.loop.time(), REALTIME_LEAD_SLACK)
            elif m.tick > self._horizon():
                self.drops["future"] += 1
                return
        if self.mode == "lockstep" and m.tick != self.last_meas + 1:
            if self._sim_lost and self.sim_alive:
                # cut off from the simulator and back: the run went on meanwhile, this is its tick
                log.warning("agent %d: back after losing the simulator; rejoining at tick %d (missed %d..%d)",
                            self.id, m.tick, self.last_meas + 1, m.tick - 1)
            elif self.seen_start or self.ticks_stepped or self.pending_meas:
                # the simulator never skips a tick, so either this agent was cut off (partition,
                # restart) and the run went on without it, or the message is forged: hold it back
                # and rejoin at its tick only if the real next measurement does not come
                self._hold_jump(m)
                return
            else:
                # a (re)joiner that missed the start: join the run at the simulator's current tick
                log.info("agent %d joins the run at tick %d", self.id, m.tick)
            self._join_at(m.tick)
        self.last_meas = m.tick
        self._last_meas_t = self.transport.loop.time()
        self._sim_lost = False
        if not self.sim_alive and self._lost_timer is None:
            self._watch_tokenless()
        if self._jump is not None and self._jump.tick <= m.tick:
            self._jump = None  # the real stream went past it: it was not ours (counted when held)
        if self.mode == "realtime" and m.tick > self.next_tick:
            # act on the latest data: skip ticks we never got
            self.pending_meas.clear()
            self.next_tick = m.tick
        self.pending_meas[m.tick] = m
        self._try_step()

    def _watch_tokenless(self) -> None:
        """Measurements come but the simulator's liveliness token (``alive/sim/0``) is not there: a
        simulator written without one, or one whose token came later than its first measurement (their
        subscriptions run on different threads). Without the token this agent cannot tell that the
        simulator is gone; so it gives up as for a lost simulator once no measurement has come for
        ``timing.sim_lost_timeout_s`` (and says so once measurements have come for a while with no token),
        instead of waiting for a ``done`` for ever."""
        wait = self.scenario.timing.sim_lost_timeout_s
        idle = self.transport.loop.time() - self._last_meas_t
        if self.sim_alive or self.done.is_set():
            self._lost_timer = None
            return
        if idle >= wait:
            self._lost_timer = None
            self._give_up()
            return
        if not self._tokenless and self.ticks_stepped >= 1:
            self._tokenless = True
            log.warning("agent %d: measurements come but the simulator's liveliness token %s is not there "
                        "(docs/wire.md): this agent gives up %g s after the last measurement unless a 'done' comes",
                        self.id, keys.alive(self.run_name, "sim", 0), wait)
        self._lost_timer = asyncio.get_running_loop().call_later(min(wait - idle, max(1.0, wait / 10)),
                                                                 self._watch_tokenless)

    def _hold_jump(self, m: Measurement) -> None:
        """Counted as a ``future`` drop now; taken back if the agent does rejoin with it."""
        self.drops["future"] += 1
        if self._jump is None or m.tick > self._jump.tick:
            self._jump = m
            self._jump_base = self.last_meas
        if self._jump_timer is None:
            self._jump_timer = asyncio.get_running_loop().call_later(
                self.scenario.timing.rejoin_after_s, self._rejoin
            )

    def _rejoin(self) -> None:
        """No measurement came since the skip was held back: the run went on without this agent,
        so it goes on from the held tick. If the stream moved meanwhile, the skip was forged."""
        self._jump_timer = None
        m, self._jump = self._jump, None
        if m is None or self.last_meas != self._jump_base or m.tick <= self.last_meas:
            return
        log.warning("agent %d: measurements %d..%d never came; rejoining at tick %d",
                    self.id, self.last_meas + 1, m.tick - 1, m.tick)
        self.drops["future"] -= 1
        if not self.drops["future"]:
            del self.drops["future"]  # not a drop after all: no `future: 0` in the report
        self._join_at(m.tick)
        self.last_meas = m.tick
        self._last_meas_t = self.transport.loop.time()
        self.pending_meas[m.tick] = m
        self._try_step()

    def _join_at(self, k: int) -> None:
        """Go on from tick k, the run having gone on without this agent: forget what was pending, and
        wait only for the neighbours whose tick k - 1 state is here already (the others come back
        into the wait with their next message; waiting for a state sent before this agent listened
        would only cost a neighbour timeout)."""
        self._jump = None
        self.pending_meas.clear()
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self.next_tick = k
        self.wait.rejoin_at(k)

    def _horizon(self) -> float:
        """Real time: the furthest tick a genuine message can carry now (see REALTIME_LEAD_SLACK)."""
        tick, t0, slack = self._anchor
        now, dt = self.transport.loop.time(), self.scenario.dt
        horizon = tick + 2.0 * (now - t0) / dt + slack
        if self.last_meas >= 0:
            horizon = min(horizon, self.last_meas + 1.5 * (now - self._last_meas_t) / dt + REALTIME_LEAD_SLACK)
        return horizon

    def _on_state(self, key: str, payload: bytes) -> None:
        sender = self._state_keys.get(key)
        if sender is None:
            # a put on a wider key expression that this subscription matched (agent/*/state)
            self.drops[keys.WRONG_KEY] += 1
            self.said.drop("state", keys.WRONG_KEY, f"a put on {key}, taken only on a neighbour's exact state key")
            return
        msg = self._decode(payload, StateMsg, key, link=sender)
        if msg is None:
            return
        if msg.sender != sender:
            self.drops["spoofed_sender"] += 1
            self.said.drop("state", "spoofed_sender", f"sender {msg.sender} on agent {sender}'s state key", key)
            return
        horizon = self._horizon() if self.mode == "realtime" and self._anchor is not None else math.inf
        refused = self.wait.admit(sender, msg.tick, self.next_tick, horizon)
        if refused is not None:
            self.drops[refused] += 1
            return
        receive_through(self.links[sender], self.stats[sender], self.line, sender, msg.tick, msg, self.scenario.dt,
                        self.mode, self.next_tick)
        self._try_step()
        self.wait.check_finish()

    # ---- stepping --------------------------------------------------------------------------
    def _try_step(self) -> None:
        while self.next_tick in self.pending_meas:
            k = self.next_tick
            if not self.wait.ready(k):
                if self._timer is None:
                    self._timer = asyncio.get_running_loop().call_later(
                        self.scenario.timing.neighbour_timeout_s, self._on_timeout, k
                    )
                return
            self._step(k)

    def _on_timeout(self, k: int) -> None:
        self._timer = None
        if self.next_tick != k:
            return
        missing = self.wait.stop_waiting(k)  # back in once they speak again
        log.warning("agent %d: tick %d: no state from %s in time; stepping without", self.id, k, missing)
        self.timeouts += 1
        self._try_step()

    def _step(self, k: int) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        m = self.pending_meas.pop(k)
        inbox = self.line.pop_due(k)
        if self.mode == "realtime":
            inbox = self._fresh(k, inbox)
        try:
            res = self.core.step(k, m.vx, m.vy, inbox)
        except Exception as exc:
            # the user's law failed (or, a bug, the core): this agent stops, as a crashed robot would (its
            # liveliness token goes: the team and the simulator go on without it), and its process exits 1
            # with one line; not left to the transport, which would log it and keep the agent half alive
            # (a lockstep run then crawled at one neighbour timeout per tick)
            if isinstance(exc, ControlLawError):
                self.failed = str(exc)
                log.error("agent %d: %s", self.id, exc)
            else:
                self.failed = f"agent {self.id} failed at tick {k}: {type(exc).__name__}: {exc}"
                log.exception("agent %d: the step of tick %d failed", self.id, k)
            self.pending_meas.clear()
            self.done.set()
            return
        pub = self.transport.publish
        # the wrench first: the simulator waits for it (critical path), neighbours need the state
        # only for the next tick
        wrench = encode(res.wrench)
        pub(self._k_wrench, wrench)
        self._resend[self._k_wrench] = wrench
        pub(self._k_state, encode(res.state))
        if k % self._record_every == 0:  # the recorder keeps only these
            estimate = encode(res.estimate)
            pub(self._k_estimate, estimate)
            self._resend[self._k_estimate] = estimate
        self.next_tick = k + 1
        self.ticks_stepped += 1

    def _fresh(self, k: int, inbox: list[StateMsg]) -> list[StateMsg]:
        """Real time: neighbour states older than ``timing.max_age_s`` are dropped (``stale_age``).

        A state sent at tick j describes its sender at j; stepping tick k it is (k - j) dt seconds
        old. In real time the simulator paces ticks on the wall clock and an agent steps a tick as
        its measurement arrives, so this is the state's wall-clock age; it is also the right age
        when the simulator was stopped meanwhile (the plant stood still too).
        """
        limit = self.max_age_ticks
        fresh = [msg for msg in inbox if k - msg.tick <= limit]
        if len(fresh) != len(inbox):
            self.drops["stale_age"] += len(inbox) - len(fresh)
        return fresh
