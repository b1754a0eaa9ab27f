"""Velocities that are differences of noisy positions: detected from the kinematics, whitened in the fit."""

from __future__ import annotations

import ctplant
import numpy as np

from ident.fit import decorrelate
from ident.stats import kinematic_lag1


def test_decorrelate_whitens_differenced_white_noise():
    """(n_k - n_(k-1)) / sqrt(2) over windows of 40 stamps (5000 windows): after the forward substitution its
    covariance is the identity within the sampling error (5000 draws: ~0.02 on each entry, 0.08 allowed)."""
    rng = np.random.default_rng(11)
    n = rng.normal(size=(5000, 41, 1, 2))
    e = np.diff(n, axis=1) / np.sqrt(2.0)
    x = decorrelate(e, -0.5)[..., 0, 0]
    cov = x.T @ x / x.shape[0]
    assert np.abs(cov - np.eye(40)).max() < 0.08
    raw = e[..., 0, 0].T @ e[..., 0, 0] / e.shape[0]
    assert abs(np.diag(raw, 1).mean() + 0.5) < 0.02  # what it was before


def test_kinematic_lag1_tells_differenced_velocities_from_sensed_ones():
    """tests/ctplant.py's plant (n = 4, 100 Hz): velocity sensors with white noise read ~0, velocities made
    of encoder positions (0.1 mm) differenced over each sample read ~-1/2 (threshold in the diagnosis: -0.4)."""
    tr = ctplant.make_recording(None, n=4, rate_hz=100, duration_s=10.0, seed=5, sigma_v=0.0, positions=True,
                                sigma_p=0.0)  # fmt: skip
    rng = np.random.default_rng(6)
    sensed = tr["vel_true"] + rng.normal(0, 0.01, tr["vel_true"].shape)
    pos = tr["pos_true"] + rng.normal(0, 1e-4, tr["pos_true"].shape)
    diffed = np.diff(pos, axis=0) / np.diff(tr["t"])[:, None, None]
    assert abs(kinematic_lag1(sensed)) < 0.05
    assert abs(kinematic_lag1(diffed) + 0.5) < 0.05
