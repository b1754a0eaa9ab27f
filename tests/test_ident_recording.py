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


def test_a_row_per_topic_at_one_stamp_is_one_sample(tmp_path):
    """A logger that writes each topic in rows of its own (a bag's velocity and wrench topics): velocity
    rows at 100 Hz, wrench rows at 50 Hz with the same stamps and at 20 Hz at stamps of their own. Rows
    of one agent at one stamp merge into one sample; a wrench between its samples is interpolated
    (here a ramp, 100 t N: exactly), a velocity at a wrench-only stamp is missing."""
    rows = []
    for k in range(41):
        t = 0.01 * k
        rows += [f"{t!r},{i},{0.1 * i},0.2,,," for i in range(2)]
        if k % 2 == 0:
            rows += [f"{t!r},{i},,,{100 * t!r},0,0" for i in range(2)]
    only = [0.005 + 0.05 * j for j in range(8)]
    rows += [f"{t!r},{i},,,{100 * t!r},0,0" for t in only for i in range(2)]
    rec = read_recording(write(tmp_path, rows))
    assert rec.T == 49 and np.allclose(rec.wrench[:, :, 0], 100 * rec.t[:, None], atol=1e-9)
    at_only = np.isin(np.round(rec.t, 9), np.round(only, 9))
    assert np.isnan(rec.vel[at_only]).all() and not np.isnan(rec.vel[~at_only]).any()
    assert rec.vel[~at_only, 1, 0] == pytest.approx(0.1)


def test_a_wrench_missing_for_long_leaves_its_stamps_out(tmp_path):
    """Agent 1's logger drops out for 0.3 s (30 of its samples) and for one sample: over the long gap the
    team's force is unknown, so those stamps leave the recording (the fit cuts its windows there) and a
    warning names the agent and when; the one missing sample is interpolated."""
    rows = [f"{0.01 * k!r},{i},0.1,0.2,{1.0 * k},0,0" for k in range(100) for i in range(2)
            if not (i == 1 and (30 <= k < 60 or k == 80))]  # fmt: skip
    rec = read_recording(write(tmp_path, rows))
    assert rec.T == 70 and not np.isnan(rec.wrench).any()
    assert np.allclose(rec.t[29:31], [0.29, 0.6]) and rec.wrench[50, 1, 0] == pytest.approx(80.0)
    assert any("agent 1 from 0.3 s to 0.59 s" in w and "30 stamps left out" in w for w in rec.warnings)
    rows = [r for r in rows if r.split(",")[1] == "0" or float(r.split(",")[0]) < 0.05]  # agent 1 logs 0.05 s
    with pytest.raises(RecordingError, match="fewer than 10 stamps with every agent's wrench known"):
        read_recording(write(tmp_path, rows))


def test_sample_period_other_than_dt_is_used_and_said(tmp_path):
    rows = [f"{0.05 * k!r},{i},0.1,0.2,1,0,0" for k in range(20) for i in range(2)]
    rec = read_recording(write(tmp_path, rows))
    assert any("dt = 0.01 s is no logged stream's sample period (all stamps: every 0.05 s" in w for w in rec.warnings)


def test_streams_at_their_own_rates_are_no_period_mismatch(tmp_path):
    """Velocities from a 120 Hz mocap and forces at 100 Hz (dt), each in rows of their own: the union of the
    stamps has no logger's period, so dt is checked against each stream's own; the wrench's interpolation to
    the velocity stamps is said as what it is."""
    rows = sorted([(k / 120, f"{k / 120!r},{i},0.1,0.2,,,") for k in range(240) for i in range(2)]
                  + [(0.01 * k, f"{0.01 * k!r},{i},,,1,0,0") for k in range(1, 200) for i in range(2)])
    rec = read_recording(write(tmp_path, [r for _, r in rows]))
    assert not any("sample period" in w for w in rec.warnings)
    assert any("the wrench is logged at stamps of its own" in w for w in rec.warnings)


def test_stamps_in_ms_ns_are_read_in_seconds(tmp_path):
    """A logger's integer milliseconds: read as ms when their interval is 1000 x dt (said), or as declared."""
    rows = [f"{10 * k},{i},0.1,0.2,1,0,0" for k in range(20) for i in range(2)]
    rec = read_recording(write(tmp_path, rows))
    assert np.allclose(rec.t, 0.01 * np.arange(20)) and any("stamps read in ms" in w for w in rec.warnings)
    assert not any("sample period" in w for w in rec.warnings)
    rows = [f"{1_700_000_000_000_000_000 + 10_000_000 * k},{i},0.1,0.2,1,0,0" for k in range(20) for i in range(2)]
    rec = read_recording(write(tmp_path, rows, toml='n = 2\ntime_unit = "ns"\n'))
    assert np.allclose(rec.t, 0.01 * np.arange(20), atol=1e-6) and not rec.warnings
    rows = [f"{10 * k},{i},0.1,0.2,1,0,0" for k in range(400) for i in range(2)]
    proc = subprocess.run(coload_cmd("diagnose", str(write(tmp_path, rows, toml="n = 2\n")), "--quiet"),
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 2 and "median stamp interval 10 s" in proc.stderr and "time_unit" in proc.stderr


def test_an_agent_without_any_row_is_left_out_and_said(tmp_path):
    """run.toml's n counts a robot that never logged (agent 1 of 3): the other two are the recording."""
    rows = [f"{0.01 * k!r},{i},0.1,0.2,{i + 1},0,0" for k in range(20) for i in (0, 2)]
    rec = read_recording(write(tmp_path, rows, toml="n = 3\ndt = 0.01\n"))
    assert rec.n == 2 and np.allclose(rec.wrench[:, :, 0], [1.0, 3.0])
    assert any("agent(s) [1] have no row" in w for w in rec.warnings)


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
    ("t,agent,vx,vy,fx,fy", ["0.0,0,0,0,0,0"], None,
     r"samples.csv:1: header lacks column\(s\) tau .*point contact applies no torque of its own: write tau as 0"),
    (None, ["0.0,0,0,0,0,0,0", "0.0,1,0,abc,0,0,0"], None, r"samples.csv:3: column 'vy': 'abc' is not a number"),
    (None, ["0.0,0,0,0,0,0,0", "0.0,7,0,0,0,0,0"], None, r"samples.csv:3: column 'agent': agent 7 out of range 0..1"),
    (None, ["0.0,0,0,0,0,0,0", "", "0.0,0,1,0,0,0,0"], None,
     r"samples.csv:4: column 'vx': agent 0 has two rows at t = 0.0 with different values \(line 2: 0.0, here: 1.0\)"),
    (None, ["0.0,0,0,0,0,0"], None, r"samples.csv:2: 6 fields, header has 7"),
    ("# logged by rig B", ["t,agent,vx,vy,fx,fy,tau"], None, r"samples.csv:1: .*the first line is a comment"),
    ("t;agent;vx;vy;fx;fy;tau", ["0,0;0;0;0;0;0;0"], None, r"samples.csv:1: .*separated by ';'; the format's separator is ','"),
    ("t [s],agent,vx,vy,fx,fy,tau", ["0.0,0,0,0,0,0,0"], None, r"samples.csv:1: .*column names carry no units"),
    (None, ["nan,0,0,0,0,0,0"], None, r"samples.csv:2: column 't': nan \(expected a number\)"),
    (None, ["0.0,0,0,0,0,0,0"], "dt = 0.01\n", r"run.toml: field 'n': expected a positive integer"),
    (None, ["0.0,0,0,0,0,0,0"], 'n = 2\ninput_hold = "spline"\n', r"run.toml: field 'input_hold'"),
    (None, ["0.0,0,0,0,0,0,0"], 'n = 2\ntime_unit = "min"\n', r"run.toml: field 'time_unit': expected one of"),
])  # fmt: skip
def test_bad_input_names_file_line_and_field(tmp_path, header, rows, toml, match):
    kw = {"header": header} if header else {}
    if toml:
        kw["toml"] = toml
    with pytest.raises(RecordingError, match=match):
        read_recording(write(tmp_path, rows, **kw))


def test_a_cell_written_nan_is_a_missing_value_said_once(tmp_path):
    rows = [f"{0.01 * k!r},{i},{k * 0.001!r},0.0,1.0,0.0,0.0" for k in range(60) for i in range(2)]
    rows[7] = rows[7].replace(",0.0,1.0,", ",nan,1.0,", 1)
    rows[9] = rows[9].replace(",0.0,1.0,", ",NaN,1.0,", 1)
    rec = read_recording(write(tmp_path, rows))
    assert np.isnan(rec.vel[3, 1, 1]) and np.isnan(rec.vel[4, 1, 1]) and np.isfinite(rec.vel[5, 1, 1])
    said = [w for w in rec.warnings if "written as nan" in w]
    assert len(said) == 1 and said[0].startswith("2 cell(s)") and "samples.csv:9: column 'vy'" in said[0]


def test_cli_bad_input_exit_2_and_import_help(tmp_path):
    rec = write(tmp_path, ["0.0,0,0,0,0,0,0", "0.0,1,0,abc,0,0,0"])
    proc = subprocess.run(coload_cmd("diagnose", str(rec), "--quiet"), capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "samples.csv:3: column 'vy'" in proc.stderr
    proc = subprocess.run(coload_cmd("import", "emps", str(tmp_path / "nope.mat"), "--out", str(tmp_path / "o")),
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 2 and "nope.mat" in proc.stderr and not (tmp_path / "o").exists()


# A cart on a rail (one agent pushing along x), written the way a lab's logger would: its own stamps
# (jittered, a gap), CRLF, a byte-order mark, an extra column, an empty cell now and then, and the y
# columns empty, absent, or zero. The plant is integrated here with scipy, independently of ident/.
M_CART, B_CART, NOISE = 12.0, 3.0, 0.002


def _cart(T: int = 1500, seed: int = 5):
    from scipy.integrate import solve_ivp

    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.006, 0.014, T))
    t = t[(t < 6.0) | (t > 6.5)] - t[0]

    def force(s):
        return 20.0 * np.sin(0.9 * s) + 6.0 * np.sin(2.3 * s + 0.4)

    sol = solve_ivp(lambda s, x: [x[1], (force(s) - B_CART * x[1]) / M_CART], (0.0, t[-1]), [0.0, 0.2],
                    t_eval=t, rtol=1e-10, atol=1e-12)
    return t, force(t), sol.y[1] + rng.normal(0.0, NOISE, t.size)


def _write_cart(tmp: Path, y: str) -> Path:
    """y: "zero" (vy, fy, tau = 0), "empty" (the columns there, their cells empty), "absent" (no such columns)."""
    t, f, v = _cart()
    header = {"absent": "t,agent,note,fx,vx", "empty": "t,agent,note,fx,vx,vy,fy,tau"}.get(y, "t,agent,note,fx,vx,vy,fy,tau")
    tail = {"absent": "", "empty": ",,,"}.get(y, ",0,0,0")
    rows = [f"{s:.6f},0,ok,{fk:.6f},{'' if k % 97 == 5 else f'{vk:.6e}'}{tail}" for k, (s, fk, vk) in enumerate(zip(t, f, v))]
    tmp.mkdir(parents=True, exist_ok=True)
    (tmp / "run.toml").write_text("n = 1\nedges = []\n")
    (tmp / "samples.csv").write_bytes(("\ufeff" + "\r\n".join([header, *rows]) + "\r\n").encode())
    return tmp


def test_one_axis_recording_reads_alike_with_its_y_columns_zero_empty_or_absent(tmp_path):
    """A rail along x: the y columns empty or left out read as the same recording as y written as 0."""
    ref = read_recording(_write_cart(tmp_path / "zero", "zero"))
    for form in ("empty", "absent"):
        rec = read_recording(_write_cart(tmp_path / form, form))
        np.testing.assert_array_equal(rec.vel, ref.vel)
        np.testing.assert_array_equal(rec.wrench, ref.wrench)
        assert any("axis y: no measurement and no force" in w for w in rec.warnings)
        assert any("tau" in w and "taken as 0" in w for w in rec.warnings)


def test_one_axis_recording_without_y_columns_is_diagnosed(tmp_path):
    """The rail's friction is named and m, b and the noise found (before: every row was dropped for its empty vy)."""
    from ident.diagnose import DiagnoseOptions, diagnose_dir

    d = diagnose_dir(_write_cart(tmp_path, "absent"),
                     options=DiagnoseOptions(candidates=("viscous_friction", "coulomb_friction", "force_bias")))
    named = {e["name"]: e["value"] for e in d.effects}
    assert list(named) == ["viscous_friction"] and not d.unexplained, d.effects
    assert d.augmented.m == pytest.approx(M_CART, rel=0.01)
    assert named["viscous_friction"] == pytest.approx(B_CART, rel=0.02)
    assert d.noise_floor["velocity"] == pytest.approx(NOISE, rel=0.15)  # jittered stamps: divided differences


def test_force_along_an_axis_no_row_measures_is_refused(tmp_path):
    d = _write_cart(tmp_path, "empty")
    text = d.joinpath("samples.csv").read_text(encoding="utf-8-sig").replace(",,,\n", ",,1.5,\n")
    d.joinpath("samples.csv").write_text(text)
    with pytest.raises(RecordingError, match="column fy applies a force along y, but no row measures the y motion"):
        read_recording(d)


def test_epoch_stamps_count_from_the_first_and_are_written_back(tmp_path):
    """A logger's Unix stamps: the model's time counts from the first stamp (at 1.7e9 s a double resolves
    0.24 us, coarser than the delay's finite difference), the recording's own clock is kept."""
    t0 = 1_700_000_000.25
    rows = [f"{t0 + 0.01 * k!r},0,{0.1 * k!r},0,1,0,0" for k in range(40)]
    (tmp_path / "in").mkdir()
    rec = read_recording(write(tmp_path / "in", rows, toml="n = 1\n"))
    assert rec.t0 == t0 and rec.t[0] == 0.0 and rec.t[-1] == pytest.approx(0.39, abs=1e-6)
    back = read_recording(write_recording(tmp_path / "out", rec))
    assert back.t0 == t0 and np.array_equal(back.t, rec.t)


@pytest.mark.long  # ~50 s: out of CI's budget; the reader's part runs in CI (test_agents_on_their_own_stamps_*)
def test_agents_logging_on_their_own_clocks_are_diagnosed(tmp_path):
    """Three robots, each logging on its own clock (no stamp shared: each row of tests/ctplant.py's 150 Hz
    recording kept for one agent only, 50 Hz each), rotational damping undeclared: named, with m, J and its
    value close (the start interpolates each agent between its own samples; ~30 s)."""
    import csv

    from ctplant import make_recording
    from ident.diagnose import DiagnoseOptions, diagnose_dir

    truth = make_recording(tmp_path, n=3, rate_hz=150, duration_s=20, sigma_v=0.01, effects=["rotational_damping"],
                           seed=4, jitter=0.2)
    rows = list(csv.reader((tmp_path / "samples.csv").open()))
    with (tmp_path / "samples.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(rows[0])
        w.writerows(r for r in rows[1:] if round(float(r[0]) * 150) % 3 == int(r[1]))
    d = diagnose_dir(tmp_path, options=DiagnoseOptions(candidates=("viscous_friction", "rotational_damping", "force_bias")))
    named = {e["name"]: e["value"] for e in d.effects}
    assert list(named) == ["rotational_damping"] and not d.unexplained, d.effects
    assert d.augmented.m == pytest.approx(truth["m"], rel=0.01)
    assert d.augmented.J == pytest.approx(truth["J"], rel=0.03)
    assert named["rotational_damping"] == pytest.approx(truth["effects"]["rotational_damping"], rel=0.05)
    assert d.noise_floor["velocity"] == pytest.approx(0.01, rel=0.1)


def test_velocities_in_mm_per_s_are_warned_about(tmp_path):
    """A logger writing mm/s: contact speeds of hundreds of "m/s"; read as written, with a warning that names
    the unit (a team pushing a load moves at walking speeds)."""
    rows = [f"{0.01 * k!r},{i},{300.0 + k},{-200.0},1,0,0" for k in range(20) for i in (0, 1)]
    rec = read_recording(write(tmp_path, rows))
    assert any("a contact speed of 319 m/s" in w and "mm/s" in w for w in rec.warnings), rec.warnings
    rows = [f"{0.01 * k!r},{i},{0.3 + 0.01 * k},-0.2,1,0,0" for k in range(20) for i in (0, 1)]
    (tmp_path / "ok").mkdir()
    assert not any("contact speed" in w for w in read_recording(write(tmp_path / "ok", rows)).warnings)
