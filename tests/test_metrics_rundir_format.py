"""The run-directory reader: round trip of a synthetic run, and precise errors on malformed files."""

from __future__ import annotations

import numpy as np
import pytest

from coload.rundir import format as rf
from tests.synthetic_run import SyntheticSpec, truth_of, write_run


@pytest.fixture
def run_dir(tmp_path):
    write_run(tmp_path, SyntheticSpec(n=3, duration=2.0, dt=0.1, every=2, drop=((1, 0.5, 1.0),)))
    return tmp_path


def test_round_trip(run_dir):
    run = rf.read_run(run_dir)
    spec = SyntheticSpec(n=3, duration=2.0, dt=0.1, every=2)
    assert run.n == 3 and run.dt == 0.1 and run.edges == ((0, 1), (1, 2)) and run.name == "synthetic"
    tr = truth_of(spec)
    assert np.allclose(run.truth.t, tr.t) and np.allclose(run.truth.zi, tr.zi)
    assert set(run.estimates.columns) == {"phase", "omega", "zi_x", "zi_y"}
    # rows were written shuffled: the grid is sorted, decimated every 2 ticks
    assert np.allclose(run.estimates.t, tr.t[::2])
    assert run.estimates.columns["omega"].shape == (len(tr.t[::2]), 3)
    down = (run.estimates.t >= 0.5) & (run.estimates.t < 1.0)
    assert np.all(np.isnan(run.estimates.columns["omega"][down, 1]))
    assert np.all(np.isfinite(run.estimates.columns["omega"][~down, 1]))
    assert set(run.pairs.zij) == {(0, 1), (1, 0), (1, 2), (2, 1)}
    assert np.allclose(run.pairs.zij[(2, 1)], tr.zi[::2, 2] - tr.zi[::2, 1])
    assert run.samples.columns["vx"].shape == (len(tr.t), 3)
    assert run.summary == {"engine": "synthetic", "n": 3, "seed": 0}
    assert np.array_equal(run.truth_index(np.array([0.0, 0.41, 0.96, 5.0])), [0, 4, 10, len(tr.t) - 1])


def test_headers_agree_with_the_docs():
    assert rf.truth_header(2)[-4:] == ("z0_x", "z0_y", "z1_x", "z1_y")
    assert rf.TRUTH_HEADER == list(rf.TRUTH_BASE_HEADER)
    assert rf.ESTIMATES_HEADER[:2] == ("t", "agent")


def test_every_estimate_column_the_agents_write_is_read_strictly(run_dir):
    """A bad cell in any column the agents write (J_local here, which Fig. 8 needs) is an error that
    names file, line and column, not a column that silently vanishes."""
    from net.vocabulary import ESTIMATE_NAMES

    assert rf.KNOWN_ESTIMATE_NAMES == ESTIMATE_NAMES
    path = run_dir / rf.ESTIMATES_CSV
    lines = path.read_text().splitlines()
    lines[0] += ",J_local"
    lines[1:] = [line + ",1.5" for line in lines[1:]]
    lines[3] = lines[3][: -len("1.5")] + "oops"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(rf.RunFormatError, match=r"estimates\.csv:4.*J_local"):
        rf.read_run(run_dir)


def test_optional_files_may_be_absent(run_dir):
    for name in (rf.TRUTH_CSV, rf.ESTIMATES_CSV, rf.PAIRS_CSV, rf.SUMMARY_JSON):
        (run_dir / name).unlink()
    run = rf.read_run(run_dir)
    assert run.truth is None and run.estimates is None and run.pairs is None and run.summary is None
    assert run.samples is not None


def test_extra_columns_and_empty_cells(run_dir):
    path = run_dir / rf.SAMPLES_CSV
    lines = path.read_text().splitlines()
    lines[0] += ",comment"
    lines[1:] = [ln + ",hello" for ln in lines[1:]]
    path.write_text("\n".join(lines) + "\n\n")
    est = run_dir / rf.ESTIMATES_CSV
    e = est.read_text().splitlines()
    e[1] = ",".join(e[1].split(",")[:3] + ["", "", ""])
    est.write_text("\n".join(e) + "\n")
    run = rf.read_run(run_dir)
    assert "comment" not in run.samples.columns  # not numeric: ignored, as the format allows
    assert np.isnan(run.estimates.columns["omega"]).sum() > 0


def _corrupt(path, line_no, column, value):
    """Replace one cell (1-based physical line) and return the expected 'file:line' prefix."""
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    cells = lines[line_no - 1].split(",")
    cells[header.index(column)] = value
    lines[line_no - 1] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    return f"{path}:{line_no}"


@pytest.mark.parametrize(
    ("name", "column", "value", "fragment"),
    [
        (rf.SAMPLES_CSV, "vx", "abc", "column 'vx': 'abc' is not a number"),
        (rf.SAMPLES_CSV, "agent", "1.5", "column 'agent': '1.5' is not an integer"),
        (rf.SAMPLES_CSV, "agent", "7", "column 'agent': agent 7 out of range 0..2"),
        (rf.SAMPLES_CSV, "t", "", "column 't': empty cell"),
        (rf.ESTIMATES_CSV, "omega", "1.2.3", "column 'omega'"),
        (rf.PAIRS_CSV, "neighbour", "-1", "column 'neighbour': agent -1 out of range"),
        (rf.TRUTH_CSV, "z2_y", "x", "column 'z2_y'"),
    ],
)
def test_malformed_cell_names_file_line_and_column(run_dir, name, column, value, fragment):
    where = _corrupt(run_dir / name, 5, column, value)
    with pytest.raises(rf.RunFormatError) as exc:
        rf.read_run(run_dir)
    msg = str(exc.value)
    assert msg.startswith(where + ":"), msg
    assert fragment in msg


def test_wrong_field_count(run_dir):
    path = run_dir / rf.PAIRS_CSV
    lines = path.read_text().splitlines()
    lines[3] += ",1.0"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(rf.RunFormatError, match=r"pairs\.csv:4: expected 5 fields, got 6"):
        rf.read_run(run_dir)


def test_a_cut_last_line_is_dropped_with_a_warning_and_nothing_else_is_lost(run_dir, caplog):
    """A recorder killed mid-write: the last line is short and has no newline. The whole rows are the
    recording; the cut one is named in a warning."""
    path = run_dir / rf.SAMPLES_CSV
    whole = rf.read_run(run_dir).samples
    text = path.read_text()
    path.write_text(text + "2.5,1,0.12")
    with caplog.at_level("WARNING", logger="coload.rundir.format"):
        cut = rf.read_run(run_dir).samples
    nlines = text.count("\n") + 1
    assert f"samples.csv:{nlines}: last line cut off (3 of 7 fields, no newline)" in caplog.text
    assert np.array_equal(cut.t, whole.t)
    for name, col in whole.columns.items():
        assert np.array_equal(cut.columns[name], col, equal_nan=True), name


@pytest.mark.parametrize("tail", ["2.5,1,0.12\n", "2.5,1,0.12\n2.6,0,1,1,1,1,1\n"])
def test_a_short_line_that_is_not_a_cut_tail_is_still_an_error(run_dir, tail):
    """A short line followed by a newline or by more rows is malformed data, not a cut write."""
    path = run_dir / rf.SAMPLES_CSV
    text = path.read_text()
    path.write_text(text + tail)
    nlines = text.count("\n") + 1
    with pytest.raises(rf.RunFormatError, match=rf"samples\.csv:{nlines}: expected 7 fields, got 3"):
        rf.read_run(run_dir)


def test_missing_header_column(run_dir):
    path = run_dir / rf.TRUTH_CSV
    lines = path.read_text().splitlines()
    lines[0] = lines[0].replace("z1_x", "zz")
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(rf.RunFormatError, match=r"truth\.csv:1: header lacks column\(s\) z1_x"):
        rf.read_run(run_dir)


def test_empty_file(run_dir):
    (run_dir / rf.SAMPLES_CSV).write_text("")
    with pytest.raises(rf.RunFormatError, match=r"samples\.csv:1: empty file"):
        rf.read_run(run_dir)


def test_pair_with_itself(run_dir):
    path = run_dir / rf.PAIRS_CSV
    lines = path.read_text().splitlines()
    cells = lines[1].split(",")
    cells[2] = cells[1]
    lines[1] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(rf.RunFormatError, match=r"pairs\.csv:2: .*paired with itself"):
        rf.read_run(run_dir)


@pytest.mark.parametrize(
    ("toml", "fragment"),
    [
        ("n = 3\ndt = 0.1\n", "missing top-level key 'edges'"),
        ("n = 3\ndt = 0.1\nedges = [[0, 3]]\n", "not a pair of distinct agents in 0..2"),
        ("n = 0\ndt = 0.1\nedges = []\n", "'n' must be a positive integer"),
        ("n = 3\ndt = -1\nedges = []\n", "'dt' must be a positive number"),
        ("n = 3\ndt = \n", "invalid TOML"),
    ],
)
def test_bad_run_toml(run_dir, toml, fragment):
    (run_dir / rf.RUN_TOML).write_text(toml)
    with pytest.raises(rf.RunFormatError, match=fragment):
        rf.read_run(run_dir)


def test_missing_run_toml_and_directory(tmp_path):
    with pytest.raises(rf.RunFormatError, match="not a directory"):
        rf.read_run(tmp_path / "nope")
    with pytest.raises(rf.RunFormatError, match=r"run\.toml: missing"):
        rf.read_run(tmp_path)


def test_bad_summary_json(run_dir):
    (run_dir / rf.SUMMARY_JSON).write_text("{\n  'x': 1\n}")
    with pytest.raises(rf.RunFormatError, match=r"summary\.json:2:3: invalid JSON"):
        rf.read_run(run_dir)


def test_fast_and_line_tracking_readers_agree(tmp_path):
    """A non-numeric extra column forces the cell-by-cell reader; it must give the same arrays."""
    fast_dir, slow_dir = tmp_path / "fast", tmp_path / "slow"
    for d in (fast_dir, slow_dir):
        write_run(d, SyntheticSpec(n=3, duration=2.0, dt=0.1, drop=((2, 0.3, 0.9),)))
    for name in (rf.SAMPLES_CSV, rf.ESTIMATES_CSV, rf.PAIRS_CSV, rf.TRUTH_CSV):
        lines = (slow_dir / name).read_text().splitlines()
        (slow_dir / name).write_text(
            "\n".join([lines[0] + ",note"] + [ln + ",text" for ln in lines[1:]]) + "\n"
        )
    a, b = rf.read_run(fast_dir), rf.read_run(slow_dir)
    for ta, tb in ((a.samples, b.samples), (a.estimates, b.estimates)):
        assert np.array_equal(ta.t, tb.t) and ta.columns.keys() == tb.columns.keys()
        for k in ta.columns:
            assert np.array_equal(ta.columns[k], tb.columns[k], equal_nan=True), k
    assert a.pairs.zij.keys() == b.pairs.zij.keys()
    for k in a.pairs.zij:
        assert np.array_equal(a.pairs.zij[k], b.pairs.zij[k], equal_nan=True)
    assert np.array_equal(a.truth.zi, b.truth.zi)


def test_a_lab_export_with_a_bom_and_a_latin1_text_column_is_read(run_dir):
    """Spreadsheet exports: a byte-order mark before the header, and a free-text column in another
    encoding (allowed and ignored): the numbers are read as they are."""
    path = run_dir / rf.SAMPLES_CSV
    want = rf.read_run(run_dir).samples.columns["vx"]
    lines = path.read_text().splitlines()
    text = [lines[0] + ",note"] + [line + ",Kraftmessung " for line in lines[1:]]
    path.write_bytes(b"\xef\xbb\xbf" + "\n".join(text).encode("latin-1") + b"\xe4\n")
    got = rf.read_run(run_dir).samples
    assert np.array_equal(got.columns["vx"], want, equal_nan=True)
    assert "note" not in got.columns


def test_an_empty_agent_cell_is_located(run_dir):
    path = run_dir / rf.SAMPLES_CSV
    lines = path.read_text().splitlines()
    head = lines[0].split(",")
    row = lines[5].split(",")
    row[head.index("agent")] = ""
    lines[5] = ",".join(row)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(rf.RunFormatError, match=r"samples\.csv:6: column 'agent': empty cell, expected an integer"):
        rf.read_run(run_dir)


def test_run_toml_that_is_not_utf8_is_located(run_dir):
    path = run_dir / rf.RUN_TOML
    text = path.read_bytes().split(b"\n")
    text[2] = b'# r\xe9glage'
    path.write_bytes(b"\n".join(text))
    with pytest.raises(rf.RunFormatError, match=r"run\.toml:3: not UTF-8"):
        rf.read_run(run_dir)
