"""Fuzzing the daemons' message handlers (hypothesis) over the in-memory transport.

Random payloads -- bytes, random msgpack, envelopes of every kind with random bodies, and
well-formed messages with random ticks and ids -- are fed to every handler of an ``AgentDaemon``
(its measurement, neighbour-state and control keys) and of a ``SimDaemon`` (wrench, estimate,
report keys). A handler never raises, and every message is either accepted (visible in the
daemon's state) or dropped and counted by reason: nothing vanishes silently.
"""

from __future__ import annotations

import asyncio

import msgpack
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from agents.daemon import AgentDaemon
from coload.rundir.recorder import Recorder
from config.loader import load_scenario
from net import keys
from net.memory import MemoryBus, MemoryTransport
from net.messages import AgentReport, Control, Estimate, Measurement, StateMsg, Wrench
from net.schema import encode
from net.vocabulary import ESTIMATE_NAMES
from simulator.daemon import SimDaemon
from tests.conftest import SCENARIOS

RUN = "fuzz"
SC = load_scenario(SCENARIOS / "quick.toml", ["duration=1.0"])

ticks = st.one_of(st.integers(-3, 2_000), st.integers(2**53 - 2, 2**53 + 2), st.sampled_from([0, 1, 2, 99, 100]))
ids = st.one_of(st.integers(-2, 8), st.integers(65_530, 70_000))
floats = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.floats(-10, 10))
names = st.text(max_size=70)
scalars = st.one_of(st.none(), st.booleans(), st.integers(-(2**64), 2**64 - 1), floats, st.text(max_size=20),
                    st.binary(max_size=20))
msgpack_values = st.recursive(
    scalars,
    lambda inner: st.one_of(st.lists(inner, max_size=5), st.dictionaries(st.text(max_size=8), inner, max_size=5)),
    max_leaves=20,
)
kinds = st.sampled_from(["meas", "wrench", "state", "estimate", "control", "report", "other", ""])


def _pack(obj) -> bytes:
    try:
        return msgpack.packb(obj, use_bin_type=True)
    except (OverflowError, ValueError, TypeError):
        return b"\xc1"


def _valid(draw) -> bytes:
    """A well-formed message of a random kind with random (in-bounds or not) ticks and ids."""
    t, i = draw(ticks.filter(lambda x: 0 <= x <= 2**53)), draw(ids.filter(lambda x: 0 <= x <= 65_535))
    f = draw(st.floats(-10, 10))
    choice = draw(st.integers(0, 5))
    if choice == 0:
        msg = Measurement(t, i, f, f)
    elif choice == 1:
        msg = Wrench(t, i, f, f, f)
    elif choice == 2:
        msg = StateMsg(t, i, f, f, 0, {"w": f}, {})
    elif choice == 3:
        msg = Estimate(t, i, {"omega": f}, {})
    elif choice == 4:
        msg = Control(draw(st.sampled_from(["start", "progress", "stop", "done"])), t,
                      draw(st.sampled_from([SC.ticks, t, 0])))
    else:
        msg = AgentReport(i, {}, {}, 0, t)
    return encode(msg)


@st.composite
def payloads(draw) -> bytes:
    how = draw(st.integers(0, 4))
    if how == 0:
        return draw(st.binary(max_size=200))
    if how == 1:
        return _pack(draw(msgpack_values))
    if how == 2:
        body = draw(st.dictionaries(st.sampled_from(["tick", "agent", "sender", "vx", "vy", "fx", "fy", "tau",
                                                     "phase", "shared", "pair", "values", "pairs", "kind",
                                                     "ticks", "links", "drops", "timeouts", "x"]),
                                    msgpack_values, max_size=8))
        return _pack((draw(kinds), draw(st.sampled_from([1, 1, 1, 0, 2])), body))
    if how == 3:
        return b"\x00" * draw(st.sampled_from([65_536, 65_537, 100_000]))
    return _valid(draw)


def _drops(d) -> int:
    return sum(d.drops.values())


def _agent_snapshot(a: AgentDaemon):
    return (a.last_meas, tuple(sorted(a.wait.last_from.items())), a.seen_start, a.done.is_set(), a.ticks_stepped,
            len(a.pending_meas))


@pytest.fixture(scope="module")
def loop():
    lp = asyncio.new_event_loop()
    yield lp
    lp.close()


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(batch=st.lists(st.tuples(st.sampled_from(["meas", "state0", "state2", "state3", "control"]), payloads()),
                      min_size=1, max_size=12))
def test_agent_handlers_never_raise_and_always_count(loop, batch):
    async def go() -> None:
        bus = MemoryBus(loop)
        transport = MemoryTransport(bus, loop)
        daemon = AgentDaemon(SC.agent_view(1), transport, RUN)  # neighbours 0 and 2
        daemon.start()
        try:
            handlers = {
                "meas": (daemon._on_meas, keys.meas(RUN, 1)),
                "state0": (daemon._on_state, keys.state(RUN, 0)),
                "state2": (daemon._on_state, keys.state(RUN, 2)),
                "state3": (daemon._on_state, keys.state(RUN, 3)),  # not a neighbour's key
                "control": (daemon._on_control, keys.sim_control(RUN)),
            }
            for which, payload in batch:
                handler, key = handlers[which]
                before, snap = _drops(daemon), _agent_snapshot(daemon)
                handler(key, payload)
                counted = _drops(daemon) - before
                assert counted in (0, 1)
                if counted == 0:  # accepted: it must show in the daemon's state
                    assert _agent_snapshot(daemon) != snap or which == "control", (which, payload[:60])
                await asyncio.sleep(0)
        finally:
            daemon.stop()
            transport.close()

    loop.run_until_complete(go())


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(batch=st.lists(st.tuples(st.sampled_from(["wrench", "estimate", "report"]), ids, payloads()),
                      min_size=1, max_size=12))
def test_sim_handlers_never_raise_and_always_count(loop, tmp_path_factory, batch):
    async def go() -> None:
        bus = MemoryBus(loop)
        transport = MemoryTransport(bus, loop)
        sim = SimDaemon(SC, transport, RUN, Recorder(tmp_path_factory.mktemp("sim"), SC, ESTIMATE_NAMES))
        sim.tick = 50
        handlers = {"wrench": sim._on_wrench, "estimate": sim._on_estimate, "report": sim._on_report}
        try:
            for which, i, payload in batch:
                key = f"coload/{RUN}/agent/{i}/{which}"
                before = _drops(sim)
                snap = (len(sim.wrenches), list(sim.last_estimate), len(sim.reports), sim.recorder.estimates_recorded)
                handlers[which](key, payload)
                counted = _drops(sim) - before
                assert counted in (0, 1)
                if counted == 0:
                    after = (len(sim.wrenches), list(sim.last_estimate), len(sim.reports),
                             sim.recorder.estimates_recorded)
                    assert after != snap, (which, i, payload[:60])
        finally:
            for table in (sim.recorder._samples, sim.recorder._estimates, sim.recorder._pairs, sim.recorder._truth):
                table.close()
            transport.close()

    loop.run_until_complete(go())



def test_realtime_a_forged_measurement_far_ahead_does_not_silence_the_agent():
    """Real time: a well-formed measurement 5000 ticks ahead of the last (50 s at dt = 0.01, within
    MAX_TICK_LEAD) arrives a moment after it, then a burst of forgeries 40 ticks apart (each one within
    the slack of the previous); a simulator cannot run ahead of the clock, so all are counted as
    future, and the genuine next measurement is used, not dropped as stale."""
    sc = load_scenario(SCENARIOS / "quick.toml", ["mode=\"realtime\""])

    async def scene():
        bus = MemoryBus()
        agent_t, sim_t = MemoryTransport(bus), MemoryTransport(bus)
        agent = AgentDaemon(sc.agent_view(0), agent_t, RUN)
        agent.start()
        try:
            # one forgery far ahead, then a burst of forgeries each within the slack of the one before
            for tick in (0, 5000, *range(80, 8000, 40), 1):
                sim_t.publish(keys.meas(RUN, 0), encode(Measurement(tick, 0, 0.1, 0.0)))
                await asyncio.sleep(0)  # delivery is scheduled on the loop
                await asyncio.sleep(0)
            return agent.last_meas, dict(agent.drops)
        finally:
            agent.stop()
            agent_t.close()
            sim_t.close()

    last, drops = asyncio.run(scene())
    assert last == 1  # the genuine stream goes on
    assert drops.get("future") == 1 + 198 and not drops.get("stale")  # every forgery past the clock is counted
