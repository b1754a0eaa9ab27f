"""The constant external force (force_bias, a slope) online, closed loop (docs/online-detection.md): the team
names it, and only it; the state message with the slope's channels passes the wire schema."""

from __future__ import annotations

import numpy as np
import pytest

from agents.effect_decision import EFFECTS
from coload.rundir import format as fmt
from coload.runs.engine import run_inproc
from config.loader import load_scenario
from tests.conftest import SCENARIOS, max_table_difference

# quick.toml (n = 5, sigma 0.1) with a short kinematic settle, m and J stages of 10 s, windows of 2.5 s
SHORT = ['dynamics.algorithm="sequential"', "dynamics.kin_settle_s=3", "dynamics.m_excite_s=10",
         "dynamics.j_excite_s=10", "duration=30", "dynamics.monitor_window_s=2.5", "dynamics.online_detection=true"]


SLOPE_RUN = SHORT + ["plant.external_force=[3.0, 4.0]", "seed=1", "dynamics.online_force_bias=true",
                     "dynamics.m_excite_s=20", "duration=40"]


@pytest.fixture(scope="module")
def slope_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("slope") / "inproc"
    return d, run_inproc(load_scenario(SCENARIOS / "quick.toml", SLOPE_RUN), d)


def test_closed_loop_names_the_slope_and_only_it(slope_run):
    """An undeclared constant 5 N force along (0.6, 0.8): every agent switches force_bias on, on one tick,
    nothing else; the averaged f within 15 % of the force, and m within 1 % (0.34 % measured): each agent's
    filter is replaced at the switch by its twin, which has carried the slope from the m stage's start. The
    m stage is 20 s: the switch comes 6 s into it (with quick's 10 s stage it comes after m is averaged)."""
    d, s = slope_run
    eff = s["effects"]
    assert eff["on"] == ["force_bias"] and eff["agree"], eff
    assert [e["effect"] for e in eff["events"] if e["event"] == "effect_switch"] == ["force_bias"]
    c = fmt.read_run(d).estimates.columns
    assert np.all(c["eff_on"][-1] == float(1 << EFFECTS.index("force_bias")))
    f = np.stack([c["fb_x"][-1], c["fb_y"][-1]], axis=1)
    assert np.all(np.hypot(f[:, 0] - 3.0, f[:, 1] - 4.0) < 0.15 * 5.0), f
    assert abs(s["errors"]["m_rel"]) < 0.01, s["errors"]["m_rel"]


@pytest.mark.slow
@pytest.mark.zenoh
def test_lockstep_over_zenoh_reproduces_the_slope_and_its_twin(tmp_path, slope_run):
    """Router, simulator and agents as processes, lockstep == the in-process engine: the same switch, and the
    twin filters handed over at it give the same estimates to rounding (~40 s)."""
    from coload.runs.orchestrate import run_processes

    a, sa = slope_run
    b = tmp_path / "zenoh"
    sb = run_processes(load_scenario(SCENARIOS / "quick.toml", SLOPE_RUN), b, quiet=True)
    assert sb is not None and sb["engine"] == "zenoh"
    for name, keys in (("samples.csv", 2), ("estimates.csv", 2), ("truth.csv", 1)):
        assert max_table_difference(a, b, name, keys) <= 1e-9, name
    assert sb["effects"] == sa["effects"] and sa["effects"]["on"] == ["force_bias"]


def test_force_bias_is_a_declarable_effect(tmp_path):
    """``dynamics.estimate_effects = ["force_bias"]`` (the offline loop's re-run names it so) loads, and the
    filter carries the slope's rates free from the m stage on."""
    sc = load_scenario(SCENARIOS / "friction-online.toml", ['dynamics.estimate_effects=["force_bias"]'])
    assert sc.dynamics.estimate_effects == ("force_bias",)
    from agents.rigid_filter import RigidEKF

    kf = RigidEKF(0.3, sc.dynamics, False)
    kf.start(0j, 1 + 0j, 0.0)
    kf.release_effects()
    assert kf.P[10, 10] > 0.0 and kf.P[11, 11] > 0.0 and kf.P[7, 7] == 0.0
