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
    m = [a[0][:] + [b[0]], a[1][:] + [b[1]], a[2][:] + [b[2]]]
    scale = max(abs(v) for row in a for v in row) or 1.0
    for c in range(3):
        p = max(range(c, 3), key=lambda r: abs(m[r][c]))
        if abs(m[p][c]) <= 1e-13 * scale:
            return None
        if p != c:
            m[c], m[p] = m[p], m[c]
        piv = m[c][c]
        for r in range(c + 1, 3):
            f = m[r][c] / piv
            if f != 0.0:
                for k in range(c, 4):
                    m[r][k] -= f * m[c][k]
    x2 = m[2][3] / m[2][2]
    x1 = (m[1][3] - m[1][2] * x2) / m[1][1]
    x0 = (m[0][3] - m[0][1] * x1 - m[0][2] * x2) / m[0][0]
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
        sol = solve3(
            [[self.sxx, self.sxy, self.sx], [self.sxy, self.syy, self.sy], [self.sx, self.sy, float(self.n)]],
            [-self.sxq, -self.syq, -self.sq],
        )
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
