"""The constant external force (force_bias, a slope) online, closed loop (docs/online-detection.md): the team
names it, and only it; the state message with the slope's channels passes the wire schema."""

from __future__ import annotations

import numpy as np

from agents.effect_decision import EFFECTS
from coload.rundir import format as fmt
from coload.runs.engine import run_inproc
from config.loader import load_scenario
from tests.conftest import SCENARIOS

# quick.toml (n = 5, sigma 0.1) with a short kinematic settle, m and J stages of 10 s, windows of 2.5 s
SHORT = ['dynamics.algorithm="sequential"', "dynamics.kin_settle_s=3", "dynamics.m_excite_s=10",
         "dynamics.j_excite_s=10", "duration=30", "dynamics.monitor_window_s=2.5", "dynamics.online_detection=true"]


def test_closed_loop_names_the_slope_and_only_it(tmp_path):
    """An undeclared constant 5 N force along (0.6, 0.8): every agent switches force_bias on, on one tick,
    nothing else; the averaged f within 15 % of the force. The m stage is 20 s: the switch comes 6 s into it,
    and a switch restarts 1/m (with quick's 10 s stage it comes 4 s before the stage's end and m is far off)."""
    sc = load_scenario(SCENARIOS / "quick.toml", SHORT + ["plant.external_force=[3.0, 4.0]", "seed=1",
                                                          "dynamics.online_force_bias=true",
                                                          "dynamics.m_excite_s=20", "duration=40"])
    s = run_inproc(sc, tmp_path / "run")
    eff = s["effects"]
    assert eff["on"] == ["force_bias"] and eff["agree"], eff
    assert [e["effect"] for e in eff["events"] if e["event"] == "effect_switch"] == ["force_bias"]
    c = fmt.read_run(tmp_path / "run").estimates.columns
    assert np.all(c["eff_on"][-1] == float(1 << EFFECTS.index("force_bias")))
    f = np.stack([c["fb_x"][-1], c["fb_y"][-1]], axis=1)
    assert np.all(np.hypot(f[:, 0] - 3.0, f[:, 1] - 4.0) < 0.15 * 5.0), f


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
