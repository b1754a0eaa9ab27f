"""Innovation monitor (agents/innovation_monitor.py, docs/innovation-monitor.md): its tests hold their
level on white innovations, find structure that is there, and in closed loop its false-alarm rate on
clean runs is consistent with ``monitor_alpha`` while an undeclared viscous friction raises alarms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agents.innovation_monitor import MONITOR_NAMES, InnovationMonitor, persistence_p, score_test, window_pvalues
from coload.rundir import format as fmt
from coload.runs.engine import run_inproc
from config.loader import load_scenario
from net.vocabulary import ESTIMATE_NAMES
from tests.conftest import SCENARIOS

# quick.toml, short stages, run on after done; monitor windows of 2.5 s: ~11 windows per agent
SHORT = ['dynamics.algorithm="sequential"', "dynamics.kin_settle_s=3", "dynamics.m_excite_s=4",
         "dynamics.j_excite_s=4", "duration=40", "dynamics.monitor_window_s=2.5"]


def test_tests_hold_their_level_on_white_innovations():
    """White w, signatures known beforehand (a random walk, its sign, a sine): each p-value is uniform,
    so each test rejects at its level."""
    rng = np.random.default_rng(11)
    n, reps = 250, 1000
    ps = []
    for _ in range(reps):
        w = rng.standard_normal((n, 2))
        walk = np.cumsum(rng.standard_normal((n, 2)), axis=0)
        sig = np.stack([walk, np.sign(walk), np.sin(np.arange(n) / 20.0)[:, None] * np.ones((n, 2)),
                        rng.standard_normal((n, 2))], axis=1)
        ps.append(window_pvalues(w, sig, 10))
    ps = np.array(ps)
    for k in range(ps.shape[1]):
        for level in (0.01, 0.05):
            rate = float(np.mean(ps[:, k] < level))
            # binomial sd at 1000 draws: 0.0031 at 1 %, 0.0069 at 5 %; four sd
            assert abs(rate - level) <= 4 * math.sqrt(level * (1 - level) / reps), (k, level, rate)


def test_tests_find_structure():
    rng = np.random.default_rng(5)
    n = 500
    e = rng.standard_normal((n, 2))
    ar = np.zeros((n, 2))  # AR(1), phi = 0.3: a slowly varying residual
    for t in range(1, n):
        ar[t] = 0.3 * ar[t - 1] + e[t]
    assert persistence_p(ar, 10) < 1e-6 and persistence_p(e, 10) > 1e-3
    vc = np.cumsum(rng.standard_normal((n, 2)), axis=0) * 0.05
    assert score_test(e - 0.3 * vc, vc) < 1e-6  # a force along -v_C
    assert math.isnan(score_test(e, np.zeros((n, 2))))


def test_monitor_whitens_counts_and_resets():
    rng = np.random.default_rng(2)
    mon = InnovationMonitor(window=100, lags=5, alpha=0.01)
    assert all(math.isnan(v) for k, v in mon.entries().items() if k.startswith("mon_p"))
    L = np.array([[2.0, 0.0], [0.6, 0.5]])  # S = L L^T
    S = L @ L.T
    for t in range(250):
        x = L @ rng.standard_normal(2)
        mon.observe(complex(*x), S[0, 0], S[0, 1], S[1, 1], complex(1.0, 0.5), 1.5, complex(0.3, 0.2),
                    complex(0.0, 1.0))
    out = mon.entries()
    assert tuple(out) == MONITOR_NAMES and out["mon_windows"] == 2.0 and mon.k == 50
    assert np.allclose(np.cov(mon.w[:50].T), np.eye(2), atol=0.45)  # whitened by L^-1
    mon.reset()
    assert mon.k == 0 and mon.entries()["mon_windows"] == 2.0
    with pytest.raises(ValueError):
        InnovationMonitor(window=20, lags=10, alpha=0.01)


def test_estimate_names_hold_the_monitor_entries_in_order():
    k = ESTIMATE_NAMES.index(MONITOR_NAMES[0])
    assert ESTIMATE_NAMES[k:k + len(MONITOR_NAMES)] == MONITOR_NAMES


def _alarms(run_dir) -> tuple[int, int]:
    c = fmt.read_run(run_dir).estimates.columns
    return int(np.nansum(c["mon_alarms"][-1])), int(np.nansum(c["mon_windows"][-1]))


@pytest.mark.slow
def test_false_alarms_on_clean_runs_and_alarms_under_viscous_friction(tmp_path):
    """Two clean seeds at monitor_alpha = 0.05: alarms at most what a rate of 0.05 allows (binomial,
    P(more) < 0.001); viscous friction the agents are not told of (5 N s/m, m / b = 10 s): alarms in
    more than a quarter of the windows (~25 s on an idle machine). More seeds: bench/innovation_monitor.py."""
    alarms = windows = 0
    for seed in (7, 8):
        d = tmp_path / f"clean{seed}"
        run_inproc(load_scenario(SCENARIOS / "quick.toml", [*SHORT, f"seed={seed}", "dynamics.monitor_alpha=0.05"]), d)
        a, w = _alarms(d)
        alarms += a
        windows += w
    assert windows >= 80
    cap = next(k for k in range(windows) if _binom_sf(k, windows, 0.05) < 1e-3)
    assert alarms <= cap, (alarms, windows, cap)
    d = tmp_path / "viscous"
    summary = run_inproc(load_scenario(SCENARIOS / "quick.toml", [*SHORT, "plant.friction={viscous=5.0}"]), d)
    a, w = _alarms(d)
    assert a > 0.25 * w, (a, w)
    assert summary["monitor"]["alarms"] == a and summary["monitor"]["windows"] == w


def _binom_sf(k: int, n: int, p: float) -> float:
    """P(X > k), X ~ Binomial(n, p)."""
    return 1.0 - sum(math.comb(n, j) * p**j * (1 - p) ** (n - j) for j in range(k + 1))
