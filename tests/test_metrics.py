"""Metrics against synthetic runs whose errors are known in closed form."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from coload.analysis import metrics
from coload.rundir.format import read_run
from tests.synthetic_run import SyntheticSpec, truth_of, write_run

N = 4


def _const(value, shape):
    return lambda t: np.broadcast_to(np.asarray(value, dtype=float), (len(t),) + shape).copy()


def test_exact_estimates_give_zero_errors(tmp_path):
    write_run(tmp_path, SyntheticSpec(n=N, extra_estimates=True))
    err = metrics.final_errors(read_run(tmp_path))
    for key in ("zi_rms", "zi_rms_window", "omega_rms", "eerd_final", "eerd_ratio", "eec_final",
                "J_rel", "m_rel", "zC_rms", "vC_rms"):
        assert err[key] == pytest.approx(0.0, abs=1e-12), key
    assert err["zi_err_per_agent"] == pytest.approx([0.0] * N, abs=1e-12)
    assert err["omega_rms_per_agent"] == pytest.approx([0.0] * N, abs=1e-12)
    assert err["eerd_ratio_per_agent"] == pytest.approx([0.0] * N, abs=1e-12)
    assert err["eerd_converge_s"] == 0.0  # below 1 % from the first sample on


def test_constant_zi_offset_gives_that_rms(tmp_path):
    # 0.1 m on every z_i, in a different direction per agent
    ang = np.arange(N) * 1.3
    off = 0.1 * np.stack([np.cos(ang), np.sin(ang)], axis=1)
    write_run(tmp_path, SyntheticSpec(n=N), zi_err=_const(off, (N, 2)))
    err = metrics.final_errors(read_run(tmp_path))
    assert err["zi_rms"] == pytest.approx(0.1, rel=1e-9)
    assert err["zi_rms_window"] == pytest.approx(0.1, rel=1e-9)
    assert err["zi_err_per_agent"] == pytest.approx([0.1] * N, rel=1e-9)
    assert err["eec_final"] == pytest.approx(N * 0.01, rel=1e-9)
    assert err["eerd_final"] == pytest.approx(0.0, abs=1e-12)  # pairs are exact, z_i are not


def test_half_pair_estimates_give_eerd_ratio_quarter(tmp_path):
    write_run(tmp_path, SyntheticSpec(n=N), pair_scale=lambda t: np.full(len(t), 0.5))
    run = read_run(tmp_path)
    err = metrics.final_errors(run)
    assert err["eerd_ratio"] == pytest.approx(0.25, rel=1e-9)
    assert err["eerd_ratio_per_agent"] == pytest.approx([0.25] * N, rel=1e-9)
    tr = truth_of(SyntheticSpec(n=N))
    ref = sum(np.sum((tr.zi[0, i] - tr.zi[0, i + 1]) ** 2) for i in range(N - 1))
    assert err["eerd_initial"] == pytest.approx(ref, rel=1e-9)
    assert err["eerd_final"] == pytest.approx(0.25 * ref, rel=1e-9)
    assert err["eerd_converge_s"] is None


def test_omega_offsets_per_agent(tmp_path):
    offsets = np.array([0.0, 0.01, -0.02, 0.03])
    write_run(tmp_path, SyntheticSpec(n=N), omega_err=_const(offsets, (N,)))
    err = metrics.final_errors(read_run(tmp_path), window_s=10.0)
    assert err["omega_rms_per_agent"] == pytest.approx(np.abs(offsets), abs=1e-12)
    assert err["omega_rms"] == pytest.approx(math.sqrt(np.mean(offsets**2)), rel=1e-9)
    assert err["window_s"] == 10.0


def test_window_excludes_early_errors(tmp_path):
    # a large z_i error before t = 5 s must not reach the last-20-s RMS of a 30 s run
    write_run(tmp_path, SyntheticSpec(n=N, duration=30.0),
              zi_err=lambda t: np.where(t < 5.0, 1.0, 0.0)[:, None, None] * np.ones((1, N, 2)))
    err = metrics.final_errors(read_run(tmp_path), window_s=20.0)
    assert err["zi_rms_window"] == pytest.approx(0.0, abs=1e-12)
    err_all = metrics.final_errors(read_run(tmp_path), window_s=30.0)
    assert err_all["zi_rms_window"] > 0.1


def test_dynamic_estimates_relative_errors(tmp_path):
    spec = SyntheticSpec(n=N, extra_estimates=True)
    ones = np.ones((1, N))
    write_run(tmp_path, spec, extra_err=lambda t: {
        "J": 0.02 * spec.inertia * ones.repeat(len(t), 0),
        "m": -0.05 * spec.mass * ones.repeat(len(t), 0),
        "zc_x": 0.03 * ones.repeat(len(t), 0),
        "zc_y": -0.04 * ones.repeat(len(t), 0),
        "vc_x": 0.006 * ones.repeat(len(t), 0),
        "vc_y": 0.008 * ones.repeat(len(t), 0),
    })
    err = metrics.final_errors(read_run(tmp_path))
    assert err["J_rel"] == pytest.approx(0.02, rel=1e-9)
    assert err["m_rel"] == pytest.approx(0.05, rel=1e-9)
    assert err["zC_rms"] == pytest.approx(0.05, rel=1e-9)
    assert err["vC_rms"] == pytest.approx(0.01, rel=1e-9)


def test_dynamic_keys_absent_without_columns(tmp_path):
    write_run(tmp_path, SyntheticSpec(n=N))
    err = metrics.final_errors(read_run(tmp_path))
    assert not {"J_rel", "m_rel", "zC_rms", "vC_rms"} & set(err)


def test_agent_down_at_the_end_uses_its_last_report(tmp_path):
    # agent 2 stops reporting at t = 20 s; its z_i error was 0.2 m, the others' 0
    off = np.zeros((N, 2))
    off[2] = (0.0, 0.2)
    write_run(tmp_path, SyntheticSpec(n=N, drop=((2, 20.0, 1e9),)), zi_err=_const(off, (N, 2)))
    err = metrics.final_errors(read_run(tmp_path), window_s=5.0)
    assert err["zi_err_per_agent"] == pytest.approx([0.0, 0.0, 0.2, 0.0], abs=1e-12)
    assert err["omega_rms_per_agent"][2] is None  # nothing reported in the window
    assert err["omega_rms"] == pytest.approx(0.0, abs=1e-12)
    assert err["eerd_final"] == pytest.approx(0.0, abs=1e-12)


def test_gap_in_the_middle_does_not_change_exact_results(tmp_path):
    write_run(tmp_path, SyntheticSpec(n=N, drop=((1, 5.0, 12.0), (3, 0.0, 2.0)), every=3))
    run = read_run(tmp_path)
    err = metrics.final_errors(run)
    assert err["zi_rms"] == pytest.approx(0.0, abs=1e-12)
    assert err["eerd_ratio"] == pytest.approx(0.0, abs=1e-12)
    series = metrics.error_series(run)
    # EEC is unknown while an agent is silent; EERD is still known from the other end of each edge
    gap = (series.est_t >= 5.0) & (series.est_t < 12.0)
    assert np.all(np.isnan(series.eec[gap]))
    assert np.all(np.isfinite(series.eerd))


def test_summary_block_is_strict_json(tmp_path):
    write_run(tmp_path, SyntheticSpec(n=N, drop=((2, 20.0, 1e9),), extra_estimates=True))
    err = metrics.final_errors(read_run(tmp_path), window_s=5.0)
    json.dumps(err, allow_nan=False)


# --- pure array functions -------------------------------------------------------------------------
def test_eerd_averages_the_two_ends_of_an_edge():
    times = np.array([0.0, 1.0])
    zi = np.array([[[0.0, 0.0], [1.0, 0.0]]] * 2)  # z_01 = (-1, 0)
    exact = np.array([[-1.0, 0.0]] * 2)
    off = np.array([[-1.0, 0.3]] * 2)
    nan = np.full((2, 2), np.nan)
    # agent 0 exact, agent 1 (holding z_10) off by 0.3: mean of 0 and 0.09
    assert metrics.eerd(times, zi, {(0, 1): exact, (1, 0): -off}, [(0, 1)]) == pytest.approx([0.045] * 2)
    # only one end reported: its error alone
    assert metrics.eerd(times, zi, {(0, 1): off, (1, 0): nan}, [(0, 1)]) == pytest.approx([0.09] * 2)
    assert np.all(np.isnan(metrics.eerd(times, zi, {}, [(0, 1)])))
    assert metrics.eerd_reference(zi, [(0, 1)]) == pytest.approx([1.0, 1.0])


def test_eec_and_zi_error():
    zi = np.zeros((3, 2, 2))
    est = np.zeros((3, 2, 2))
    est[:, 1] = (0.3, 0.4)
    assert metrics.zi_error(zi, est)[:, 1] == pytest.approx([0.5] * 3)
    assert metrics.eec(np.arange(3.0), zi, est) == pytest.approx([0.25] * 3)


def test_time_to_converge_exponential():
    t = np.arange(0.0, 30.0, 0.01)
    tau = 2.0
    values = 5.0 * np.exp(-t / tau)
    expected = tau * math.log(100.0)  # 9.21 s
    got = metrics.time_to_converge(t, values)
    assert got == pytest.approx(expected, abs=0.011)
    # an excursion above 1 % at 20 s pushes convergence past it
    bumped = values.copy()
    bumped[t >= 20.0] = np.where(t[t >= 20.0] < 21.0, 1.0, bumped[t >= 20.0])
    assert metrics.time_to_converge(t, bumped) == pytest.approx(21.0, abs=0.011)
    # never below: None; explicit initial value
    assert metrics.time_to_converge(t, np.full(len(t), 5.0)) is None
    assert metrics.time_to_converge(t, values, initial=1000.0) == 0.0
    assert metrics.time_to_converge(t, np.full(len(t), np.nan)) is None


def test_hold_last_and_last_finite():
    a = np.array([[np.nan, 1.0], [2.0, np.nan], [np.nan, np.nan]])
    held = metrics.hold_last(a)
    assert np.isnan(held[0, 0])
    assert held[1:, 0].tolist() == [2.0, 2.0] and held[:, 1].tolist() == [1.0, 1.0, 1.0]
    vals, idx = metrics.last_finite(a)
    assert vals.tolist() == [2.0, 1.0] and idx.tolist() == [1, 0]
    vals, idx = metrics.last_finite(np.full((2, 3), np.nan))
    assert np.all(np.isnan(vals)) and idx.tolist() == [-1, -1, -1]


@settings(max_examples=40, deadline=None)
@given(
    n=st.integers(2, 6),
    scale=st.floats(-2.0, 2.0, allow_nan=False),
    seed=st.integers(0, 2**16),
)
def test_eerd_of_scaled_estimates_is_scaled_reference(n, scale, seed):
    """Estimates (1 - s) z_ij give EERD = s^2 sum |z_ij|^2, for any graph and any numbering."""
    rng = np.random.default_rng(seed)
    zi = rng.normal(size=(5, n, 2))
    edges = [(i, j) for i in range(n) for j in range(i + 1, n) if rng.random() < 0.6] or [(0, 1)]
    est = {}
    for i, j in edges:
        est[(i, j)] = (1 - scale) * (zi[:, i] - zi[:, j])
        est[(j, i)] = (1 - scale) * (zi[:, j] - zi[:, i])
    times = np.arange(5.0)
    got = metrics.eerd(times, zi, est, edges)
    assert got == pytest.approx(scale**2 * metrics.eerd_reference(zi, edges), rel=1e-9, abs=1e-12)
    share, ref = metrics.eerd_per_agent(times, zi, est, edges, n)
    assert share.sum(axis=1) == pytest.approx(2 * got, rel=1e-9, abs=1e-12)
    assert ref.sum(axis=1) == pytest.approx(2 * metrics.eerd_reference(zi, edges), rel=1e-9)
