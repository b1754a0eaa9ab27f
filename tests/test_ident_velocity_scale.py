"""One agent's velocity logged at a wrong scale (ident/vscale.py, docs/diagnose.md "Input"): the rigid body's
kinematics show it before any force is looked at, where an actuator's gain leaves them rigid. The recordings
come from bench/foreign_recordings.py's plant (no code shared with ident/)."""

from __future__ import annotations

import pytest

from ident.diagnose import diagnose_dir
from tests.foreign_plant import plant


def test_one_agents_velocity_scale_is_named_and_corrected_not_read_as_its_actuator(tmp_path):
    """Agent 1 logs 0.9 x its velocity, nothing else (12 s): the probe's generator (with viscous friction) had it
    named an actuator gain of 1.079 with a random force and m +5.6 % outside its interval; now velocity_scale
    names agent 1 alone at 0.895 +- 0.005 (the per-stamp motion fitted with the scales leaves them ~0.5 % low),
    its velocities are corrected, nothing else is named and m, J are the plant's within 1 % and 2 %."""
    truth = plant.record(tmp_path, n=4, dur=12.0, vscale=(1, 0.9))
    d = diagnose_dir(tmp_path)
    assert [e["name"] for e in d.effects] == ["velocity_scale"], d.effects
    sc = d.effects[0]
    assert sc["agents"] == [1] and abs(sc["value"][1] - 0.9) < 0.01
    assert abs(d.augmented.m / truth["m"] - 1) < 0.01 and abs(d.augmented.J / truth["J"] - 1) < 0.02


@pytest.mark.long
def test_an_actuator_gain_is_not_a_velocity_scale(tmp_path):
    """One actuator at 0.8 (the bench's one_actuator_80pct, 12 s): the kinematics stay rigid, no velocity
    scale; the actuator's gain is named."""
    plant.record(tmp_path, n=4, dur=12.0, b=8.0, gain=(2, 0.8))
    d = diagnose_dir(tmp_path)
    assert "velocity_scale" not in {e["name"] for e in d.effects}
    assert "agent_actuator_gain" in {e["name"] for e in d.effects}
