"""The random force's walk (ident/random_force.py) on synthetic walks seen through white noise."""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import minimize_scalar

from ident.random_force import _local_level, walk_form


def _walks(rng: np.random.Generator, rows: int, L: int, dt: float, q: float) -> np.ndarray:
    return np.cumsum(rng.normal(0.0, math.sqrt(q * dt), (rows, L)), axis=1)


def test_local_level_recovers_the_walk_diffusion():
    """Ten windows of 125 stamps (a 25 s recording at 50 Hz), walk variance per window about the white
    noise's: over 30 draws the maximum-likelihood q has its median within 15 % of the truth and 90 % of
    draws within a factor 2 (200 draws of this setting: median 0.97, 5-95 % 0.52-1.50)."""
    rng = np.random.default_rng(3)
    S, L, dt, q, R = 10, 125, 0.02, 0.08, 0.25
    Rm = np.full((S, L), R)
    dts = np.full((S, L), dt)
    dts[:, 0] = 0.0
    est = []
    for _ in range(30):
        y = _walks(rng, S, L, dt, q) + rng.normal(0.0, math.sqrt(R), (S, L))
        y -= y.mean(axis=1, keepdims=True)  # the fit's free start state takes each window's level
        res = minimize_scalar(lambda u: _local_level(y, Rm, dts, math.exp(u))[0], bounds=(-20, 5), method="bounded")
        est.append(math.exp(res.x) / q)
    est = np.array(est)
    assert 0.85 < np.median(est) < 1.15, est
    assert np.mean((est > 0.5) & (est < 2.0)) >= 0.9, est


def test_local_level_white_noise_alone_prefers_no_walk():
    """Without a walk the likelihood ratio of the fitted q against 0 is small (below chi2(1)'s 99.8 %
    quantile, 9.5, the level the diagnosis uses at alpha 1e-3) in at least 27 of 30 draws."""
    rng = np.random.default_rng(4)
    S, L, R = 10, 125, 0.25
    Rm = np.full((S, L), R)
    dts = np.full((S, L), 0.02)
    dts[:, 0] = 0.0
    small = 0
    for _ in range(30):
        y = rng.normal(0.0, math.sqrt(R), (S, L))
        nll0 = _local_level(y, Rm, dts, 0.0)[0]
        res = minimize_scalar(lambda u: _local_level(y, Rm, dts, math.exp(u))[0], bounds=(-20, 5), method="bounded")
        small += 2 * (nll0 - res.fun) < 9.5
    assert small >= 27


def test_walk_form_is_the_covariance_of_weighted_walks():
    """sum_l P_l W(t_l) over 4000 simulated unit walks: its sample covariance matches the closed form
    within the sampling error (4000 draws: ~2.2 % standard error on a variance, 5 x that allowed)."""
    rng = np.random.default_rng(5)
    R_, L, k = 3, 30, 2
    dt = rng.uniform(0.01, 0.03, (R_, L))
    dt[:, 0] = 0.0
    P = rng.normal(size=(R_, L, k))
    steps = rng.normal(size=(4000, R_, L)) * np.sqrt(dt)
    W = np.cumsum(steps, axis=2)
    x = np.einsum("drl,rlk->dk", W, P)
    emp = np.cov(x.T)
    want = walk_form(P, dt)
    assert np.allclose(emp, want, rtol=0.11, atol=0.11 * np.sqrt(np.outer(np.diag(want), np.diag(want))).max())
