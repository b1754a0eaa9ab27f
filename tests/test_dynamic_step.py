"""The fused tick of the dynamical phase (agents/kernels/dynamic_step.py): on its calls recorded from
quick-dynamics runs (every stop for a Python handler included: the detection, a restart's fit, a law), compiled
equals the same source interpreted (``py_func``) bit for bit, and two agents' rows in one call give each
the bits of its own call."""

from __future__ import annotations

import numpy as np
import pytest

from agents.kernels import dynamic_step as T
from config.loader import load_scenario
from net.rows import SENDER

AGENTS = (1, 2)  # degree 2 on the line: their rows stack into one batch
SCENARIOS = {
    "quick-dynamics": ([], 1),
    "online": (["duration=16", "plant.friction.viscous=5", "dynamics.online_detection=true"], 2),
    "lock": (["dynamics.lock_nis=1.8", "dynamics.lock_hold_s=0.5", "dynamics.brake=0.5"], 1),
    "law": (['control.law="agents.laws:TrackVelocity"', "control.law_params={v_ref=[0.3, 0.0], omega_ref=0.0}"], 1),
}


def _record(overrides: list[str], age: int) -> list[tuple]:
    """(arguments before, arguments after, result) of agents 1 and 2's rows in the team's dyn_tick calls, each cut
    to a call of its own (the batch's results as the row's), on every 5th tick and on every call that starts or
    stops at a Python handler."""
    from agents.factory import build_team
    from coload.runs.team import team_ticks
    from simulator.plant import Plant

    recs: list[tuple] = []
    orig = T.dyn_tick

    def rec(*args):  # noqa: ANN002, ANN202
        tick = int(args[2][args[0][0], T.K_TICK])
        mine = [b for b in args[0].tolist() if int(args[10][b, SENDER]) in AGENTS]
        before = [_row(args, b) for b in mine]
        left = orig(*args)
        for b, x in zip(mine, before, strict=True):
            stop = int(args[1][b] != T.AT_END)
            if tick % 5 == 0 or x[1][0] != T.AT_BEGIN or stop:
                recs.append((x, _row(args, b), stop))
        return left

    sc = load_scenario("quick-dynamics", overrides)
    T.dyn_tick = rec
    try:
        team = build_team([sc.agent_view(i) for i in range(sc.n)], age + 1)
        for _ in team_ticks(sc, Plant(sc), team, age):
            pass
    finally:
        T.dyn_tick = orig
    return recs


def _row(args: tuple, b: int) -> tuple:
    """Row b of a team's dyn_tick call as a call of its own (copies)."""
    rows, at, kin, inbox, in_ptr, late_t, late_z, lay, ids, res, out, est, *banks = args
    lo, hi = int(in_ptr[b]), int(in_ptr[b + 1])
    one = (at, kin, None, None, late_t, late_z, None, ids, res, out, est, *banks)
    cut = tuple(None if a is None else a[b:b + 1].copy() for a in one)
    return (np.zeros(1, np.int64), cut[0], cut[1], inbox[lo:hi].copy(), np.array([0, hi - lo], np.int64), *cut[4:6],
            lay.copy(), *cut[7:])


@pytest.fixture(scope="module", params=list(SCENARIOS))
def recs(request) -> tuple[str, list]:  # noqa: ANN001
    return request.param, _record(*SCENARIOS[request.param])


def _same(x: tuple, y: tuple) -> bool:
    return all(a.tobytes() == b.tobytes() for a, b in zip(x, y, strict=True))


def test_the_recording_covers_the_stops(recs):
    name, calls = recs
    assert len(calls) > 200
    starts = {int(before[1][0]) for before, _, _ in calls}
    stops = {int(after[1][0]) for _, after, _ in calls}
    if name == "online":
        assert T.AT_UPDATE in stops and T.AT_UPDATE in starts  # P1 every tick
    if name == "lock":
        assert T.AT_CONTROL in stops and T.AT_CONTROL in starts  # P2's restarts
    if name == "law":
        assert T.AT_FINISH in stops and T.AT_FINISH in starts  # P3 from the done stage on
    assert T.AT_END in stops


def test_compiled_equals_py_func(recs):
    for before, after, left in recs[1]:
        got = tuple(a.copy() for a in before)
        assert T.dyn_tick.py_func(*got) == left
        assert _same(got, after)


def _stack(a: tuple, b: tuple) -> tuple:
    """Two one-row calls' arguments as one call of two rows (rows [0, 1])."""
    rows, at, kin, inbox, in_ptr, late_t, late_z, lay, ids, res, out, est, *banks = (
        tuple(np.concatenate((x, y)) if i not in (0, 3, 4, 5, 6, 7) else None for i, (x, y) in
              enumerate(zip(a, b, strict=True))))
    inbox = np.concatenate((a[3], b[3]))
    in_ptr = np.array([0, a[4][1], a[4][1] + b[4][1]], np.int64)
    w = max(a[5].shape[1], b[5].shape[1])
    late_t = np.full((2, w), -1, np.int64)
    late_z = np.zeros((2, w))
    for r, x in enumerate((a, b)):
        late_t[r, :x[5].shape[1]] = x[5][0]
        late_z[r, :x[6].shape[1]] = x[6][0]
    return (np.array([0, 1], np.int64), at, kin, inbox, in_ptr, late_t, late_z, a[7], ids, res, out, est, *banks)


def test_batch_of_one_equals_batch_of_two(recs):
    """Agents 1 and 2 of the same tick and starting point, stacked: each row's results are its own call's."""
    by: dict[tuple, dict[int, tuple]] = {}
    for call in recs[1]:
        before = call[0]
        by.setdefault((int(before[2][0, T.K_TICK]), int(before[1][0])), {})[int(before[10][0, SENDER])] = call
    n = 0
    for pair in by.values():
        if len(pair) < 2:
            continue
        (b1, a1, l1), (b2, a2, l2) = pair[AGENTS[0]], pair[AGENTS[1]]
        got = _stack(b1, b2)
        assert T.dyn_tick(*got) == l1 + l2
        for i in (1, 2, *range(8, len(got))):
            assert got[i][0:1].tobytes() == a1[i].tobytes() and got[i][1:2].tobytes() == a2[i].tobytes(), i
        n += 1
    assert n > 50
