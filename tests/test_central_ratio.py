"""The batch-fit yardstick in every run's summary (issue 3): ``centralized`` and
``distributed_over_centralized``, checked against the simulator's truth.

Runs are short quick.toml runs (n = 5, sigma = 0.1, kinematic phase only): the centralized fit of
their samples is still a real fit against the pymunk plant, and the distributed side is given known
errors by rewriting the estimates, so the ratio has an answer in closed form.
"""

from __future__ import annotations

import dataclasses
import json
import math
import subprocess
from pathlib import Path

import numpy as np
import pytest

from coload.analysis import campaign, report, yardstick
from coload.analysis.yardstick import CENTRAL_KEYS, centralized_blocks
from coload.rundir.format import AgentTable, read_run
from coload.runs.engine import run_inproc
from config.loader import load_scenario
from ident import batch_fit
from tests.conftest import coload_cmd

ROOT = Path(__file__).resolve().parents[1]
QUICK = ROOT / "config/scenarios/quick.toml"


@pytest.fixture(scope="module")
def fitted_run(tmp_path_factory):
    """A 12 s quick run (the load spins from ~5 s) with the batch fit on: (run dir, summary)."""
    out = tmp_path_factory.mktemp("central") / "run"
    summary = run_inproc(load_scenario(QUICK, ["duration=12", "record.batch_fit=true"]), out)
    return out, summary


def test_summary_carries_the_centralized_block(fitted_run):
    out, summary = fitted_run
    assert json.loads((out / "summary.json").read_text()) == json.loads(json.dumps(summary))
    c = summary["centralized"]
    assert set(c) == set(CENTRAL_KEYS)
    truth = read_run(out).truth.columns
    m_true, j_true = float(truth["mass"][0]), float(truth["inertia"][0])
    # the centralized estimate on the same data: J within its own 95 % interval of the truth, and
    # the interval itself tight (a 12 s, sigma = 0.1 recording: ~0.2 % on J, ~2 % on m)
    assert abs(c["J"] - j_true) <= c["J_ci95"] and c["J_in_ci95"] is True
    assert c["J_ci95"] / j_true < 0.01 and c["m_ci95"] / m_true < 0.05
    assert c["J_rel"] == pytest.approx(c["J"] / j_true - 1) and c["m_rel"] == pytest.approx(c["m"] / m_true - 1)
    assert abs(c["m_rel"]) < 0.05
    assert c["residual_rms"] == pytest.approx(0.1, rel=0.05)  # the noise sigma: the model fits
    assert (c["t0"], c["t1"]) == (0.0, pytest.approx(11.99))  # the whole recording
    assert c["fit_s"] > 0 and c["reason"] is None and c["flags"] == []
    # the kinematic phase alone: no distributed m or J, so no ratio, and the reason says why
    r = summary["distributed_over_centralized"]
    assert r["J"] is None and r["m"] is None and "dynamics.algorithm = none" in r["reason"]
    lines = report.centralized_lines(summary)
    assert lines[0].startswith("centralized (batch fit of all samples, 0-11.99 s")
    assert "distributed / centralized" in lines[1]


def _with_estimates(run, j_rel, m_rel):
    """The run as if agent i had ended with J (1 + j_rel[i]), m (1 + m_rel[i]) and run Algorithm 1."""
    est = run.estimates
    truth = run.truth.columns
    ti = run.truth_index(est.t)
    cols = dict(est.columns)
    cols["J"] = truth["inertia"][ti][:, None] * (1 + np.asarray(j_rel))[None, :]
    cols["m"] = truth["mass"][ti][:, None] * (1 + np.asarray(m_rel))[None, :]
    cols["J"][-1, 2] = np.nan  # agent 2 silent at the end: its last estimate counts
    config = {**run.config, "dynamics": {**run.config["dynamics"], "algorithm": "sequential"}}
    return dataclasses.replace(run, estimates=AgentTable(t=est.t, columns=cols), config=config)


def test_ratio_is_median_agent_error_over_centralized_error(fitted_run):
    out, summary = fitted_run
    j_rel = [0.004, -0.001, 0.002, -0.003, 0.010]
    m_rel = [0.02, 0.02, -0.01, 0.0, 0.05]
    blocks = centralized_blocks(_with_estimates(read_run(out), j_rel, m_rel))
    c, r = blocks["centralized"], blocks["distributed_over_centralized"]
    assert c["J"] == pytest.approx(summary["centralized"]["J"], rel=1e-12)  # the same fit
    assert r["J_dist_rel"] == pytest.approx(0.003) and r["m_dist_rel"] == pytest.approx(0.02)
    assert r["J"] == pytest.approx(0.003 / abs(c["J_rel"]))
    assert r["m"] == pytest.approx(0.02 / abs(c["m_rel"]))
    truth = read_run(out).truth.columns
    assert r["J_over_ci95"] == pytest.approx(0.003 / (c["J_ci95"] / truth["inertia"][0]))
    assert set(r) == set(yardstick.RATIO_KEYS) and r["reason"] is None


def test_a_load_that_changes_is_not_fitted(fitted_run):
    out, _ = fitted_run
    run = read_run(out)
    cols = dict(run.truth.columns)
    cols["mass"] = cols["mass"].copy()
    cols["mass"][len(cols["mass"]) // 2:] = 40.0
    blocks = centralized_blocks(dataclasses.replace(run, truth=dataclasses.replace(run.truth, columns=cols)))
    c = blocks["centralized"]
    assert c["m"] is None and c["J"] is None and "changes during the run" in c["reason"]
    assert blocks["distributed_over_centralized"]["J"] is None


def test_lab_data_without_truth_is_fitted_without_errors(fitted_run):
    out, summary = fitted_run
    blocks = centralized_blocks(dataclasses.replace(read_run(out), truth=None))
    c, r = blocks["centralized"], blocks["distributed_over_centralized"]
    assert c["J"] == pytest.approx(summary["centralized"]["J"], rel=1e-12) and c["J_ci95"] is not None
    assert c["J_rel"] is None and c["J_in_ci95"] is None and r["J"] is None
    assert "no truth" in r["reason"]


def test_a_failed_fit_gives_nulls_and_a_reason_not_a_crash(tmp_path):
    # 0.3 s = 30 ticks: too short to fit (and the load has not started to turn)
    summary = run_inproc(load_scenario(QUICK, ["duration=0.3", "record.batch_fit=true"]), tmp_path / "short")
    c = summary["centralized"]
    assert set(c) == set(CENTRAL_KEYS)
    assert c["m"] is None and c["J"] is None and c["J_rel"] is None
    assert c["reason"].startswith("batch fit failed: too short")
    assert summary["distributed_over_centralized"]["J"] is None
    assert "errors" in summary and (tmp_path / "short" / "summary.json").exists()


def test_an_unexpected_error_in_the_fit_still_leaves_the_summary(tmp_path, monkeypatch):
    def boom(run, **kw):
        raise RuntimeError("simulated bug")

    monkeypatch.setattr(yardstick, "centralized_blocks", boom)
    summary = run_inproc(load_scenario(QUICK, ["duration=1", "record.batch_fit=true"]), tmp_path / "r")
    assert summary["centralized"]["J"] is None
    assert summary["centralized"]["reason"] == "batch fit not run: RuntimeError: simulated bug"
    assert json.loads((tmp_path / "r" / "summary.json").read_text())["centralized"]["reason"].endswith("simulated bug")


def test_library_runs_leave_it_off(tmp_path):
    summary = run_inproc(load_scenario(QUICK, ["duration=1"]), tmp_path / "r")
    assert "centralized" not in summary and "distributed_over_centralized" not in summary


def test_cli_run_fits_by_default_and_no_batch_fit_omits_it(tmp_path):
    common = [str(QUICK), "--engine", "inproc", "--set", "duration=8", "--no-report", "--quiet"]
    on = subprocess.run(coload_cmd("run", *common, "--out", str(tmp_path / "on")), capture_output=True, text=True,
                        timeout=300)  # fmt: skip
    assert on.returncode == 0, on.stderr
    s_on = json.loads((tmp_path / "on" / "summary.json").read_text())
    assert s_on["centralized"]["J"] is not None
    assert "centralized (batch fit of all samples" in on.stdout  # the console summary shows it
    off = subprocess.run(coload_cmd("run", *common, "--no-batch-fit", "--out", str(tmp_path / "off")),
                         capture_output=True, text=True, timeout=300)  # fmt: skip
    assert off.returncode == 0, off.stderr
    s_off = json.loads((tmp_path / "off" / "summary.json").read_text())
    assert "centralized" not in s_off and "distributed_over_centralized" not in s_off
    assert "centralized" not in off.stdout
    assert s_off["errors"] == s_on["errors"]  # the fit is analysis only: the run is the same


def test_report_table_and_campaign_row_carry_it(fitted_run):
    out, summary = fitted_run
    run = read_run(out)
    table = report.summary_table(run, summary["errors"])
    assert "centralized (batch fit of all samples" in table
    fake = {**summary, "distributed_over_centralized": {"J": 4.5, "m": 1.25, "J_dist_rel": 0.003, "m_dist_rel": 0.002,
                                                         "J_over_ci95": 6.0, "m_over_ci95": 0.8, "reason": None}}
    planned = campaign.plan(load_scenario(QUICK, ["duration=12"]), out.parent / "camp", [5], [0.1], 1)[0]
    row = campaign.row_of(planned, fake)
    assert row["dist_over_central_J"] == 4.5 and row["dist_over_central_m"] == 1.25 and row["dist_over_ci95_J"] == 6.0
    assert row["central_J_rel"] == summary["centralized"]["J_rel"]
    assert row["central_J_in_ci95"] == 1.0
    cols = campaign.columns_of([row])
    assert set(campaign.CENTRAL_COLUMNS) <= set(cols)


def test_zenoh_run_carries_the_same_block(tmp_path):
    """One place for both engines: the simulator daemon's recorder fits the same samples to the same numbers."""
    common = [str(QUICK), "--set", "duration=8", "--no-report", "--quiet"]
    for engine in ("zenoh", "inproc"):
        proc = subprocess.run(coload_cmd("run", *common, "--engine", engine, "--out", str(tmp_path / engine)),
                              capture_output=True, text=True, timeout=300)  # fmt: skip
        assert proc.returncode == 0, proc.stderr
    z, i = (json.loads((tmp_path / e / "summary.json").read_text()) for e in ("zenoh", "inproc"))
    assert z["engine"] == "zenoh"
    # same samples bit for bit; the fit's own arithmetic may differ in the last bits with BLAS threading
    for key in ("m", "J", "m_ci95", "J_ci95", "zc_x", "zc_y", "residual_rms"):
        assert z["centralized"][key] == pytest.approx(i["centralized"][key], rel=1e-9), key
    assert z["centralized"]["J"] is not None


def _record_unstable(duration: float, k_in: float, seed: int = 5):
    """(samples, truth m, J, n, dt): the load spun up and held at ~1.5 rad/s while every agent also pushes
    its contact inward, f_i = -k_in (R(theta) r_i) in the world frame. Replayed open loop with the recorded
    world-frame forces, an error delta in theta gives a torque k_in sum |r_i|^2 sin(delta) that grows it
    (rate sqrt(k_in sum |r_i|^2 / J) ~ 0.6/s here): what made single shooting drift on paper-fig4 seed 3."""
    from simulator.plant import Plant

    sc = load_scenario(ROOT / "config/scenarios/paper-fig4.toml", ["noise.sigma_v=0.3", f"seed={seed}",
                                                                   f"duration={duration}"])  # fmt: skip
    plant = Plant(sc)
    n, dt = sc.n, sc.dt
    rng = np.random.default_rng(seed)
    T = round(duration / dt)
    out = np.empty((T, n, 5))
    for k in range(T):
        tr = plant.truth()
        v = np.asarray(plant.measure(rng))
        r = np.asarray(tr.zi)  # z_i = p_Ci - p_G: the contact points from the CoM, world frame
        sgn = 1.0 if (k * dt) % 4.0 < 2.0 else -1.0
        f = -k_in * r + sgn * 3.0 * np.array([math.cos(0.5), math.sin(0.5)])
        tau = np.clip(2.0 * (1.5 - tr.omega) + rng.normal(0, 0.5, n), -5, 5)
        out[k, :, :2], out[k, :, 2:4], out[k, :, 4] = v, f, tau
        plant.apply_and_step([(float(a), float(b), float(c)) for (a, b), c in zip(f, tau)])
    return out, plant.mass, plant.inertia, n, dt


def test_fit_does_not_drift_where_an_open_loop_replay_would():
    samples, m, J, n, dt = _record_unstable(40.0, k_in=1.0)
    fit = batch_fit.fit_recording(samples, n, dt)
    assert fit.residual_rms == pytest.approx(0.3, rel=0.03)  # the model explains the data: noise only
    assert abs(fit.J.value - J) <= 2 * fit.J.ci95 and fit.J.ci95 / J < 0.02  # (the former single-shooting stage 4: J -23 %, residual 1.7 m/s)
    assert abs(fit.m.value - m) <= 2 * fit.m.ci95 and fit.m.ci95 / m < 0.02
    assert not fit.warnings
