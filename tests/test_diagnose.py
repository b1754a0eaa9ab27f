"""``coload diagnose`` on recordings the tests generate with effects the diagnosis is not told about.

Every recording comes from the in-process engine (the agents' own control, quick.toml: n = 5,
sigma = 0.1 m/s, 30 s, a 3 N common force per agent flipped every 4 s); the effect sits in the
scenario's [plant] section, which reaches neither the agents nor the diagnosis (it reads
samples.csv and run.toml only; truth.csv only for the error report).
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

from config.loader import load_scenario
from ident.diagnose import (
    CANDIDATES,
    DiagnoseError,
    diagnose_dir,
    format_diagnosis,
    ljung_box,
    read_recording,
)
from tests.conftest import coload_cmd

ROOT = Path(__file__).resolve().parents[1]
BASE = ["duration=30", "control.force=3", "seed=2"]

# effect -> (scenario override, truth value of the named effect)
EFFECTS = {
    "viscous_friction": ("plant.friction.viscous=5.0", 5.0),  # m/b = 10 s
    "coulomb_friction": ("plant.friction.coulomb=2.0", 2.0),
    "rotational_damping": ("plant.friction.rotational=8.0", 8.0),  # J/c = 11 s
    "measurement_delay": ("plant.sensor.delay=0.1", 0.1),
    "force_bias": ("plant.external_force=[0.5, -0.3]", (0.5, -0.3)),  # a slope of ~0.07 degrees
}


def record(path: Path, *overrides: str) -> Path:
    from coload.runs.engine import run_inproc

    run_inproc(load_scenario(ROOT / "config/scenarios/quick.toml", [*BASE, *overrides]), path)
    return path


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    base = tmp_path_factory.mktemp("recordings")
    cache: dict[str, Path] = {}

    def get(name: str, *overrides: str) -> Path:
        if name not in cache:
            cache[name] = record(base / name, *overrides)
        return cache[name]

    return get


def rel(a, b) -> float:
    return float(np.max(np.abs(np.asarray(a, float) - b) / np.abs(b)))


@pytest.mark.parametrize("effect", list(EFFECTS))
def test_single_effect_is_named_alone_with_its_value(recordings, effect):
    override, truth = EFFECTS[effect]
    r = diagnose_dir(recordings(effect, override))
    assert [e["name"] for e in r.effects] == [effect], r.warnings
    assert not r.unexplained
    assert rel(r.effects[0]["value"], truth) < 0.15
    assert r.augmented.whiteness_p > 0.01 and r.nominal.whiteness_p < 0.01
    for key in ("m_rel_err", "J_rel_err"):
        before, after = abs(getattr(r.nominal, key)), abs(getattr(r.augmented, key))
        assert after <= before / 3 or after < 0.01, (key, before, after)
    assert r.augmented.heldout_rms <= r.nominal.heldout_rms


def test_clean_recording_names_nothing_and_cli_writes_the_schema(recordings, tmp_path):
    rec = recordings("nominal")
    out = tmp_path / "d.json"
    proc = subprocess.run(coload_cmd("diagnose", str(rec), "--json", str(out), "--plot"), capture_output=True,
                          text=True, timeout=600)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "nominal model" in proc.stderr  # progress
    d = json.loads(out.read_text())
    for key in ("nominal", "augmented"):
        assert {"m", "J", "residual_rms", "whiteness_p"} <= d[key].keys()
    assert d["effects"] == [] and d["unexplained"] is False and isinstance(d["warnings"], list)
    assert abs(d["nominal"]["m_rel_err"]) < 0.01 and abs(d["nominal"]["J_rel_err"]) < 0.01
    assert d["nominal"]["whiteness_p"] > 0.01
    assert (rec / "diagnose.png").stat().st_size > 10_000


def test_velocity_bias_is_reported_as_not_identifiable(recordings):
    """A common velocity bias is exactly an initial velocity for the nominal model: say so, name nothing."""
    r = diagnose_dir(recordings("bias", "plant.sensor.velocity_bias=[0.05, -0.03]"))
    assert r.effects == [] and not r.unexplained
    assert any(w.startswith("velocity_bias: not identifiable") for w in r.warnings)
    assert abs(r.nominal.m_rel_err) < 0.01 and abs(r.nominal.J_rel_err) < 0.01


def test_a_load_that_changes_mid_run_is_found_and_each_side_diagnosed(recordings):
    """m 50 -> 40 kg and J 86.89 -> 70 kg m^2 at 15 s of 30 (no effect): one model over the whole run leaves
    a structured residual; the change is found in the two windows around 15 s, and each side, diagnosed
    as a recording of its own, has its own m and J (within 1.5 times their 95 % half-widths: 0.5-2.5 %
    with 12.5 s on each side) and a white residual."""
    r = diagnose_dir(recordings("change", "plant.load_changes=[{t = 15.0, mass = 40.0, inertia = 70.0}]"))
    assert r.nominal.whiteness_p < 0.01 and r.effects == []
    ch = r.change
    assert ch["found"] and not r.unexplained and ch["window"][0] <= 15.0 <= ch["window"][1]
    assert ch["window"][1] - ch["window"][0] <= 2 * r.model["window_s"] + 1e-9
    for side, m, J in (("before", 50.0, 86.89), ("after", 40.0, 70.0)):
        d = ch[side]
        assert abs(d["m"] - m) <= 1.5 * d["m_ci95"] and abs(d["J"] - J) <= 1.5 * d["J_ci95"], (side, d)
        assert d["m"] == pytest.approx(m, rel=0.03) and d["J"] == pytest.approx(J, rel=0.03), (side, d)
        assert d["effects"] == [] and d["whiteness_p"] > 0.01
    assert "the load changes between" in format_diagnosis(r)


def test_a_change_is_located_where_the_window_scores_break():
    """The break statistic on synthetic per-window scores of two parameters (known truth): the parameters
    step at window 12 of 20, the scores are the information times the step from the whole-run estimate
    plus white noise of that information: the largest statistic is at the step; without a step the
    statistic at a fixed boundary is chi2 with 2 dof (mean 2 over 400 draws, +-4 standard errors)."""
    from ident.change import break_statistic

    rng = np.random.default_rng(7)
    S, k0 = 20, 12
    info = 50 * np.array([a @ a.T + 0.5 * np.eye(2) for a in rng.normal(size=(S, 2, 2))])
    theta = np.where(np.arange(S)[:, None] < k0, [1.0, -0.5], [1.4, -0.2])  # the parameters per window

    def scores(th):
        est = np.linalg.solve(info.sum(0), np.einsum("sij,sj->i", info, th))  # the whole run's fit
        noise = np.array([np.linalg.cholesky(i) @ rng.normal(size=2) for i in info])
        return np.einsum("sij,sj->si", info, th - est) + noise

    lm = break_statistic(scores(theta), info, 1.0)
    assert int(np.nanargmax(lm)) == k0
    null = [break_statistic(scores(np.zeros((S, 2))), info, 1.0)[7] for _ in range(400)]
    assert abs(np.mean(null) - 2.0) < 4 * 2.0 / np.sqrt(400)


def test_effect_names_and_units_are_the_documented_vocabulary():
    assert {k: v[1] for k, v in CANDIDATES.items()} == {
        "viscous_friction": "N s/m", "anisotropic_friction": "N s/m", "coulomb_friction": "N",
        "rotational_damping": "N m s", "measurement_delay": "s", "force_sensor_lag": "s", "force_sensor_lowpass": "s",
        "force_bias": "N", "torque_bias": "N m", "velocity_bias": "m/s",
        "agent_actuator_gain": "-", "agent_clock_offset": "s", "force_sensor_offset": "N",
        "sensor_offset_body": "N, N, N m",
    }  # fmt: skip


def test_ljung_box_is_calibrated_on_white_noise():
    """dof = K * lags: over 400 white 3-channel series the 5 % test rejects 5 % (binomial 99.9 % band)."""
    rng = np.random.default_rng(5)
    p = np.array([ljung_box(rng.normal(size=(300, 3)), 20)[2] for _ in range(400)])
    assert 6 <= np.sum(p < 0.05) <= 38
    assert ljung_box(np.cumsum(rng.normal(size=(300, 3)), axis=0), 20)[2] < 1e-6  # a random walk is not white


# --- bad input ------------------------------------------------------------------------------------
def write(tmp: Path, rows: list[str], header="t,agent,vx,vy,fx,fy,tau", n=2) -> Path:
    (tmp / "run.toml").write_text(f"n = {n}\ndt = 0.01\nedges = [[0, 1]]\n")
    (tmp / "samples.csv").write_text("\n".join([header, *rows]) + "\n")
    return tmp


@pytest.mark.parametrize("header, rows, match", [
    ("t,agent,vx,vy,fx,tau", ["0.0,0,0,0,0,0"], r"samples.csv:1: header lacks column\(s\) fy"),
    (None, ["0.0,0,0,0,0,0,0", "0.0,1,0,abc,0,0,0"], r"samples.csv:3: column 'vy': 'abc' is not a number"),
    (None, ["0.0,0,0,0,0,0,0", "0.0,7,0,0,0,0,0"], r"samples.csv:3: column 'agent': agent 7 out of range 0..1"),
])  # fmt: skip
def test_bad_input_names_file_line_and_column(tmp_path, header, rows, match):
    rec = write(tmp_path, rows, **({"header": header} if header else {}))
    with pytest.raises(DiagnoseError, match=match):
        read_recording(rec)


def test_cli_reports_bad_input_with_exit_code_2(tmp_path):
    rec = write(tmp_path, ["0.0,0,0,0,0,0,0", "0.0,1,0,abc,0,0,0"])
    proc = subprocess.run(coload_cmd("diagnose", str(rec), "--quiet"), capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "samples.csv:3: column 'vy'" in proc.stderr


def test_missing_run_toml_key_is_named(tmp_path):
    """n is the one required key of a recording's run.toml (dt and edges are optional: the stamps say when)."""
    (tmp_path / "run.toml").write_text("dt = 0.01\nedges = [[0, 1]]\n")
    (tmp_path / "samples.csv").write_text("t,agent,vx,vy,fx,fy,tau\n")
    with pytest.raises(DiagnoseError, match=r"run.toml: field 'n': expected a positive integer"):
        read_recording(tmp_path)


def test_too_short_recording_is_refused(tmp_path):
    rows = [f"{k * 0.01!r},{i},0.1,0.0,0,0,0" for k in range(10) for i in range(2)]
    with pytest.raises(DiagnoseError, match="too short"):
        diagnose_dir(write(tmp_path, rows))
