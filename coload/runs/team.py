"""A fault-free team loop on one plant, for diagnostics and tests that look inside the agents."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from agents.team import TeamCore, empty_inbox, lockstep_inboxes
from config.scenario import Scenario
from simulator.plant import Plant, sensor_rng


def team_ticks(scenario: Scenario, plant: Plant, team: TeamCore, age: int = 1) -> Iterator[tuple[int, np.ndarray]]:
    """Steps ``team`` (agents.factory.build_team of the scenario's agents) on ``plant`` with fault-free
    links of ``age`` ticks (every state reaches the neighbours ``age`` ticks later; 1: as on the in-process engine
    without faults; the team's OUT ring needs more than ``age`` slots), for diagnostics and tests that look inside
    the agents (``team.agent(i)``). Yields (tick,
    wrenches (n, 3)) after the team's step, before the plant applies the wrenches: the plant still holds
    that tick's truth then. Stop iterating to stop."""
    nbrs = scenario.neighbours()
    n = len(nbrs)
    rng = sensor_rng(scenario.seed)
    inboxes = lockstep_inboxes(team, [[i for i in range(n) if r in nbrs[i]] for r in range(n)], age)
    for k in range(scenario.ticks):
        meas = plant.measure(rng).tolist()
        wr = team.step(k, meas, inboxes[k % team.ring] if k >= age else empty_inbox(team))
        yield k, wr
        plant.apply_and_step(wr)
