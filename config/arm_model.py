"""The geometry and mass of a two-link arm with uniform-rod links, which the plant (simulator/arms.py)
and the arm agents' observer (agents/arm.py) both build from a scenario's ``[arms]`` (docs/speed-observer.md)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

Array = np.ndarray


@dataclass(frozen=True)
class ArmModel:
    """Uniform-rod links: lengths l1, l2 (m), masses m1, m2 (kg); centre of mass mid-link."""

    l1: float
    l2: float
    m1: float
    m2: float

    def __post_init__(self) -> None:
        if min(self.l1, self.l2, self.m1, self.m2) <= 0:
            raise ValueError("arm link lengths and masses must be positive")

    @property
    def inertias(self) -> tuple[float, float]:
        """Link moments about their centres of mass (kg m^2)."""
        return self.m1 * self.l1**2 / 12.0, self.m2 * self.l2**2 / 12.0

    @property
    def constants(self) -> tuple[float, float, float]:
        """(c1, c2, c3) of M(q) (paper 004 eq. 56) for absolute angles."""
        i1, i2 = self.inertias
        lc1, lc2 = 0.5 * self.l1, 0.5 * self.l2
        return self.m1 * lc1**2 + i1 + self.m2 * self.l1**2, self.m2 * self.l1 * lc2, self.m2 * lc2**2 + i2

    @property
    def reach(self) -> tuple[float, float]:
        """Inner and outer radius of the workspace annulus (m)."""
        return abs(self.l1 - self.l2), self.l1 + self.l2

    def tip(self, q: Array) -> Array:
        """Contact point relative to the base (m), forward kinematics."""
        return np.array([self.l1 * math.cos(q[0]) + self.l2 * math.cos(q[1]),
                         self.l1 * math.sin(q[0]) + self.l2 * math.sin(q[1])])

    def jacobian(self, q: Array) -> Array:
        """d tip / d q (2 x 2): tip velocity = J q', generalized force of a tip force f = J^T f."""
        return np.array([[-self.l1 * math.sin(q[0]), -self.l2 * math.sin(q[1])],
                         [self.l1 * math.cos(q[0]), self.l2 * math.cos(q[1])]])

    def ik(self, p: Sequence[float], elbow: int = 1) -> Array:
        """Absolute angles that put the tip at ``p`` (relative to the base); ``elbow`` = +1 or -1 picks the branch.

        Raises ValueError outside the open workspace annulus (where the arm is singular or cannot reach).
        """
        px, py = float(p[0]), float(p[1])
        d2 = px * px + py * py
        c = (d2 - self.l1**2 - self.l2**2) / (2 * self.l1 * self.l2)
        if not -1.0 < c < 1.0:
            lo, hi = self.reach
            raise ValueError(f"point at {math.sqrt(d2):.3f} m from the base is outside the reach ({lo:.3f}, {hi:.3f}) m")
        g = math.copysign(math.acos(c), elbow)  # elbow angle q2 - q1
        q1 = math.atan2(py, px) - math.atan2(self.l2 * math.sin(g), self.l1 + self.l2 * math.cos(g))
        q1 = math.remainder(q1, 2 * math.pi)  # in [-pi, pi]: the encoders start there
        return np.array([q1, q1 + g])
