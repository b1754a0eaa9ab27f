"""A state message as a fixed-layout float row: the compiled core's form of :class:`net.messages.StateMsg`.

The kernels read and write messages as float64 rows whose slots are fixed per team by :class:`Layout`
(docs/fast-core-plan.md section 2); the wire keeps its msgpack dicts, converted here at the edge:
:func:`raw_values` (a decoded message -> the raw row of one receiver, which the compiled core checks into its
IN row: agents/kernels/message_rows.py ``check_rows``), :func:`state_from_row` (an agent's OUT row -> the
message it sends), :func:`estimate_from_row` (its estimate row -> :class:`Estimate`).

Row slots: ``TICK, SENDER, VX, VY, PHASE, STATUS, HAS_PAIR``, a spare, then the shared states in the order
the agent writes them (``om, oi, ph, yx, yy``; with the dynamical phase ``c0.. dg, Sk, ps, B0.. Bt, Bs`` and
with online detection ``Ds, De, Dz``), then the pair blocks from ``Layout.p0`` on, ``Layout.block`` floats
each: ``zx, zy, Fx, Fy`` (and the ``nch`` flows): in an OUT row one block per neighbour in the sender's
neighbour order, in a raw or IN row the one block meant for the receiver.

``STATUS`` says what the receive path does with a message whose header it accepts: :data:`OK` (both parts
taken, unless a value is NaN or infinite: the receiving kernel checks that), :data:`MALFORMED` (dropped: a key
missing, a pair of the wrong length, a value its conversion or its check rejects), :data:`KIN_MALFORMED` (its
dynamical states are taken, then the message is dropped: a kinematic value that is not a number).

Here only the types decide: each value is taken as the old receive path took it: ``float()`` for the channels,
``ps``, ``Ds, De, Dz``, the flows and, with the dynamical phase, ``om``; ``int()`` for ``dg, Sk, Bt, Bs`` and,
with the dynamical phase, the stage; a comparison with a float for ``oi`` and the mask chunks (a real number
only); the kinematic values as they are. A conversion that raises makes the message MALFORMED. The values'
ranges (finite, integral, a mask chunk in [0, 2^MASK_BITS), a decision code) are checked once, by the compiled
core, for a daemon's inbox and an in-process team's alike. A message overtaken on its link is used for its
velocity alone, whatever its status: ``VX, VY`` hold it (NaN if not a number); of a MALFORMED row nothing else
is read.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Sequence
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
    # the dynamical states' (slot, name, conversion) as the receive path takes them (raw_values)
    taking: tuple[tuple[int, str, Callable[[object], float]], ...] = field(init=False, repr=False, compare=False)

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
        # int() for the integer states, a comparison for the mask chunks, float() for the rest (the channels, ps,
        # the decision)
        ints, chunks = (dg, sk, bt, bs), range(b0, b0 + nbk)
        put(self, "taking", tuple((slot, key, _integer if slot in ints else _real if slot in chunks else float)
                                  for slot, key in enumerate(keys[len(KIN_KEYS):], C0)))

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


def _is_number(x: object) -> bool:
    """Whether ``x`` adds to a float (the kinematic values' finiteness sum raises on anything else)."""
    return type(x) is float or isinstance(x, numbers.Real)


def _real(x: object) -> float:
    """A value the receive path compares with a float (``oi``, a mask chunk): a real number as a float, anything
    else raises TypeError (as the comparison does)."""
    if type(x) is float:
        return x
    if isinstance(x, numbers.Real):
        return float(x)
    raise TypeError(f"not a number: {type(x).__name__}")


def _integer(x: object) -> float:
    """A value the receive path takes with ``int()`` (``dg, Sk, Bt, Bs``, the stage): a float as it is (the check
    rejects NaN and infinities and truncates it), anything else as ``int()`` makes it (a str parsed; raises where
    int() raises)."""
    return x if type(x) is float else float(int(x))  # type: ignore[call-overload]


def raw_values(msg: StateMsg, me: int, lay: Layout) -> list[float]:
    """The raw row of ``msg`` for receiver ``me``, as a list (many rows become one array at once): the type-level
    decode of the receive path. Each value as the float it stands for, in the IN row's slots (the shared states
    as sent, the receiver's pair block, ``HAS_PAIR``: 0 when there is none); ``STATUS`` only for what is not a
    number at all: :data:`MALFORMED` (a key missing, a pair of the wrong length, a value its conversion
    rejects: the module docstring), :data:`KIN_MALFORMED` (a kinematic value that is not a number). The values'
    checks are the compiled core's (agents/kernels/message_rows.py ``check_rows``), which makes the IN row."""
    v = [0.0] * lay.size_in
    v[TICK] = msg.tick
    v[SENDER] = msg.sender
    v[VX] = _num(msg.vx)
    v[VY] = _num(msg.vy)
    v[PHASE] = _num(msg.phase)
    p = lay.p0
    try:
        sh = msg.shared
        om, oi, ph, yx, yy = sh["om"], sh["oi"], sh["ph"], sh["yx"], sh["yy"]
        v[OI] = _real(oi)
        pz = msg.pair.get(me)
        fl: list = []
        if pz is None:
            zx = zy = fx = fy = 0.0
        elif lay.dynamic:
            zx, zy, fx, fy, *fl = pz
        else:
            zx, zy, fx, fy = pz
        if lay.dynamic:
            float(om)  # the dynamical phase's decoder takes om with float()
            v[PHASE] = _integer(msg.phase)
            for slot, key, take in lay.taking:
                v[slot] = take(sh[key])
            if pz is not None:
                if len(fl) != lay.nch:
                    raise ValueError("flows of the wrong length")
                v[p + PAIR_HEAD:p + lay.block] = [float(x) for x in fl]
    except _MALFORMED:
        v[STATUS] = MALFORMED
        return v
    v[HAS_PAIR] = 0.0 if pz is None else 1.0
    v[OM] = _num(om)
    v[PH] = _num(ph)
    v[YX] = _num(yx)
    v[YY] = _num(yy)
    v[p:p + PAIR_HEAD] = _num(zx), _num(zy), _num(fx), _num(fy)
    if not all(map(_is_number, (om, ph, yx, yy, zx, zy, fx, fy, msg.vx, msg.vy))):
        v[STATUS] = KIN_MALFORMED
    return v


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
