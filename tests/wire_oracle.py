"""The receive path's decode of a state message before the value checks moved to the compiled core (net/rows.py
``row_values`` at commit 5c4acdf, frozen): the oracle tests/test_message_rows.py compares today's decode
(net.rows.raw_values + agents.kernels.message_rows.check_rows) against, on generated and forged messages.

Its statements are the old receive path's (``AgentCore.step``'s try-block, then the dynamical phase's decoder),
in that order; the first raise decides ``STATUS``. Not to be edited: it is the behaviour the new path keeps.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from net.messages import StateMsg
from net.rows import (
    C0,
    HAS_PAIR,
    KIN_MALFORMED,
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
)

_CHUNK_END = 2.0**MASK_BITS
_MALFORMED = (KeyError, TypeError, IndexError, AttributeError, ValueError, OverflowError)


def _num(x: object) -> float:
    """A kinematic value as the receiving kernel reads it: a number as is, anything else NaN (today it
    fails the finiteness sum, as NaN does)."""
    if type(x) is float:
        return x
    try:
        return float(x)  # type: ignore[arg-type]
    except (TypeError, ValueError, OverflowError):
        return math.nan


def row_values(msg: StateMsg, me: int, lay: Layout) -> list[float]:
    """The IN row of ``msg`` for receiver ``me``, as a list (many rows become one array at once). Its
    statements are the receive path's (the inbox's try-block, then the dynamical phase's decoder), in
    that order; the first raise decides ``STATUS``."""
    v = [0.0] * lay.size_in
    v[TICK] = msg.tick
    v[SENDER] = msg.sender
    v[VX] = _num(msg.vx)
    v[VY] = _num(msg.vy)
    v[PHASE] = _num(msg.phase)
    p = lay.p0
    try:
        sh = msg.shared
        s_om = sh["om"]
        s_ph = sh["ph"]
        yx = sh["yx"]
        yy = sh["yy"]
        v[OI] = 1.0 if sh["oi"] > 0.0 else 0.0  # the one use of "oi": a bool, so store what it decides
        pz = msg.pair.get(me)
        if not lay.dynamic:
            if pz is None:
                zx = zy = fx = fy = 0.0
            else:
                zx, zy, fx, fy = pz
        else:
            if pz is None:
                zx = zy = fx = fy = 0.0
                fl = None
            else:
                zx, zy, fx, fy, *fl = pz
            _decode_dynamic(v, lay, msg.phase, sh, fl)
    except _MALFORMED:
        v[STATUS] = MALFORMED
    else:
        v[HAS_PAIR] = 0.0 if pz is None else 1.0
        try:
            chk = s_om + s_ph + yx + yy + zx + zy + fx + fy + msg.vx + msg.vy
            chk - chk  # noqa: B018 (the old finiteness test: raises on a type the sum let through)
        except _MALFORMED:
            v[STATUS] = KIN_MALFORMED
        if not lay.dynamic:
            v[OM] = _num(s_om)
        v[PH] = _num(s_ph)
        v[YX] = _num(yx)
        v[YY] = _num(yy)
        v[p:p + PAIR_HEAD] = _num(zx), _num(zy), _num(fx), _num(fy)
    return v


def _decode_dynamic(v: list[float], lay: Layout, phase: object, sh: dict, fl: Sequence[float] | None) -> None:
    """The dynamical states of ``sh`` (and the flows ``fl`` meant for the receiver, None: none sent yet)
    into the row values ``v``, checked as the dynamical phase's decoder checks them (it raises where that
    raises)."""
    nch = lay.nch
    psi = float(sh["ps"])
    degj = sh["dg"]
    xj = [float(sh[k]) for k in lay.ch_keys]
    if psi - psi != 0.0:
        raise ValueError("non-finite")
    om = float(sh.get("om", math.nan))
    degj = int(degj)
    flows = [0.0] * nch if fl is None else list(map(float, fl))
    if degj < 1 or len(flows) != nch:
        raise ValueError("bad dynamic state")
    b = lay.b0
    for key in lay.mask_keys:
        x = sh[key]
        if not (0.0 <= x < _CHUNK_END) or x != int(x):
            raise ValueError("bad mask chunk")
        v[b] = int(x)
        b += 1
    v[lay.bt] = int(sh["Bt"])
    v[lay.bs] = int(sh["Bs"])
    if not all(map(math.isfinite, xj)):
        raise ValueError("non-finite")
    if lay.detection:
        s, e, z = float(sh["Ds"]), float(sh["De"]), float(sh["Dz"])
        if s != int(s) or e != int(e) or not (-1 <= e < N_DECISION_CODES) or z - z != 0.0:
            raise ValueError("bad decision")
        v[lay.ds:lay.ds + 3] = s, e, z
    v[PHASE] = int(phase)  # type: ignore[call-overload]
    v[lay.sk] = int(sh["Sk"])
    v[OM] = om
    v[C0:C0 + nch] = xj
    v[lay.dg] = degj
    v[lay.ps] = psi
    p = lay.p0 + PAIR_HEAD
    v[p:p + nch] = flows
