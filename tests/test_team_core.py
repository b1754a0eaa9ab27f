"""The team core: one team of n agents steps every agent as n teams of one fed the same inboxes do, to the last
bit of every output (message, wrench, estimate) at every tick; and the inboxes the engines build name the
messages a DelayLine releases, in its order."""

from __future__ import annotations

import numpy as np
import pytest

from agents.factory import build_agent, build_team
from agents.team import TeamCore, empty_inbox, handle_inbox, lockstep_inboxes
from coload.runs.engine import LinkNetwork
from config.loader import load_scenario
from config.scenario import Scenario
from net.link import DelayLine
from net.rows import SENDER, TICK
from net.vocabulary import BACKGROUND, J_EXCITE, M_EXCITE, SPINUP
from simulator.plant import Plant, sensor_rng
from tests.conftest import SCENARIOS

FAULTY = ["link.delay_ticks=2", "link.jitter_ticks=3", 'link.loss.model="bernoulli"', "link.loss.p=0.2",
          "link.duplicate=0.1"]
ONLINE = ["plant.friction.viscous=5", "dynamics.online_detection=true"]
# Algorithm 2 under the user's law (P3 from the background stage on) with the innovation monitor
LAW = ['dynamics.algorithm="background"', 'control.law="agents.laws:TrackVelocity"',
       "control.law_params={v_ref=[0.3, 0.0], omega_ref=0.0}", "dynamics.monitor_window_s=2"]


def _team_equals_teams_of_one(sc: Scenario) -> int:
    """Steps the scenario's agents as one team (B = n, its messages rows in its OUT ring, its inboxes from
    handles through the link models, as the in-process engine does with faults) and each as an AgentCore (a
    team of one behind the edge codec) fed the StateMsgs the link models deliver; asserts their outputs
    (wrench, message, estimate, stage) equal at every tick; returns the ticks stepped and the last stage reached."""
    n = sc.n
    plant = Plant(sc)
    rng = sensor_rng(sc.seed)
    net = LinkNetwork(sc, sc.mode)
    views = [sc.agent_view(i) for i in range(n)]
    team = build_team(views, ring=1 + net.reach)
    alone = [build_agent(v) for v in views]
    stages = set()
    sent: dict[int, list] = {}  # the agents' messages by tick (not a ring: independent of its slots)
    for k in range(sc.ticks):
        meas = plant.measure(rng).tolist()  # Python floats, as the engine gives the agents
        due = [pop(k) for pop in net.pops]
        wrenches = team.step(k, meas, handle_inbox(team, k, due))
        estimates = team.estimates()
        sent[k] = []
        for i in range(n):
            res = alone[i].step(k, *meas[i], [sent[t][s] for t, s in due[i]])
            assert repr([res.wrench.fx, res.wrench.fy, res.wrench.tau]) == repr(wrenches[i].tolist()), (k, i)
            assert repr(res.state) == repr(team.message(k, i)), (k, i)
            assert repr(res.estimate) == repr(estimates[i]), (k, i)
            assert alone[i].stage == team.stages[i]
            stages.add(team.stages[i])
            sent[k].append(res.state)
        sent.pop(k - team.ring, None)
        for i in range(n):
            net.send(i, k, (k, i))
        plant.apply_and_step(wrenches)
    return sc.ticks, max(stages)


@pytest.mark.slow
@pytest.mark.parametrize("sets, seconds, stage", [
    (FAULTY, 16, M_EXCITE),  # into the m stage (from 14 s) with held, reordered and duplicated states
    (ONLINE, 27, J_EXCITE),  # past the monitor's first windows and the team's detection decision (at 26 s)
    (LAW, 16, BACKGROUND),  # the law's wrench (P3) every tick of the background stage
], ids=["faulty-links", "online-detection", "background-law"])
def test_one_team_equals_teams_of_one(sets, seconds, stage):
    sc = load_scenario(SCENARIOS / "quick-dynamics.toml", [f"duration={seconds}", *sets])
    assert _team_equals_teams_of_one(sc) == (100 * seconds, stage)


def test_one_team_equals_teams_of_one_kinematic():
    sc = load_scenario(SCENARIOS / "quick.toml", ["duration=1.5", *FAULTY])
    assert _team_equals_teams_of_one(sc) == (150, SPINUP)


def _three(ring: int) -> TeamCore:
    sc = load_scenario(SCENARIOS / "quick.toml", ["n=3"])
    return build_team([sc.agent_view(i) for i in range(3)], ring)


def test_lockstep_inboxes_name_what_a_delay_line_releases():
    team = _three(ring=4)
    senders = [[1], [0, 2], [1]]
    fixed = lockstep_inboxes(team, senders, age=3)
    lines = [DelayLine() for _ in senders]
    for k in range(12):
        for s in (2, 0, 1):  # pushed out of order: the line sorts by sender
            for r, row in enumerate(senders):
                if s in row:
                    lines[r].push(k + 3, s, k, 0, (k, s))
        want = handle_inbox(team, k, [line.pop_due(k) for line in lines])
        got = fixed[k % team.ring] if k >= 3 else empty_inbox(team)
        assert got.ptr.tolist() == want.ptr.tolist()
        assert got.ref.tolist() == want.ref.tolist()


def test_inboxes_refuse_what_the_ring_cannot_hold():
    team = _three(ring=3)
    assert handle_inbox(team, 5, [[(3, 1)], [], [(4, 1), (4, 1)]]).ref.tolist() == [[0, 1, 0], [1, 1, 1], [1, 1, 1]]
    with pytest.raises(ValueError, match="beyond the OUT ring"):
        handle_inbox(team, 5, [[(2, 1)], [], []])
    with pytest.raises(ValueError, match="ring of more than 3"):
        lockstep_inboxes(team, [[1], [0, 2], [1]], age=3)
    with pytest.raises(ValueError):
        TeamCore([], ring=1)


def test_messages_land_after_every_agent_read_its_inbox():
    team = _three(ring=2)
    meas = [(0.1, 0.0), (0.0, 0.1), (-0.1, 0.0)]
    fixed = lockstep_inboxes(team, [[1], [0, 2], [1]], age=1)
    w0 = team.step(0, meas, empty_inbox(team))
    assert w0.shape == (3, 3) and w0.dtype == np.float64
    first = team.states(0).copy()
    assert first[:, TICK].tolist() == [0, 0, 0] and first[:, SENDER].tolist() == [0, 1, 2]
    team.step(1, meas, fixed[1])
    assert team.states(0).tobytes() == first.tobytes()  # tick 1 wrote the other slot
    assert team.states(1)[:, TICK].tolist() == [1, 1, 1]
    assert [e.tick for e in team.estimates()] == [1, 1, 1]
    assert [m.tick for m in (team.message(0, 1), team.message(1, 1))] == [0, 1]
    assert team.agent(1).id == 1 and team.agent(1).omega == team.kin["omega"][1]
