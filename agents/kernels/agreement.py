"""The agreement leaves of the dynamical phase, compiled: the flow-updating average and the stage barrier.

* :func:`flow_step` -- one edge of flow-updating consensus (the scalar of the kinematic phase's z_i and of every
  channel of the average; why this form: agents/consensus.py).
* :func:`flow_average_update` -- row ``b`` of a bank of :class:`agents.consensus.FlowAverage`: every
  neighbour's flows from the latest received (x_j, F_ji, d_j), then x = u - sum_j F_ij.
* ``barrier_*`` -- :class:`agents.stage_agreement.StageBarrier` on 50-bit mask chunks (int64 holds no n-bit
  Python int): row ``b`` of ``S (B, SBITS + NBk)`` i8 = ME, N, HORIZON, TMAX, SWITCH, then the mask's chunks
  (chunk c holds agents 50 c .. 50 c + 49, as on the wire).
(The detection's decision flood stays Python, agents/effect_decision.DecisionFlood, with the detection.)

Flow-average bank (docs/fast-core-plan.md, section 1.5): two arenas, so that a call passes three arguments
(numba's dispatch cost grows with their number). ``F (B, 2 + 3 D, nch)`` f8: rows ``U``, ``X``, then three
blocks of ``D`` rows: F_ij (from ``FLOW``), the received F_ji and x_j; slot k < deg is the k-th neighbour id
as given. ``I (B, 1 + 2 D)`` i8: ``DEG``, then per slot ``HEARD`` (a state of that neighbour has arrived),
then per slot its degree (1 until heard). The operations are those of the Python they replaced, in the same
order, so the bits are the same (tests/test_agreement_kernels.py).
"""

from __future__ import annotations

import numpy as np

from agents.kernels import jit, register_warm

U, X, FLOW = 0, 1, 2  # rows of F; the received F_ji from FLOW + D, x_j from FLOW + 2 D
DEG, HEARD = 0, 1  # columns of I; the degrees from HEARD + D


@jit
def flow_step(f_ij, f_ji, eps, d_ij):
    """Agent i's new flow to j: (F_ij - F_ji)/2 + eps d_ij, d_ij = x_i - x_j (+ an edge term); ``d_ij``
    None: no new difference this tick (the flow only loses its asymmetry). Why the mean of the two ends'
    flows: agents/consensus.py. Floats or complex numbers (each compiles its own)."""
    if d_ij is None:
        return 0.5 * (f_ij - f_ji)
    return 0.5 * (f_ij - f_ji) + eps * d_ij


@jit
def flow_average_update(b, F, I):
    """Row b's update: the flows of every neighbour heard from (eps_ij = 1 / (1 + max(d_i, d_j)), the
    Metropolis weight), each from the old x; then x = u - sum_j F_ij, summed in neighbour order."""
    nch = F.shape[2]
    D = (F.shape[1] - FLOW) // 3
    deg = I[b, DEG]
    tot = np.zeros(nch)
    for k in range(deg):  # the row's own slots only: an empty slot's 0.0 would turn a -0.0 sum into 0.0
        fl = FLOW + k
        if I[b, HEARD + k]:
            eps = 1.0 / (1.0 + max(deg, I[b, HEARD + D + k]))
            for c in range(nch):
                F[b, fl, c] = flow_step(F[b, fl, c], F[b, fl + D, c], eps, F[b, X, c] - F[b, fl + 2 * D, c])
        for c in range(nch):
            tot[c] += F[b, fl, c]
    for c in range(nch):
        F[b, X, c] = F[b, U, c] - tot[c]


def flow_average_bank(B: int, D: int, nch: int) -> tuple[np.ndarray, np.ndarray]:
    """A zeroed bank of B averages with D neighbour slots (no neighbour heard, degrees 1): (F, I)."""
    F = np.zeros((B, FLOW + 3 * D, nch))
    I = np.zeros((B, HEARD + 2 * D), np.int64)
    I[:, HEARD + D:] = 1
    return F, I


MASK_BITS = 50  # agents per chunk of the barrier's mask (exact in a double on the wire)
ME, N, HORIZON, TMAX, SWITCH, SBITS = 0, 1, 2, 3, 4, 5  # columns of S; the mask's chunks from SBITS on


def barrier_bank(B: int, nbk: int) -> np.ndarray:
    """B barriers' rows with room for ``nbk`` mask chunks (all reset; ME, N, HORIZON set by the caller)."""
    S = np.zeros((B, SBITS + nbk), np.int64)
    S[:, TMAX] = S[:, SWITCH] = -1
    return S


@jit
def _full_chunk(n, c):
    """Chunk c of the full mask of a team of n."""
    bits = min(MASK_BITS, n - MASK_BITS * c)
    return (np.int64(1) << bits) - 1 if bits > 0 else np.int64(0)


@jit
def barrier_reset(b, S):
    for c in range(SBITS, S.shape[1]):
        S[b, c] = 0
    S[b, TMAX] = -1
    S[b, SWITCH] = -1


@jit
def barrier_complete(b, S):
    """Every agent is known to be ready."""
    for c in range(S.shape[1] - SBITS):
        if S[b, SBITS + c] != _full_chunk(S[b, N], c):
            return False
    return True


@jit
def _barrier_check(b, S):
    if S[b, SWITCH] < 0 and barrier_complete(b, S):
        S[b, SWITCH] = S[b, TMAX] + S[b, HORIZON]


@jit
def barrier_set_ready(b, S, tick):
    me = S[b, ME]
    c = SBITS + me // MASK_BITS
    bit = np.int64(1) << (me % MASK_BITS)
    if not S[b, c] & bit:
        S[b, c] |= bit
        S[b, TMAX] = max(S[b, TMAX], tick)
        _barrier_check(b, S)


@jit
def barrier_merge(b, S, mask, tmax, switch):
    """A neighbour's (mask chunks, latest ready tick, switch tick); ``mask`` may be shorter than the row's."""
    if switch >= 0 and S[b, SWITCH] < 0:
        S[b, SWITCH] = switch
    new = False
    for c in range(mask.shape[0]):
        if mask[c] & ~S[b, SBITS + c]:
            new = True
    if new:
        for c in range(mask.shape[0]):
            S[b, SBITS + c] |= mask[c] & _full_chunk(S[b, N], c)
        S[b, TMAX] = max(S[b, TMAX], tmax)
        _barrier_check(b, S)


@register_warm
def warm() -> None:
    for args in ((1.0, 0.5, 0.25, 0.1), (1.0, 0.5, 0.25, None), (1j, 0.5j, 0.25, 0.1j), (1j, 0.5j, 0.25, None)):
        flow_step(*args)
    F, I = flow_average_bank(1, 1, 1)
    flow_average_update(0, F, I)
    S = barrier_bank(1, 1)
    S[0, N] = 2
    barrier_set_ready(0, S, 3)
    barrier_merge(0, S, np.ones(1, np.int64), 4, -1)
    barrier_complete(0, S)
    barrier_reset(0, S)
