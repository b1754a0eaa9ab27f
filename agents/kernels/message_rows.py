"""In-process messages as rows: an agent's OUT row from its kinematic results, and the IN rows a team's
agents read from the OUT ring (net/rows.py layout; docs/fast-core-plan.md section 2).

:func:`write_kin_out` writes every agent's OUT row head: the header, the kinematic shared states and
each neighbour's pair head (z_ij as sent, F_ij), from :func:`agents.kernels.kinematic.kin_step`'s
results; the dynamical phase writes its own slots after it. :func:`gather_inbox` builds each receiver's
IN rows from the senders' OUT rows: the header and shared slots, the receiver's pair block, and the
``STATUS`` of the values' checks. :func:`check_rows` runs the same checks (one :func:`_gather_row`) on the raw
rows a daemon decodes from its inbox's messages (``net.rows.raw_values``: the values as floats, ``STATUS``
for what is not a number), so a message's IN row is the same in process and over the wire: :func:`in_rows`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from agents.kernels import jit, register_warm
from agents.kernels.kinematic import R_OM_INIT, R_OMEGA, R_PAIRS, R_PHI, R_Y
from net.messages import StateMsg
from net.rows import (
    C0,
    HAS_PAIR,
    L_B0,
    L_BLOCK,
    L_BS,
    L_BT,
    L_DETECT,
    L_DG,
    L_DS,
    L_DYNAMIC,
    L_NBK,
    L_NCH,
    L_P0,
    L_PS,
    L_SK,
    MALFORMED,
    MASK_BITS,
    N_DECISION_CODES,
    OI,
    OM,
    PAIR_HEAD,
    PH,
    PHASE,
    SENDER,
    STATUS,
    TICK,
    VX,
    VY,
    YX,
    YY,
    Layout,
    raw_values,
)
from net.vocabulary import KINEMATIC, SPINUP

_CHUNK_END = 2.0**MASK_BITS  # a mask chunk is an integer below this


@jit
def _int(x: float) -> float:
    """``int(x)`` of a finite float, as a float (``+ 0.0``: int() has no negative zero)."""
    return np.trunc(x) + 0.0


@jit
def write_kin_out(out, tick, ids, meas, deg, res, lay) -> None:
    """Every agent b's OUT row ``out[b]``: tick, sender ``ids[b]``, its measured velocity ``meas[b]``,
    the kinematic stage (SPINUP until omega_hat exists; a dynamical phase overwrites it), omega_hat, its
    initialisation flag, phi, y, and per neighbour slot k < ``deg[b]`` the pair head from ``res[b]``."""
    p0 = lay[L_P0]
    bl = lay[L_BLOCK]
    for b in range(out.shape[0]):
        row = out[b]
        r = res[b]
        for i in range(row.shape[0]):
            row[i] = 0.0
        row[TICK] = tick
        row[SENDER] = ids[b]
        row[VX] = meas[b, 0]
        row[VY] = meas[b, 1]
        om_init = r[R_OM_INIT] != 0.0
        row[PHASE] = KINEMATIC if om_init else SPINUP
        row[OM] = r[R_OMEGA]
        row[OI] = 1.0 if om_init else 0.0
        row[PH] = r[R_PHI]
        row[YX] = r[R_Y]
        row[YY] = r[R_Y + 1]
        for k in range(deg[b]):
            q = p0 + k * bl
            for c in range(PAIR_HEAD):
                row[q + c] = r[R_PAIRS + PAIR_HEAD * k + c]


@jit
def _decode_dynamic(src, fl, lay, v) -> bool:
    """The dynamical slots of OUT row ``src`` (its flows to the receiver from ``fl``, -1: none) and its stage into
    IN row ``v``, each value checked as the dynamical phase needs it (finite; ``dg, Sk, Bt, Bs``, the stage and
    the decision integral, as int() takes them; a mask chunk an integer in [0, 2^MASK_BITS); ``dg`` >= 1; a
    decision code in [-1, N_DECISION_CODES)); False at the first value rejected (what was written stays: a
    MALFORMED row's slots past its header are not read)."""
    nch = lay[L_NCH]
    psi = src[lay[L_PS]]
    if psi - psi != 0.0:
        return False
    om = src[OM]
    degj = src[lay[L_DG]]
    if degj - degj != 0.0:  # int() raises
        return False
    degj = _int(degj)
    if degj < 1.0:
        return False
    b0 = lay[L_B0]
    for c in range(lay[L_NBK]):
        x = src[b0 + c]
        if not (0.0 <= x < _CHUNK_END) or x != np.trunc(x):
            return False
        v[b0 + c] = x + 0.0
    for s in (lay[L_BT], lay[L_BS]):
        x = src[s]
        if x - x != 0.0:
            return False
        v[s] = _int(x)
    for c in range(nch):
        x = src[C0 + c]
        if x - x != 0.0:
            return False
    if lay[L_DETECT]:
        ds = lay[L_DS]
        s = src[ds]
        e = src[ds + 1]
        z = src[ds + 2]
        if (s - s != 0.0 or s != np.trunc(s) or e - e != 0.0 or e != np.trunc(e) or not (-1.0 <= e < N_DECISION_CODES)
                or z - z != 0.0):
            return False
        v[ds] = s
        v[ds + 1] = e
        v[ds + 2] = z
    x = src[PHASE]
    if x - x != 0.0:
        return False
    v[PHASE] = _int(x)
    x = src[lay[L_SK]]
    if x - x != 0.0:
        return False
    v[lay[L_SK]] = _int(x)
    v[OM] = om
    for c in range(nch):
        v[C0 + c] = src[C0 + c]
    v[lay[L_DG]] = degj
    v[lay[L_PS]] = psi
    if fl >= 0:
        p = lay[L_P0] + PAIR_HEAD
        for c in range(nch):
            v[p + c] = src[fl + c]
    return True


@jit
def _gather_row(src, blk, lay, v) -> None:
    """IN row ``v`` of OUT row ``src`` for the receiver whose pair block in it is ``blk`` (-1: none)."""
    for i in range(v.shape[0]):
        v[i] = 0.0
    v[TICK] = src[TICK]
    v[SENDER] = src[SENDER]
    v[VX] = src[VX]
    v[VY] = src[VY]
    v[PHASE] = src[PHASE]
    v[OI] = 1.0 if src[OI] > 0.0 else 0.0
    p0 = lay[L_P0]
    q = p0 + blk * lay[L_BLOCK]
    if blk >= 0:
        zx = src[q]
        zy = src[q + 1]
        fx = src[q + 2]
        fy = src[q + 3]
    else:
        zx = zy = fx = fy = 0.0
    if lay[L_DYNAMIC]:
        if not _decode_dynamic(src, q + PAIR_HEAD if blk >= 0 else -1, lay, v):
            v[STATUS] = MALFORMED
            return
    else:
        v[OM] = src[OM]
    # (float values throughout: a kinematic value that is not a number is a raw row's STATUS, check_rows)
    v[HAS_PAIR] = 1.0 if blk >= 0 else 0.0
    v[PH] = src[PH]
    v[YX] = src[YX]
    v[YY] = src[YY]
    v[p0] = zx
    v[p0 + 1] = zy
    v[p0 + 2] = fx
    v[p0 + 3] = fy


@jit
def check_rows(raw, lay, rows) -> None:
    """rows[e] = the IN row of the raw row ``raw[e]`` (``net.rows.raw_values``, a one-block OUT row whose
    ``HAS_PAIR`` says whether its block was sent): its values checked as an OUT row's, its own ``STATUS`` kept
    where the checks pass (MALFORMED, KIN_MALFORMED: not numbers)."""
    for e in range(raw.shape[0]):
        src = raw[e]
        v = rows[e]
        _gather_row(src, 0 if src[HAS_PAIR] != 0.0 else -1, lay, v)
        if v[STATUS] != MALFORMED:
            v[STATUS] = src[STATUS]


def in_rows(msgs: Sequence[StateMsg], me: int, lay: Layout) -> np.ndarray:
    """The IN rows (len(msgs), lay.size_in) of received messages for receiver ``me``: decoded
    (``net.rows.raw_values``), then checked (:func:`check_rows`)."""
    raw = np.array([raw_values(m, me, lay) for m in msgs], np.float64).reshape(len(msgs), lay.size_in)
    rows = np.empty_like(raw)
    check_rows(raw, lay.lay, rows)
    return rows


@jit
def gather_inbox(ring, ref, lay, rows) -> None:
    """rows[e] = the IN row of ``ref[e]`` = (ring slot, sender row, the receiver's block in the sender's
    OUT row, -1: none) from the OUT ring ``ring`` (slots, B, size_out)."""
    for e in range(ref.shape[0]):
        _gather_row(ring[ref[e, 0], ref[e, 1]], ref[e, 2], lay, rows[e])


@register_warm
def warm() -> None:
    """Compile the kernels: a dynamical layout with detection (every check) and a kinematic one."""
    for lay in (Layout(True, 3, 1, True, 2), Layout(False, 0, 0, False, 2)):
        ring = np.zeros((2, 2, lay.size_out))
        res = np.zeros((2, R_PAIRS + 8))
        write_kin_out(ring[0], 1, np.array([0, 1], np.int64), np.zeros((2, 2)), np.array([1, 1], np.int64), res,
                      lay.lay)
        gather_inbox(ring, np.array([[0, 1, 0], [0, 0, -1]], np.int64), lay.lay, np.zeros((2, lay.size_in)))
        check_rows(np.zeros((2, lay.size_in)), lay.lay, np.zeros((2, lay.size_in)))
