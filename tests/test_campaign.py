"""``coload campaign``: the grid's geometry, and a runner that resumes without redoing finished runs."""

from __future__ import annotations

import csv
import json
import math
import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from coload.analysis import campaign as cp
from coload.analysis import metrics
from coload.cli import main as cli_main
from coload.rundir.format import read_run
from config.loader import load_scenario, scenario_from_dict
from simulator.plant import Plant, contact_points_body, load_inertia, load_polygon_body
from tests.conftest import coload_cmd
from tests.synthetic_run import SyntheticSpec, write_run

FIG4 = cp.DEFAULT_BASE


@pytest.fixture(scope="module")
def fig4():
    return load_scenario(FIG4)


def _arc_positions(scenario) -> np.ndarray:
    """Where each contact sits along the load's outline (arc length from its first vertex, m)."""
    outline = np.asarray(load_polygon_body(scenario))
    c = np.asarray(contact_points_body(scenario))
    pos = []
    start = 0.0
    edges = [(outline[k], outline[(k + 1) % len(outline)]) for k in range(len(outline))]
    for p in c:
        start = 0.0
        for a, b in edges:
            length = float(np.hypot(*(b - a)))
            t = float(np.dot(p - a, b - a)) / length**2
            if -1e-12 <= t <= 1 + 1e-12 and np.hypot(*(a + t * (b - a) - p)) < 1e-9:
                pos.append(start + t * length)
                break
            start += length
        else:
            raise AssertionError(f"contact {p} is not on the outline")
    return np.array(pos)


# --- geometry -----------------------------------------------------------------------------------


@settings(max_examples=25, deadline=None)
@given(n=st.integers(min_value=2, max_value=40), sigma=st.floats(min_value=0.0, max_value=2.0))
def test_spacing_mass_and_inertia_scale_with_the_team(fig4, n, sigma):
    scn = cp.campaign_scenario(fig4, n, sigma, seed=3)
    g = cp.geometry(scn)
    assert g["spacing"] == pytest.approx(1.24, rel=1e-12)  # paper-fig4's 12.4 m / 10
    assert scn.load.mass == pytest.approx(5.0 * n)
    s = n / 10
    assert (scn.load.width, scn.load.height) == pytest.approx((4.0 * s, 2.2 * s))
    assert scn.load.com_offset == pytest.approx((0.3 * s, -0.2 * s))
    # J = m L^2 scaling of paper-fig4's J; the plant simulates exactly that
    assert load_inertia(scn) == pytest.approx(86.89 * s**3, rel=1e-12)
    truth = Plant(scn).truth()
    assert (truth.mass, truth.inertia) == pytest.approx((5.0 * n, 86.89 * s**3), rel=1e-12)
    # same spin-up for every n: the team's torque over J does not depend on n
    assert n * scn.control.spin_torque / load_inertia(scn) == pytest.approx(10 * 3.0 / 86.89, rel=1e-12)
    assert n * scn.control.k_omega / load_inertia(scn) == pytest.approx(10 * 3.0 / 86.89, rel=1e-12)
    assert n * scn.dynamics.dither_torque / load_inertia(scn) == pytest.approx(
        10 * fig4.dynamics.dither_torque / 86.89, rel=1e-12)
    # the background observers' walks of 1/J and 1/m stay the same relative to 1/J and 1/m
    assert scn.dynamics.iota_walk * load_inertia(scn) == pytest.approx(fig4.dynamics.iota_walk * 86.89, rel=1e-12)
    assert scn.dynamics.mu_walk * scn.load.mass == pytest.approx(fig4.dynamics.mu_walk * 50.0, rel=1e-12)
    assert scn.graph.topology == "line" and scn.n == n and scn.seed == 3
    assert scn.noise.sigma_v == sigma


def test_contacts_equally_spaced_on_the_outline(fig4):
    for n in cp.PAPER_N:
        scn = cp.campaign_scenario(fig4, n, 0.3, seed=0)
        arc = _arc_positions(scn)
        perimeter = 1.24 * n
        gaps = np.mod(np.diff(np.concatenate([arc, arc[:1]])), perimeter)
        assert gaps == pytest.approx(np.full(n, 1.24), rel=1e-9)


def test_inertia_is_the_uniform_lamina_when_the_base_leaves_it_unset(fig4):
    data = fig4.model_dump(mode="python", exclude_none=True)
    del data["load"]["inertia"]
    base = scenario_from_dict(data)
    for n in (5, 13, 20):
        scn = cp.campaign_scenario(base, n, 0.3, seed=0)
        w, h = scn.load.width, scn.load.height
        ox, oy = scn.load.com_offset
        lamina = scn.load.mass * ((w * w + h * h) / 12.0 + ox * ox + oy * oy)  # about the offset CoM
        assert load_inertia(scn) == pytest.approx(lamina, rel=1e-12)


def test_the_n10_cell_is_paper_fig4(fig4):
    scn = cp.campaign_scenario(fig4, 10, fig4.noise.sigma_v, fig4.seed)
    assert scn.model_dump(exclude={"name"}) == fig4.model_dump(exclude={"name"})


def test_seeds_are_distinct_and_do_not_depend_on_the_grid_subset(fig4, tmp_path):
    full = cp.plan(fig4, tmp_path, cp.PAPER_N, cp.PAPER_SIGMA, 3, seed0=7)
    seeds = [r.seed for r in full]
    assert len(set(seeds)) == len(seeds) == 6 * 10 * 3
    sub = cp.plan(fig4, tmp_path, [11], [0.3], 3, seed0=7)
    assert [r.seed for r in sub] == [r.seed for r in full if r.n == 11 and r.sigma == 0.3]
    assert {r.seed for r in cp.plan(fig4, tmp_path, [11], [0.3], 3, seed0=8)}.isdisjoint(seeds)


def test_explicit_contacts_cannot_follow_n(fig4):
    data = fig4.model_dump(mode="python", exclude_none=True)
    data["contacts"] = {"layout": "explicit", "points": [(0.1 * i, 0.0) for i in range(fig4.n)]}
    with pytest.raises(ValueError, match="perimeter"):
        cp.campaign_scenario(scenario_from_dict(data), 5, 0.3, 0)


# --- the runner ---------------------------------------------------------------------------------

GRID = {"ns": [4, 6], "sigmas": [0.1], "runs_per_cell": 1}


def _base(duration: float = 15.0):
    """paper-fig4's kinematic phase alone: cheap, and no J or m columns to fill."""
    return load_scenario(FIG4, [f"duration={duration}", 'dynamics.algorithm="none"'])


def _read_rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _without(row: dict, keys: tuple[str, ...]) -> dict:
    return {k: v for k, v in row.items() if k not in keys}


def test_campaign_table_plots_and_resume(tmp_path):
    out = tmp_path / "camp"
    runs = cp.plan(_base(), out, seed0=1, **GRID)
    res = cp.run_campaign(runs, out, jobs=2, keep_data=True)
    assert (res.planned, res.reused, res.ran, res.failed) == (2, 0, 2, [])

    rows = _read_rows(out / cp.CSV_NAME)
    assert [(int(r["n"]), float(r["sigma"]), int(r["run"]), int(r["seed"])) for r in rows] == \
        [(r.n, r.sigma, r.k, r.seed) for r in runs]
    for row, run in zip(rows, runs, strict=True):
        summary = json.loads((run.run_dir / "summary.json").read_text())
        truth = read_run(run.run_dir).truth.columns
        # the table states the load the simulator pushed
        assert float(row["mass"]) == pytest.approx(truth["mass"][0]) == pytest.approx(5.0 * run.n)
        assert float(row["inertia"]) == pytest.approx(truth["inertia"][0])
        for key in ("zi_rms", "omega_rms", "eerd_ratio"):
            assert float(row[key]) == summary["errors"][key]
        assert row["J_rel"] == row["m_local_rel"] == ""  # not estimated yet: empty, not missing
        # the runs are real: after 15 s at sigma = 0.1 the relative positions are known within 1 %
        assert float(row["eerd_ratio"]) < 0.01
        assert float(row["zi_rel"]) < 0.1
    assert (out / cp.PLOT_NAME).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not (out / cp.CONSENSUS_PLOT_NAME).exists()  # no J_local/m_local in these runs

    # resume: nothing is redone
    mtimes = {r.run_dir.name: (r.run_dir / "summary.json").stat().st_mtime_ns for r in runs}
    res2 = cp.run_campaign(runs, out, jobs=2)
    assert (res2.reused, res2.ran) == (2, 0)
    assert {r.run_dir.name: (r.run_dir / "summary.json").stat().st_mtime_ns for r in runs} == mtimes
    assert _read_rows(out / cp.CSV_NAME) == rows

    # a run killed while writing its summary, and one killed mid-run, are redone; the table is whole
    a, b = runs
    (a.run_dir / "summary.json").write_text((a.run_dir / "summary.json").read_text()[:100])
    (b.run_dir / "summary.json").unlink()
    res3 = cp.run_campaign(runs, out, jobs=2)
    assert (res3.reused, res3.ran, res3.failed) == (0, 2, [])
    timings = ("wall_s", "agent_step_us")
    assert [_without(r, timings) for r in _read_rows(out / cp.CSV_NAME)] == [_without(r, timings) for r in rows]
    assert not (a.run_dir / "samples.csv").exists()  # bulk tables dropped by default

    # a run directory of another setting (here: another duration) is redone, not mistaken for finished
    longer = cp.plan(_base(duration=16.0), out, seed0=1, **GRID)
    res4 = cp.run_campaign(longer[:1], out, jobs=1, plots=False)
    assert (res4.reused, res4.ran) == (0, 1)
    # ... and the table still has the run this invocation did not plan (a subset never shrinks it)
    after = _read_rows(out / cp.CSV_NAME)
    assert [r["n"] for r in after] == [r["n"] for r in rows] and len(res4.rows) == 2
    assert _without(after[1], timings) == _without(rows[1], timings)  # the unplanned run, unchanged


def test_cli_killed_campaign_leaves_a_valid_table_and_resumes(tmp_path):
    out = tmp_path / "camp"
    sigmas = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6]  # ~0.5 s of work each: the kill lands mid-campaign
    argv = coload_cmd("campaign", "--out", str(out), "--n", "4", "--sigma", ",".join(map(str, sigmas)),
                      "--runs-per-cell", "1", "--duration", "30", "--jobs", "1", "--quiet")
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    table = out / cp.CSV_NAME
    try:
        deadline = time.monotonic() + 60
        while not (table.exists() and len(_read_rows(table)) >= 1):
            assert proc.poll() is None, "campaign ended before it could be interrupted"
            assert time.monotonic() < deadline, "no run finished within 60 s"
            time.sleep(0.02)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    killed_rows = _read_rows(table)  # parses: the table is replaced atomically
    assert 1 <= len(killed_rows) < len(sigmas)
    done = subprocess.run(argv, check=False, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    rows = _read_rows(table)
    assert [float(r["sigma"]) for r in rows] == sigmas
    assert all(r in rows for r in killed_rows)  # finished runs were kept as they were
    assert f"{len(killed_rows)} finished before" in done.stdout
    # the wall time of the whole grid adds up over both invocations (the killed one up to its last run)
    wall, ran, segments = cp.logged_wall(out / cp.LOG_NAME)
    assert (ran, segments) == (len(sigmas), 2)
    assert wall > 0 and f"over every invocation on {out}: {len(sigmas)} runs" in done.stdout


def test_plots_draw_the_consensus_figure_when_local_estimates_exist(tmp_path):
    rng = np.random.default_rng(0)
    rows = [
        {"n": n, "sigma": s, "run": k, "zi_rel": abs(rng.normal(0.02, 0.01)), "J_local_rel": abs(rng.normal(0.05)),
         "J_rel": abs(rng.normal(0.01)), "m_local_rel": abs(rng.normal(0.03)), "m_rel": abs(rng.normal(0.005)),
         "omega_rms": -1.0 if k == 0 else 0.1}  # a non-positive value: linear axis, still drawn
        for n in (5, 8) for s in (0.1, 0.5) for k in range(4)
    ]
    paths = cp.plot_campaign(rows, tmp_path)
    assert paths == [tmp_path / cp.PLOT_NAME, tmp_path / cp.CONSENSUS_PLOT_NAME]
    assert all(p.stat().st_size > 10_000 for p in paths)
    table = cp.cell_table(rows)
    assert "J_local_rel" in table and len(table.splitlines()) == 2 + 4


def test_local_relative_errors_in_the_summary(tmp_path):
    """J_local_rel / m_local_rel: RMS over agents of each agent's own (pre-consensus) relative error."""
    spec = SyntheticSpec(n=4, extra_estimates=True)
    write_run(tmp_path, spec)
    path = tmp_path / "estimates.csv"
    with open(path, newline="") as f:
        table = list(csv.reader(f))
    local_err = {0: 0.01, 1: -0.02, 2: 0.03, 3: -0.04}
    table[0] += ["J_local", "m_local"]
    for row in table[1:]:
        e = local_err[int(row[1])]
        row += [repr(spec.inertia * (1 + e)), repr(spec.mass * (1 - e))]
    with open(path, "w", newline="") as f:
        csv.writer(f).writerows(table)
    err = metrics.final_errors(read_run(tmp_path))
    rms = math.sqrt(np.mean(np.square(list(local_err.values()))))
    assert err["J_local_rel"] == pytest.approx(rms, rel=1e-9)
    assert err["m_local_rel"] == pytest.approx(rms, rel=1e-9)
    assert err["J_local_rel_per_agent"] == pytest.approx(list(local_err.values()), rel=1e-9)
    assert err["J_rel"] == pytest.approx(0.0, abs=1e-12)  # the consensus estimates are exact here


def test_a_run_logged_by_a_killed_invocation_and_redone_counts_once(tmp_path):
    """A kill after a run's log line and before its files land: the next invocation redoes and logs it
    again; both segments' time counts, the run once."""
    log = tmp_path / cp.LOG_NAME
    log.write_text("".join(json.dumps(rec) + "\n" for rec in (
        {"segment": "a", "run": "r0", "elapsed_s": 5.0},
        {"segment": "a", "run": "r1", "elapsed_s": 9.0},
        {"segment": "b", "run": "r1", "elapsed_s": 4.5},
        {"segment": "b", "run": "r2", "elapsed_s": 8.0})) + '{"segment": "b", "ru', encoding="utf-8")
    assert cp.logged_wall(log) == (17.0, 3, 2)


def test_cli_rejects_a_bad_grid(tmp_path, capsys):
    assert cli_main(["campaign", "--out", str(tmp_path), "--n", "5,x"]) == 2
    assert "--n" in capsys.readouterr().err
    assert cli_main(["campaign", "--out", str(tmp_path), "--sigma", "0.1,0.1"]) == 2
    assert "repeat" in capsys.readouterr().err
    assert cli_main(["campaign", "--out", str(tmp_path), "--runs-per-cell", "0"]) == 2


def test_cli_plan_prints_the_geometry(tmp_path, capsys):
    assert cli_main(["campaign", "--out", str(tmp_path), "--plan"]) == 0
    text = capsys.readouterr().out
    assert "| 20 | 8.00 x 4.40 |" in text and "3000 runs" in text
    assert not (tmp_path / cp.CSV_NAME).exists()


def test_table_of_a_campaign_directory_without_running(tmp_path, capsys):
    """``--table``: the grid as sigma x n tables of what OUT holds (median and p90 over the runs of a
    cell), runs lacking J or m named and counted in their cell, the logged wall time; nothing run."""
    rows = [{"n": n, "sigma": s, "run": k, "J_rel": 0.001 * (k + 1) * n, "m_rel": 0.002, "finished_s": 80.0 + k}
            for n in (5, 8) for s in (0.1, 0.9) for k in range(5)]
    del rows[-1]["J_rel"]  # n8-s0.9-r4: its agents never estimated J
    cp.write_csv(tmp_path / cp.CSV_NAME, rows)
    (tmp_path / cp.LOG_NAME).write_text("".join(
        json.dumps({"segment": seg, "run": f"{seg}{k}", "elapsed_s": 10.0 * (k + 1)}) + "\n"
        for seg in ("a", "b") for k in range(3)), encoding="utf-8")
    assert cli_main(["campaign", "--out", str(tmp_path), "--table"]) == 0
    text = capsys.readouterr().out
    j_median = text.split("RE of J (%), median:")[1].split("\n\n")[1]
    # n = 5: J_rel = 0.005 (k + 1), median over k = 0..4 is 0.015 -> 1.50 %; n = 8 at sigma 0.9 has 4 runs
    assert "| 0.1 | 1.50 | 2.40 |" in j_median
    assert "| 0.9 | 1.50 | 2.00 (1 n/a) |" in j_median
    assert "p90" not in j_median and "RE of J (%), 90th percentile:" in text
    assert "1 run(s) without an estimate of J or m: n8-s0.9-r4" in text
    assert "6 runs in 60 s wall over 2 invocation(s)" in text
    assert "20 finished runs in 4 cells (5 per cell)" in text
    assert (tmp_path / cp.PLOT_NAME).exists() and not (tmp_path / cp.RUNS_DIR).exists()


def test_table_names_the_line_and_column_of_a_bad_value(tmp_path, capsys):
    assert cli_main(["campaign", "--out", str(tmp_path), "--table"]) == 2
    assert "no such file" in capsys.readouterr().err
    (tmp_path / cp.CSV_NAME).write_text("n,sigma,run,J_rel\n5,0.1,0,0.01\n5,0.1,1,abc\n", encoding="utf-8")
    assert cli_main(["campaign", "--out", str(tmp_path), "--table"]) == 2
    err = capsys.readouterr().err
    assert "line 3, column J_rel: expected a number, got 'abc'" in err
    (tmp_path / cp.CSV_NAME).write_text("n,run,J_rel\n5,0,0.01\n", encoding="utf-8")
    assert cli_main(["campaign", "--out", str(tmp_path), "--table"]) == 2
    assert "line 1: the header lacks the column(s) sigma" in capsys.readouterr().err


def test_algorithm_1_fills_the_dynamic_columns_and_the_consensus_figure(tmp_path):
    """With the dynamical phase (paper-fig4's Algorithm 1) the table carries J and m before and after
    the averaging consensus and the time the team finished; the Fig. 8-like figure is drawn."""
    base = load_scenario(FIG4, ["duration=90", "stop_after_done_s=2"])
    runs = cp.plan(base, tmp_path, [5], [0.3], 1, seed0=2)
    res = cp.run_campaign(runs, tmp_path, jobs=1)
    assert res.failed == []
    (row,) = _read_rows(tmp_path / cp.CSV_NAME)
    summary = json.loads((runs[0].run_dir / "summary.json").read_text())
    for key in ("J_rel", "m_rel", "J_local_rel", "m_local_rel"):
        assert float(row[key]) == summary["errors"][key]
        assert float(row[key]) < 0.05, key  # loose: the estimator's own tests hold the tight targets
    assert 0 < float(row["finished_s"]) < 90
    # the run ended 2 s after the team was done (the recorded grid is 0.1 s)
    assert float(row["t_final"]) == pytest.approx(float(row["finished_s"]) + 2.0, abs=0.11)
    assert (tmp_path / cp.CONSENSUS_PLOT_NAME).stat().st_size > 10_000
