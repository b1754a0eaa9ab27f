"""One agent's velocity logged at a wrong scale (odometry with a wrong wheel radius): checked on the kinematics
before the diagnosis (docs/diagnose.md, "Input").

A rigid body's contact velocities are u_j = v + h d_j (v, h complex per stamp, d_j the contact's fixed
complex arm): a scale s_j on agent j's log (y_j = s_j u_j) breaks that shape, where a gain on its actuator
(the force) does not. The velocities are fitted with and without a real scale per agent (alternating least
squares); the scales pass when the nested F-test rejects the shape without them at the selection's level and,
with them, what is left is at the agents' own noise (their divided differences): a remainder still above it
is another fault (a clock off, the robots' frames), which the scales only partly take up. Scales are relative
to the team's median agent (a scale common to all is m and J's, and invisible here). Pure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy import stats as sst
from scipy.optimize import minimize

from ident import stats
from ident.recording import Recording
from ident.stats import Z95


@dataclass(frozen=True)
class ScaleCheck:
    """The kinematics' remainder without and with per-agent scales, the F-test, the remainder over the agents'
    own noise, and the scales (relative to the median agent) with their 95 % half-widths."""

    rss_one: float
    rss_scaled: float
    F: float
    p: float
    over_noise: float
    scales: np.ndarray
    ci95: np.ndarray

    def passed(self, level: float, tol: float) -> bool:
        return bool(self.p < level and self.over_noise < tol)

    def summary(self, level: float, tol: float) -> dict:
        return {"scaled": self.passed(level, tol), "rss_one": self.rss_one, "rss_scaled": self.rss_scaled,
                "F": self.F, "p": self.p, "over_noise": self.over_noise, "scales": self.scales.tolist(),
                "ci95": self.ci95.tolist()}  # fmt: skip


def _remainder(Y: np.ndarray, w: np.ndarray, s: np.ndarray) -> np.ndarray:
    """The rigid body's remainder of the velocities ``Y`` (T, n) complex, agent j's read as s_j (v + h d_j) and
    weighted by ``w_j`` (1 / its noise): the weighted columns less their part along the agents' c = s w (v's
    share) and the rank one of what is left (h's)."""
    Z = Y * w[None, :]
    c = s * w
    Z = Z - np.outer(Z @ c, c) / float(c @ c)
    U, sv, Vh = np.linalg.svd(Z, full_matrices=False)
    return Z - np.outer(U[:, 0] * sv[0], Vh[0])


def _fit(Y: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, float]:
    """The scales (median 1) that leave the least weighted remainder, from all 1 (agent 0's held at 1 in the
    search: a common scale is no scale here), and that remainder's sum of squares."""
    n = Y.shape[1]

    def cost(x: np.ndarray) -> float:
        return float(np.sum(np.abs(_remainder(Y, w, np.exp(np.r_[0.0, x]))) ** 2))

    x = minimize(cost, np.zeros(n - 1), method="BFGS").x
    s = np.exp(np.r_[0.0, x])
    return s / float(np.median(s)), cost(x)


def scale_check(rec: Recording) -> ScaleCheck | None:
    """The check on a velocity recording of n >= 3 agents (rows with every agent); None where it cannot be made
    (fewer than 100 such rows)."""
    if rec.vel is None or rec.n < 3:
        return None
    Y = rec.vel[..., 0] + 1j * rec.vel[..., 1]
    ok = ~np.isnan(Y).any(axis=1)
    if ok.sum() < 100:
        return None
    Y = Y[ok]
    T, n = Y.shape
    own = np.array([stats.difference_noise(rec.t[ok], rec.vel[ok, j], 3) for j in range(n)])
    if not (np.isfinite(own).all() and (own > 0).all()):
        return None
    w = 1.0 / own
    rss1 = float(np.sum(np.abs(_remainder(Y, w, np.ones(n))) ** 2))
    s, rss2 = _fit(Y, w)
    N = 2 * T * n
    P = 4 * T + 2 * n  # v, h per row; the arms
    q = n - 1
    F = ((rss1 - rss2) / q) / (rss2 / (N - P - q))
    p = float(sst.f.sf(F, q, N - P - q))
    over = math.sqrt(rss2 / (N - P - q))  # the weights are the agents' own noise: 1 at it
    # each scale's spread from the remainder's curvature in it (the others at their fit), by finite differences
    h = 1e-4
    ci = np.zeros(n)
    for j in range(n):
        e = np.zeros(n)
        e[j] = h
        c2 = (np.sum(np.abs(_remainder(Y, w, s * np.exp(e))) ** 2) - 2 * rss2
              + np.sum(np.abs(_remainder(Y, w, s * np.exp(-e))) ** 2)) / h**2  # fmt: skip
        ci[j] = Z95 * s[j] * math.sqrt(2.0 * rss2 / (N - P - q) / c2) if c2 > 0 else math.inf
    return ScaleCheck(rss1, rss2, float(F), p, over, s, ci)


def agents_off(sc: ScaleCheck, level: float) -> list[int]:
    """The agents whose scale differs from 1 at the family-wise ``level`` (two-sided, Bonferroni over them)."""
    z = float(sst.norm.isf(level / (2 * sc.scales.size))) / Z95
    return [j for j in range(sc.scales.size) if abs(sc.scales[j] - 1.0) > z * sc.ci95[j]]


def rescaled(rec: Recording, sc: ScaleCheck, off: list[int]) -> Recording:
    """``rec`` with the velocities of the agents ``off`` divided by their scales."""
    k = np.ones(rec.n)
    k[off] = sc.scales[off]
    return replace(rec, vel=rec.vel / k[None, :, None])


__all__ = ["ScaleCheck", "agents_off", "rescaled", "scale_check"]
