"""The dynamical phase's wire: its message decoder and the stage barrier's wire form; one flow edge.

A neighbour's dynamical states are decoded and checked before anything of them is kept; the barrier's
wire form round-trips; one flow exchange removes the asymmetry a lost message leaves.
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from agents import dynamic_phase as D
from agents import stage_agreement as SA
from agents.consensus import flow_step

finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_infinity=False)


@settings(max_examples=60, deadline=None)
@given(f_ij=finite, f_ji=finite, eps=st.floats(0.0, 0.5), d=finite)
def test_flow_edge_is_antisymmetric_after_one_exchange(f_ij: float, f_ji: float, eps: float, d: float) -> None:
    """Both ends update from each other's previous flows with opposite differences: whatever asymmetry
    F_ij + F_ji a lost message left, it is gone after the exchange (the network sum is exact again)."""
    a = flow_step(f_ij, f_ji, eps, d)
    b = flow_step(f_ji, f_ij, eps, -d)
    assert abs(a + b) <= 1e-9 * (1 + abs(f_ij) + abs(f_ji) + abs(d))
    assert flow_step(f_ij, f_ji, eps, None) == 0.5 * (f_ij - f_ji)


def test_dynamic_states_are_decoded_and_checked_at_the_edge() -> None:
    """A neighbour's dynamical states are checked as a whole by the receive path (net/rows.py's decode, the
    compiled check of agents/kernels/message_rows.py): one bad value or missing key marks the row malformed
    (nothing of it is taken); the flows default to zeros when it sent none for us yet."""
    from agents.kernels import dynamic as K
    from agents.kernels.agreement import FLOW
    from agents.kernels.message_rows import in_rows
    from config.agent_params import DynamicsSpec
    from net import rows as R
    from net.messages import StateMsg

    dyn = D.DynamicPhase(1, [0, 2], 3, 0.01, 0.1, DynamicsSpec())
    lay = dyn.lay
    o = np.zeros(lay.size_out)
    K.dyn_write_out(0, o, lay.lay, dyn._dyn, dyn._S, dyn._F, dyn._I)  # a fresh phase's OUT row
    out = {"om": 0.5, "oi": 1.0, "ph": 0.0, "yx": 0.0, "yy": 0.0,
           **dict(zip(lay.keys[len(R.KIN_KEYS):], o[R.OM + len(R.KIN_KEYS):lay.p0].tolist(), strict=True))}
    nch = dyn.nch
    flows = [0.5] * nch

    def row(sh: dict, fl: list | None = flows) -> np.ndarray:
        return in_rows([StateMsg(5, 0, 0.0, 0.0, K.KINEMATIC, sh, {} if fl is None else {1: (0, 0, 0, 0, *fl)})], 1,
                       lay)[0]

    def receive(v: np.ndarray) -> None:  # neighbour 0's row into its slot 0
        b = dyn._banks
        K.dyn_receive(0, 0, v, lay.lay, b[0], b[1], b[2], b[3], b[4], dyn._F, dyn._I)

    D2 = 2
    receive(row(dict(out)))
    assert dyn._F[0, FLOW + 2 * D2].tolist() == [float(out[k]) for k in dyn.ch_keys]
    assert dyn._F[0, FLOW + D2].tolist() == flows
    e = dyn._dnb[0, 0]
    assert (float(e["psi"]), int(e["psi_t"]), float(e["om"])) == (out["ps"], 5, 0.5)
    receive(row(dict(out), None))
    assert dyn._F[0, FLOW + D2].tolist() == [0.0] * nch  # none sent for us yet
    for bad in ({"c3": math.nan}, {"ps": math.inf}, {"dg": 0.0}, {"B0": 0.5}, {"B0": -1.0}):
        assert row({**out, **bad})[R.STATUS] == R.MALFORMED
    for missing in ("c0", "ps", "dg", "Bt", "Bs", "B0", "Sk"):
        assert row({k: v for k, v in out.items() if k != missing})[R.STATUS] == R.MALFORMED
    assert row(dict(out), flows[:-1])[R.STATUS] == R.MALFORMED
    assert row(dict(out), ["x"] * nch)[R.STATUS] == R.MALFORMED


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(2, 120),
    steps=st.lists(st.tuples(st.sampled_from(["ready", "merge", "reset"]), st.integers(0, 119), st.integers(-1, 500)),
                   max_size=12),
)
def test_stage_barrier_wire_form_round_trips(n: int, steps: list[tuple[str, int, int]]) -> None:
    bar = SA.StageBarrier(0, n, 7)
    other = SA.StageBarrier(1, n, 7)
    for kind, who, tick in steps:
        if kind == "ready":
            bar.set_ready(tick)
        elif kind == "merge":
            bar.merge((1 << (who % n)) | 1, tick, -1 if tick % 3 else tick)
        else:
            bar.reset()
        wire = bar.encode()
        assert set(wire) == {*SA.mask_keys(n), "Bt", "Bs"}
        assert all(float(v).is_integer() and 0 <= v < 2.0**SA.MASK_BITS
                   for k, v in wire.items() if k.startswith("B") and k[1:].isdigit())
        assert other.decode(wire) == (bar.mask, bar.tmax, bar.switch)
