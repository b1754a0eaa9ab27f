"""A recorder that keeps its tables in memory (``tables=False``, a campaign's runs) stands for the files it
does not write: ``Recorder.held()`` is the run ``read_run`` reads from a recorder that writes them, and a run's
summary is the same either way."""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from coload.rundir import format as fmt
from coload.rundir.recorder import Recorder
from coload.runs.engine import run_inproc
from config.loader import load_scenario
from net.vocabulary import ESTIMATE_NAMES

TIMING = ("wall_s", "agent_step_us")  # the only keys of a summary that two runs of one scenario may differ in
# (and the centralized fit's fit_s)

# every kind of float a table cell meets: NaN (an empty cell), infinities, signed zeros, subnormals, the
# extremes and ordinary numbers
cells = st.one_of(st.floats(allow_nan=True, allow_infinity=True, allow_subnormal=True), st.just(-0.0),
                  st.just(math.nan), st.sampled_from([5e-324, 1.7976931348623157e308, 0.1, 1 / 3]))


def _same(a: np.ndarray, b: np.ndarray, where: str) -> None:
    """Equal shapes and values bit for bit, except that any NaN equals any NaN (an empty cell has no sign)."""
    assert a.shape == b.shape, where
    nan = np.isnan(a)
    assert np.array_equal(nan, np.isnan(b)), where
    assert np.array_equal(a[~nan].view(np.int64), b[~nan].view(np.int64)), where


def _same_run(held: fmt.RunData, read: fmt.RunData) -> None:
    assert (held.config, held.n, held.dt, held.edges, held.name, held.summary) == \
        (read.config, read.n, read.dt, read.edges, read.name, read.summary)
    for name in ("samples", "estimates"):
        h, r = getattr(held, name), getattr(read, name)
        _same(h.t, r.t, f"{name}.t")
        assert list(h.columns) == list(r.columns), name
        for col in r.columns:
            _same(h.columns[col], r.columns[col], f"{name}.{col}")
    _same(held.pairs.t, read.pairs.t, "pairs.t")
    assert list(held.pairs.zij) == list(read.pairs.zij)
    for key, zij in read.pairs.zij.items():
        _same(held.pairs.zij[key], zij, f"pairs {key}")
    _same(held.truth.t, read.truth.t, "truth.t")
    assert list(held.truth.columns) == list(read.truth.columns)
    for col in read.truth.columns:
        _same(held.truth.columns[col], read.truth.columns[col], f"truth.{col}")
    _same(held.truth.zi, read.truth.zi, "truth.zi")


@settings(max_examples=40, deadline=None, derandomize=True)
@given(ticks=st.integers(0, 9), every=st.integers(1, 3), data=st.data())
def test_held_tables_read_as_the_files(tmp_path_factory, ticks, every, data) -> None:
    """Whatever numbers are recorded, the held tables are bit for bit what reading the written files gives."""
    scenario = load_scenario("quick", [f"record.every_ticks={every}"])
    n = scenario.n
    dirs = tmp_path_factory.mktemp("files"), tmp_path_factory.mktemp("held")
    recs = [Recorder(d, scenario, ESTIMATE_NAMES, tables=t) for d, t in zip(dirs, (True, False), strict=True)]

    def floats(k: int) -> list[float]:
        return data.draw(st.lists(cells, min_size=k, max_size=k))

    for tick in range(ticks):
        truth = SimpleNamespace(tick=tick, t=tick * scenario.dt, x=floats(1)[0], y=floats(1)[0],
                                angle=floats(1)[0], vc=floats(2), omega=floats(1)[0], zc=floats(2), pg=floats(2),
                                mass=floats(1)[0], inertia=floats(1)[0],
                                zi=np.array(floats(2 * n)).reshape(n, 2))
        velocities = np.array(floats(2 * n)).reshape(n, 2)
        wrenches = np.array(floats(3 * n)).reshape(n, 3)
        values = [floats(len(ESTIMATE_NAMES)) for _ in range(n)]
        pairs = [[(j, *floats(2)) for j in range(n) if j != i and (i + j + tick) % 2 == 0] for i in range(n)]
        for rec in recs:
            rec.truth(truth)
            rec.estimate_rows(tick, list(range(n)), values, pairs)
            rec.samples(tick, velocities, wrenches)
    for rec in recs:
        rec.close({"ticks": ticks})
    assert not any((dirs[1] / name).exists() for name in (fmt.SAMPLES_CSV, fmt.ESTIMATES_CSV, fmt.PAIRS_CSV,
                                                         fmt.TRUTH_CSV))
    _same_run(recs[1].held(), fmt.read_run(dirs[0]))


def test_held_needs_a_closed_memory_recorder(tmp_path: Path) -> None:
    scenario = load_scenario("quick")
    with pytest.raises(RuntimeError, match="tables=False"):
        Recorder(tmp_path / "a", scenario, ESTIMATE_NAMES).held()
    with pytest.raises(RuntimeError, match="closed"):
        Recorder(tmp_path / "b", scenario, ESTIMATE_NAMES, tables=False).held()


@pytest.mark.parametrize("scenario, overrides", [
    ("quick", ["duration=10", "record.batch_fit=true"]),  # kinematic phase, the centralized yardstick
    ("quick-dynamics", []),  # Algorithm 1 to its end: m, J, the trust and monitor blocks
    ("friction-online", ["duration=60"]),  # online detection: the effects block and its events
    ("faults-partition", ["duration=20"]),  # lossy links, a partition: estimates missing at some ticks
])
def test_summary_without_tables_is_the_summary_with_them(tmp_path: Path, scenario, overrides) -> None:
    """A campaign's run (no CSV tables) scores exactly as a run that writes and reads them back."""
    sc = load_scenario(scenario, overrides)
    with_tables = run_inproc(sc, tmp_path / "files")
    without = run_inproc(sc, tmp_path / "held", tables=False)
    assert sorted(p.name for p in (tmp_path / "held").iterdir()) == ["logs", fmt.RUN_TOML, fmt.SUMMARY_JSON]
    assert with_tables["errors"], "the run is scored"
    on_disk = [json.loads((tmp_path / d / fmt.SUMMARY_JSON).read_text()) for d in ("files", "held")]
    for summary in (with_tables, without, *on_disk):
        for key in TIMING:
            summary.pop(key)
        summary.get("centralized", {}).pop("fit_s", None)
    text = [json.dumps(s, default=repr) for s in (with_tables, without, *on_disk)]  # NaN == NaN as text
    assert text[1] == text[0]
    assert text[3] == text[2]
