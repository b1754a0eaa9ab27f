"""Consensus primitives used by the agent core (one agent's update; scalars or complex numbers).

Every function is one agent's local update from its own state and its neighbours' latest states,
so that the cost depends on the number of neighbours only.

* :func:`average_step` -- static average consensus x_i += eps sum_j (x_j - x_i). With a symmetric
  graph and synchronous values, sum_i x_i is invariant (each edge term is antisymmetric).
* :func:`centroid_step` -- ref. [19] of paper 000 (Result 3): x_i += eps sum_j (x_j - x_i + e_ij)
  with an antisymmetric edge term e_ij = (z_ij - z_ji)/2 built from *both* ends' estimates, so that
  sum_i x_i stays 0 even when the two ends disagree; the fixed point is the centroid-relative
  positions z_i = p_Ci - p_G when the z_ij are exact.
* :func:`fodac_step` -- first-order input dynamic average consensus (Zhu & Martinez):
  x_i(k+1) = x_i(k) + eps sum_j (x_j - x_i) + u_i(k+1) - u_i(k); with x_i(0) = u_i(0) it keeps
  sum x = sum u exactly and tracks the average of constant inputs exactly and of ramps with a
  bounded error. It passes each agent's input noise straight through (no time averaging) and a lost
  message breaks the invariant for good, so the agent core uses :func:`lowpass_step` for omega.
* :func:`lowpass_step` -- consensus with input injection (a "low-pass consensus filter"):
  x_i += eps sum_j (x_j - x_i) + beta (u_i - x_i). At steady state (eps L + beta I) x = beta u,
  so 1^T x = 1^T u (the network average is kept, L having zero column sums), common inputs are
  tracked exactly, and the state averages over time (time constant ~ dt/beta) *and* space. Errors
  from lost or stale messages decay at rate beta instead of persisting.

eps must satisfy eps * max_degree < 1 for stability.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import TypeVar

T = TypeVar("T", float, complex)


def average_step(x_i: T, neighbours: Iterable[T], eps: float) -> T:
    """One static average-consensus update of agent i."""
    acc = 0.0
    for x_j in neighbours:
        acc += x_j - x_i
    return x_i + eps * acc


def centroid_step(x_i: complex, neighbours: Iterable[tuple[complex, complex]], eps: float) -> complex:
    """One centroid-estimation update (ref. [19]): ``neighbours`` = [(x_j, e_ij)], e_ij ~ z_ij = p_Ci - p_Cj."""
    acc = 0j
    for x_j, e_ij in neighbours:
        acc += x_j - x_i + e_ij
    return x_i + eps * acc


def fodac_step(x_i: T, neighbours: Iterable[T], eps: float, du_i: T) -> T:
    """One first-order input dynamic consensus update; du_i = u_i(k+1) - u_i(k)."""
    acc = 0.0
    for x_j in neighbours:
        acc += x_j - x_i
    return x_i + eps * acc + du_i


def lowpass_step(x_i: T, neighbours: Iterable[T], eps: float, beta: float, u_i: T | None) -> T:
    """One low-pass consensus update; ``u_i`` None means no new input this tick (consensus only)."""
    acc = 0.0
    for x_j in neighbours:
        acc += x_j - x_i
    x = x_i + eps * acc
    if u_i is not None:
        x += beta * (u_i - x_i)
    return x


# ---------------------------------------------------------------------------- network-level helpers
# Synchronous runs of the one-agent updates over a whole graph, for tests and offline analysis.


def run_average(x0: Sequence[T], nbrs: Sequence[Sequence[int]], eps: float, iters: int) -> list[T]:
    x = list(x0)
    for _ in range(iters):
        x = [average_step(x[i], (x[j] for j in nbrs[i]), eps) for i in range(len(x))]
    return x


def run_centroid(
    z: dict[tuple[int, int], complex], nbrs: Sequence[Sequence[int]], eps: float, iters: int
) -> list[complex]:
    """``z[(i, j)]`` is agent i's estimate of z_ij; the edge term is (z_ij - z_ji)/2."""
    n = len(nbrs)
    x = [0j] * n
    for _ in range(iters):
        x = [centroid_step(x[i], ((x[j], 0.5 * (z[(i, j)] - z[(j, i)])) for j in nbrs[i]), eps) for i in range(n)]
    return x
