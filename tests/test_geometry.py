"""Geometry helpers: perp, rotation, wrap, eq. (9), 3x3 solve and the algebraic circle fit."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from agents.geometry import (
    cross,
    dot,
    fit_circle_points,
    omega_from_pair,
    perp,
    rot,
    wrap,
)
from agents.kernels.pair import solve3

fin = st.floats(-100, 100, allow_nan=False)
ang = st.floats(-20, 20, allow_nan=False)


def test_perp_is_plus_90_degrees() -> None:
    assert perp(1 + 0j) == 1j  # x axis -> y axis
    assert perp(0 + 1j) == -1 + 0j  # (-q_y, q_x)
    assert perp(complex(2.0, 3.0)) == complex(-3.0, 2.0)


@given(fin, fin, ang)
def test_rotation_preserves_norm_and_composes(x: float, y: float, a: float) -> None:
    q = complex(x, y)
    assert math.isclose(abs(rot(q, a)), abs(q), rel_tol=1e-12, abs_tol=1e-12)
    assert abs(rot(rot(q, a), -a) - q) <= 1e-9 * (1 + abs(q))
    assert abs(rot(q, math.pi / 2) - perp(q)) <= 1e-12 * (1 + abs(q))


@given(ang)
def test_wrap_range_and_equivalence(a: float) -> None:
    w = wrap(a)
    assert -math.pi < w <= math.pi
    assert abs(math.sin(w) - math.sin(a)) < 1e-9 and abs(math.cos(w) - math.cos(a)) < 1e-9


@given(fin, fin, fin, fin)
def test_cross_dot_match_numpy(ax: float, ay: float, bx: float, by: float) -> None:
    a, b = complex(ax, ay), complex(bx, by)
    assert math.isclose(cross(a, b), float(np.cross([ax, ay, 0.0], [bx, by, 0.0])[2]), rel_tol=1e-9, abs_tol=1e-6)
    assert math.isclose(dot(a, b), ax * bx + ay * by, rel_tol=1e-9, abs_tol=1e-6)


@given(st.floats(0.05, 10), ang, st.floats(-5, 5))
def test_eq9_with_corrected_sign_recovers_omega(r: float, a: float, omega: float) -> None:
    z = r * complex(math.cos(a), math.sin(a))
    zdot = 1j * omega * z  # rigid rotation: zdot = omega * perp(z)
    assert math.isclose(omega_from_pair(z, zdot), omega, rel_tol=1e-9, abs_tol=1e-9)
    # the paper's form: omega = -z^T zdot_perp / |z|^2
    zp = perp(zdot)
    assert math.isclose(-(z.real * zp.real + z.imag * zp.imag) / r**2, omega, rel_tol=1e-9, abs_tol=1e-9)


def test_eq9_zero_vector_is_zero() -> None:
    assert omega_from_pair(0j, 1 + 1j) == 0.0


@settings(deadline=None)  # the first call loads the compiled kernel
@given(st.lists(st.floats(-10, 10), min_size=9, max_size=9), st.lists(st.floats(-10, 10), min_size=3, max_size=3))
def test_solve3_against_numpy(a: list[float], b: list[float]) -> None:
    m = np.array(a).reshape(3, 3)
    if abs(np.linalg.det(m)) < 1e-3 or np.linalg.cond(m) > 1e6:
        return
    ok, *x = solve3(*m[0], b[0], *m[1], b[1], *m[2], b[2])
    assert ok
    assert np.allclose(m @ np.array(x), b, atol=1e-6)


def test_solve3_singular() -> None:
    assert not solve3(1.0, 2.0, 3.0, 1.0, 2.0, 4.0, 6.0, 2.0, 0.0, 0.0, 1.0, 3.0)[0]


@settings(max_examples=50, deadline=None)  # the first call loads the compiled kernels
@given(st.floats(-5, 5), st.floats(-5, 5), st.floats(0.1, 5), st.floats(-3, 3), st.floats(0.8, 6.28))
def test_circle_fit_exact_on_noise_free_arcs(cx: float, cy: float, r: float, a0: float, span: float) -> None:
    pts = [complex(cx, cy) + r * complex(math.cos(a0 + span * k / 50), math.sin(a0 + span * k / 50)) for k in range(51)]
    fit = fit_circle_points(pts)
    assert fit is not None
    assert abs(fit.centre - complex(cx, cy)) < 1e-6 * (1 + r)
    assert math.isclose(fit.radius, r, rel_tol=1e-6)
    assert fit.rms < 1e-4 * (1 + r + abs(cx) + abs(cy))  # moment expansion: cancellation-limited


def test_circle_fit_with_integrated_noise_is_nearly_unbiased() -> None:
    """The integral form: points = z(t) - z(0) + random walk; the radius bias stays well below 1 %."""
    rng = np.random.default_rng(1)
    r, omega, dt, sigma = 1.2, 1.5, 0.01, 0.3
    radii = []
    for _ in range(40):
        t = np.arange(420) * dt
        z = r * np.exp(1j * (omega * t + rng.uniform(0, 6.3)))
        noise = rng.normal(size=t.size) + 1j * rng.normal(size=t.size)
        w = 1j * omega * z + sigma * math.sqrt(2) * noise / math.sqrt(2)
        s = np.concatenate([[0], np.cumsum(0.5 * dt * (w[1:] + w[:-1]))])
        fit = fit_circle_points(complex(p) for p in s)
        assert fit is not None
        radii.append(fit.radius)
        # the fitted centre gives z(t) with its sign: z(t_end) = s(t_end) - centre
        assert abs((s[-1] - fit.centre) - z[-1]) < 0.25
    assert abs(np.mean(radii) / r - 1) < 0.01


def test_circle_fit_degenerate() -> None:
    assert fit_circle_points([0j, 1 + 0j]) is None
    assert fit_circle_points([0j, 1 + 0j, 2 + 0j, 3 + 0j]) is None  # collinear
