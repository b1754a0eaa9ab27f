"""The centralized batch fit (ident.batch_fit) against the project's own plant.

Recordings come straight from simulator.plant.Plant (pymunk), driven by a small test controller, so
the fit is checked against the real integrator, not against a copy of its own model.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from coload.analysis.yardstick import fit_run_dir
from config.loader import load_scenario
from ident.batch_fit import (
    BatchFitError,
    FitOptions,
    fit_recording,
    samples_array,
)
from simulator.plant import Plant

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "config/scenarios/paper-fig4.toml"


def record(duration=15.0, sigma=0.0, seed=1, force=5.0, torque=True, spin=1.5):
    """(samples (T, n, 5), truth dict, n, dt): spin the load up, hold ~spin rad/s with noisy torques,
    push with a common force that flips every 2 s. The controller sees the true omega (test only)."""
    sc = load_scenario(SCENARIO, [f"noise.sigma_v={sigma}", f"seed={seed}", f"duration={duration}"])
    plant = Plant(sc)
    n, dt = sc.n, sc.dt
    rng = np.random.default_rng(seed)
    T = round(duration / dt)
    out = np.empty((T, n, 5))
    zi = np.empty((T, n, 2))
    zc = np.empty((T, 2))
    omega = np.empty(T)
    d = np.array([math.cos(0.5), math.sin(0.5)])
    for k in range(T):
        tr = plant.truth()
        zi[k], zc[k], omega[k] = tr.zi, tr.zc, tr.omega
        v = np.asarray(plant.measure(rng))
        sgn = 1.0 if (k * dt) % 4.0 < 2.0 else -1.0
        f = np.tile(sgn * force * d, (n, 1))
        tau = np.clip(2.0 * (spin - tr.omega) + rng.normal(0, 0.5, n), -5, 5) if torque else np.zeros(n)
        out[k, :, :2], out[k, :, 2:4], out[k, :, 4] = v, f, tau
        plant.apply_and_step([(float(a), float(b), float(c)) for (a, b), c in zip(f, tau)])
    truth = {"m": plant.mass, "J": plant.inertia, "zi": zi, "zc": zc, "omega": omega}
    return out, truth, n, dt


@pytest.fixture(scope="module")
def clean():
    return record()


def test_noise_free_recovers_everything(clean):
    """The fit's model is the continuous-time rigid body (ident.model), not the simulator's discrete step:
    on the simulator's noise-free data it is off by the step's O(dt) angle lag (dt = 0.01 s at ~1.5 rad/s),
    measured m 4.3e-4, J 7.4e-4, z_i 8.9 mm, z_C 2.1 mm, omega 1.4e-3 rad/s, residual 1.5e-3 m/s; bounds ~2x."""
    samples, truth, n, dt = clean
    fit = fit_recording(samples, n, dt)
    assert fit.m.identifiable and fit.J.identifiable
    assert abs(fit.m.value / truth["m"] - 1) < 1e-3
    assert abs(fit.J.value / truth["J"] - 1) < 2e-3
    assert np.abs(fit.zi - truth["zi"]).max() < 0.02
    assert np.abs(fit.zc - truth["zc"]).max() < 0.005
    assert np.abs(fit.omega - truth["omega"]).max() < 0.005
    assert fit.residual_rms < 0.003


def test_missing_measurements_are_skipped_not_zero(clean):
    samples, truth, n, dt = clean
    s = samples.copy()
    s[300:420, 3, :2] = np.nan  # agent 3 silent for 1.2 s
    s[700, :, :2] = np.nan  # a whole tick lost
    fit = fit_recording(s, n, dt)
    assert abs(fit.m.value / truth["m"] - 1) < 1e-3
    assert abs(fit.J.value / truth["J"] - 1) < 2e-3


def test_no_force_flags_mass_not_identifiable():
    samples, truth, n, dt = record(duration=12.0, sigma=0.1, force=0.0)
    fit = fit_recording(samples, n, dt)
    assert not fit.m.identifiable and math.isnan(fit.m.value)
    assert "m" in fit.m.note and any("not observable" in w for w in fit.warnings)
    assert fit.J.identifiable and abs(fit.J.value / truth["J"] - 1) < 0.02


def test_tiny_force_gives_wide_interval_and_flag():
    samples, _, n, dt = record(duration=12.0, sigma=0.3, force=0.01)
    fit = fit_recording(samples, n, dt)
    assert not fit.m.identifiable and math.isnan(fit.m.value) and "weakly excited" in fit.m.note


@pytest.mark.parametrize(
    "bad, n, dt, match",
    [
        (np.zeros((100, 10, 4)), 10, 0.01, "shape"),
        (np.zeros((100, 9, 5)), 10, 0.01, "shape"),
        (np.zeros((10, 10, 5)), 10, 0.01, "too short"),
        (np.zeros((100, 10, 5)), 10, 0.0, "dt"),
        (np.zeros((100, 10, 5)), 1, 0.01, "n must"),
        ("abc", 10, 0.01, "numeric"),
        (np.full((100, 10, 5), np.inf), 10, 0.01, "inf"),
        (np.full((100, 10, 5), np.nan), 10, 0.01, "no velocity"),
    ],
)
def test_malformed_input_raises_clear_error(bad, n, dt, match):
    with pytest.raises(BatchFitError, match=match):
        fit_recording(bad, n, dt)


def test_load_that_never_rotates_is_refused():
    samples, _, n, dt = record(duration=3.0, sigma=0.3, torque=False, force=1.0)
    with pytest.raises(BatchFitError, match="hardly rotates"):
        fit_recording(samples, n, dt)


def test_samples_array_checks_the_tick_grid():
    cols = {c: np.zeros((3, 2)) for c in ("vx", "vy", "fx", "fy", "tau")}
    arr = samples_array(np.array([0.0, 0.01, 0.03]), cols, 0.01)
    assert arr.shape == (4, 2, 5) and np.isnan(arr[2]).all()
    with pytest.raises(BatchFitError, match="tick grid"):
        samples_array(np.array([0.0, 0.015, 0.03]), cols, 0.01)
    with pytest.raises(BatchFitError, match="missing column"):
        samples_array(np.array([0.0]), {"vx": np.zeros((1, 2))}, 0.01)


def test_noisy_fit_is_accurate_and_ci_covers_truth():
    hits = 0
    for seed in (1, 2):
        samples, truth, n, dt = record(duration=10.0, sigma=0.3, seed=seed)
        fit = fit_recording(samples, n, dt)
        assert 0.27 < fit.residual_rms < 0.33
        assert abs(fit.m.value / truth["m"] - 1) < 0.02 and abs(fit.J.value / truth["J"] - 1) < 0.02
        hits += abs(fit.m.value - truth["m"]) <= fit.m.ci95
        hits += abs(fit.J.value - truth["J"]) <= fit.J.ci95
    assert hits >= 3


@pytest.mark.slow
def test_ci_coverage_over_seeds():
    """95 % intervals: over 8 seeds x 2 parameters, expect ~15 of 16 to cover; demand 13."""
    hits = 0
    for seed in range(10, 18):
        samples, truth, n, dt = record(duration=15.0, sigma=0.3, seed=seed)
        fit = fit_recording(samples, n, dt)
        hits += abs(fit.m.value - truth["m"]) <= fit.m.ci95
        hits += abs(fit.J.value - truth["J"]) <= fit.J.ci95
    assert hits >= 13


@pytest.mark.slow
def test_engine_run_dir(tmp_path):
    """A paper-fig4 recording of the real engine (its own controller), fitted from samples.csv alone."""
    from coload.rundir.format import read_run
    from coload.runs.engine import run_inproc

    run_dir = tmp_path / "run"
    run_inproc(load_scenario(SCENARIO, ["duration=40", "noise.sigma_v=0.1", "seed=4"]), run_dir)
    fit = fit_run_dir(run_dir, options=FitOptions())
    tr = read_run(run_dir).truth
    m, J = tr.columns["mass"][0], tr.columns["inertia"][0]
    assert abs(fit.m.value / m - 1) < 0.01 and abs(fit.J.value / J - 1) < 0.005
    k = np.rint(tr.t / 0.01).astype(int)
    assert np.sqrt(np.mean(np.sum((fit.zi[k] - tr.zi) ** 2, -1))) < 0.01
