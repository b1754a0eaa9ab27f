"""One agent's logger or actuator off the others' (docs/diagnose.md, "Measured: recordings as other loggers
write them"): an actuator delivering 80 % of the force it logs, a logger's clock 50 ms late, forces logged in
each robot's own frame. The recordings come from bench/foreign_recordings.py's plant (scipy, no code shared
with ident/), loaded by its path.
"""

from __future__ import annotations

import numpy as np

from ident.diagnose import diagnose_dir
from tests.foreign_plant import plant


def _named(d) -> dict:
    return {e["name"]: e for e in d.effects}


def _only(tmp_path, effect: str, dur: float = 10.0, **shape) -> tuple[dict, object, dict]:
    """(truth, diagnosis, the effect's entry) of a ``dur`` s, four-agent recording of the plant with
    ``shape``; the effect named alone, the residual explained."""
    truth = plant.record(tmp_path, n=4, dur=dur, **shape)
    d = diagnose_dir(tmp_path)
    named = _named(d)
    assert set(named) == {effect} and not d.unexplained, named
    return truth, d, named[effect]


def _mj_within(d, truth) -> None:
    """m within 1 %, J within twice its 95 % half-width (10 s of a slowly turning load: J is wide)."""
    a = d.augmented
    assert abs(a.m / truth["m"] - 1) < 0.01, (a.m, truth["m"])
    assert abs(a.J - truth["J"]) < 2 * a.J_ci95 and a.J_ci95 < 0.15 * truth["J"], (a.J, a.J_ci95, truth["J"])


def test_one_actuator_delivering_80_percent_is_named_with_its_agent(tmp_path):
    truth, d, e = _only(tmp_path, "agent_actuator_gain", gain=(1, 0.8))
    assert e["agents"] == [1] and e["reference"] != 1
    # within 3 of its 95 % half-widths (0.007 here), and that half-width small against the fault
    assert abs(e["value"][1] - 0.8) < 3 * e["ci95"][1] and e["ci95"][1] < 0.02
    assert d.nominal.m / truth["m"] - 1 > 0.05  # before: the nominal model reads the missing force as mass
    _mj_within(d, truth)


def test_one_logger_clock_50ms_late_is_named_with_its_agent(tmp_path):
    truth, d, e = _only(tmp_path, "agent_clock_offset", clock=(2, 0.05))
    assert e["agents"] == [2]
    assert abs(e["value"][2] - 0.05) < max(3 * e["ci95"][2], 0.002)
    # the kinematic floor counts the offset as noise; re-read with the velocities re-timed it is the sensor's
    assert abs(d.noise_floor["velocity_retimed"] / 0.01 - 1) < 0.1, d.noise_floor
    _mj_within(d, truth)


def test_forces_logged_in_each_robots_frame_are_turned_to_the_world(tmp_path):
    truth, d, e = _only(tmp_path, "robot_frame_forces", dur=8.0, robot_frame=True)
    assert d.frames["robot_frame"]
    # the mounting angles (body frame at the first stamp) differ as the robots' do: within each one's 95 %
    # half-width (or a degree)
    got, ci, true = (np.asarray(v, float) for v in (e["value"], e["ci95"], truth["mounting_deg"]))
    diff = np.angle(np.exp(1j * np.radians((got - got[0]) - (true - true[0]))), deg=True)
    assert np.all(np.abs(diff) < np.maximum(ci + ci[0], 1.0)), (diff, ci)
    _mj_within(d, truth)
