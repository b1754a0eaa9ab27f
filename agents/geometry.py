"""Small planar-geometry helpers for the agent core.

2-vectors are Python ``complex`` numbers (x + iy): rotation is a multiplication, the paper's perp
operator q_perp = Q q = (-q_y, q_x) is multiplication by 1j, and no numpy array is allocated on the
hot path. Everything here is pure and allocation-light.

Circle fit: the rigid-body constraint |z_ij| = const (paper eq. (4)) in integral form says that the
integrated relative velocity s(t) = int (v_Ci - v_Cj) dt = z_ij(t) - z_ij(t0) lies on a circle of
radius |z_ij| centred at -z_ij(t0). :class:`CircleSums` accumulates the moments of those points so
that the algebraic (Kasa) fit can be solved at any time in O(1) without storing the points.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

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


def solve3(a: list[list[float]], b: list[float]) -> tuple[float, float, float] | None:
    """Solve a 3x3 linear system by Gaussian elimination with partial pivoting (None if singular)."""
    return _solve3(a[0][0], a[0][1], a[0][2], b[0], a[1][0], a[1][1], a[1][2], b[1], a[2][0], a[2][1], a[2][2], b[2])


def _solve3(
    a00: float, a01: float, a02: float, b0: float,
    a10: float, a11: float, a12: float, b1: float,
    a20: float, a21: float, a22: float, b2: float,
) -> tuple[float, float, float] | None:
    """Gaussian elimination with partial pivoting on scalars, unrolled (the circle fit's hot path).

    The operations and their order are those of the textbook loop (pivot = the first row with the
    largest |entry|, a row is only updated when its factor is non-zero), so results are bit for bit
    those of the loop; entries below the pivot are not written since nothing reads them again.
    """
    scale = max(abs(a00), abs(a01), abs(a02), abs(a10), abs(a11), abs(a12), abs(a20), abs(a21), abs(a22)) or 1.0
    tol = 1e-13 * scale
    # column 0
    p = 0
    best = abs(a00)
    v = abs(a10)
    if v > best:
        p = 1
        best = v
    v = abs(a20)
    if v > best:
        p = 2
        best = v
    if best <= tol:
        return None
    if p == 1:
        a00, a01, a02, b0, a10, a11, a12, b1 = a10, a11, a12, b1, a00, a01, a02, b0
    elif p == 2:
        a00, a01, a02, b0, a20, a21, a22, b2 = a20, a21, a22, b2, a00, a01, a02, b0
    f = a10 / a00
    if f != 0.0:
        a11 -= f * a01
        a12 -= f * a02
        b1 -= f * b0
    f = a20 / a00
    if f != 0.0:
        a21 -= f * a01
        a22 -= f * a02
        b2 -= f * b0
    # column 1
    if abs(a21) > abs(a11):
        if abs(a21) <= tol:
            return None
        a11, a12, b1, a21, a22, b2 = a21, a22, b2, a11, a12, b1
    elif abs(a11) <= tol:
        return None
    f = a21 / a11
    if f != 0.0:
        a22 -= f * a12
        b2 -= f * b1
    # column 2
    if abs(a22) <= tol:
        return None
    x2 = b2 / a22
    x1 = (b1 - a12 * x2) / a11
    x0 = (b0 - a01 * x1 - a02 * x2) / a00
    return x0, x1, x2


@dataclass(slots=True)
class CircleFit:
    """Result of an algebraic circle fit: centre (complex), radius, RMS radial residual (m)."""

    centre: complex
    radius: float
    rms: float


class CircleSums:
    """Running moments of 2-D points for the algebraic (Kasa) circle fit.

    Minimises sum (x^2 + y^2 + D x + E y + F)^2, which is linear in (D, E, F); centre = -(D, E)/2,
    r^2 = (D^2 + E^2)/4 - F. With points spread over a large arc and small noise this is close to the
    geometric fit; the callers only accept windows covering a large arc.
    """

    __slots__ = ("n", "sx", "sy", "sxx", "sxy", "syy", "sxq", "syq", "sq", "sqq")

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.n = 0
        self.sx = self.sy = self.sxx = self.sxy = self.syy = 0.0
        self.sxq = self.syq = self.sq = self.sqq = 0.0

    def add(self, p: complex) -> None:
        x = p.real
        y = p.imag
        q = x * x + y * y
        self.n += 1
        self.sx += x
        self.sy += y
        self.sxx += x * x
        self.sxy += x * y
        self.syy += y * y
        self.sxq += x * q
        self.syq += y * q
        self.sq += q
        self.sqq += q * q

    def extend(self, points: Sequence[complex], start: int = 0) -> None:
        """``add`` every point of ``points[start:]`` in order (the same sums, bit for bit; locals are faster)."""
        n, sx, sy, sxx, sxy, syy = self.n, self.sx, self.sy, self.sxx, self.sxy, self.syy
        sxq, syq, sq, sqq = self.sxq, self.syq, self.sq, self.sqq
        for p in points[start:] if start else points:
            x = p.real
            y = p.imag
            q = x * x + y * y
            n += 1
            sx += x
            sy += y
            sxx += x * x
            sxy += x * y
            syy += y * y
            sxq += x * q
            syq += y * q
            sq += q
            sqq += q * q
        self.n, self.sx, self.sy, self.sxx, self.sxy, self.syy = n, sx, sy, sxx, sxy, syy
        self.sxq, self.syq, self.sq, self.sqq = sxq, syq, sq, sqq

    def fit(self) -> CircleFit | None:
        """Solve the Kasa normal equations; None when there are too few points or they are degenerate."""
        if self.n < 3:
            return None
        sol = _solve3(
            self.sxx, self.sxy, self.sx, -self.sxq,
            self.sxy, self.syy, self.sy, -self.syq,
            self.sx, self.sy, float(self.n), -self.sq,
        )  # fmt: skip
        if sol is None:
            return None
        d, e, f = sol
        r2 = 0.25 * (d * d + e * e) - f
        if not r2 > 0.0:
            return None
        # Mean squared algebraic residual, expanded from the moments:
        # sum (q + D x + E y + F)^2 / n; the algebraic residual is about 2 r * radial residual.
        res = (
            self.sqq
            + d * d * self.sxx
            + e * e * self.syy
            + f * f * self.n
            + 2.0 * d * self.sxq
            + 2.0 * e * self.syq
            + 2.0 * f * self.sq
            + 2.0 * d * e * self.sxy
            + 2.0 * d * f * self.sx
            + 2.0 * e * f * self.sy
        ) / self.n
        r = math.sqrt(r2)
        rms = math.sqrt(max(res, 0.0)) / (2.0 * r)
        return CircleFit(complex(-0.5 * d, -0.5 * e), r, rms)


def fit_circle_points(points: list[complex]) -> CircleFit | None:
    """Convenience: Kasa fit of a list of points (tests, offline use)."""
    s = CircleSums()
    for p in points:
        s.add(p)
    return s.fit()
