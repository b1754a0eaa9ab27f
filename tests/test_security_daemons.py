"""Defence in depth in the daemons' receive paths (docs/security.md), on the in-memory transport.

A message is accepted only on the exact key of its kind and sender: Zenoh hands a put on a wider key
expression (``coload/r/agent/*/meas``, ``coload/r/**``) to every subscriber it matches, under the key
it was put on, so each handler here is called with such a key and must drop and count it
(``wrong_key``) without touching the daemon's state. In real time a far-future tick is refused
against the clock horizon of the simulator's start notice, so it can neither blind an agent nor cut
a link.
"""

from __future__ import annotations

import asyncio

from agents.daemon import REALTIME_LEAD_SLACK, START_SLACK_S, AgentDaemon
from config.loader import load_scenario
from net import keys
from net.memory import MemoryBus, MemoryTransport
from net.messages import AgentReport, Control, Estimate, Measurement, StateMsg, Wrench
from net.schema import decode, encode
from tests.conftest import SCENARIOS

RUN = "sec"
FAR = 5_000


def _state(tick: int, sender: int) -> StateMsg:
    return StateMsg(tick=tick, sender=sender, vx=0.1, vy=0.0, phase=0, shared={"w": 0.0}, pair={})


def _agent(mode: str, scene):
    sc = load_scenario(SCENARIOS / "quick.toml", [f'mode="{mode}"'])

    async def main():
        bus = MemoryBus()
        t = MemoryTransport(bus)
        agent = AgentDaemon(sc.agent_view(1), t, RUN)  # neighbours 0 and 2
        agent.start()
        try:
            return await scene(agent, sc)
        finally:
            agent.stop()
            t.close()

    return asyncio.run(main())


def test_agent_refuses_puts_on_wider_key_expressions():
    async def scene(agent: AgentDaemon, sc):
        ticks = sc.ticks
        wide = {
            "coload/sec/agent/*/meas": encode(Measurement(0, 1, 9.0, 9.0)),
            "coload/sec/**": encode(Control("done", ticks, ticks)),
            "coload/sec/agent/*/state": encode(_state(0, 0)),
        }
        agent._on_meas("coload/sec/agent/*/meas", wide["coload/sec/agent/*/meas"])
        agent._on_meas("coload/sec/**", wide["coload/sec/agent/*/meas"])
        agent._on_control("coload/sec/**", wide["coload/sec/**"])
        agent._on_control("coload/*/sim/control", wide["coload/sec/**"])
        agent._on_state("coload/sec/agent/*/state", wide["coload/sec/agent/*/state"])
        agent._on_state(keys.state(RUN, 3), encode(_state(0, 3)))  # not a neighbour's key
        return dict(agent.drops), agent.last_meas, agent.pending_meas, dict(agent.wait.last_from), agent.wait.finish.active

    drops, last_meas, pending, last_from, finishing = _agent("lockstep", scene)
    assert drops == {keys.WRONG_KEY: 6}
    assert last_meas == -1 and not pending and last_from == {0: -1, 2: -1} and not finishing


def test_agent_takes_the_genuine_keys():
    async def scene(agent: AgentDaemon, sc):
        agent._on_control(keys.sim_control(RUN), encode(Control("start", 0, sc.ticks)))
        agent._on_state(keys.state(RUN, 0), encode(_state(0, 0)))
        agent._on_meas(keys.meas(RUN, 1), encode(Measurement(0, 1, 0.1, 0.0)))
        return dict(agent.drops), agent.seen_start, agent.wait.last_from[0], agent.last_meas

    assert _agent("lockstep", scene) == ({}, True, 0, 0)


def test_realtime_far_future_tick_neither_blinds_an_agent_nor_cuts_a_link():
    """Right after the start notice a measurement and a neighbour's state claim tick 5000 (50 s
    ahead): both are refused as ``future``; the genuine tick-0 messages that follow are taken."""

    async def scene(agent: AgentDaemon, sc):
        agent._on_control(keys.sim_control(RUN), encode(Control("start", 0, sc.ticks)))
        agent._on_meas(keys.meas(RUN, 1), encode(Measurement(FAR, 1, 9.0, 9.0)))
        agent._on_state(keys.state(RUN, 0), encode(_state(FAR, 0)))
        agent._on_state(keys.state(RUN, 0), encode(_state(int(START_SLACK_S / sc.dt) + 30, 0)))  # < MAX_TICK_LEAD
        forged = dict(agent.drops)
        agent._on_state(keys.state(RUN, 0), encode(_state(0, 0)))
        agent._on_meas(keys.meas(RUN, 1), encode(Measurement(0, 1, 0.1, 0.0)))
        await asyncio.sleep(0)
        return forged, dict(agent.drops), agent.wait.last_from[0], agent.last_meas

    forged, drops, last_from0, last_meas = _agent("realtime", scene)
    assert forged == {"future": 3}
    assert drops == {"future": 3}  # the genuine ones are not stale
    assert last_from0 == 0 and last_meas == 0


def test_realtime_horizon_grows_with_the_clock():
    """A genuine run far along (tick 150 after 1.5 s of a 0.01 s tick) is not refused: the horizon
    is twice the clock's pace plus the slack; once a measurement is in, a state further ahead of it
    than the slack is refused."""

    async def scene(agent: AgentDaemon, sc):
        loop = asyncio.get_running_loop()
        agent._anchor = (0, loop.time() - 1.5, REALTIME_LEAD_SLACK)  # the start notice came 1.5 s ago
        agent._on_meas(keys.meas(RUN, 1), encode(Measurement(int(1.5 / sc.dt), 1, 0.1, 0.0)))
        agent._on_state(keys.state(RUN, 0), encode(_state(int(1.5 / sc.dt), 0)))
        agent._on_state(keys.state(RUN, 2), encode(_state(150 + REALTIME_LEAD_SLACK + 20, 2)))
        return dict(agent.drops), agent.last_meas, agent.wait.last_from

    drops, last_meas, last_from = _agent("realtime", scene)
    assert drops == {"future": 1}
    assert last_meas == 150 and last_from == {0: 150, 2: -1}


def test_realtime_start_notice_handled_late_does_not_refuse_genuine_measurements():
    """The loop stalled: the start notice is handled with 1.5 s of measurements right behind it
    (START_SLACK_S covers it); a forgery 5 s ahead of the last measurement is still refused."""

    async def scene(agent: AgentDaemon, sc):
        agent._on_control(keys.sim_control(RUN), encode(Control("start", 0, sc.ticks)))
        for k in range(0, 150, 10):
            agent._on_meas(keys.meas(RUN, 1), encode(Measurement(k, 1, 0.1, 0.0)))
        agent._on_meas(keys.meas(RUN, 1), encode(Measurement(150 + 500, 1, 9.0, 9.0)))
        agent._on_meas(keys.meas(RUN, 1), encode(Measurement(150, 1, 0.1, 0.0)))
        return dict(agent.drops), agent.last_meas

    assert _agent("realtime", scene) == ({"future": 1}, 150)


def test_simulator_refuses_puts_on_wider_key_expressions(tmp_path):
    from coload.rundir.recorder import Recorder
    from net.vocabulary import ESTIMATE_NAMES as NAMES
    from simulator.daemon import SimDaemon

    sc = load_scenario(SCENARIOS / "quick.toml", ["duration=1.0"])

    async def main():
        bus = MemoryBus()
        t = MemoryTransport(bus)
        sim = SimDaemon(sc, t, RUN, Recorder(tmp_path, sc, NAMES))
        sim.tick = 5
        sim._on_wrench("coload/sec/agent/*/wrench", encode(Wrench(5, 0, 1e3, 1e3, 1e3)))
        sim._on_wrench("coload/sec/**", encode(Wrench(5, 0, 1e3, 1e3, 1e3)))
        sim._on_wrench(keys.estimate(RUN, 0), encode(Wrench(5, 0, 1e3, 1e3, 1e3)))  # another kind's key
        sim._on_estimate("coload/sec/agent/*/estimate", encode(Estimate(5, 0, {"omega": 42.0}, {})))
        sim._on_report("coload/sec/agent/**", encode(AgentReport(0, {}, {}, 0, 5)))
        sim._on_wrench(keys.wrench(RUN, 7), encode(Wrench(5, 7, 1.0, 1.0, 1.0)))  # no agent 7: a real key
        sim._on_wrench(keys.wrench(RUN, 0), encode(Wrench(5, 0, 1.0, 2.0, 3.0)))  # genuine
        out = dict(sim.drops), dict(sim.wrenches)
        t.close()
        return out

    drops, wrenches = asyncio.run(main())
    assert drops == {keys.WRONG_KEY: 5, "unknown_sender": 1}
    assert wrenches == {0: (1.0, 2.0, 3.0)}


def _team_in_memory(tmp_path, sc, forge):
    """The simulator and every agent on one in-memory bus, plus an attacker on the same bus that
    hears agent 1's measurements and calls ``forge(tick, publish)`` for each (an insecure team: any
    client may put on any key). Returns the simulator's summary."""
    from coload.rundir.recorder import Recorder
    from net.vocabulary import ESTIMATE_NAMES as NAMES
    from simulator.daemon import SimDaemon

    async def main():
        bus = MemoryBus()
        transports = [MemoryTransport(bus) for _ in range(sc.n + 2)]
        agents = [AgentDaemon(sc.agent_view(i), transports[i], RUN) for i in range(sc.n)]
        tasks = [asyncio.ensure_future(a.run()) for a in agents]
        for task, t in zip(tasks, transports, strict=False):  # an agent that ends leaves, as its process would
            task.add_done_callback(lambda _, t=t: t.close())
        attacker = transports[-1]
        attacker.subscribe(keys.meas(RUN, 1), lambda key, payload: forge(
            decode(payload, Measurement).tick, attacker.publish))
        try:
            summary = await SimDaemon(sc, transports[-2], RUN, Recorder(tmp_path, sc, NAMES)).run()
            await asyncio.wait_for(asyncio.gather(*tasks), 10.0)
        finally:
            for t in tasks:
                t.cancel()
            for t in transports:
                t.close()
        return summary

    return asyncio.run(main())


def test_insecure_team_takes_forgeries_on_the_exact_keys(tmp_path):
    """What only the access-control list stops: a well-formed message on the exact key of another
    member, ahead of the genuine one. The daemons cannot tell it from the genuine one (it is
    counted only as the genuine one's ``duplicate``): forged wrenches of agent 2 steer the load.
    bench/bench_attacks.py measures every attack of docs/security.md on real processes."""
    sc = load_scenario(SCENARIOS / "quick.toml", ["duration=1.5"])

    def clean(tick, publish):
        return None

    def wrenches(tick, publish):
        if tick >= 50:
            publish(keys.wrench(RUN, 2), encode(Wrench(tick, 2, 500.0, 0.0, 0.0)))

    ref = _team_in_memory(tmp_path / "ref", sc, clean)
    steered = _team_in_memory(tmp_path / "wrench", sc, wrenches)
    x = {name: float((tmp_path / name / "truth.csv").read_text().splitlines()[-1].split(",")[1])
         for name in ("ref", "wrench")}
    assert ref["drops"] == {} and ref["agents_reported"] == list(range(sc.n))
    assert steered["drops"] == {"duplicate": sc.ticks - 50}  # every genuine wrench of agent 2 from then on
    assert x["wrench"] > x["ref"] + 1.0, x  # 500 N more along x for 1 s: a 50 kg load moves metres further
