"""The periodic external force (``plant.periodic_force``, simulator/effects.py) against its closed form, its
validation, and the online detection's verdict on it (docs/online-detection.md): an effect outside the
vocabulary is ``unexplained`` and ends with nothing switched on (a candidate it contradicts is ruled out, a
switch it passed for is withdrawn)."""

from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np
import pytest

from coload.runs.engine import run_inproc
from config.loader import ScenarioError, load_scenario, scenario_from_dict
from simulator.plant import Plant
from tests.conftest import SCENARIOS

M, J, DT = 50.0, 86.89, 0.01


def make(plant: dict, dt: float = DT):
    return scenario_from_dict({
        "n": 4, "dt": dt,
        "load": {"width": 4.0, "height": 2.2, "mass": M, "inertia": J, "com_offset": [0.3, -0.2]},
        "contacts": {"start": 0.05},
        "noise": {"sigma_v": 0.0},
        "plant": plant,
    })  # fmt: skip


def test_force_of_each_tick_is_the_closed_form_and_moves_the_com_by_it():
    """F(k) = A sin(2 pi k dt / T) u acts over k -> k+1: v_C steps by F(k) dt / m, no torque."""
    amp, period, deg = 4.0, 0.37, 120.0
    p = Plant(make({"periodic_force": {"amplitude": amp, "period_s": period, "direction_deg": deg}}))
    u = np.array((math.cos(math.radians(deg)), math.sin(math.radians(deg))))
    for k in (0, 1, 9, 10, 37, 123):
        np.testing.assert_allclose(p.effects.periodic_force(k), amp * math.sin(2 * math.pi * k * DT / period) * u,
                                   rtol=1e-12, atol=1e-12)
    v_prev = np.zeros(2)
    for k in range(200):
        p.apply_and_step([(0.0, 0.0, 0.0)] * p.n)
        v = np.array(p.truth().vc)
        np.testing.assert_allclose(v - v_prev, amp * math.sin(2 * math.pi * k * DT / period) * u * DT / M,
                                   rtol=1e-6, atol=1e-15)
        v_prev = v
    assert p.truth().omega == 0.0  # the force acts at the CoM


def test_off_by_default():
    assert Plant(make({})).effects is None
    assert Plant(make({"periodic_force": {"amplitude": 1.0}})).effects is not None


@pytest.mark.parametrize("pf, match", [
    ({"amplitude": -1.0}, "plant.periodic_force.amplitude"),
    ({"amplitude": 1.0, "period_s": 0.0}, "plant.periodic_force.period_s"),
    ({"amplitude": 1.0, "period_s": 0.03}, "shorter than four ticks"),
    ({"amplitude": 1.0, "perod_s": 3.0}, "perod_s"),
])  # fmt: skip
def test_bad_periodic_force_is_a_clear_error(pf, match):
    with pytest.raises(ScenarioError, match=match):
        make({"periodic_force": pf})


# quick.toml (n = 5, sigma 0.1) with a short kinematic settle, m and J stages of 10 s, windows of 2.5 s
# (as tests/test_effect_decision.py), and a force of 6 N at the m stage's flip period (10 s) along its force.
SHORT = ['dynamics.algorithm="sequential"', "dynamics.kin_settle_s=3", "dynamics.m_excite_s=10",
         "dynamics.j_excite_s=10", "duration=30", "dynamics.monitor_window_s=2.5", "dynamics.online_detection=true"]
PERIODIC = ["plant.periodic_force={amplitude=6.0, period_s=10.0, direction_deg=28.6479}"]


@pytest.fixture(scope="module")
def periodic_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("periodic") / "inproc"
    return d, run_inproc(load_scenario(SCENARIOS / "quick.toml", SHORT + PERIODIC + ["seed=1"]), d)


def test_closed_loop_periodic_force_switches_nothing_on_and_leaves_a_window_unexplained(periodic_run):
    """An effect outside the vocabulary (~8 s): no candidate is switched on, and the window whose friction scores
    are significantly negative (seed 1: viscous z -4.6, Coulomb -4.9, the m stage's first) rules the most
    negative out, ``unexplained``: an event of the summary (tick, effect, statistic, every agent), as a switch
    is. The persistence test alone
    stays below its level here: the closed loop's innovations are negatively correlated (a clean plant's
    persistence z is negative too) and 1/m absorbs the force's fundamental."""
    _, summary = periodic_run
    eff = summary["effects"]
    assert eff["on"] == [] and eff["unexplained_windows"] >= 1
    assert {e["event"] for e in eff["events"]} == {"effect_ruled_out"}
    first = eff["events"][0]
    assert first["effect"] == "coulomb_friction" and first["agents"] == list(range(5))
    assert first["statistic"] < -NormalDist().inv_cdf(1 - 0.01 / 4)
    # the summary's run events carry it beside the partitions, with its time
    (ev,) = [e for e in summary["events"] if e["event"] == "effect_ruled_out" and e["tick"] == first["tick"]]
    assert ev["effect"] == "coulomb_friction" and ev["t"] == pytest.approx(first["tick"] * 0.01)


def test_a_ruled_out_candidate_is_a_marker_in_the_report(periodic_run):
    """The report draws the ruling-out as it draws a switch: a dashed black line on every panel at its time,
    labelled once on the top panel, and a line in the events table."""
    from coload.analysis import metrics, report
    from coload.rundir.format import read_run

    d, summary = periodic_run
    first = summary["effects"]["events"][0]
    run = read_run(d)
    fig = report.build_figure(run)
    try:
        panels = [ax for ax in fig.axes if ax.get_label() in report._DRAWERS]
        assert len(panels) >= 6
        for ax in panels:
            lines = [a for a in ax.get_children() if a.get_gid() == "effect_ruled_out"]
            assert [ln.get_xdata()[0] for ln in lines][:1] == pytest.approx([first["tick"] * run.dt])
            assert lines[0].get_color() == "black" and lines[0].get_linestyle() == "--"
        labels = [a.get_text() for a in panels[0].get_children() if a.get_gid() == "effect_ruled_out_label"]
        assert labels[0] == f"coulomb_friction ruled out, z {first['statistic']:.1f}"
    finally:
        report.plt.close(fig)
    table = report.summary_table(run, metrics.final_errors(run, report.WINDOW_S)).splitlines()
    assert any(line.split()[:3] == ["ruled_out", "coulomb_friction", str(first["tick"])] for line in table)


@pytest.mark.long  # ~1 min: out of CI's budget; quick's closed loop above runs there
def test_paper_fig4_geometry_periodic_force_ends_with_nothing_on_and_unexplained(tmp_path):
    """friction-online (n = 10, sigma 0.3) without friction, m stage 25 s: the bench's plant, shorter (~30 s).
    The force's part along v_C alternates the viscous score's sign with its period; a positive window can pass
    for viscous friction, but a negative one rules it out first (seed 1: the m stage's first window) or the
    released rate turns out significantly negative and the team withdraws it: nothing on at the end."""
    sc = load_scenario(SCENARIOS / "friction-online.toml", [
        "dynamics.estimate_effects=[]", "plant.friction={}", "dynamics.online_detection=true", *PERIODIC,
        "dynamics.m_excite_s=25", "dynamics.j_excite_s=5", "duration=62", "seed=1"])
    eff = run_inproc(sc, tmp_path / "run")["effects"]
    assert eff["on"] == [] and eff["agree"] and eff["unexplained_windows"] >= 1
    kinds = [(e["event"], e["effect"]) for e in eff["events"] if e["event"] != "effect_ruled_out"]
    assert kinds in ([], [("effect_switch", "viscous_friction"), ("effect_withdrawn", "viscous_friction")]), kinds
    # a withdrawal and a ruling-out are at the level's lower quantile
    assert all(e["statistic"] < -NormalDist().inv_cdf(1 - 0.01 / 4) for e in eff["events"]
               if e["event"] != "effect_switch")
