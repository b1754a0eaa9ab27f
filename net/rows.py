"""A state message as a fixed-layout float row: the compiled core's form of :class:`net.messages.StateMsg`.

The kernels read and write messages as float64 rows whose slots are fixed per team by :class:`Layout`
(docs/fast-core-plan.md section 2); the wire keeps its msgpack dicts, converted here at the edge:
:func:`row_from_state` (a decoded message -> the IN row of one receiver), :func:`state_from_row` (an
agent's OUT row -> the message it sends), :func:`estimate_from_row` (its estimate row -> :class:`Estimate`).

Row slots: ``TICK, SENDER, VX, VY, PHASE, STATUS, HAS_PAIR``, a spare, then the shared states in the order
the agent writes them (``om, oi, ph, yx, yy``; with the dynamical phase ``c0.. dg, Sk, ps, B0.. Bt, Bs`` and
with online detection ``Ds, De, Dz``), then the pair blocks from ``Layout.p0`` on, ``Layout.block`` floats
each: ``zx, zy, Fx, Fy`` (and the ``nch`` flows): in an OUT row one block per neighbour in the sender's
neighbour order, in an IN row the one block meant for the receiver.

``STATUS`` says what today's receive path (``AgentCore.step``: the inbox's try-block and the dynamical
phase's decoder) does with a message whose header it accepts: :data:`OK` (both parts taken, unless a value
is NaN or infinite: the receiving kernel checks that), :data:`MALFORMED` (dropped: a key missing, a pair of
the wrong length, a value its decoder rejects), :data:`KIN_MALFORMED` (its dynamical states are taken, then
the message is dropped: a kinematic value that is not a number). A message overtaken on its link is used
for its velocity alone, whatever its status: ``VX, VY`` hold it (NaN if not a number).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from net.messages import Estimate, StateMsg
from net.vocabulary import ESTIMATE_NAMES

TICK, SENDER, VX, VY, PHASE, STATUS, HAS_PAIR = range(7)
OM, OI, PH, YX, YY = range(8, 13)
C0 = 13  # the first consensus channel (dynamical phase)
OK, MALFORMED, KIN_MALFORMED = 0, 1, 2
KIN_KEYS = ("om", "oi", "ph", "yx", "yy")
PAIR_HEAD = 4  # zx, zy, Fx, Fy before a block's flows
# wire constants of the agents' layer (pinned to theirs by tests/test_rows.py): a barrier mask chunk's bits
# (agents.stage_agreement.MASK_BITS), a flooded decision's effect codes [-1, 2 N_EFF) (agents.effect_decision)
MASK_BITS = 50
N_DECISION_CODES = 8
_CHUNK_END = 2.0**MASK_BITS

# the kernels' view of a Layout: lay[L_*] (int64)
(L_DYNAMIC, L_NCH, L_NBK, L_DETECT, L_DEGREE, L_DG, L_SK, L_PS, L_B0, L_BT, L_BS, L_DS, L_DE, L_DZ, L_P0, L_BLOCK,
 L_SIZE_OUT, L_SIZE_IN) = range(18)

# the errors today's receive path counts as a malformed message (OverflowError: int() of an infinite
# integral field, which the wire's schema never lets through and the old path raised on)
_MALFORMED = (KeyError, TypeError, IndexError, AttributeError, ValueError, OverflowError)


@dataclass(frozen=True)
class Layout:
    """The slots of a team's message rows (module docstring). ``nbk``: barrier mask chunks
    (agents.stage_agreement.mask_keys); ``degree``: the most neighbours an agent has (D)."""

    dynamic: bool
    nch: int
    nbk: int
    detection: bool
    degree: int
    keys: tuple[str, ...] = field(init=False)  # the shared states' names, slots OM .. p0 - 1
    ch_keys: tuple[str, ...] = field(init=False)  # the channels' names (c0 ..)
    mask_keys: tuple[str, ...] = field(init=False)  # the barrier mask chunks' names (B0 ..)
    dg: int = field(init=False)  # slots of the dynamical states (-1 without them)
    sk: int = field(init=False)
    ps: int = field(init=False)
    b0: int = field(init=False)
    bt: int = field(init=False)
    bs: int = field(init=False)
    ds: int = field(init=False)  # the flooded decision (-1 without online detection)
    p0: int = field(init=False)  # the first pair block
    block: int = field(init=False)  # floats per pair block
    lay: np.ndarray = field(init=False, repr=False, compare=False)  # the kernels' offset table (L_*)

    def __post_init__(self) -> None:
        if self.detection and not self.dynamic:
            raise ValueError("online detection needs the dynamical phase")
        nch, nbk = (self.nch, self.nbk) if self.dynamic else (0, 0)
        keys = list(KIN_KEYS)
        dg = sk = ps = b0 = bt = bs = ds = -1
        if self.dynamic:
            keys += [f"c{c}" for c in range(nch)] + ["dg", "Sk", "ps"] + [f"B{c}" for c in range(nbk)] + ["Bt", "Bs"]
            dg = C0 + nch
            sk, ps, b0 = dg + 1, dg + 2, dg + 3
            bt = b0 + nbk
            bs = bt + 1
            if self.detection:
                keys += ["Ds", "De", "Dz"]
                ds = bs + 1
        p0 = OM + len(keys)
        block = PAIR_HEAD + nch
        put = object.__setattr__
        for name, v in (("keys", tuple(keys)), ("ch_keys", tuple(f"c{c}" for c in range(nch))),
                        ("mask_keys", tuple(f"B{c}" for c in range(nbk))), ("dg", dg), ("sk", sk), ("ps", ps),
                        ("b0", b0), ("bt", bt), ("bs", bs), ("ds", ds), ("p0", p0), ("block", block)):
            put(self, name, v)
        lay = np.array([self.dynamic, nch, nbk, self.detection, self.degree, dg, sk, ps, b0, bt, bs, ds,
                        ds + 1 if ds >= 0 else -1, ds + 2 if ds >= 0 else -1, p0, block,
                        p0 + self.degree * block, p0 + block], dtype=np.int64)
        lay.flags.writeable = False
        put(self, "lay", lay)

    @property
    def size_out(self) -> int:
        """Floats in an OUT row (every neighbour's block)."""
        return self.p0 + self.degree * self.block

    @property
    def size_in(self) -> int:
        """Floats in an IN row (the receiver's block)."""
        return self.p0 + self.block


def _num(x: object) -> float:
    """A kinematic value as the receiving kernel reads it: a number as is, anything else NaN (today it
    fails the finiteness sum, as NaN does)."""
    if type(x) is float:
        return x
    try:
        return float(x)  # type: ignore[arg-type]
    except (TypeError, ValueError, OverflowError):
        return math.nan


def row_from_state(msg: StateMsg, me: int, lay: Layout) -> np.ndarray:
    """The IN row of ``msg`` for receiver ``me`` (:func:`row_values`)."""
    return np.array(row_values(msg, me, lay))


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


def state_from_row(row: np.ndarray, lay: Layout, nbr_ids: Sequence[int]) -> StateMsg:
    """The message an agent's OUT row stands for (``nbr_ids``: its neighbours in its own order, one pair
    block each; an IN row with ``[me]`` gives the message as far as ``me`` received it). Python floats
    and ints throughout, as the wire and the recorder's ``repr`` need."""
    v = row.tolist()
    p0 = lay.p0
    bl = lay.block
    shared = dict(zip(lay.keys, v[OM:p0], strict=True))
    pair = {j: tuple(v[p0 + k * bl:p0 + (k + 1) * bl]) for k, j in enumerate(nbr_ids)}
    return StateMsg(int(v[TICK]), int(v[SENDER]), v[VX], v[VY], int(v[PHASE]), shared, pair)


def estimate_from_row(est: np.ndarray, out: np.ndarray, lay: Layout, nbr_ids: Sequence[int]) -> Estimate:
    """The :class:`Estimate` of an agent from its estimate row (``ESTIMATE_NAMES`` order) and its OUT
    row (tick, sender, and each neighbour's z_ij from the pair blocks)."""
    v = out.tolist()
    p0 = lay.p0
    bl = lay.block
    pairs = {j: (v[p0 + k * bl], v[p0 + k * bl + 1]) for k, j in enumerate(nbr_ids)}
    return Estimate(int(v[TICK]), int(v[SENDER]), dict(zip(ESTIMATE_NAMES, est.tolist(), strict=True)), pairs)
