"""The engines agree: the daemons (over the in-memory transport) reproduce the in-process engine.

Both feed every agent the same inbox per tick, so estimates must match to the last bit, with and
without link faults.
"""

from __future__ import annotations

import asyncio
import json

import pytest

from coload.runs.engine import run_inproc
from coload.runs.orchestrate import run_daemons_in_memory
from config.loader import load_scenario
from tests.conftest import SCENARIOS, max_table_difference

FAULTS = [
    [],
    ["link.delay_ticks=2", "link.jitter_ticks=3", 'link.loss.model="bernoulli"', "link.loss.p=0.2",
     "link.duplicate=0.1"],
    ['link.loss.model="gilbert_elliott"', "link.loss.p_good_to_bad=0.05", "link.loss.p_bad_to_good=0.3"],
    # a partition that splits the line in two (edge 1-2 cut) and heals, one that cuts an edge, with loss
    ["link.partitions=[{start=0.5, end=1.5, groups=[[0, 1]]}, {start=1.0, end=2.2, cut=[[3, 4]]}]",
     'link.loss.model="bernoulli"', "link.loss.p=0.1", "link.jitter_ticks=1"],
]


@pytest.mark.parametrize("faults", FAULTS, ids=["clean", "delay-loss-dup", "bursty", "partition"])
def test_memory_daemons_reproduce_inproc(tmp_path, faults):
    sc = load_scenario(SCENARIOS / "quick.toml", ["duration=3.0", *faults])
    a, b = tmp_path / "inproc", tmp_path / "memory"
    run_inproc(sc, a)
    summary = asyncio.run(run_daemons_in_memory(sc, b))
    assert summary["engine"] == "memory"
    assert summary["timeouts"] == {"wrench": 0, "neighbour": 0}
    for name, keys in (("samples.csv", 2), ("estimates.csv", 2), ("pairs.csv", 3), ("truth.csv", 1)):
        assert max_table_difference(a, b, name, keys) <= 1e-9, name
    # the link statistics are the same draws, counted at the receiving end
    links_a = json.loads((a / "summary.json").read_text())["links"]
    assert links_a == summary["links"]
    if faults:
        assert sum(v["dropped"] for v in links_a.values()) > 0
    # the partition schedule is recorded alike, and cut links count it apart from random loss
    events_a = json.loads((a / "summary.json").read_text())["events"]
    assert [e for e in summary["events"] if e["event"].startswith("partition")] == events_a
    if any("partitions" in f for f in faults):
        assert [e["event"] for e in events_a] == ["partition_start", "partition_start", "partition_end",
                                                  "partition_end"]
        assert events_a[0]["cut"] == [[1, 2]] and events_a[1]["cut"] == [[3, 4]]
        # 100 ticks cut in each direction of 1-2, 120 of 3-4
        assert {k: v["partitioned"] for k, v in links_a.items() if v["partitioned"]} == {
            "1->2": 100, "2->1": 100, "3->4": 120, "4->3": 120}


def test_stop_after_done_ends_both_engines_on_the_same_tick(tmp_path):
    """stop_after_done_s: the run ends 1 s after the team agreed it was done, on the same tick in both
    engines (the daemons' rule reads the published estimates, as the in-process engine does), with the
    estimates of the full-length run up to there."""
    short = ['dynamics.algorithm="sequential"', "dynamics.kin_settle_s=3", "dynamics.m_excite_s=8",
             "dynamics.j_excite_s=10", "duration=60"]
    sc = load_scenario(SCENARIOS / "quick.toml", [*short, "stop_after_done_s=1.0"])
    a, b = tmp_path / "inproc", tmp_path / "memory"
    sa = run_inproc(sc, a)
    sb = asyncio.run(run_daemons_in_memory(sc, b))
    done = sa["errors"]["finished_s"]
    assert done is not None and done < 50.0
    # the tick after the first recorded all-done tick, plus 100 ticks
    assert sa["sim_s"] == pytest.approx(done + 0.01 + 1.0)
    assert sb["sim_s"] == sa["sim_s"]
    assert sb["timeouts"] == {"wrench": 0, "neighbour": 0}
    assert sorted(sb["agents_reported"]) == list(range(sc.n))  # every agent reported after the early `done`
    for name, keys in (("samples.csv", 2), ("estimates.csv", 2), ("truth.csv", 1)):
        assert max_table_difference(a, b, name, keys) <= 1e-9, name
    assert sa["links"] == sb["links"]
    # the same run without the stop: identical up to the early end, and the same final J and m
    full = run_inproc(load_scenario(SCENARIOS / "quick.toml", short), tmp_path / "full")
    assert full["sim_s"] == 60.0
    assert full["errors"]["J_rel"] == sa["errors"]["J_rel"] and full["errors"]["m_rel"] == sa["errors"]["m_rel"]
