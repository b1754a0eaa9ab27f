"""The engines agree: the daemons (over the in-memory transport) reproduce the in-process engine.

Both feed every agent the same inbox per tick, so estimates must match to the last bit, with and
without link faults.
"""

from __future__ import annotations

import asyncio
import json

import pytest

from coload.engine import run_inproc
from coload.orchestrate import run_daemons_in_memory
from config.loader import load_scenario
from tests.conftest import SCENARIOS, max_table_difference

FAULTS = [
    [],
    ["link.delay_ticks=2", "link.jitter_ticks=3", 'link.loss.model="bernoulli"', "link.loss.p=0.2",
     "link.duplicate=0.1"],
    ['link.loss.model="gilbert_elliott"', "link.loss.p_good_to_bad=0.05", "link.loss.p_bad_to_good=0.3"],
]


@pytest.mark.parametrize("faults", FAULTS, ids=["clean", "delay-loss-dup", "bursty"])
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
