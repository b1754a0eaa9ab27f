"""Real-time mode: neighbour states older than ``timing.max_age_s`` are recognised by age in the agent
daemon, kept out of the core's step and counted as ``stale_age``; fresher ones are used."""

from __future__ import annotations

import asyncio

from agents.daemon import AgentDaemon
from agents.factory import build_agent
from config.loader import load_scenario
from net import keys
from net.memory import MemoryBus, MemoryTransport
from net.messages import Measurement
from net.schema import encode
from tests.conftest import SCENARIOS

ME = 2  # neighbours 1 and 3 on the line


async def _drive(max_age_s: float):
    sc = load_scenario(SCENARIOS / "quick.toml", ['mode="realtime"', f"timing.max_age_s={max_age_s}"])
    loop = asyncio.get_running_loop()
    bus, run = MemoryBus(), "age"
    t_agent, t_test = MemoryTransport(bus, loop), MemoryTransport(bus, loop)
    agent = AgentDaemon(sc.agent_view(ME), t_agent, run)
    seen: dict[int, list[tuple[int, int]]] = {}  # tick stepped -> (sender, tick) of the inbox it used
    stepped: dict[int, asyncio.Future] = {}

    class Spy:
        """The agent's core, recording the inbox of every step."""

        def __init__(self, core) -> None:
            self.core = core

        def step(self, tick, vx, vy, inbox):
            seen[tick] = sorted((m.sender, m.tick) for m in inbox)
            stepped.setdefault(tick, loop.create_future()).set_result(None)
            return self.core.step(tick, vx, vy, inbox)

    agent.core = Spy(agent.core)
    agent.start()
    # the neighbours' genuine states, from their own cores
    cores = {j: build_agent(sc.agent_view(j)) for j in (1, 3)}
    states = {j: [cores[j].step(k, 0.0, 0.0, []).state for k in range(40)] for j in (1, 3)}

    async def meas(k: int) -> None:
        stepped.setdefault(k, loop.create_future())
        t_test.publish(keys.meas(run, ME), encode(Measurement(k, ME, 0.0, 0.0)))
        await asyncio.wait_for(stepped[k], 5)

    def state(j: int, k: int) -> None:
        t_test.publish(keys.state(run, j), encode(states[j][k]))

    try:
        await meas(0)
        state(1, 0), state(3, 0)
        await meas(1)  # both one tick old: used
        state(1, 1), state(3, 20)
        await meas(30)  # real time skips to the latest tick: 1's is 29 ticks old, 3's 10
        state(1, 35)
        await meas(36)  # 1 tick old
    finally:
        agent.stop()
        t_agent.close(), t_test.close()
    return seen, agent.drops


def test_old_neighbour_states_are_dropped_by_age():
    seen, drops = asyncio.run(_drive(max_age_s=0.15))  # 15 ticks of 10 ms
    assert seen[0] == []
    assert seen[1] == [(1, 0), (3, 0)]
    assert seen[30] == [(3, 20)]  # (1, 1) is 0.29 s old
    assert seen[36] == [(1, 35)]
    assert drops == {"stale_age": 1}


def test_a_generous_bound_keeps_them():
    seen, drops = asyncio.run(_drive(max_age_s=1.0))
    assert seen[30] == [(1, 1), (3, 20)]
    assert "stale_age" not in drops


def _realtime_run(tmp_path, max_age_s: float) -> dict:
    from coload.runs.orchestrate import run_daemons_in_memory

    # real time over the in-memory daemons: every neighbour state arrives 0.3 s after it was sent
    sc = load_scenario(SCENARIOS / "quick.toml", ['mode="realtime"', "duration=1.5", "link.delay_s=0.3",
                                                   f"timing.max_age_s={max_age_s}"])
    return asyncio.run(run_daemons_in_memory(sc, tmp_path / f"run-{max_age_s}"))


def test_realtime_run_counts_stale_age_in_summary(tmp_path):
    """States delayed 0.3 s by the link model against a 0.2 s bound: each one the agents step on is
    dropped by age, and summary.json says so; with a 0.5 s bound none is."""
    strict = _realtime_run(tmp_path, 0.2)
    used = sum(link["delivered"] for link in strict["links"].values())
    assert 0 < strict["drops"]["stale_age"] <= used
    # those not dropped were still in flight (delivery due after the agent's last step)
    lenient = _realtime_run(tmp_path, 0.5)
    assert "stale_age" not in lenient["drops"]
