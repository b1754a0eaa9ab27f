"""Consensus primitives (agents/consensus.py) and the paper's (agents/paper_observers.py): average
preservation, centroid estimation (ref. [19]), dynamic consensus."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from agents.consensus import average_step, lowpass_step
from agents.paper_observers import centroid_step, fodac_step, run_average, run_centroid


def _random_connected_graph(rng: np.random.Generator, n: int, extra: int) -> list[list[int]]:
    """A random spanning tree plus ``extra`` random edges."""
    edges = set()
    order = rng.permutation(n)
    for k in range(1, n):
        a, b = int(order[k]), int(order[rng.integers(0, k)])
        edges.add((min(a, b), max(a, b)))
    for _ in range(extra):
        a, b = (int(v) for v in rng.choice(n, 2, replace=False))
        edges.add((min(a, b), max(a, b)))
    nb: list[list[int]] = [[] for _ in range(n)]
    for a, b in edges:
        nb[a].append(b)
        nb[b].append(a)
    return nb


def _eps(nbrs: list[list[int]]) -> float:
    return 0.9 / (max(len(x) for x in nbrs) + 1)


@settings(max_examples=15, deadline=None)
@given(st.integers(2, 12), st.integers(0, 10), st.integers(0, 2**31 - 1))
def test_average_consensus_preserves_average_and_converges(n: int, extra: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    nbrs = _random_connected_graph(rng, n, extra)
    x0 = rng.normal(size=n).tolist()
    x = run_average(x0, nbrs, _eps(nbrs), 1)
    assert abs(sum(x) - sum(x0)) < 1e-9
    x = run_average(x0, nbrs, _eps(nbrs), 6000)
    assert abs(sum(x) - sum(x0)) < 1e-8
    assert max(abs(v - np.mean(x0)) for v in x) < 1e-6


def test_average_step_complex() -> None:
    assert average_step(1 + 1j, [3 + 1j, -1 + 1j], 0.25) == 1 + 1j


@settings(max_examples=15, deadline=None)
@given(st.integers(2, 12), st.integers(0, 10), st.integers(0, 2**31 - 1))
def test_centroid_iteration_converges_to_centroid_relative_positions(n: int, extra: int, seed: int) -> None:
    """Exact z_ij on a random connected graph: x_i -> z_i = p_i - mean(p), and sum x_i = 0 throughout."""
    rng = np.random.default_rng(seed)
    nbrs = _random_connected_graph(rng, n, extra)
    p = rng.normal(size=n) + 1j * rng.normal(size=n)
    z = {(i, j): complex(p[i] - p[j]) for i in range(n) for j in nbrs[i]}
    eps = _eps(nbrs)
    x = [0j] * n
    for _ in range(30):
        x = [centroid_step(x[i], ((x[j], 0.5 * (z[(i, j)] - z[(j, i)])) for j in nbrs[i]), eps) for i in range(n)]
        assert abs(sum(x)) < 1e-9
    x = run_centroid(z, nbrs, eps, 6000)
    assert abs(sum(x)) < 1e-8
    assert max(abs(x[i] - (p[i] - p.mean())) for i in range(n)) < 1e-6


@settings(max_examples=10, deadline=None)
@given(st.integers(3, 10), st.integers(0, 2**31 - 1))
def test_centroid_sum_stays_zero_with_inconsistent_pair_estimates(n: int, seed: int) -> None:
    """Both ends' estimates differ (noise): the antisymmetric edge term keeps sum x_i = 0."""
    rng = np.random.default_rng(seed)
    nbrs = _random_connected_graph(rng, n, 3)
    z = {(i, j): complex(rng.normal(), rng.normal()) for i in range(n) for j in nbrs[i]}
    x = run_centroid(z, nbrs, _eps(nbrs), 500)
    assert abs(sum(x)) < 1e-9


def _run_fodac(u_of_k, nbrs: list[list[int]], eps: float, ticks: int) -> tuple[np.ndarray, np.ndarray]:
    n = len(nbrs)
    u_prev = u_of_k(0)
    x = list(u_prev)
    for k in range(1, ticks):
        u = u_of_k(k)
        x = [fodac_step(x[i], (x[j] for j in nbrs[i]), eps, u[i] - u_prev[i]) for i in range(n)]
        u_prev = u
    return np.array(x), np.array(u_prev)


@settings(max_examples=10, deadline=None)
@given(st.integers(2, 10), st.integers(0, 2**31 - 1))
def test_dynamic_consensus_tracks_average_of_constant_inputs(n: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    nbrs = _random_connected_graph(rng, n, 2)
    u0 = rng.normal(size=n)
    x, u = _run_fodac(lambda k: u0, nbrs, _eps(nbrs), 6000)
    assert np.allclose(x, u0.mean(), atol=1e-6)
    assert abs(x.sum() - u.sum()) < 1e-9


@settings(max_examples=10, deadline=None)
@given(st.integers(2, 10), st.integers(0, 2**31 - 1))
def test_dynamic_consensus_tracks_average_of_ramps_with_bounded_error(n: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    nbrs = _random_connected_graph(rng, n, 2)
    u0 = rng.normal(size=n)
    slope = rng.normal(size=n) * 1e-3
    ticks = 6000
    x, u = _run_fodac(lambda k: u0 + slope * k, nbrs, _eps(nbrs), ticks)
    assert abs(x.sum() - u.sum()) < 1e-7  # the sum is tracked exactly
    # steady-state error of a ramp: bounded by the slope spread over the algebraic connectivity
    lap = np.zeros((n, n))
    for i in range(n):
        for j in nbrs[i]:
            lap[i, j] -= 1
            lap[i, i] += 1
    lam2 = np.sort(np.linalg.eigvalsh(lap))[1]
    bound = np.abs(slope - slope.mean()).max() * np.sqrt(n) / (_eps(nbrs) * lam2) + 1e-9
    assert np.abs(x - u.mean()).max() <= bound
    # a common ramp is tracked exactly
    x2, u2 = _run_fodac(lambda k: u0 + 1e-3 * k, nbrs, _eps(nbrs), ticks)
    assert np.allclose(x2, u2.mean(), atol=1e-6)


@settings(max_examples=10, deadline=None)
@given(st.integers(2, 10), st.integers(0, 2**31 - 1))
def test_lowpass_consensus_keeps_the_average_and_tracks_common_input(n: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    nbrs = _random_connected_graph(rng, n, 2)
    eps, beta = _eps(nbrs), 0.02
    u = rng.normal(size=n)
    x = [0.0] * n
    for _ in range(6000):
        x = [lowpass_step(x[i], [x[j] for j in nbrs[i]], eps, beta, float(u[i])) for i in range(n)]
    assert abs(np.mean(x) - u.mean()) < 1e-9  # (eps L + beta I) x = beta u  =>  1'x = 1'u
    x = [0.0] * n
    for _ in range(5000):
        x = [lowpass_step(x[i], [x[j] for j in nbrs[i]], eps, beta, 1.5) for i in range(n)]
    assert np.allclose(x, 1.5, atol=1e-9)
    # no input this tick: plain consensus
    assert lowpass_step(1.0, [3.0], 0.5, 0.1, None) == 2.0


def test_lowpass_averages_noise_in_time_and_space() -> None:
    rng = np.random.default_rng(3)
    n = 10
    nbrs = [[j for j in (i - 1, i + 1) if 0 <= j < n] for i in range(n)]
    x = [0.0] * n
    errs = []
    for k in range(6000):
        u = 1.0 + 0.35 * rng.normal(size=n)
        x = [lowpass_step(x[i], [x[j] for j in nbrs[i]], 0.3, 0.02, float(u[i])) for i in range(n)]
        if k > 1000:
            errs.extend(v - 1.0 for v in x)
    assert abs(np.mean(errs)) < 0.01
    assert np.std(errs) < 0.35 * 0.1 / 1.5  # far below a single sample's noise
