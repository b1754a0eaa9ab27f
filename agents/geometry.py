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


def _elim(r: list[float], c: int, piv_row: list[float], piv: float) -> None:
    """Row r -= (r[c] / piv) * pivot row, for columns c..3 (skipped when the factor is 0)."""
    f = r[c] / piv
    if f != 0.0:
        for k in range(c, 4):
            r[k] -= f * piv_row[k]


def _solve3(
    a00: float, a01: float, a02: float, b0: float,
    a10: float, a11: float, a12: float, b1: float,
    a20: float, a21: float, a22: float, b2: float,
) -> tuple[float, float, float] | None:
    """:func:`solve3` on scalars (the circle fit's hot path): the same operations in the same order,
    without the nested lists, generator and key lambdas of the generic loop."""
    scale = max(abs(a00), abs(a01), abs(a02), abs(a10), abs(a11), abs(a12), abs(a20), abs(a21), abs(a22)) or 1.0
    tol = 1e-13 * scale
    m = [[a00, a01, a02, b0], [a10, a11, a12, b1], [a20, a21, a22, b2]]
    for c in range(3):
        # partial pivoting: the first row with the largest |m[r][c]| (max() semantics)
        p = c
        best = abs(m[c][c])
        for r in range(c + 1, 3):
            v = abs(m[r][c])
            if v > best:
                p = r
                best = v
        if best <= tol:
            return None
        if p != c:
            m[c], m[p] = m[p], m[c]
        row = m[c]
        piv = row[c]
        for r in range(c + 1, 3):
            _elim(m[r], c, row, piv)
    r0, r1, r2 = m
    x2 = r2[3] / r2[2]
    x1 = (r1[3] - r1[2] * x2) / r1[1]
    x0 = (r0[3] - r0[1] * x1 - r0[2] * x2) / r0[0]
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
