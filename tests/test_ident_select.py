"""ident.select on recordings of an independent continuous-time plant (scipy's DOP853, smooth forces,
shares no code with simulator/): a clean recording names nothing and its residual sits at the noise
floor and is white; a hidden viscous friction is named alone with its value."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from ident.recording import recording_from_arrays
from ident.select import diagnose


def plant(rate=50.0, T=30.0, n=4, sigma=0.02, seed=1, viscous=0.0, m=50.0, J=86.89):
    rng = np.random.default_rng(seed)
    ang = np.sort(rng.uniform(0, 2 * np.pi, n))
    r = np.stack((1.5 * np.cos(ang), 1.2 * np.sin(ang)), 1) + [0.3, -0.2]
    A, W, P = rng.normal(0, 4, (n, 3, 3)), rng.uniform(0.1, 0.8, (n, 3, 3)), rng.uniform(0, 6.3, (n, 3, 3))
    A[:, 2] *= 0.5

    def wrench(t):
        return (A * np.sin(2 * np.pi * W * t + P)).sum(-1)

    def f(t, s):
        w = wrench(t)
        c, sn = np.cos(s[3]), np.sin(s[3])
        Rx, Ry = c * r[:, 0] - sn * r[:, 1], sn * r[:, 0] + c * r[:, 1]
        tq = w[:, 2].sum() + np.sum(Rx * w[:, 1] - Ry * w[:, 0])
        return [(w[:, 0].sum() - viscous * s[0]) / m, (w[:, 1].sum() - viscous * s[1]) / m, tq / J, s[2]]

    t = np.arange(0, T, 1 / rate)
    sol = solve_ivp(f, (0, T), [0.1, -0.05, 0.05, 0.0], t_eval=t, rtol=1e-10, atol=1e-12, method="DOP853")
    vx, vy, om, th = sol.y
    c, sn = np.cos(th)[:, None], np.sin(th)[:, None]
    Rx, Ry = c * r[:, 0] - sn * r[:, 1], sn * r[:, 0] + c * r[:, 1]
    vel = np.stack((vx[:, None] - om[:, None] * Ry, vy[:, None] + om[:, None] * Rx), -1)
    vel += rng.normal(0, sigma, vel.shape)
    return recording_from_arrays(t, np.stack([wrench(x) for x in t]), vel=vel, truth={"m": m, "J": J})


@pytest.mark.slow
def test_clean_recording_fits_at_the_noise_floor_and_names_nothing():
    r = diagnose(plant())
    assert r.effects == [] and not r.unexplained
    assert r.nominal.residual_over_floor < 1.2  # the discrete held-force step left ~4.5x
    assert r.nominal.whiteness_p > 0.01
    assert abs(r.nominal.m_rel_err) < 0.01 and abs(r.nominal.J_rel_err) < 0.02


@pytest.mark.slow
def test_viscous_friction_is_named_alone_with_its_value():
    r = diagnose(plant(viscous=5.0))
    assert [e["name"] for e in r.effects] == ["viscous_friction"], r.warnings
    assert abs(r.effects[0]["value"] / 5.0 - 1) < 0.15
    assert r.augmented.whiteness_p > 0.01
    for key in ("m_rel_err", "J_rel_err"):
        before, after = abs(getattr(r.nominal, key)), abs(getattr(r.augmented, key))
        assert after <= before / 3 or after < 0.01, (key, before, after)


def test_a_long_recording_is_fitted_on_runs_of_windows_spread_over_it():
    """240 windows, room for 74: runs of four consecutive windows from the first to the last, none twice."""
    from ident.prepare import RUN, spread_windows

    idx = spread_windows(240, 74)
    assert idx[0] == 0 and idx[-1] == 239 and np.all(np.diff(idx) > 0)
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
    assert all(r.size % RUN == 0 for r in runs) and 74 <= idx.size <= 74 + RUN
    assert np.array_equal(spread_windows(50, 60), np.arange(50))
