"""The consensus updates the agent runs: one agent's update from its own state and its neighbours'.

* :func:`average_step` -- x_i + eps sum_j (x_j - x_i): the body-frame angle phi; with per-edge weights
  (:func:`weighted_average_step`) the dynamical phase's body-frame angle psi.
* :func:`lowpass_step` -- x_i + eps sum_j (x_j - x_i) + beta (u_i - x_i): omega_hat (a low-pass
  consensus filter: it averages the per-tick noise over time and over the graph).
* :func:`flow_step` -- one edge of flow-updating average consensus, F_ij = (F_ij - F_ji)/2 + eps d_ij:
  the centroid iteration (z_i) and every channel of :class:`FlowAverage` (the dynamical phase).

Scalars, complex numbers or numpy arrays alike. Why these forms: docs/agent-step.md.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import TypeVar

T = TypeVar("T", float, complex)


def disagreement(x_i: T, neighbours: Iterable[T]) -> T:
    """sum_j (x_j - x_i), in neighbour order: the consensus term of every update below."""
    acc = 0.0
    for x_j in neighbours:
        acc += x_j - x_i
    return acc


def average_step(x_i: T, neighbours: Iterable[T], eps: float) -> T:
    """One static average-consensus update of agent i; eps * max_degree < 1 for stability."""
    return x_i + eps * disagreement(x_i, neighbours)


def weighted_average_step(x_i: T, neighbours: Iterable[tuple[T, float]]) -> T:
    """x_i + sum_j eps_ij (x_j - x_i) over ``neighbours`` = [(x_j, eps_ij)] (Metropolis weights: psi)."""
    acc = 0.0
    for x_j, eps_ij in neighbours:
        acc += eps_ij * (x_j - x_i)
    return x_i + acc


def lowpass_step(x_i: T, neighbours: Iterable[T], eps: float, beta: float, u_i: T | None) -> T:
    """One low-pass consensus update; ``u_i`` None means no new input this tick (consensus only).

    At steady state (eps L + beta I) x = beta u: the network average of the inputs is kept, common
    inputs are tracked exactly, and errors from lost or stale messages decay at rate beta.
    """
    x = x_i + eps * disagreement(x_i, neighbours)
    if u_i is not None:
        x += beta * (u_i - x_i)
    return x


def flow_step(f_ij: T, f_ji: T, eps: float, d_ij: T | None) -> T:
    """Agent i's new flow to j: (F_ij - F_ji)/2 + eps d_ij, d_ij = x_i - x_j (+ an edge term).

    x_i = u_i - sum_j F_ij. The mean of the two ends' flows, not -F_ji: both ends update at once
    from each other's previous flows, and with -F_ji the asymmetry a lost message leaves would flip
    sign every exchange and never decay; the mean removes it at the next exchange. While messages
    flow the flows stay antisymmetric, so sum_i x_i = sum_i u_i at every tick. ``d_ij`` None: no
    new difference this tick (the flow only loses its asymmetry).
    """
    if d_ij is None:
        return 0.5 * (f_ij - f_ji)
    return 0.5 * (f_ij - f_ji) + eps * d_ij


class FlowAverage:
    """Flow-updating average consensus of ``nch`` real channels (one agent's side).

    Each tick: set the inputs ``u``, :meth:`receive` the neighbours' latest (x_j, F_ji, degree),
    :meth:`update`. eps_ij is the Metropolis weight 1 / (1 + max(d_i, d_j)); a neighbour not heard
    from yet keeps its flows. ``x`` is replaced on every update, never changed in place.
    """

    __slots__ = ("u", "x", "flow", "nx", "nf", "ndeg", "deg", "nch", "eps")

    def __init__(self, nbr_ids: Sequence[int], nch: int) -> None:
        self.nch = nch
        self.u = [0.0] * nch
        self.x = [0.0] * nch
        self.deg = len(nbr_ids)
        self.flow = {j: [0.0] * nch for j in nbr_ids}  # F_ij, in neighbour order (updated in place)
        self.nx: dict[int, list[float]] = {}  # x_j, latest received
        self.nf = {j: [0.0] * nch for j in nbr_ids}  # F_ji, latest received
        self.ndeg = {j: 1 for j in nbr_ids}
        self.eps: dict[int, float] = {}  # eps_ij of the neighbours heard from

    def receive(self, j: int, xj: list[float], fji: list[float], degj: int) -> None:
        self.nx[j] = xj
        self.nf[j] = fji
        self.ndeg[j] = degj
        self.eps[j] = 1.0 / (1.0 + max(self.deg, degj))

    def update(self) -> None:
        x = self.x
        tot = [0.0] * self.nch
        for j, fl in self.flow.items():
            xj = self.nx.get(j)
            if xj is not None:
                eps = self.eps[j]
                fji = self.nf[j]
                for c in range(self.nch):
                    fl[c] = flow_step(fl[c], fji[c], eps, x[c] - xj[c])
            for c in range(self.nch):
                tot[c] += fl[c]
        self.x = [u - t for u, t in zip(self.u, tot, strict=True)]
