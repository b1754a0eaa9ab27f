"""Builds an agent from a scenario, the same way for every engine.

The in-process engine and the daemons both call this (and ``net.link.build_in_links`` for the
links), so a lockstep run over Zenoh and an in-process run with the same seed start identical.
"""

from __future__ import annotations

from agents.agent import AgentCore
from config.scenario import Scenario


def build_agent(scenario: Scenario, agent_id: int) -> AgentCore:
    sigma = scenario.estimator.sigma_v
    return AgentCore(
        agent_id=agent_id,
        neighbours=scenario.neighbours()[agent_id],
        n=scenario.n,
        dt=scenario.dt,
        sigma_v=scenario.noise.sigma_v if sigma is None else sigma,
        estimator=scenario.estimator,
        control=scenario.control,
        dynamics=scenario.dynamics,
    )
