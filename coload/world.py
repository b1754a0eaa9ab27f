"""Builds the pieces of a run from a scenario, the same way for every engine.

The in-process engine and the daemons both call these, so a lockstep run over Zenoh and an
in-process run with the same seed start from identical agents and identical link models.
"""

from __future__ import annotations

from agents.agent import AgentCore
from config.scenario import Scenario
from net.link import LinkModel


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
    )


def build_in_links(scenario: Scenario, receiver: int, mode: str | None = None) -> dict[int, LinkModel]:
    """The fault models of every link that ends at ``receiver``, keyed by sender."""
    mode = mode or scenario.mode
    return {
        sender: LinkModel(scenario.link, scenario.seed, sender, receiver, mode)
        for sender in scenario.neighbours()[receiver]
    }
