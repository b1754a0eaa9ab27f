"""The report's marks of the online detection (coload/analysis/report.py, docs/online-detection.md): a
vertical line at each effect event on every panel, labelled once, a table line per event, the windows
judged ``unexplained``; nothing of it for a run without detection."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from coload.analysis import metrics, report
from coload.rundir.format import SUMMARY_JSON, read_run
from coload.runs.engine import run_inproc
from config.loader import load_scenario
from tests.conftest import SCENARIOS
from tests.synthetic_run import SyntheticSpec, write_run

# quick.toml (n = 5) with stages of 10 s and windows of 2.5 s: undeclared viscous friction is switched on
# in the m stage (tests/test_effect_decision.py's closed loop; ~6 s)
SHORT = ['dynamics.algorithm="sequential"', "dynamics.kin_settle_s=3", "dynamics.m_excite_s=10",
         "dynamics.j_excite_s=10", "duration=30", "dynamics.monitor_window_s=2.5", "dynamics.online_detection=true",
         "plant.friction={viscous=5.0}", "seed=1"]


@pytest.fixture(scope="module")
def switched(tmp_path_factory):
    d = tmp_path_factory.mktemp("report_effects") / "run"
    s = run_inproc(load_scenario(SCENARIOS / "quick.toml", SHORT), d)
    (ev,) = [e for e in s["events"] if e["event"] == "effect_switch"]
    return d, ev


def _panels(fig):
    return [ax for ax in fig.axes if ax.get_label() in report._DRAWERS]


def _marks(ax, gid):
    return [a for a in ax.get_children() if a.get_gid() == gid]


def _figure(run):
    fig = report.build_figure(run)
    return fig, _panels(fig)


def test_a_switch_is_a_line_on_every_panel_at_its_time_labelled_once(switched):
    d, ev = switched
    run = read_run(d)
    fig, panels = _figure(run)
    try:
        assert len(panels) >= 6
        for ax in panels:
            (line,) = _marks(ax, "effect_switch")
            assert np.allclose(line.get_xdata(), ev["tick"] * run.dt), ax.get_label()
            assert line.get_color() == "magenta" and line.get_linestyle() == "-"
        (label,) = _marks(panels[0], "effect_switch_label")
        assert label.get_text() == f"viscous_friction on, z {ev['statistic']:.1f}"
        assert label.xy[0] == pytest.approx(ev["tick"] * run.dt)
        assert all(not _marks(ax, "effect_switch_label") for ax in panels[1:])
        assert all(not _marks(ax, "effect_unexplained") for ax in panels)  # none on this plant
    finally:
        report.plt.close(fig)


def test_the_table_has_a_line_per_switch(switched):
    d, ev = switched
    run = read_run(d)
    table = report.summary_table(run, metrics.final_errors(run, report.WINDOW_S)).splitlines()
    assert "online detection: 1 effect event(s), 0 window(s) unexplained" in table
    rows = [line.split() for line in table if line.split()[:1] == ["switch"]]
    assert rows == [["switch", "viscous_friction", str(ev["tick"]), f"{ev['tick'] * run.dt:.2f}",
                     f"{ev['statistic']:.2f}", "all", "5"]]


def test_a_withdrawal_and_unexplained_windows_are_marked_apart(switched, tmp_path):
    """Any ``effect_*`` event is drawn (a withdrawal dotted black, a switch solid magenta), and each growth of the team's
    ``eff_unexplained`` count is a triangle on the top panel's edge at that time."""
    d, ev = switched
    copy = tmp_path / "run"
    shutil.copytree(d, copy)
    summary = json.loads((copy / SUMMARY_JSON).read_text())
    back = {"tick": ev["tick"] + 150, "t": (ev["tick"] + 150) * 0.01, "event": "effect_withdrawn",
            "effect": "viscous_friction", "statistic": -1.25, "agents": [0, 2]}
    summary["events"].append(back)
    (copy / SUMMARY_JSON).write_text(json.dumps(summary))
    run = read_run(copy)
    col = run.estimates.columns["eff_unexplained"]
    t = run.estimates.t
    col[:] = 0.0
    col[t >= 12.0, 1] = 1.0  # agent 1 counts one window at 12 s, agent 3 another at 17 s
    col[t >= 17.0, 3] = 2.0
    fig, panels = _figure(run)
    try:
        for ax in panels:
            assert [m.get_xdata()[0] for m in _marks(ax, "effect_switch")] == pytest.approx([ev["tick"] * run.dt])
            (line,) = _marks(ax, "effect_withdrawn")
            assert line.get_xdata()[0] == pytest.approx(back["t"])
            assert line.get_color() == "black" and line.get_linestyle() == ":"
        (label,) = _marks(panels[0], "effect_withdrawn_label")
        assert label.get_text() == "viscous_friction withdrawn, z -1.2"
        (tri,) = _marks(panels[0], "effect_unexplained")
        assert list(tri.get_xdata()) == pytest.approx([t[t >= 12.0][0], t[t >= 17.0][0]])
    finally:
        report.plt.close(fig)
    table = report.summary_table(run, metrics.final_errors(run, report.WINDOW_S)).splitlines()
    assert [line.split()[0] for line in table if line.split()[:1] in (["switch"], ["withdrawn"])] == [
        "switch", "withdrawn"]
    assert any(line.split()[:6] == ["withdrawn", "viscous_friction", str(back["tick"]), f"{back['t']:.2f}",
                                    "-1.25", "0,2"] for line in table)
    assert any(line.startswith("online detection: 2 effect event(s), 2 window(s) unexplained") for line in table)


def test_without_the_summary_block_the_switches_come_from_the_estimates(switched, tmp_path):
    d, ev = switched
    copy = tmp_path / "run"
    shutil.copytree(d, copy)
    (copy / SUMMARY_JSON).unlink()
    assert report.effect_events(read_run(copy)) == [
        {"kind": "switch", "t": pytest.approx(ev["t"]), "tick": ev["tick"], "effect": ev["effect"],
         "statistic": pytest.approx(ev["statistic"]), "agents": ev["agents"]}]


def test_a_run_without_detection_has_no_effect_marks(tmp_path):
    write_run(tmp_path, SyntheticSpec(n=3, duration=20.0, dt=0.05))
    run = read_run(tmp_path)
    fig, panels = _figure(run)
    try:
        assert panels and not [a for ax in fig.axes for a in ax.get_children()
                               if str(a.get_gid()).startswith("effect_")]
    finally:
        report.plt.close(fig)
    assert "online detection" not in report.summary_table(run, metrics.final_errors(run, report.WINDOW_S))
