"""The consensus updates the agent runs: one agent's update from its own state and its neighbours'.

* :func:`average_step` -- x_i + eps sum_j (x_j - x_i): the body-frame angle phi (with per-edge Metropolis
  weights it is the dynamical phase's psi, agents/kernels/dynamic.py ``body_frame``).
* :func:`lowpass_step` -- x_i + eps sum_j (x_j - x_i) + beta (u_i - x_i): omega_hat (a low-pass
  consensus filter: it averages the per-tick noise over time and over the graph).
* :func:`flow_step` -- one edge of flow-updating average consensus, F_ij = (F_ij - F_ji)/2 + eps d_ij,
  d_ij = x_i - x_j (+ an edge term): the centroid iteration (z_i) and every channel of :class:`FlowAverage`
  (the dynamical phase). x_i = u_i - sum_j F_ij. The mean of the two ends' flows, not -F_ji: both ends
  update at once from each other's previous flows, and with -F_ji the asymmetry a lost message leaves
  would flip sign every exchange and never decay; the mean removes it at the next exchange. While
  messages flow the flows stay antisymmetric, so sum_i x_i = sum_i u_i at every tick.

Scalars or complex numbers (the first three also numpy arrays). :func:`flow_step` and the update of
:class:`FlowAverage` are compiled (:mod:`agents.kernels.agreement`). Why these forms: docs/agent-step.md.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import TypeVar

import numpy as np

from agents.kernels import agreement
from agents.kernels.agreement import DEG, FLOW, HEARD, U, X, flow_average_bank, flow_average_update

# Python callers run the kernel's source interpreted: from Python a compiled call costs more than its
# arithmetic (0.2 against 0.1 us); kernels call the compiled one (with NUMBA_DISABLE_JIT=1 the
# decorator returns the function itself, which has no py_func)
flow_step = getattr(agreement.flow_step, "py_func", agreement.flow_step)

__all__ = ["FlowAverage", "average_step", "disagreement", "flow_step", "lowpass_step"]

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


def lowpass_step(x_i: T, neighbours: Iterable[T], eps: float, beta: float, u_i: T | None) -> T:
    """One low-pass consensus update; ``u_i`` None means no new input this tick (consensus only).

    At steady state (eps L + beta I) x = beta u: the network average of the inputs is kept, common
    inputs are tracked exactly, and errors from lost or stale messages decay at rate beta.
    """
    x = x_i + eps * disagreement(x_i, neighbours)
    if u_i is not None:
        x += beta * (u_i - x_i)
    return x


class FlowAverage:
    """Flow-updating average consensus of ``nch`` real channels (one agent's side): a view of row ``b``
    of a bank (:mod:`agents.kernels.agreement`; its own bank of one unless given).

    Each tick: set the inputs ``u``, :meth:`receive` the neighbours' latest (x_j, F_ji, degree),
    :meth:`update`. eps_ij is the Metropolis weight 1 / (1 + max(d_i, d_j)); a neighbour not heard
    from yet keeps its flows. ``x`` is a list replaced on every update, never changed in place.
    """

    __slots__ = ("u", "x", "nx", "ndeg", "deg", "nch", "ids", "_slot", "_b", "_F", "_I", "_nf", "_nx", "_ndeg")

    def __init__(self, nbr_ids: Sequence[int], nch: int, bank: tuple[np.ndarray, np.ndarray] | None = None,
                 b: int = 0) -> None:
        self.nch = nch
        self.ids = tuple(nbr_ids)
        self.deg = len(self.ids)
        self._slot = {j: k for k, j in enumerate(self.ids)}
        self._F, self._I = flow_average_bank(1, self.deg, nch) if bank is None else bank
        self._b = b
        D = (self._F.shape[1] - FLOW) // 3  # the bank's slots (>= deg)
        self._nf, self._nx, self._ndeg = FLOW + D, FLOW + 2 * D, HEARD + D  # where slot 0's rows start
        self._I[b, DEG] = self.deg
        self.u = [0.0] * nch  # the inputs, written in place by the caller (a list: cheap to write from Python)
        self.x = self._F[b, X].tolist()
        # the latest received x_j and degree per neighbour, in first-heard order: what the Python readers
        # of the phase iterate (the order reaches their sums); the kernel reads the bank's rows
        self.nx: dict[int, list[float]] = {}
        self.ndeg = dict.fromkeys(self.ids, 1)

    @classmethod
    def view(cls, nbr_ids: Sequence[int], bank: tuple[np.ndarray, np.ndarray], b: int) -> FlowAverage:
        """Row ``b`` of ``bank`` as it stands (the kernels' row: ``u`` a view of its inputs, ``x`` and ``nx``
        copies of its values, the neighbours in first-heard order not known: ``nx`` in slot order)."""
        new = cls.__new__(cls)
        new.ids = tuple(nbr_ids)
        new.deg = len(new.ids)
        new._slot = {j: k for k, j in enumerate(new.ids)}
        new._F, new._I = bank
        new._b = b
        new.nch = new._F.shape[2]
        D = (new._F.shape[1] - FLOW) // 3
        new._nf, new._nx, new._ndeg = FLOW + D, FLOW + 2 * D, HEARD + D
        new.u = new._F[b, U]
        new.x = new._F[b, X].tolist()
        heard = new._I[b, HEARD:HEARD + new.deg].tolist()
        new.nx = {j: new._F[b, new._nx + k].tolist() for k, j in enumerate(new.ids) if heard[k]}
        new.ndeg = {j: int(new._I[b, new._ndeg + k]) for k, j in enumerate(new.ids)}
        return new

    @property
    def flow(self) -> dict[int, list[float]]:
        """F_ij per neighbour, in neighbour order (a copy)."""
        return dict(zip(self.ids, self._F[self._b, FLOW:FLOW + self.deg].tolist(), strict=True))

    def receive(self, j: int, xj: list[float], fji: list[float], degj: int) -> None:
        k, b = self._slot[j], self._b
        self._F[b, self._nf + k] = fji
        self._F[b, self._nx + k] = xj
        self._I[b, HEARD + k] = 1
        self._I[b, self._ndeg + k] = degj
        self.nx[j] = xj
        self.ndeg[j] = degj

    def update(self) -> None:
        b = self._b
        self._F[b, U] = self.u
        flow_average_update(b, self._F, self._I)
        self.x = self._F[b, X].tolist()
