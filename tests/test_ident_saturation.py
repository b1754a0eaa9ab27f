"""Logged forces at a limit (ident/saturation.py): an extreme value that recurs in many separate runs is
flagged; a held or smooth wrench is not. Recordings from bench/foreign_recordings.py's plant."""

from __future__ import annotations

import numpy as np

from ident.diagnose import diagnose_dir, read_recording
from ident.recording import recording_from_arrays
from ident.saturation import at_limit, saturated, saturation_warning, without_limits
from tests.foreign_plant import plant


def test_a_clipped_force_log_is_flagged_per_agent_and_axis(tmp_path):
    """Every agent's logged fx, fy clipped at +-10 N (the plant gets the true force; 7-18 % of each agent's
    rows): every agent and axis is named with the value and its share; before, nothing said so (the probe's
    clip6: `unexplained`, no hint)."""
    plant.record(tmp_path, n=4, dur=10.0, fclip=10.0)
    found = saturated(read_recording(tmp_path))
    assert {(d["agent"], d["axis"]) for d in found} == {(i, a) for i in range(4) for a in ("fx", "fy")}
    assert all(abs(d["value"]) == 10.0 and d["share"] > 0.01 for d in found)
    assert saturation_warning(found).startswith("saturated forces: agent ")


def test_held_and_smooth_wrenches_are_not_flagged(tmp_path):
    """A controller at 25 Hz logged at 100 Hz repeats each value 4 rows in a row, the extremes included: one
    run each, not a limit; nor is a smooth wrench's."""
    for k, kw in enumerate(({"hold_hz": 25.0}, {}, {"hold_hz": 20.0, "rate": 20.0})):
        plant.record(tmp_path / str(k), n=4, dur=10.0, **kw)
        assert saturated(read_recording(tmp_path / str(k))) == []


def test_a_switching_force_of_two_levels_is_not_a_limit():
    """coload's own control law pushes at +-a (every row at one of the two extremes): no continuum to clip.
    Before this rule tests/test_diagnose.py's recordings read '100 % of its rows' saturated."""
    t = np.arange(0, 10, 0.01)
    w = np.zeros((t.size, 2, 3))
    w[:, :, 0] = np.where(np.sin(1.3 * t) > 0, 2.6, -2.6)[:, None]
    w[:, :, 1] = np.where(np.sin(0.7 * t + 1) > 0, 1.4, -1.4)[:, None]
    rec = recording_from_arrays(t, w, vel=np.zeros((t.size, 2, 2)))
    assert saturated(rec) == []


def test_one_clipped_sensor_s_stamps_are_left_out_of_the_fit(tmp_path):
    """Agent 0's force sensor clipped at +-10 N (the plant gets the true force; 38 % of the stamps), viscous 8:
    those stamps are left out as a missing wrench's are, and the fit names the viscous friction within its
    interval and nothing else, m and J within theirs. Before, the clipped rows were fitted (the seventh
    probe's clipped_light: an actuator gain on the clipped agent 1.124 +- 0.056 and a random force named,
    neither there)."""
    truth = plant.record(tmp_path, n=4, dur=10.0, b=8.0, fclip=10.0, fclip_agents=(0,))
    d = diagnose_dir(tmp_path)
    assert {x["agent"] for x in d.saturation} == {0}
    assert "the fit leaves those " in d.warnings[0]
    assert [e["name"] for e in d.effects] == ["viscous_friction"] and d.random_force is None
    assert abs(d.effects[0]["value"] - 8.0) < d.effects[0]["ci95"]
    mj = d.fits["augmented"].mj()
    for k in ("m", "J"):
        assert abs(mj[k] - truth[k]) < mj[f"{k}_ci95"], (k, mj[k], mj[f"{k}_ci95"], truth[k])


def test_a_limit_hit_at_most_stamps_keeps_the_rows(tmp_path):
    """Every agent clipped at +-10 N (89 % of the stamps at a limit): cutting would leave fragments of a few
    samples, so the rows stay and the warning says why."""
    plant.record(tmp_path, n=4, dur=20.0, b=8.0, fclip=10.0)
    rec = read_recording(tmp_path)
    found = saturated(rec)
    assert without_limits(rec, at_limit(rec, found)) == (rec, 0)
    assert "the rows are kept: a limit is hit at 89 % of the stamps" in saturation_warning(found, 0, 0.887)
