"""net/rows.py: a state message as a float row and back, and what the row says of a malformed message.

Valid messages round-trip (message -> IN row -> message, equal by repr: Python floats and ints, the same key
order); an estimate round-trips through its row. A malformed message's IN row (agents/kernels/message_rows.py
``in_rows``: net/rows.py's decode, then the compiled check) classifies it as the receive path does: dropped, its
dynamical states taken only, or taken; the cases are a frozen table, checked here against ``AgentCore.step``
and, through the table, against any later receive path.
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from agents.agent import AgentCore
from agents.effect_decision import N_EFF
from agents.kernels.message_rows import in_rows
from agents.stage_agreement import MASK_BITS, mask_keys
from config.agent_params import ControlSpec, DynamicsSpec, EstimatorSpec
from net import rows as R
from net.messages import StateMsg
from net.vocabulary import ESTIMATE_NAMES

N = 3
NCH_DETECT = 37  # the dynamical phase's channels with online detection (agents/dynamic_phase.py)


def _spec(dyn: bool) -> DynamicsSpec | None:
    return DynamicsSpec(algorithm="sequential", online_detection=True) if dyn else None


def _core(me: int, nbrs: list[int], dyn: bool) -> AgentCore:
    return AgentCore(me, nbrs, N, 0.01, 0.3, EstimatorSpec(), ControlSpec(), _spec(dyn))


def _layout(dyn: bool, degree: int = 2) -> R.Layout:
    return R.Layout(dyn, NCH_DETECT, len(mask_keys(N)), dyn, degree)


def _base_msg(dyn: bool) -> StateMsg:
    """Agent 0's message of tick 0 (its neighbour: 1)."""
    return _core(0, [1], dyn).step(0, 0.25, -0.5, []).state


def _outcome(dyn: bool, msg: StateMsg) -> str:
    """What agent 1 (neighbours 0 and 2) does with ``msg`` (of tick 0) at tick 1."""
    core = _core(1, [0, 2], dyn)
    core.step(1, 0.0, 0.0, [msg])
    taken = core.nbr["last"][0, 0] == msg.tick  # (slot 0: neighbour 0)
    dyn_in = core._dyn is not None and msg.sender in core._dyn.nbr_stage
    assert core.dropped_stale == (0 if taken else 1) and core.dropped_unknown == 0
    return "taken" if taken else "dynamic" if dyn_in else "dropped"


def _row_class(row: np.ndarray, lay: R.Layout) -> str:
    """The receiving kernel's reading of an IN row whose header it accepts (docs/fast-core-plan.md
    section 2): the status, then the finiteness sum over the kinematic values in the old order."""
    v = row.tolist()
    if v[R.STATUS] == R.MALFORMED:
        return "dropped"
    p = lay.p0
    chk = v[R.OM] + v[R.PH] + v[R.YX] + v[R.YY] + v[p] + v[p + 1] + v[p + 2] + v[p + 3] + v[R.VX] + v[R.VY]
    if v[R.STATUS] == R.KIN_MALFORMED or chk - chk != 0.0:
        return "dynamic" if lay.dynamic else "dropped"
    return "taken"


BAD = {"x": "x", "true": True, "none": None, "nan": math.nan, "inf": math.inf, "half": 0.5, "neg": -1.0}


def _mutations(base: StateMsg, dyn: bool):
    """(name, message): each shared key dropped or replaced, the pair's entry dropped, cut, lengthened or
    spoilt, the velocity and the stage spoilt."""
    sh = base.shared
    keys = [k for k in sh if not (k.startswith("c") and k not in ("c0", f"c{NCH_DETECT - 1}"))]
    for k in keys:
        yield f"-{k}", StateMsg(0, 0, base.vx, base.vy, base.phase, {q: v for q, v in sh.items() if q != k}, base.pair)
        for bn, bv in BAD.items():
            yield f"{k}={bn}", StateMsg(0, 0, base.vx, base.vy, base.phase, {**sh, k: bv}, base.pair)
    pz = base.pair[1]
    yield "-pair", StateMsg(0, 0, base.vx, base.vy, base.phase, sh, {})
    yield "pair-other", StateMsg(0, 0, base.vx, base.vy, base.phase, sh, {2: pz})
    yield "pair-short", StateMsg(0, 0, base.vx, base.vy, base.phase, sh, {1: pz[:-1]})
    yield "pair-long", StateMsg(0, 0, base.vx, base.vy, base.phase, sh, {1: (*pz, 0.0)})
    yield "pair-none", StateMsg(0, 0, base.vx, base.vy, base.phase, sh, {1: None})
    for pos in sorted({0, 3, 4, len(pz) - 1} & set(range(len(pz)))):
        for bn in ("x", "nan", "inf", "true"):
            bad = list(pz)
            bad[pos] = BAD[bn]
            yield f"pair[{pos}]={bn}", StateMsg(0, 0, base.vx, base.vy, base.phase, sh, {1: tuple(bad)})
    for bn in ("x", "nan", "inf", "true", "none"):
        yield f"vx={bn}", StateMsg(0, 0, BAD[bn], base.vy, base.phase, sh, base.pair)
        yield f"vy={bn}", StateMsg(0, 0, base.vx, BAD[bn], base.phase, sh, base.pair)
    yield "phase=x", StateMsg(0, 0, base.vx, base.vy, "x", sh, base.pair)  # type: ignore[arg-type]
    yield "phase=2.5", StateMsg(0, 0, base.vx, base.vy, 2.5, sh, base.pair)  # type: ignore[arg-type]
    yield "shared-none", StateMsg(0, 0, base.vx, base.vy, base.phase, None, base.pair)  # type: ignore[arg-type]
    yield "pair-list", StateMsg(0, 0, base.vx, base.vy, base.phase, sh, [pz])  # type: ignore[arg-type]
    yield "ok", base


def _table(**groups: str) -> dict[str, str]:
    return {name: outcome for outcome, names in groups.items() for name in names.split()}


# the frozen table: (dynamical phase, mutation) -> what the receive path does (generated from AgentCore.step
# before the kinematic phase moved to the kernel; "raises": that step raised OverflowError, int() of an
# infinite integral field, which the wire's schema never lets through; the rows drop it)
TABLE_KIN = _table(
    dropped=("-om om=x om=none om=nan om=inf -oi oi=x oi=none -ph ph=x ph=none ph=nan ph=inf -yx yx=x yx=none "
             "yx=nan yx=inf -yy yy=x yy=none yy=nan yy=inf pair-short pair-long pair[0]=x pair[0]=nan pair[0]=inf "
             "pair[3]=x pair[3]=nan pair[3]=inf vx=x vy=x vx=nan vy=nan vx=inf vy=inf vx=none vy=none shared-none "
             "pair-list"),
    taken=("om=true om=half om=neg oi=true oi=nan oi=inf oi=half oi=neg ph=true ph=half ph=neg yx=true yx=half "
           "yx=neg yy=true yy=half yy=neg -pair pair-other pair-none pair[0]=true pair[3]=true vx=true vy=true "
           "phase=x phase=2.5 ok"),
)
TABLE_DYN = _table(
    dropped=("-om om=x om=none -oi oi=x oi=none -ph -yx -yy -c0 c0=x c0=none c0=nan c0=inf -c36 c36=x c36=none "
             "c36=nan c36=inf -dg dg=x dg=none dg=nan dg=half dg=neg -Sk Sk=x Sk=none Sk=nan -ps ps=x ps=none "
             "ps=nan ps=inf -B0 B0=x B0=none B0=nan B0=inf B0=half B0=neg -Bt Bt=x Bt=none Bt=nan -Bs Bs=x Bs=none "
             "Bs=nan -Ds Ds=x Ds=none Ds=nan Ds=half -De De=x De=none De=nan De=half -Dz Dz=x Dz=none Dz=nan "
             "Dz=inf pair-short pair-long pair[4]=x pair[40]=x phase=x shared-none pair-list"),
    taken=("om=true om=half om=neg oi=true oi=nan oi=inf oi=half oi=neg ph=true ph=half ph=neg yx=true yx=half "
           "yx=neg yy=true yy=half yy=neg c0=true c0=half c0=neg c36=true c36=half c36=neg dg=true Sk=true "
           "Sk=half Sk=neg ps=true ps=half ps=neg B0=true Bt=true Bt=half Bt=neg Bs=true Bs=half Bs=neg Ds=true "
           "Ds=neg De=true De=neg Dz=true Dz=half Dz=neg -pair pair-other pair-none pair[0]=true pair[3]=true "
           "pair[4]=nan pair[4]=inf pair[4]=true pair[40]=nan pair[40]=inf pair[40]=true vx=true vy=true "
           "phase=2.5 ok"),
    dynamic=("om=nan om=inf ph=x ph=none ph=nan ph=inf yx=x yx=none yx=nan yx=inf yy=x yy=none yy=nan yy=inf "
             "pair[0]=x pair[0]=nan pair[0]=inf pair[3]=x pair[3]=nan pair[3]=inf vx=x vy=x vx=nan vy=nan vx=inf "
             "vy=inf vx=none vy=none"),
    raises="dg=inf Sk=inf Bt=inf Bs=inf Ds=inf De=inf",
)


def test_wire_constants_are_the_agents() -> None:
    assert R.MASK_BITS == MASK_BITS
    assert R.N_DECISION_CODES == 2 * N_EFF


def test_layout_slots() -> None:
    lay = _layout(True)
    base = _base_msg(True)
    assert lay.keys == tuple(base.shared)  # the order the agent writes them
    assert lay.size_in == R.OM + len(base.shared) + len(base.pair[1])
    assert lay.block == len(base.pair[1]) == R.PAIR_HEAD + NCH_DETECT
    assert lay.keys[lay.dg - R.OM] == "dg" and lay.keys[lay.ds - R.OM] == "Ds" and lay.keys[lay.b0 - R.OM] == "B0"
    assert lay.lay[R.L_SIZE_OUT] == lay.size_out == lay.p0 + 2 * lay.block
    kin = _layout(False)
    assert kin.keys == tuple(_base_msg(False).shared) and kin.block == R.PAIR_HEAD and kin.dg == -1
    # the plan's sizes (n = 10 line): 57 floats nominal, 141 with detection
    assert R.Layout(True, 10, 1, False, 2).size_out == 57 and R.Layout(True, 37, 1, True, 2).size_out == 141


def _out_row(msg: StateMsg, lay: R.Layout, nbrs: list[int]) -> np.ndarray:
    """An OUT row of ``msg``: its head and every neighbour's block, as the sending kernel lays them out."""
    out = np.zeros(lay.size_out)
    for k, j in enumerate(nbrs):
        row = in_rows([msg], j, lay)[0]
        assert row[R.STATUS] == R.OK and row[R.HAS_PAIR] == 1.0
        out[:lay.p0] = row[:lay.p0]
        out[lay.p0 + k * lay.block:lay.p0 + (k + 1) * lay.block] = row[lay.p0:]
    return out


def test_a_team_s_messages_and_estimates_round_trip() -> None:
    """Three agents in a line exchange their messages for 120 ticks (synthetic velocities): every message
    and estimate goes through its rows unchanged, by repr."""
    for dyn in (False, True):
        nbrs = {0: [1], 1: [0, 2], 2: [1]}
        cores = {i: _core(i, nbrs[i], dyn) for i in nbrs}
        rng = np.random.default_rng(3)
        last: dict[int, StateMsg] = {}
        for k in range(120):
            now = {}
            for i, core in cores.items():
                inbox = [last[j] for j in nbrs[i] if j in last]
                r = core.step(k, float(rng.normal()), float(rng.normal()), inbox)
                now[i] = r.state
                lay = _layout(dyn, len(nbrs[i]))
                out = _out_row(r.state, lay, nbrs[i])
                assert repr(R.state_from_row(out, lay, nbrs[i])) == repr(r.state)
                est = np.array(list(r.estimate.values.values()))
                assert tuple(r.estimate.values) == ESTIMATE_NAMES
                assert repr(R.estimate_from_row(est, out, lay, nbrs[i])) == repr(r.estimate)
            last = now


finite = st.floats(-1e300, 1e300)  # (ten of them sum to a finite number: the receiver's check)
integral = st.integers(-(2**40), 2**40).map(float)


@st.composite
def _valid(draw, dyn: bool) -> StateMsg:
    lay = _layout(dyn, 1)
    sh = {"om": draw(finite), "oi": draw(st.sampled_from([0.0, 1.0])), "ph": draw(finite), "yx": draw(finite),
          "yy": draw(finite)}
    if dyn:
        sh |= {f"c{c}": draw(finite) for c in range(lay.nch)}
        sh |= {"dg": float(draw(st.integers(1, 1000))), "Sk": draw(integral), "ps": draw(finite)}
        sh |= {k: float(draw(st.integers(0, 2**MASK_BITS - 1))) for k in mask_keys(N)}
        sh |= {"Bt": draw(integral), "Bs": draw(integral)}
        sh |= {"Ds": draw(integral), "De": float(draw(st.integers(-1, 2 * N_EFF - 1))), "Dz": draw(finite)}
    pz = tuple(draw(finite) for _ in range(lay.block))
    phase = draw(st.integers(0, 7))
    return StateMsg(draw(st.integers(0, 2**53)), draw(st.integers(0, 10**6)), draw(finite), draw(finite), phase, sh,
                    {5: pz})


@settings(max_examples=60, deadline=None)
@given(msg=st.booleans().flatmap(lambda d: st.tuples(st.just(d), _valid(d))))
def test_valid_messages_round_trip(msg: tuple[bool, StateMsg]) -> None:
    dyn, m = msg
    lay = _layout(dyn, 1)
    row = in_rows([m], 5, lay)[0]
    assert row[R.STATUS] == R.OK and row[R.HAS_PAIR] == 1.0 and _row_class(row, lay) == "taken"
    assert repr(R.state_from_row(row, lay, [5])) == repr(m)
    # a receiver the sender has sent nothing for yet: zeros in its block
    none = in_rows([m], 6, lay)[0]
    assert none[R.HAS_PAIR] == 0.0 and not none[lay.p0:].any() and (none[:R.HAS_PAIR] == row[:R.HAS_PAIR]).all()


def test_malformed_messages_are_classified_as_the_receive_path_does() -> None:
    for dyn, table in ((False, TABLE_KIN), (True, TABLE_DYN)):
        base = _base_msg(dyn)
        lay = _layout(dyn)
        seen = set()
        for name, msg in _mutations(base, dyn):
            seen.add(name)
            row = in_rows([msg], 1, lay)[0]
            want = "dropped" if table[name] == "raises" else table[name]
            assert _row_class(row, lay) == want, (dyn, name)
            assert _outcome(dyn, msg) == want, (dyn, name)
            # an overtaken message is used for its velocity alone: kept whatever the status, NaN if not a number
            for slot, v in ((R.VX, msg.vx), (R.VY, msg.vy)):
                ok = isinstance(v, (int, float))
                assert (row[slot] == float(v)) if ok and v == v else math.isnan(row[slot]), (dyn, name)
        assert seen == set(table)
