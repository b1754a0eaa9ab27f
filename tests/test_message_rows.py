"""agents/kernels/message_rows.py: a received message's IN row is one compiled check of its values, in process and
over the wire alike.

An in-process IN row gathered from a sender's OUT row equals, bit for bit, the row a daemon makes of the message
that OUT row stands for (``in_rows([state_from_row(out)])``: net.rows.raw_values, then check_rows), for valid
rows and rows with NaN, infinite, fractional, negative-zero and out-of-range values in any slot. A daemon's row
of any message, forged ones included (strings, None, bools, ints, missing keys, pairs of the wrong length), is
the old receive path's (tests/wire_oracle.py, frozen): the same STATUS; every slot when the message is not
dropped; the header and velocity (all that is read of it) when it is. Compiled == interpreted.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agents.kernels.kinematic import R_OM_INIT, R_OMEGA, R_PAIRS, R_PHI, R_Y
from agents.kernels.message_rows import check_rows, gather_inbox, in_rows, write_kin_out
from net import rows as R
from net.messages import StateMsg
from tests.wire_oracle import row_values as old_row_values

JIT = hasattr(gather_inbox, "py_func")
NBRS = [10, 11, 12]  # the sender's neighbours; the receiver is one of them or 99 (no pair block)
EDGE = [math.nan, -math.nan, math.inf, -math.inf, 0.0, -0.0, 0.5, -0.5, 1.0, -1.0, 7.0, 8.0, 2.0**50, 2.0**50 - 1.0,
        1e300, -1e300, 5e-324]

LAYOUTS = [R.Layout(False, 0, 0, False, 2), R.Layout(True, 3, 1, False, 3), R.Layout(True, 4, 2, True, 2),
           R.Layout(True, 2, 1, True, 1)]


def _valid_out(lay: R.Layout, draw: st.DrawFn) -> np.ndarray:
    """An OUT row every check accepts: integral header, finite values, in-range integral dynamical slots."""
    finite = st.floats(-1e6, 1e6, allow_nan=False)
    row = np.array([draw(finite) for _ in range(lay.size_out)])
    row[R.TICK] = draw(st.integers(0, 10**6))
    row[R.SENDER] = draw(st.integers(0, 200))
    row[R.PHASE] = draw(st.integers(0, 7))
    row[R.STATUS] = row[R.HAS_PAIR] = 0.0
    if lay.dynamic:
        row[lay.dg] = draw(st.integers(1, 50))
        row[lay.sk] = draw(st.integers(-1, 10**6))
        for c in range(lay.nbk):
            row[lay.b0 + c] = draw(st.integers(0, 2**50 - 1))
        row[lay.bt] = draw(st.integers(-1, 10**6))
        row[lay.bs] = draw(st.integers(-1, 10**6))
        if lay.detection:
            row[lay.ds] = draw(st.integers(-1, 10**6))
            row[lay.ds + 1] = draw(st.integers(-1, R.N_DECISION_CODES - 1))
    return row


@st.composite
def cases(draw: st.DrawFn) -> tuple[R.Layout, np.ndarray, int]:
    lay = draw(st.sampled_from(LAYOUTS))
    row = _valid_out(lay, draw)
    # a few slots past the header spoilt with edge values (the header is the system's own integers)
    slots = [R.VX, R.VY, *range(R.STATUS, lay.size_out)]
    for _ in range(draw(st.integers(0, 3))):
        row[draw(st.sampled_from(slots))] = draw(st.one_of(st.sampled_from(EDGE), st.floats()))
    row[R.VX] = row[R.VX] if draw(st.booleans()) else draw(st.sampled_from(EDGE))
    blk = draw(st.integers(-1, lay.degree - 1))
    return lay, row, blk


def _expected(lay: R.Layout, out: np.ndarray, blk: int) -> np.ndarray:
    """A daemon's IN row of the message OUT row ``out`` stands for, as the receiver of block ``blk``."""
    nbrs = NBRS[:lay.degree]
    me = nbrs[blk] if blk >= 0 else 99
    return in_rows([R.state_from_row(out, lay, nbrs)], me, lay)[0]


@settings(max_examples=400, deadline=None, derandomize=True)
@given(case=cases())
def test_a_gathered_row_is_a_daemon_s_row_of_the_message(case: tuple[R.Layout, np.ndarray, int]) -> None:
    lay, out, blk = case
    ring = out.reshape(1, 1, -1)
    ref = np.array([[0, 0, blk]], np.int64)
    got = np.full((1, lay.size_in), 7.0)
    gather_inbox(ring, ref, lay.lay, got)
    want = _expected(lay, out, blk)
    assert got[0].tobytes() == want.tobytes(), (got[0].tolist(), want.tolist())
    if JIT:
        interp = np.full((1, lay.size_in), 7.0)
        gather_inbox.py_func(ring, ref, lay.lay, interp)
        assert interp.tobytes() == got.tobytes()


def test_each_rejected_value_marks_the_row_malformed() -> None:
    lay = R.Layout(True, 3, 2, True, 2)
    base = np.zeros(lay.size_out)
    base[lay.dg] = 2.0
    for slot, bad in [(lay.ps, math.nan), (lay.dg, 0.0), (lay.dg, math.inf), (lay.b0 + 1, 0.5), (lay.b0, -1.0),
                      (lay.b0, 2.0**50), (lay.bt, math.nan), (lay.bs, -math.inf), (R.C0 + 2, math.inf),
                      (lay.ds, 0.5), (lay.ds + 1, 8.0), (lay.ds + 1, -2.0), (lay.ds + 2, math.nan), (lay.sk, math.nan)]:
        out = base.copy()
        out[slot] = bad
        got = np.zeros((1, lay.size_in))
        gather_inbox(out.reshape(1, 1, -1), np.array([[0, 0, 1]], np.int64), lay.lay, got)
        assert got[0, R.STATUS] == R.MALFORMED, (slot, bad)
        assert got.tobytes() == _expected(lay, out, 1).reshape(1, -1).tobytes()
    got = np.zeros((1, lay.size_in))
    gather_inbox(base.reshape(1, 1, -1), np.array([[0, 0, 0]], np.int64), lay.lay, got)
    assert got[0, R.STATUS] == R.OK and got[0, R.HAS_PAIR] == 1.0
    # the stage, which only a message from outside can spoil: int() of it, with the dynamical phase only
    raw = np.zeros((2, lay.size_in))
    raw[:, lay.dg] = 2.0
    raw[:, R.PHASE] = math.nan, 2.5
    got = np.zeros_like(raw)
    check_rows(raw, lay.lay, got)
    assert got[:, R.STATUS].tolist() == [R.MALFORMED, R.OK] and got[1, R.PHASE] == 2.0
    kin = R.Layout(False, 0, 0, False, 2)
    got = np.zeros((2, kin.size_in))
    check_rows(raw[:, :kin.size_in].copy(), kin.lay, got)
    assert got[:, R.STATUS].tolist() == [R.OK, R.OK] and got[1, R.PHASE] == 2.5


# what a forged message may hold where a float belongs: edge floats, ints (msgpack's range), bools, strings (some
# int() or float() parse), bytes, None, containers
FORGED = [*EDGE, True, False, 0, 1, -1, 3, 2**50 - 1, 2**50, 2**53 + 1, 2**63, -(2**63), 2**64 - 1, "x", "1.5", "3",
          "-0", "nan", "inf", "", b"2", None, [], [1.0], {}, {"a": 1.0}]
forged = st.one_of(st.sampled_from(FORGED), st.floats(), st.integers(-(2**63), 2**64 - 1))


@st.composite
def forged_msgs(draw: st.DrawFn) -> tuple[R.Layout, StateMsg, int]:
    """A valid message (of a valid OUT row) for receiver ``me``, with up to four of its parts forged: a shared
    value replaced or dropped, the receiver's pair entry replaced, cut, lengthened, spoilt or dropped, the
    velocity or stage replaced, the shared map or the pair map not a map."""
    lay, out, blk = draw(cases())
    nbrs = NBRS[:lay.degree]
    me = nbrs[blk] if blk >= 0 else 99
    m = R.state_from_row(out, lay, nbrs)
    sh, pair, head = dict(m.shared), dict(m.pair), {"vx": m.vx, "vy": m.vy, "phase": m.phase}
    pz = list(pair.get(nbrs[0]))
    maps = False
    for _ in range(draw(st.integers(0, 4))):
        what = draw(st.sampled_from(["value", "value", "value", "drop", "pair", "pair", "head", "maps"]))
        if what == "value":
            sh[draw(st.sampled_from(lay.keys if draw(st.booleans()) else R.KIN_KEYS))] = draw(forged)
        elif what == "drop":
            sh.pop(draw(st.sampled_from(lay.keys)), None)
        elif what == "pair":
            kind = draw(st.sampled_from(["spoil", "spoil", "cut", "long", "none", "drop", "str", "int"]))
            if kind == "spoil":
                pz[draw(st.integers(0, len(pz) - 1))] = draw(forged)
            pair[me] = {"spoil": tuple(pz), "cut": tuple(pz[:-1]), "long": (*pz, 0.0), "none": None,
                        "str": "1" * len(pz), "int": 5, "drop": None}[kind]
            if kind == "drop":
                del pair[me]
        elif what == "head":
            head[draw(st.sampled_from(sorted(head)))] = draw(forged)
        else:
            maps = True
    if maps:
        sh, pair = draw(st.sampled_from([(sh, [pz]), (None, pair), (list(sh.values()), pair), ("x", pair)]))
    return lay, StateMsg(m.tick, m.sender, head["vx"], head["vy"], head["phase"], sh, pair), me


@settings(max_examples=1000, deadline=None, derandomize=True)
@given(case=forged_msgs())
def test_a_forged_message_s_row_is_the_old_receive_path_s(case: tuple[R.Layout, StateMsg, int]) -> None:
    """The type-level decode + the one value check == the old receive path (_assert_old_row), up to four parts of a
    message forged at once; compiled == interpreted."""
    lay, msg, me = case
    _assert_old_row(lay, msg, me)
    if JIT:
        raw = np.array([R.raw_values(msg, me, lay)])
        interp = np.full_like(raw, 7.0)
        check_rows.py_func(raw, lay.lay, interp)
        assert interp.tobytes() == in_rows([msg], me, lay).tobytes()


def _assert_old_row(lay: R.Layout, msg: StateMsg, me: int) -> None:
    """The message's IN row is the old receive path's: the same STATUS; all its slots unless it is dropped, else
    those the kernels read of a dropped message (agents/kernels/kinematic.py: its order, its sender, an overtaken
    message's velocity)."""
    got = in_rows([msg], me, lay)[0]
    want = np.array(old_row_values(msg, me, lay), np.float64)
    assert got[R.STATUS] == want[R.STATUS], (msg, got.tolist(), want.tolist())
    read = slice(None) if want[R.STATUS] != R.MALFORMED else [R.TICK, R.SENDER, R.VX, R.VY]
    assert got[read].tobytes() == want[read].tobytes(), (msg, got.tolist(), want.tolist())


@pytest.mark.parametrize("lay", LAYOUTS, ids=["kinematic", "dynamic", "detection", "detection-1"])
def test_every_single_forgery_gives_the_old_row(lay: R.Layout) -> None:
    """Each part of a valid message forged alone, with every value of FORGED: each shared value, each slot of
    the receiver's pair entry, the velocity and the stage; each shared key dropped; the pair entry cut,
    lengthened, None, dropped."""
    out = np.zeros(lay.size_out)
    out[R.PHASE] = 3.0
    if lay.dynamic:
        out[lay.dg] = 2.0
    nbrs = NBRS[:lay.degree]
    m = R.state_from_row(out, lay, nbrs)
    me = nbrs[0]
    pz = m.pair[me]
    msgs = [StateMsg(1, 2, m.vx, m.vy, m.phase, {q: v for q, v in m.shared.items() if q != k}, m.pair)
            for k in lay.keys]
    msgs += [StateMsg(1, 2, m.vx, m.vy, m.phase, m.shared, {**m.pair, me: p}) for p in (pz[:-1], (*pz, 0.0), None)]
    for bad in FORGED:
        msgs += [StateMsg(1, 2, m.vx, m.vy, m.phase, {**m.shared, k: bad}, m.pair) for k in lay.keys]
        msgs += [StateMsg(1, 2, m.vx, m.vy, m.phase, m.shared, {me: (*pz[:c], bad, *pz[c + 1:])})
                 for c in range(len(pz))]
        msgs += [StateMsg(1, 2, bad, m.vy, m.phase, m.shared, m.pair),
                 StateMsg(1, 2, m.vx, bad, m.phase, m.shared, m.pair),
                 StateMsg(1, 2, m.vx, m.vy, bad, m.shared, m.pair)]  # type: ignore[arg-type]
    for msg in msgs:
        _assert_old_row(lay, msg, me)


@pytest.mark.parametrize("lay", LAYOUTS[:3], ids=["kinematic", "dynamic", "detection"])
def test_the_kinematic_out_row_is_the_team_s_message_head(lay: R.Layout) -> None:
    """write_kin_out: the header, kinematic states and pair heads of every row, the rest zero; compiled ==
    interpreted; a row's neighbours beyond its degree stay empty."""
    rng = np.random.default_rng(3)
    B = 3
    res = rng.normal(size=(B, R_PAIRS + 4 * lay.degree))
    res[:, R_OM_INIT] = [0.0, 1.0, 1.0]
    meas = rng.normal(size=(B, 6))
    deg = np.array([lay.degree, 1, 0], np.int64)
    out = np.full((B, lay.size_out), 9.0)
    write_kin_out(out, 17, np.array([4, 5, 6], np.int64), meas, deg, res, lay.lay)
    for b in range(B):
        v = out[b]
        assert v[[R.TICK, R.SENDER, R.VX, R.VY, R.PHASE]].tolist() == [17.0, 4.0 + b, meas[b, 0], meas[b, 1],
                                                                         float(b > 0)]
        assert v[[R.OM, R.OI, R.PH, R.YX, R.YY]].tolist() == [res[b, R_OMEGA], float(b > 0), res[b, R_PHI],
                                                              res[b, R_Y], res[b, R_Y + 1]]
        for k in range(lay.degree):
            q = lay.p0 + k * lay.block
            want = res[b, R_PAIRS + 4 * k:R_PAIRS + 4 * k + 4].tolist() if k < deg[b] else [0.0] * 4
            assert v[q:q + 4].tolist() == want
    if JIT:
        again = np.full((B, lay.size_out), 9.0)
        write_kin_out.py_func(again, 17, np.array([4, 5, 6], np.int64), meas, deg, res, lay.lay)
        assert again.tobytes() == out.tobytes()
