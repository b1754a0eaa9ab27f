"""Glitches (ident/glitches.py): isolated spikes found, clean data left alone."""

from __future__ import annotations

import ctplant
import numpy as np
import pytest

from ident.glitches import find_glitches


def _smooth(t: np.ndarray, rng: np.random.Generator, n: int) -> np.ndarray:
    f = rng.uniform(0.1, 2.0, (n, 2, 4))
    a = rng.uniform(0.1, 1.0, (n, 2, 4))
    p = rng.uniform(0, 6.3, (n, 2, 4))
    return (a * np.sin(2 * np.pi * f * t[:, None, None, None] + p)).sum(-1)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_spikes_are_found_on_irregular_stamps_with_a_gap(seed):
    """20 spikes of 15-40 floors among 4 agents' 2000 samples each (stamps jittered by +-30 % of the 10 ms
    interval, a 1 s gap, some empty cells; two spikes may be neighbours): every spike flagged, nothing
    else. (A spike within two samples of the gap or an end has no cubic of its own: not asked.)"""
    rng = np.random.default_rng(seed)
    t = np.sort(np.concatenate((np.arange(0, 8, 0.01), np.arange(9, 21, 0.01)))) + rng.uniform(-3e-3, 3e-3, 2000)
    sigma = 0.01
    y = _smooth(t, rng, 4) + rng.normal(0, sigma, (t.size, 4, 2))
    y[rng.uniform(size=(t.size, 4)) < 0.01] = np.nan
    k = rng.choice(np.r_[4:794, 806:1996], 20, replace=False)
    i = rng.integers(0, 4, 20)
    y[k, i, rng.integers(0, 2, 20)] += rng.choice([-1, 1], 20) * rng.uniform(15, 40, 20) * sigma
    spiked = np.zeros((t.size, 4), bool)
    spiked[k, i] = ~np.isnan(y[k, i]).any(axis=1)
    got = find_glitches(t, y, np.full(4, sigma))
    assert (got == spiked).all(), (np.argwhere(got & ~spiked), np.argwhere(spiked & ~got))


@pytest.mark.parametrize("rate", [20, 100])
def test_a_clean_recording_has_no_glitch(rate):
    """tests/ctplant.py's plant at 20 and 100 Hz (forces with pulses, low noise: the signal's own curvature
    is what a detector would take for a spike): no sample flagged."""
    tr = ctplant.make_recording(None, n=5, rate_hz=rate, duration_s=30.0, seed=7, sigma_v=0.002)
    vel = tr["vel_true"] + np.random.default_rng(1).normal(0, 0.002, tr["vel_true"].shape)
    assert not find_glitches(tr["t"], vel, np.full(5, 0.002)).any()
