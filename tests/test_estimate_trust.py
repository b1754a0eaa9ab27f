"""Estimate trust (agents/estimate_trust.py, docs/estimate-trust.md): the stage test's false-alarm rate
is its level; a J stage whose neighbour states arrive too old (a ``stale_age`` window) leaves J flagged
untrusted in the estimates, summary.json and the report, a clean run flags nothing, and the daemons
reproduce the in-process engine's flags bit for bit (lockstep over Zenoh processes)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from agents.estimate_trust import EstimateTrust, poor, wilson_upper
from coload.analysis.report import make_report
from coload.runs.engine import run_inproc
from coload.runs.orchestrate import run_processes
from config.loader import load_scenario
from net.vocabulary import ESTIMATE_NAMES, J_AVERAGE, J_EXCITE, M_EXCITE
from tests.conftest import SCENARIOS, max_table_difference

# quick.toml with short stages: m stage from 14.9 s, J excitation 20.4-24.4 s, done at ~26 s (seed 7)
SHORT = ['dynamics.algorithm="sequential"', "dynamics.kin_settle_s=3", "dynamics.m_excite_s=4",
         "dynamics.j_excite_s=4", "duration=40", "stop_after_done_s=0.5"]
# every link's states arrive too old from 20.5 s to 24 s: the J excitation stage's
STALE_J = ["link.partitions=[{start=20.5, end=24.0, groups=[[0], [1], [2], [3]], drop=\"stale_age\"}]"]


def test_wilson_bound_false_alarm_rate_is_the_level():
    """Slots drawn at exactly min_fresh: the stage is called poor in about alpha of the draws."""
    rng = np.random.default_rng(3)
    for n, alpha in ((800, 0.01), (800, 0.05), (60, 0.05)):
        k = rng.binomial(n, 0.5, size=20_000)
        rate = np.mean([poor(int(x), n, 0.5, alpha) for x in k])
        # the bound is approximate (Wilson) and the binomial discrete: within 40 % of alpha
        assert 0.6 * alpha <= rate <= 1.4 * alpha, (n, alpha, rate)
    # far below: always poor; far above or no slots: never
    assert poor(100, 1000, 0.5, 0.01) and not poor(900, 1000, 0.5, 0.01) and not poor(0, 0, 0.5, 0.01)
    assert wilson_upper(0, 0, 0.01) == 1.0 and wilson_upper(10, 10, 0.01) == 1.0


def test_lost_and_reordered_states_count_while_newer_ones_keep_coming():
    """Slots are about the newest state held: a neighbour heard every few ticks stays fresh."""
    tr = EstimateTrust(degree=2, max_age=50, min_fresh=0.9, alpha=0.01)
    for k in range(1000):  # neighbour 0: 1 message in 5, 30 ticks late; neighbour 1: every tick, reordered
        taken = [(0, k - 30)] if k % 5 == 0 else []
        taken.append((1, k - 1 - (k % 3)))
        tr.observe(k, J_EXCITE, taken)
    out = tr.entries(50.0, 1.0, 87.0, 2.0)
    assert out["J_trusted"] == 1.0 and out["J_fresh"] > 0.98


def test_stage_evidence_flags_only_poor_stages():
    tr = EstimateTrust(degree=2, max_age=5, min_fresh=0.5, alpha=0.01)
    nan_flag = tr.entries(50.0, 1.0, math.nan, math.nan)
    assert math.isnan(nan_flag["m_trusted"]) and math.isnan(nan_flag["J_trusted"])
    for k in range(100):  # m stage: both neighbours' states fresh (1 tick old)
        tr.observe(k, M_EXCITE, [(0, k - 1), (1, k - 1)])
    for k in range(100, 300):  # J stage: neighbour 0's states 10 ticks old, in 3 of 4 ticks; none from 1
        tr.observe(k, J_EXCITE, [(0, k - 10)] if k % 4 else [])
    out = tr.entries(50.0, 1.0, 87.0, 2.0)
    assert out["m_trusted"] == 1.0 and out["m_fresh"] == 1.0 and out["m_sd"] == 1.0
    assert out["J_trusted"] == 0.0 and out["J_fresh"] < 0.05 and out["J_sd"] == 2.0  # the m stage's last states age out
    # the averaging stage on its own is fine, the estimate stays untrusted (its excitation was poor)
    for k in range(300, 400):
        tr.observe(k, J_AVERAGE, [(0, k - 1), (1, k - 2)])
    assert tr.entries(50.0, 1.0, 87.0, 2.0)["J_trusted"] == 0.0


def test_an_averaging_stage_is_judged_on_its_tail():
    """A gap in the averaging stage followed by fresh states over the tail: trusted; a gap at its end: not."""
    for gap_first, expect in ((True, 1.0), (False, 0.0)):
        tr = EstimateTrust(degree=2, max_age=5, min_fresh=0.5, alpha=0.01, tail=150)
        for k in range(100):
            tr.observe(k, J_EXCITE, [(0, k - 1), (1, k - 1)])
        for k in range(100, 500):
            gap = (k < 350) if gap_first else (k >= 245)  # the newest states age past 5 ticks at 250
            tr.observe(k, J_AVERAGE, [] if gap else [(0, k - 1), (1, k - 1)])
        out = tr.entries(50.0, 1.0, 87.0, 2.0)
        assert out["J_trusted"] == expect and out["J_fresh"] == expect, gap_first
        assert tr.stages[J_AVERAGE].slots == 300


def test_estimate_names_hold_the_trust_entries_in_order():
    names = tuple(EstimateTrust(1, 1, 0.5, 0.01).entries(1.0, 1.0, 1.0, 1.0))
    k = ESTIMATE_NAMES.index(names[0])
    assert ESTIMATE_NAMES[k:k + len(names)] == names


def _final(run_dir, name):
    from coload.rundir import format as fmt

    col = fmt.read_run(run_dir).estimates.columns[name]
    return col[-1]


@pytest.fixture(scope="module")
def stale_run(tmp_path_factory):
    """The in-process run with the stale J stage: (run directory, summary)."""
    d = tmp_path_factory.mktemp("stale") / "inproc"
    return d, run_inproc(load_scenario(SCENARIOS / "quick.toml", SHORT + STALE_J), d)


def test_stale_j_stage_flags_j_and_a_clean_run_flags_nothing(tmp_path, stale_run):
    clean = run_inproc(load_scenario(SCENARIOS / "quick.toml", SHORT), tmp_path / "clean")
    stale_dir, stale = stale_run
    assert clean["errors"]["finished_s"] is not None and stale["errors"]["finished_s"] is not None
    # clean: both trusted at every agent, no warning, nothing stale
    assert clean["trust"]["m"]["trusted"] and clean["trust"]["J"]["trusted"]
    assert clean["trust"]["J"]["fresh_min"] == 1.0 and not clean.get("warnings")
    assert sum(v["stale_age"] for v in clean["links"].values()) == 0
    # stale: 350 send ticks on each of the 8 directed links counted stale_age, none partitioned
    links = stale["links"]
    assert {v["stale_age"] for v in links.values()} == {350} and sum(v["partitioned"] for v in links.values()) == 0
    assert stale["trust"]["m"]["trusted"]
    j = stale["trust"]["J"]
    assert not j["trusted"] and j["untrusted_agents"] == [0, 1, 2, 3, 4]
    assert j["fresh_min"] < 0.3 and all(sd > 0 for sd in j["sd"])
    assert any("J untrusted" in w for w in stale["warnings"])
    assert list(_final(stale_dir, "J_trusted")) == [0.0] * 5
    assert list(_final(tmp_path / "clean", "J_trusted")) == [1.0] * 5
    _, table = make_report(stale_dir)
    assert "J: UNTRUSTED at agents [0, 1, 2, 3, 4]" in table and "m: trusted" in table
    summary = json.loads((stale_dir / "summary.json").read_text())
    assert summary["trust"] == stale["trust"]


@pytest.mark.slow
@pytest.mark.zenoh
def test_lockstep_over_zenoh_reproduces_the_stale_flags(tmp_path, stale_run):
    """Router, simulator and agents as processes, lockstep == the in-process engine, trust columns
    included (~25 s)."""
    a, sa = stale_run
    b = tmp_path / "zenoh"
    sb = run_processes(load_scenario(SCENARIOS / "quick.toml", SHORT + STALE_J), b, quiet=True)
    assert sb is not None and sb["engine"] == "zenoh"
    assert sb["timeouts"] == {"wrench": 0, "neighbour": 0}
    for name, keys in (("samples.csv", 2), ("estimates.csv", 2), ("truth.csv", 1)):
        assert max_table_difference(a, b, name, keys) <= 1e-9, name
    assert sa["links"] == sb["links"]
    assert sb["trust"] == sa["trust"] and not sb["trust"]["J"]["trusted"]
    assert sb["monitor"] == sa["monitor"] and sa["monitor"]["windows"] > 0  # detection on, bit for bit
    stale_events = [e for e in sb["events"] if e["event"].startswith("partition")]
    assert stale_events == sa["events"] and stale_events[0]["drop"] == "stale_age"
