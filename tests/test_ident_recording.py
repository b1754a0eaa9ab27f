"""ident.recording: the measured-data format as a lab would write it, and clear errors for bad input."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest

from ident.recording import RecordingError, read_recording, recording_from_arrays, write_recording
from tests.conftest import coload_cmd


TOML = "n = 2\ndt = 0.01\nedges = [[0, 1]]\n"


def write(tmp: Path, rows: list[str], header="t,agent,vx,vy,fx,fy,tau", toml=TOML) -> Path:
    (tmp / "run.toml").write_text(toml)
    (tmp / "samples.csv").write_text("\n".join([header, *rows]) + "\n")
    return tmp


def test_positions_irregular_stamps_gaps_one_agent_no_dt(tmp_path):
    """x,y instead of vx,vy; stamps irregular with a gap; n = 1; no dt, no edges, no noise declared."""
    t = [float(x) for x in np.concatenate((np.arange(0, 1, 0.01), np.arange(2.0, 3.0, 0.013)))]
    rows = [f"{x!r},0,{0.5 * x * x!r},0.0,1.0,0,0" for x in t]
    rows[5] = f"{t[5]!r},0,,0.0,1.0,0,0"  # a missing position: empty cell
    rec = read_recording(write(tmp_path, rows, header="t,agent,x,y,fx,fy,tau", toml="n = 1\n"))
    assert rec.n == 1 and rec.vel is None and rec.pos.shape == (len(t), 1, 2)
    assert np.isnan(rec.pos[5, 0, 0]) and rec.hold == "cubic" and rec.dt is None
    assert np.allclose(rec.t, t) and rec.T == len(t)


def test_agents_on_their_own_stamps_and_missing_wrench_are_interpolated(tmp_path):
    rows = [f"{0.01 * k!r},{k % 2},0.1,0.2,{1.0 * k},0,0" for k in range(40)]
    rows[10] = f"{0.1!r},0,0.1,0.2,,0,0"  # no force in that row
    rec = read_recording(write(tmp_path, rows))
    assert rec.T == 40 and np.isnan(rec.vel[::2, 1]).all() and not np.isnan(rec.wrench).any()
    assert rec.wrench[10, 0, 0] == pytest.approx(10.0) and any("interpolated" in w for w in rec.warnings)


def test_sample_period_other_than_dt_is_used_and_said(tmp_path):
    rows = [f"{0.05 * k!r},{i},0.1,0.2,1,0,0" for k in range(20) for i in range(2)]
    rec = read_recording(write(tmp_path, rows))
    assert any("differs from run.toml dt" in w for w in rec.warnings)


def test_round_trip(tmp_path):
    t = np.arange(30) * 0.02
    wr = np.random.default_rng(1).normal(size=(30, 2, 3))
    vel = np.random.default_rng(2).normal(size=(30, 2, 2))
    vel[3, 1] = np.nan
    out = write_recording(tmp_path / "r", recording_from_arrays(t, wr, vel=vel, hold="zoh", dt=0.02))
    back = read_recording(out)
    assert back.hold == "zoh" and np.allclose(back.wrench, wr) and np.allclose(back.vel, vel, equal_nan=True)


@pytest.mark.parametrize("header, rows, toml, match", [
    ("t,agent,vx,vy,fx,tau", ["0.0,0,0,0,0,0"], None, r"samples.csv:1: header lacks column\(s\) fy"),
    ("t,agent,fx,fy,tau", ["0.0,0,0,0,0"], None, r"samples.csv:1: header lacks measured columns"),
    (None, ["0.0,0,0,0,0,0,0", "0.0,1,0,abc,0,0,0"], None, r"samples.csv:3: column 'vy': 'abc' is not a number"),
    (None, ["0.0,0,0,0,0,0,0", "0.0,7,0,0,0,0,0"], None, r"samples.csv:3: column 'agent': agent 7 out of range 0..1"),
    (None, ["0.0,0,0,0,0,0,0", "0.0,0,1,0,0,0,0"], None, r"samples.csv:3: field 't': agent 0 has two rows"),
    (None, ["0.0,0,0,0,0,0"], None, r"samples.csv:2: 6 fields, header has 7"),
    (None, ["0.0,0,0,0,0,0,0"], "dt = 0.01\n", r"run.toml: field 'n': expected a positive integer"),
    (None, ["0.0,0,0,0,0,0,0"], 'n = 2\ninput_hold = "spline"\n', r"run.toml: field 'input_hold'"),
])  # fmt: skip
def test_bad_input_names_file_line_and_field(tmp_path, header, rows, toml, match):
    kw = {"header": header} if header else {}
    if toml:
        kw["toml"] = toml
    with pytest.raises(RecordingError, match=match):
        read_recording(write(tmp_path, rows, **kw))


def test_cli_bad_input_exit_2_and_import_help(tmp_path):
    rec = write(tmp_path, ["0.0,0,0,0,0,0,0", "0.0,1,0,abc,0,0,0"])
    proc = subprocess.run(coload_cmd("diagnose", str(rec), "--quiet"), capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "samples.csv:3: column 'vy'" in proc.stderr
    proc = subprocess.run(coload_cmd("import", "emps", str(tmp_path / "nope.mat"), "--out", str(tmp_path / "o")),
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 2 and "nope.mat" in proc.stderr and not (tmp_path / "o").exists()
