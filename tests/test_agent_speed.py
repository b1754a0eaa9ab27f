"""The agent step's fast paths compute exactly what the plain code computed (bit for bit).

The speed work on the agent step (docs/agent-step.md) rewrote FlowAverage's arithmetic as generated
straight-line code and caches the stage barrier's wire form; these tests hold them to the plain
formulation they replaced, on random inputs, including lost messages and changing barrier states.
"""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agents import dynamic as D

finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_infinity=False)


def _reference_update(a: D.FlowAverage) -> list[float]:
    """FlowAverage.update as first written (loops over neighbours and channels); mutates a.flow."""
    x = a.x
    tot = [0.0] * a.nch
    for j, fl in a.flow.items():
        xj = a.nx.get(j)
        if xj is not None:
            eps = 1.0 / (1.0 + max(a.deg, a.ndeg[j]))
            fji = a.nf[j]
            for c in range(a.nch):
                fl[c] = 0.5 * (fl[c] - fji[c]) + eps * (x[c] - xj[c])
        for c in range(a.nch):
            tot[c] += fl[c]
    return [a.u[c] - tot[c] for c in range(a.nch)]


def _bits(v: list[float]) -> list[str]:
    return [float(x).hex() for x in v]  # distinguishes -0.0 from 0.0, unlike ==


@settings(max_examples=60, deadline=None)
@given(
    nch=st.sampled_from([1, D.N_CH, D.N_CH_AUG]),
    nbrs=st.lists(st.integers(0, 30), min_size=0, max_size=4, unique=True),
    ticks=st.integers(1, 6),
    data=st.data(),
)
def test_unrolled_flow_update_is_bit_identical_to_the_loop(nch: int, nbrs: list[int], ticks: int, data) -> None:  # noqa: ANN001
    fast = D.FlowAverage(nbrs, nch)
    ref = D.FlowAverage(nbrs, nch)
    vec = st.lists(finite, min_size=nch, max_size=nch)
    for _ in range(ticks):
        u = data.draw(vec)
        fast.u[:] = u
        ref.u[:] = u
        for j in nbrs:
            if data.draw(st.booleans()):  # this tick's message from j arrived (else: lost)
                xj, fji = data.draw(vec), data.draw(vec)
                degj = data.draw(st.integers(1, 5))
                fast.receive(j, list(xj), fji, degj)
                ref.receive(j, list(xj), fji, degj)
        fast.update()
        ref.x = _reference_update(ref)
        assert _bits(fast.x) == _bits(ref.x)
        for j in nbrs:
            assert _bits(fast.flow[j]) == _bits(ref.flow[j])


def test_dynamic_receive_rejects_what_it_rejected_and_keeps_flows_in_place() -> None:
    from config.agent_params import DynamicsSpec

    dyn = D.DynamicPhase(1, [0, 2], 3, 0.01, 0.1, DynamicsSpec())
    out: dict[str, float] = {}
    dyn.shared(out)
    flows = [0.5] * dyn.avg.nch
    dyn.receive(0, 5, D.KINEMATIC, dict(out), flows)
    assert dyn.avg.nx[0] == [float(out[k]) for k in dyn.ch_keys]
    assert dyn.avg.nf[0] == flows and dyn.avg.nf[0] is not flows
    assert dyn.nbr_psi[0] == (out["ps"], 5)
    held = dyn.avg.flow[2]
    for bad in ({"c3": math.nan}, {"ps": math.inf}, {"dg": 0.0}, {"B0": 0.5}, {"B0": -1.0}):
        with pytest.raises(ValueError):
            dyn.receive(2, 6, D.KINEMATIC, {**out, **bad}, flows)
    for missing in ("c0", "ps", "dg", "Bt", "Bs", "B0"):
        with pytest.raises(KeyError):
            dyn.receive(2, 6, D.KINEMATIC, {k: v for k, v in out.items() if k != missing}, flows)
    with pytest.raises(ValueError):
        dyn.receive(2, 6, D.KINEMATIC, dict(out), flows[:-1])
    assert 2 not in dyn.avg.nx and 2 not in dyn.nbr_stage  # nothing of a rejected message was kept
    dyn.avg.update()
    assert dyn.avg.flow[2] is held  # the flows sent to j are updated in place


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(2, 120),
    steps=st.lists(st.tuples(st.sampled_from(["ready", "merge", "reset"]), st.integers(0, 119), st.integers(-1, 500)),
                   max_size=12),
)
def test_stage_barrier_cached_wire_form_follows_its_state(n: int, steps: list[tuple[str, int, int]]) -> None:
    bar = D.StageBarrier(0, n, 7)
    other = D.StageBarrier(1, n, 7)
    for kind, who, tick in steps:
        if kind == "ready":
            bar.set_ready(tick)
        elif kind == "merge":
            bar.merge((1 << (who % n)) | 1, tick, -1 if tick % 3 else tick)
        else:
            bar.reset()
        wire: dict[str, float] = {}
        bar.encode(wire)
        # the plain encoding, as first written
        plain = {key: float((bar.mask >> (c * D._MASK_BITS)) & ((1 << D._MASK_BITS) - 1))
                 for c, key in enumerate(bar.mask_keys)}
        plain.update(Bt=float(bar.tmax), Bs=float(bar.switch))
        assert wire == plain
        assert other.decode(wire) == (bar.mask, bar.tmax, bar.switch)
        assert other.decode(dict(wire)) == (bar.mask, bar.tmax, bar.switch)  # again, from the cache
