"""agents/kernels/message_rows.py: an in-process IN row gathered from a sender's OUT row equals, bit for bit,
the row the edge codec makes of the message that OUT row stands for (``row_values(state_from_row(out))``),
for valid rows and rows with NaN, infinite, fractional, negative-zero and out-of-range values in any slot;
compiled == interpreted."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agents.kernels.kinematic import R_OM_INIT, R_OMEGA, R_PAIRS, R_PHI, R_Y
from agents.kernels.message_rows import gather_inbox, write_kin_out
from net import rows as R

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
    nbrs = NBRS[:lay.degree]
    me = nbrs[blk] if blk >= 0 else 99
    return np.array(R.row_values(R.state_from_row(out, lay, nbrs), me, lay), np.float64)


@settings(max_examples=400, deadline=None, derandomize=True)
@given(case=cases())
def test_a_gathered_row_is_the_edge_codec_s_row_of_the_message(case: tuple[R.Layout, np.ndarray, int]) -> None:
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
