"""A fault-free team loop on one plant, for diagnostics and tests that look inside the agents."""

from __future__ import annotations

from collections.abc import Iterator, Sequence

from agents.agent import AgentCore
from config.scenario import Scenario
from simulator.plant import Plant, sensor_rng


def team_ticks(scenario: Scenario, plant: Plant, agents: Sequence[AgentCore]
               ) -> Iterator[tuple[int, list[tuple[float, float, float]]]]:
    """Steps ``agents`` on ``plant`` with fault-free one-tick links (every state reaches the neighbours
    on the next tick, as on the in-process engine without faults), for diagnostics and tests that look
    inside the agents. Yields (tick, wrenches) after the agents' step, before the plant applies the
    wrenches: the plant still holds that tick's truth then. Stop iterating to stop."""
    nbrs = scenario.neighbours()
    rng = sensor_rng(scenario.seed)
    inbox: list[list] = [[] for _ in agents]
    for k in range(scenario.ticks):
        meas = plant.measure(rng)
        nxt: list[list] = [[] for _ in agents]
        wr = []
        for i, a in enumerate(agents):
            res = a.step(k, meas[i][0], meas[i][1], inbox[i])
            for j in nbrs[i]:
                nxt[j].append(res.state)
            wr.append((res.wrench.fx, res.wrench.fy, res.wrench.tau))
        inbox = nxt
        yield k, wr
        plant.apply_and_step(wr)
