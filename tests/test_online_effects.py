"""Issue 4, online part: the agents' augmented model (DynamicsSpec.estimate_effects).

* The filter's augmented model is the plant's own discrete step: driven by the pymunk plant with viscous
  friction and rotational damping (tests/plant_drive.py, the real integrator), one agent's RigidEKF finds b
  and c, and m and J, where the nominal filter on the same data is far off.
* The whole team (in-process engine, Algorithm 1) on a plant with friction: the augmented agents' m and J
  errors are small and at most a third of the nominal agents', on the same plant and seed.
* Without estimate_effects nothing changes: the extra consensus channels never touch the nominal ones
  (property test on FlowAverage), and a run with the field empty equals one with it absent.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agents.consensus import FlowAverage
from agents.dynamic_phase import N_CH, N_CH_AUG
from agents.rigid_filter import RigidEKF
from coload.runs.engine import run_inproc
from config.agent_params import DynamicsSpec
from config.loader import ScenarioError, load_scenario
from tests.plant_drive import drive, push_and_spin

ROOT = Path(__file__).resolve().parents[1]
FRICTION = ROOT / "config" / "scenarios" / "friction-online.toml"
B_TRUE, C_TRUE = 5.0, 8.69  # friction-online.toml's plant
M_TRUE, J_TRUE = 50.0, 86.89


def _filter_on_plant(effects: tuple[str, ...], seconds: float = 40.0, sigma: float = 0.1):
    """One agent's filter (agent 0) on the real plant with friction, fed the exact total wrench and the
    true omega as its pooled-rate measurement (variance of the pooled eq. (9) for n = 10, sigma)."""
    rec = drive(
        seconds, push_and_spin(10, force=3.0, switch_s=5.0, k_omega=10.0, dither=20.0, dither_s=6.0),
        overrides=[f"plant.friction.viscous={B_TRUE}", f"plant.friction.rotational={C_TRUE}"], sigma=sigma, seed=3,
    )
    rng = np.random.default_rng(11)
    spec = DynamicsSpec(algorithm="sequential", estimate_effects=effects)
    kf = RigidEKF(sigma, spec, background=False)
    q0 = complex(*(rec.zi[0, 0] + rec.zc[0]))
    kf.start(complex(*rec.vci[0, 0]), q0, float(rec.omega[0]))
    kf.release_effects()
    u_var = 2 * sigma**2 / 20.0
    for k in range(len(rec.t)):
        u = rec.omega[k] + rng.normal(0.0, math.sqrt(u_var))
        kf.update(complex(*rec.vci[k, 0]), float(u), u_var)
        q = rec.zi[k] + rec.zc[k]  # p_Ci - p_C
        f = rec.forces[k]
        force = complex(*f.sum(axis=0))
        torque = float(np.sum(q[:, 0] * f[:, 1] - q[:, 1] * f[:, 0]) + rec.taus[k].sum())
        kf.predict(force, torque, rec.dt)
    return kf


def test_augmented_filter_matches_the_plant_step():
    kf = _filter_on_plant(("viscous_friction", "rotational_damping"))
    m, J = 1.0 / kf.mu, 1.0 / kf.iota
    b, c = kf.beta * m, kf.gamma * J
    # measured on this recording: m, J -0.3 %, b -2.0 %, c +1.9 % (the filter's own std: 0.6, 4.6, 10, 17 %,
    # pessimistic through the release priors and the effect walk); bounds 2.5-7x the measured errors
    assert abs(m / M_TRUE - 1) < 0.01
    assert abs(J / J_TRUE - 1) < 0.02
    assert abs(b / B_TRUE - 1) < 0.05
    assert abs(c / C_TRUE - 1) < 0.05
    nominal = RigidEKF(0.1, DynamicsSpec(algorithm="sequential"), background=False)
    assert nominal.s.shape == (8,)  # no effect states without estimate_effects (7 + the rate's error b)


def test_nominal_filter_is_biased_on_the_same_data():
    kf = _filter_on_plant(())
    assert abs(1.0 / kf.mu / M_TRUE - 1) > 0.05 or not kf.mu > 0
    assert abs(1.0 / kf.iota / J_TRUE - 1) > 0.05 or not kf.iota > 0


def test_one_effect_leaves_the_other_state_pinned_at_zero():
    kf = _filter_on_plant(("viscous_friction",), seconds=10.0)
    assert kf.s[8] == 0.0 and kf.P[8, 8] == 0.0
    assert kf.beta > 0.0


def test_unknown_effect_is_a_clear_config_error():
    with pytest.raises(ScenarioError, match="estimate_effects"):
        load_scenario(FRICTION, ["dynamics.estimate_effects=['coulomb']"])


@settings(max_examples=30, deadline=None)
@given(
    st.lists(st.lists(st.floats(-10, 10), min_size=N_CH_AUG, max_size=N_CH_AUG), min_size=3, max_size=3),
    st.lists(st.booleans(), min_size=40, max_size=40),
)
def test_extra_channels_never_touch_the_nominal_ones(inputs, losses):
    """Three agents on a line; the same exchanges (with losses) in an 11-channel and a 13-channel average:
    channels 0..10 stay bit-identical (every update is per channel)."""
    ids = [[1], [0, 2], [1]]
    small = [FlowAverage(nb, N_CH) for nb in ids]
    big = [FlowAverage(nb, N_CH_AUG) for nb in ids]
    for i in range(3):
        small[i].u[:] = inputs[i][:N_CH]
        big[i].u[:] = inputs[i]
    for lost in losses:
        for net in (small, big):
            sent = [(list(a.x), {j: list(f) for j, f in a.flow.items()}) for a in net]
            for i, a in enumerate(net):
                for j in ids[i]:
                    if not (lost and i == 1):
                        a.receive(j, sent[j][0], sent[j][1][i], len(ids[j]))
                a.update()
        for a, b in zip(small, big):
            assert a.x == b.x[:N_CH]


def test_augmented_state_message_passes_the_wire_schema():
    """With the augmented model a state message's per-neighbour value has 4 + 13 floats: the codec the
    daemons use over Zenoh must carry it unchanged (not drop it as malformed)."""
    from agents.factory import build_agent
    from net.messages import StateMsg
    from net.schema import decode, encode

    sc = load_scenario(FRICTION)
    agent = build_agent(sc.agent_view(1))
    res = None
    for k in range(3):
        res = agent.step(k, 0.1, -0.2, [])
    msg = res.state
    assert {len(v) for v in msg.pair.values()} == {4 + N_CH_AUG}
    assert decode(encode(msg), StateMsg) == msg


# ---------------------------------------------------------------------------------------------------------
# The whole team: a reduced friction-online (5 agents, sigma 0.1, shorter stages), one seed, before/after.
REDUCED = ["n=5", "contacts.start=0.1", "noise.sigma_v=0.1", "dynamics.kin_settle_s=5", "dynamics.m_excite_s=15",
           "dynamics.j_excite_s=25", "duration=70", "seed=2"]


def _errors(tmp_path: Path, extra: list[str]) -> dict:
    sc = load_scenario(FRICTION, [*REDUCED, *extra])
    return run_inproc(sc, tmp_path / "-".join(extra or ["aug"]).replace("=", "").replace(".", ""))["errors"]


def test_team_with_augmented_model_beats_the_nominal_one(tmp_path):
    before = _errors(tmp_path, ["dynamics.estimate_effects=[]"])
    after = _errors(tmp_path, [])
    assert after["finished_s"] is not None
    # the nominal model is badly off on this plant (the regulation torque against the damping looks like
    # a torque that does not accelerate the load; the friction force like extra mass)
    assert before["m_rel"] > 0.05 and before["J_rel"] > 0.3
    # issue 4: after at most a third of before, or below 1 %; and an absolute bound. Measured (seed 2):
    # before m 12.0 %, J 323 %; after m 0.11 %, J 0.49 %, b 0.64 %, c 0.79 % (friction-online over 5
    # seeds: m <= 0.24 %, J <= 0.29 %, docs/diagnose.md); 3 % leaves room for a seed or a filter change
    for key in ("m_rel", "J_rel"):
        assert after[key] <= before[key] / 3 or after[key] < 0.01, (key, after[key], before[key])
        assert after[key] < 0.03, (key, after[key])
    assert after["b_rel"] < 0.1 and after["c_rel"] < 0.1, (after["b_rel"], after["c_rel"])
    assert "b_rel" not in before  # the nominal agents report no b, c


def test_empty_estimate_effects_is_the_nominal_run(tmp_path):
    """A short run (through the m stage) with the field empty equals the run without the field, and
    reports no b, c."""
    short = ["duration=30", "plant.friction.viscous=5.0", "dynamics.algorithm=sequential"]
    absent = load_scenario(ROOT / "config" / "scenarios" / "quick.toml", short)
    empty = load_scenario(ROOT / "config" / "scenarios" / "quick.toml", [*short, "dynamics.estimate_effects=[]"])
    assert "estimate_effects" not in (ROOT / "config" / "scenarios" / "quick.toml").read_text()
    run_inproc(absent, tmp_path / "absent")
    run_inproc(empty, tmp_path / "empty")
    a = (tmp_path / "absent" / "estimates.csv").read_bytes()
    e = (tmp_path / "empty" / "estimates.csv").read_bytes()
    assert a == e
    header = a.split(b"\n", 1)[0].decode().split(",")
    rows = [line.split(",") for line in a.decode().splitlines()[1:]]
    phases = {float(r[header.index("phase")]) for r in rows}
    assert max(phases) >= 2  # the dynamical phase ran
    for col in ("b", "c", "b_local", "c_local"):
        vals = {r[header.index(col)] for r in rows}
        assert vals <= {"", "nan"}, (col, vals)
