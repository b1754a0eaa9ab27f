"""ident.stats: the noise floor from the data, and the whiteness test's calibration."""

from __future__ import annotations

import numpy as np

from ident.stats import difference_noise, kinematic_noise, ljung_box


def test_ljung_box_is_calibrated_on_white_noise():
    """dof = K * lags: over 400 white 3-channel series the 5 % test rejects 5 % (binomial 99.9 % band)."""
    rng = np.random.default_rng(5)
    p = np.array([ljung_box(rng.normal(size=(300, 3)), 20)[2] for _ in range(400)])
    assert 6 <= np.sum(p < 0.05) <= 38
    assert ljung_box(np.cumsum(rng.normal(size=(300, 3)), axis=0), 20)[2] < 1e-6  # a random walk is not white


def test_ljung_box_center_removes_a_known_projection_bias():
    """White noise with its mean removed per 10-sample window is anti-correlated at lags < 10: the plain
    test over-rejects; with the projected autocorrelation (estimated on other draws) subtracted it does not."""
    rng = np.random.default_rng(7)

    def draw():
        x = rng.normal(size=(600, 1)).reshape(60, 10, 1)
        return (x - x.mean(axis=1, keepdims=True)).reshape(600, 1)

    from ident.stats import autocorrelation

    center = np.mean([autocorrelation(draw()[:, 0], 20) for _ in range(50)], axis=0)[None]
    plain = np.array([ljung_box(draw(), 20)[2] for _ in range(200)])
    fixed = np.array([ljung_box(draw(), 20, center)[2] for _ in range(200)])
    assert np.mean(plain < 0.05) > 0.5
    assert 0.0 <= np.mean(fixed < 0.05) <= 0.12


def test_difference_noise_finds_sigma_under_a_smooth_signal_with_steps():
    rng = np.random.default_rng(3)
    t = np.concatenate((np.arange(0, 30, 0.02), np.arange(31, 60, 0.02)))  # a gap at 30 s
    smooth = np.sin(0.5 * t) + 0.3 * np.cos(1.7 * t) + 0.05 * np.floor(t / 20)  # slow + steps
    for sigma in (0.001, 0.02, 0.3):
        y = smooth + rng.normal(0, sigma, t.size)
        est = difference_noise(t, y[:, None], 3)
        assert abs(est / sigma - 1) < 0.1, (sigma, est)


def test_kinematic_noise_of_a_rigid_body():
    rng = np.random.default_rng(4)
    T, n = 2000, 5
    om = np.sin(np.linspace(0, 8, T))
    z = rng.normal(size=n) + 1j * rng.normal(size=n)
    v = (0.3 + 0.1j) + 1j * om[:, None] * z[None]
    vel = np.stack((v.real, v.imag), -1) + rng.normal(0, 0.05, (T, n, 2))
    assert abs(kinematic_noise(vel) / 0.05 - 1) < 0.05


def test_ljung_box_center_from_few_draws_is_corrected_for_its_scatter():
    """A center averaged over only 5 draws carries their scatter into every autocorrelation (variance
    1 + 1/5 times a white series'): uncorrected the test over-rejects; ``center_draws`` restores the level."""
    from ident.stats import autocorrelation

    rng = np.random.default_rng(11)
    draws, trials = 5, 600
    plain, fixed = [], []
    for _ in range(trials):
        center = np.mean([autocorrelation(rng.normal(size=400), 20) for _ in range(draws)], axis=0)[None]
        x = rng.normal(size=(400, 1))
        plain.append(ljung_box(x, 20, center)[2])
        fixed.append(ljung_box(x, 20, center, center_draws=draws)[2])
    # binomial(600, 0.05): sd 0.009, so a level within 0.025 of 0.05 is a 2.8 sd band
    assert np.mean(np.array(plain) < 0.05) > 0.08
    assert abs(np.mean(np.array(fixed) < 0.05) - 0.05) < 0.025


def test_difference_noise_on_jittered_stamps_and_beside_a_constant_column():
    """A lab logger's own stamps (+-50 % jitter) under a fast ramp: divided differences keep the slope out of
    the noise; a column written as 0 (an axis not measured) does not halve the estimate."""
    rng = np.random.default_rng(4)
    t = np.cumsum(0.01 * (1 + rng.uniform(-0.5, 0.5, 4000)))
    smooth = 3.0 * np.sin(1.3 * t) + 2.0 * t
    for sigma in (0.001, 0.02):
        y = np.stack((smooth + rng.normal(0, sigma, t.size), np.zeros(t.size)), axis=1)
        est = difference_noise(t, y, 3)
        assert abs(est / sigma - 1) < 0.1, (sigma, est)


def test_difference_noise_of_agents_on_their_own_clocks():
    """Three columns, each with a value at every third stamp only (agents that log on their own clocks):
    each is taken on its own samples (on the union of stamps no run of four is complete)."""
    rng = np.random.default_rng(6)
    t = np.cumsum(0.004 * (1 + rng.uniform(-0.3, 0.3, 6000)))
    y = np.full((t.size, 3), np.nan)
    for i in range(3):
        k = np.arange(i, t.size, 3)
        y[k, i] = np.sin(0.8 * t[k] + i) + rng.normal(0, 0.01, k.size)
    assert abs(difference_noise(t, y, 3) / 0.01 - 1) < 0.1
