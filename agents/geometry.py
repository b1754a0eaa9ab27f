"""Small planar-geometry helpers for the agent core.

2-vectors are Python ``complex`` numbers (x + iy): rotation is a multiplication, the paper's perp
operator q_perp = Q q = (-q_y, q_x) is multiplication by 1j, and no numpy array is allocated on the
hot path. Everything here is pure and allocation-light.

Circle fit: the rigid-body constraint |z_ij| = const (paper eq. (4)) in integral form says that the
integrated relative velocity s(t) = int (v_Ci - v_Cj) dt = z_ij(t) - z_ij(t0) lies on a circle of
radius |z_ij| centred at -z_ij(t0). The pair estimator's kernels (agents/kernels/pair.py) accumulate the
moments of those points so that the algebraic (Kasa) fit is solved at any time in O(1);
:func:`fit_circle_points` runs that fit on a list of points.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

from agents.kernels.pair import circle_add, circle_fit, pair_bank

TWO_PI = 2.0 * math.pi


def perp(q: complex) -> complex:
    """+90 degree rotation: q_perp = (-q_y, q_x) (the paper's Q; see pitfalls note)."""
    return 1j * q


def rot(q: complex, angle: float) -> complex:
    """Rotate q by ``angle`` (rad, counter-clockwise)."""
    return q * complex(math.cos(angle), math.sin(angle))


def expi(angle: float) -> complex:
    """e^{i angle}: the rotation by ``angle`` as a unit complex number."""
    return complex(math.cos(angle), math.sin(angle))


def wrap(angle: float) -> float:
    """Wrap an angle to (-pi, pi]."""
    a = math.fmod(angle + math.pi, TWO_PI)
    if a <= 0.0:
        a += TWO_PI
    return a - math.pi


def cross(a: complex, b: complex) -> float:
    """Planar cross product a x b = a_x b_y - a_y b_x = Im(conj(a) b)."""
    return a.real * b.imag - a.imag * b.real


def dot(a: complex, b: complex) -> float:
    """a . b = Re(conj(a) b)."""
    return a.real * b.real + a.imag * b.imag


def omega_from_pair(z: complex, zdot: complex) -> float:
    """Paper eq. (9) with the corrected sign: omega = -z^T zdot_perp / |z|^2 = (z x zdot) / |z|^2.

    ``z`` should be a *predicted* estimate of z_ij, not one built from the same sample's axis (that
    returns |zdot|/|d| and biases |omega| up).
    """
    n2 = z.real * z.real + z.imag * z.imag
    if n2 <= 0.0:
        return 0.0
    return (z.real * zdot.imag - z.imag * zdot.real) / n2


@dataclass(slots=True)
class CircleFit:
    """Result of an algebraic circle fit: centre (complex), radius, RMS radial residual (m)."""

    centre: complex
    radius: float
    rms: float


def fit_circle_points(points: Iterable[complex]) -> CircleFit | None:
    """Algebraic (Kasa) circle fit of the points (agents/kernels/pair.py ``circle_fit``); None when there are
    fewer than 3 or they are degenerate (tests, offline use)."""
    P, _, _ = pair_bank(1, 1, 1)
    for p in points:
        circle_add(P, 0, 0, p.real, p.imag)
    ok, cx, cy, r, rms = circle_fit(P, 0, 0)
    return CircleFit(complex(cx, cy), r, rms) if ok else None
