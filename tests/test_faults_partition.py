"""Partitions over time windows: the scenario model, the link model and the engines' accounting.

(Equality of the in-process engine and the daemons under a partition is in tests/test_engines.py.)
"""

from __future__ import annotations

import json

import pytest

from coload.runs.engine import run_inproc
from config.loader import ScenarioError, load_scenario
from config.scenario import LinkSpec, LossSpec, PartitionSpec
from net.link import DelayLine, LinkModel, LinkStats, build_in_links, partition_events
from tests.conftest import SCENARIOS

DT = 0.01


def _spec(partitions, **kw) -> LinkSpec:
    return LinkSpec(partitions=[PartitionSpec(**p) for p in partitions], **kw)


def test_partition_spec_validation():
    with pytest.raises(ValueError, match="exactly one"):
        PartitionSpec(start=0, end=1)
    with pytest.raises(ValueError, match="exactly one"):
        PartitionSpec(start=0, end=1, cut=[(0, 1)], groups=[[0]])
    with pytest.raises(ValueError, match="after start"):
        PartitionSpec(start=2, end=1, cut=[(0, 1)])
    with pytest.raises(ValueError, match="distinct"):
        PartitionSpec(start=0, end=1, cut=[(1, 1)])
    with pytest.raises(ValueError, match="disjoint"):
        PartitionSpec(start=0, end=1, groups=[[0, 1], [1, 2]])


@pytest.mark.parametrize(("value", "message"), [
    ("[{start=1.0, end=2.0, cut=[[0, 2]]}]", "not an edge of the graph"),
    ("[{start=1.0, end=2.0, groups=[[0, 9]]}]", "names agent 9"),
    ("[{start=1.0, end=2.0}]", "exactly one"),
])
def test_bad_partitions_are_scenario_errors(value, message):
    with pytest.raises(ScenarioError, match=message) as info:
        load_scenario(SCENARIOS / "quick.toml", [f"link.partitions={value}"])
    assert "link.partitions" in str(info.value)


def test_groups_cut_every_edge_between_groups():
    p = PartitionSpec(start=0, end=1, groups=[[0, 1], [3]])
    # 0,1 | 3 | the rest (2, 4) together
    assert not p.cuts(0, 1) and p.cuts(1, 2) and p.cuts(2, 3) and p.cuts(3, 4) and not p.cuts(2, 4)
    assert PartitionSpec(start=0, end=1, cut=[(2, 1)]).cuts(1, 2)


def test_partition_cuts_only_its_window_and_leaves_other_draws_alone():
    loss = LossSpec(model="gilbert_elliott", p_good_to_bad=0.1, p_bad_to_good=0.3, loss_bad=0.9)
    base = LinkModel(LinkSpec(loss=loss, jitter_ticks=2, duplicate=0.1), 3, 1, 2, dt=DT)
    cut = LinkModel(_spec([{"start": 1.0, "end": 2.5, "cut": [(1, 2)]}], loss=loss, jitter_ticks=2, duplicate=0.1),
                    3, 1, 2, dt=DT)
    for k in range(400):
        a, b = base.deliveries(k), cut.deliveries(k)
        if 100 <= k < 250:
            assert b == () and cut.partitioned(k)
        else:
            assert a == b and not cut.partitioned(k)
    # the reverse direction is cut too; another link is not
    assert LinkModel(_spec([{"start": 1.0, "end": 2.5, "cut": [(1, 2)]}]), 3, 2, 1, dt=DT).partitioned(100)
    assert not LinkModel(_spec([{"start": 1.0, "end": 2.5, "cut": [(1, 2)]}]), 3, 2, 3, dt=DT).partitioned(100)


def test_faultless_partitioned_link_and_fast_path():
    spec = _spec([{"start": 0.05, "end": 0.1, "groups": [[0]]}], delay_ticks=1)
    m = LinkModel(spec, 0, 0, 1, dt=DT)
    assert m.fixed_delays is None  # the engine's constant-fate fast path must not be used
    assert [m.deliveries(k) for k in range(12)] == [(1,)] * 5 + [()] * 5 + [(1,)] * 2
    # a link the partition does not touch keeps its constant fate
    assert LinkModel(spec, 0, 1, 2, dt=DT).fixed_delays == (1,)
    with pytest.raises(ValueError, match="dt"):
        LinkModel(spec, 0, 0, 1)


def test_delay_line_counts_partitioned_apart_from_dropped():
    spec = _spec([{"start": 0.0, "end": 0.5, "cut": [(0, 1)]}], loss=LossSpec(model="bernoulli", p=0.3))
    link, line, st = LinkModel(spec, 5, 0, 1, dt=DT), DelayLine(), LinkStats()
    for k in range(200):
        line.offer(link, k, k, st)
    assert st.partitioned == 50 and st.sent == 200
    assert 0 < st.dropped < 150 and len(line) == 200 - 50 - st.dropped


def test_inproc_run_counts_and_records_the_partition(tmp_path):
    sc = load_scenario(SCENARIOS / "quick.toml",
                       ["duration=2.0", ("link.partitions=[{start=0.5, end=1.0, groups=[[0, 1]]}, "
                                         "{start=1.5, end=5.0, cut=[[2, 3]]}]")])
    summary = run_inproc(sc, tmp_path)
    links = summary["links"]
    assert links["1->2"]["partitioned"] == links["2->1"]["partitioned"] == 50
    assert links["2->3"]["partitioned"] == links["3->2"]["partitioned"] == 50  # until the end of the run
    assert all(v["dropped"] == 0 for v in links.values())
    assert links["1->2"]["delivered"] == 200 - 50 and links["0->1"]["delivered"] == 200
    # the second partition outlasts the run: no heal event
    assert [(e["event"], e["tick"]) for e in summary["events"]] == [
        ("partition_start", 50), ("partition_end", 100), ("partition_start", 150)]
    assert summary["events"] == partition_events(sc)
    assert json.loads((tmp_path / "summary.json").read_text())["events"] == summary["events"]
    assert set(build_in_links(sc.agent_view(2))) == {1, 3}
