"""Wide time-series tables (trace.csv of hinf runs, series.csv of observer runs): written and read
back bit for bit, and one clear error per malformed file."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from coload.rundir.series import read_series, write_series
from ident.tables import RunFormatError

floats = st.floats(allow_nan=True, allow_infinity=True, width=64)


@given(T=st.integers(0, 6), k=st.integers(1, 4), data=st.data())
def test_round_trip_is_bit_identical(tmp_path_factory, T, k, data):
    t = data.draw(arrays(float, T, elements=st.floats(-1e6, 1e6)))
    x = data.draw(arrays(float, (T, k), elements=floats))
    r = data.draw(arrays(float, T, elements=floats))
    got = data.draw(arrays(bool, (T, 2)))
    path = tmp_path_factory.mktemp("s") / "trace.csv"
    write_series(path, t, {"x": x, "r": r, "got": got})
    t2, cols = read_series(path)
    assert set(cols) == {"x", "r", "got"}
    np.testing.assert_array_equal(t2, t)
    np.testing.assert_array_equal(cols["x"], x)  # every bit of a number; NaN reads back as NaN
    real = ~np.isnan(x)
    assert np.array_equal(np.signbit(cols["x"][real]), np.signbit(x[real]))  # -0.0 stays -0.0
    np.testing.assert_array_equal(cols["r"], r)
    np.testing.assert_array_equal(cols["got"].astype(bool), got)


def test_header_names_each_column(tmp_path):
    write_series(tmp_path / "s.csv", np.array([0.0, 0.5]), {"y": np.zeros((2, 2)), "r": np.ones(2)})
    assert (tmp_path / "s.csv").read_text().splitlines()[0] == "t,y_0,y_1,r"


@pytest.mark.parametrize("name", ["t", "x_0", "speed_12"])
def test_reserved_names_are_refused(tmp_path, name):
    with pytest.raises(ValueError, match="reserved"):
        write_series(tmp_path / "s.csv", np.zeros(1), {name: np.zeros(1)})


@pytest.mark.parametrize("text, message", [
    ("", r"s.csv:1: expected a header starting with 't'"),
    ("t,x_0\n0.0,1.0,2.0\n", r"s.csv:2: 3 fields, expected 2"),
    ("t,x_0\n0.0,abc\n", r"s.csv:2: column 'x_0': 'abc' is not a number"),
    ("t,x_0,x_2\n0.0,1.0,2.0\n", r"s.csv:1: columns x_k are not numbered 0..1"),
])
def test_malformed_files_name_line_and_column(tmp_path, text, message):
    (tmp_path / "s.csv").write_text(text)
    with pytest.raises(RunFormatError, match=message):
        read_series(tmp_path / "s.csv")


def test_an_empty_cell_reads_as_nan(tmp_path):
    (tmp_path / "s.csv").write_text("t,r\n0.0,\n")
    _, cols = read_series(tmp_path / "s.csv")
    assert np.isnan(cols["r"][0])
