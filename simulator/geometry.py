"""Planar polygon geometry for the load: pure numpy, no pymunk, no scenario objects.

Kept apart from the plant so the same formulas serve the plant, the tests and any analysis tool,
and so that they can be checked against closed forms on their own.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


def rectangle(width: float, height: float) -> FloatArray:
    """Counter-clockwise rectangle about the origin, starting at the bottom-left corner.

    The start corner fixes what ``contacts.start = 0`` means for a rectangular load.
    """
    w, h = 0.5 * width, 0.5 * height
    return np.array([(-w, -h), (w, -h), (w, h), (-w, h)], dtype=float)


def signed_area(vertices: ArrayLike) -> float:
    """Shoelace area; positive when the outline runs counter-clockwise."""
    v = np.asarray(vertices, dtype=float)
    nxt = np.roll(v, -1, axis=0)
    return 0.5 * float(np.sum(v[:, 0] * nxt[:, 1] - nxt[:, 0] * v[:, 1]))


def centroid(vertices: ArrayLike) -> FloatArray:
    """Area centroid of a simple polygon (not the mean of its vertices)."""
    v = np.asarray(vertices, dtype=float)
    nxt = np.roll(v, -1, axis=0)
    cross = v[:, 0] * nxt[:, 1] - nxt[:, 0] * v[:, 1]
    a6 = 3.0 * np.sum(cross)  # 6 * signed area
    return np.array([np.sum((v[:, 0] + nxt[:, 0]) * cross), np.sum((v[:, 1] + nxt[:, 1]) * cross)]) / a6


def polar_moment_per_mass(vertices: ArrayLike) -> float:
    """Moment of inertia about the origin of a uniform lamina of unit mass bounded by the polygon."""
    v = np.asarray(vertices, dtype=float)
    nxt = np.roll(v, -1, axis=0)
    cross = v[:, 0] * nxt[:, 1] - nxt[:, 0] * v[:, 1]
    terms = np.sum(v * v, axis=1) + np.sum(v * nxt, axis=1) + np.sum(nxt * nxt, axis=1)
    return float(np.sum(cross * terms) / (6.0 * np.sum(cross)))


def perimeter_points(vertices: ArrayLike, n: int, start: float) -> FloatArray:
    """n points evenly spaced in arc length along the closed outline, the first at fraction ``start``.

    Arc length is measured from vertex 0 in vertex order (counter-clockwise for a CCW outline).
    """
    v = np.asarray(vertices, dtype=float)
    seg = np.roll(v, -1, axis=0) - v
    lengths = np.hypot(seg[:, 0], seg[:, 1])
    cum = np.concatenate(([0.0], np.cumsum(lengths)))
    total = cum[-1]
    s = np.mod(start + np.arange(n) / n, 1.0) * total
    k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(v) - 1)
    # Zero-length edges never get chosen by searchsorted(side="right"), so lengths[k] > 0 here.
    frac = (s - cum[k]) / lengths[k]
    return v[k] + frac[:, None] * seg[k]


def distance_to_outline(points: ArrayLike, vertices: ArrayLike) -> FloatArray:
    """Distance of each point to the nearest edge of the closed outline (for checking layouts)."""
    p = np.asarray(points, dtype=float)[:, None, :]
    a = np.asarray(vertices, dtype=float)[None, :, :]
    b = np.roll(a, -1, axis=1)
    ab = b - a
    denom = np.maximum(np.sum(ab * ab, axis=2), 1e-300)
    t = np.clip(np.sum((p - a) * ab, axis=2) / denom, 0.0, 1.0)
    d = p - (a + t[..., None] * ab)
    return np.min(np.hypot(d[..., 0], d[..., 1]), axis=1)
