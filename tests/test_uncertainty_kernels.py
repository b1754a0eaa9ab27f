"""The uncertainty kernels (agents/kernels/uncertainty.py): on states recorded from the Python DynamicPhase
(tests/dynamic_reference.py) in quick-dynamics runs (the flow average's row, the first-heard order of its
neighbours, the local sds, and what ``DynamicPhase.uncertainties`` returned), the kernel gives the Python's
result bit for bit, compiled equals the same source interpreted (``py_func``), and a row's result does not
depend on the batch it is in."""

from __future__ import annotations

import math

import dynamic_reference as DP
import numpy as np
import pytest

from agents.kernels import uncertainty as K
from agents.kernels.agreement import FLOW, X, flow_average_bank
from config.loader import load_scenario

PAIRS = ((K.CH_MN, K.CH_MW), (K.CH_JN, K.CH_JW))
D = 4  # the largest degree recorded: every recorded row fits a bank of D slots


def _record(overrides: list[str], loss: float, loss_until: int, seed: int) -> list[tuple]:
    """Runs quick-dynamics on links of one tick that lose each message with probability ``loss`` up to tick
    ``loss_until`` (so that neighbours are first heard out of id order), and records at every tick each
    agent's (flow-average row in a bank of D slots, slots in first-heard order, m_local_sd, j_local_sd,
    DynamicPhase.uncertainties())."""
    from agents.factory import member
    from agents.team import handle_inbox
    from simulator.plant import Plant, sensor_rng

    recs: list[tuple] = []

    def record(self):  # noqa: ANN001, ANN202
        out = self.uncertainties()
        avg = self.avg
        slot = {j: k for k, j in enumerate(avg.ids)}
        spreads = tuple(DP.spread_sd(avg.x[num] / avg.x[wch], (xj[num] / xj[wch] for xj in avg.nx.values()
                                                            if xj[wch] > 0.0)) if avg.x[wch] > 0.0 else None
                        for num, wch in PAIRS)  # as the phase computes them
        recs.append((_row_in_bank(avg._F[avg._b], avg.deg), [slot[j] for j in avg.nx], self.m_local_sd,
                     self.j_local_sd, out, spreads))
        return out

    sc = load_scenario("quick-dynamics", overrides)
    nbrs = sc.neighbours()
    senders = [[i for i in range(sc.n) if r in nbrs[i]] for r in range(sc.n)]
    drop = np.random.default_rng(seed)
    plant = Plant(sc)
    team = DP.ReferenceTeam([member(sc.agent_view(i)) for i in range(sc.n)], 2)  # the team runs the reference
    rng = sensor_rng(sc.seed)
    for k in range(sc.ticks):
        due = [[(k - 1, s) for s in row if k > loss_until or drop.random() >= loss] if k else [] for row in senders]
        wr = team.step(k, plant.measure(rng).tolist(), handle_inbox(team, k, due))
        for dp in team.ref:
            record(dp)
        plant.apply_and_step(wr)
    return recs


def _row_in_bank(row: np.ndarray, deg: int) -> np.ndarray:
    """A flow-average row of ``deg`` slots laid out as a row of a bank of D slots (the same values)."""
    F, _ = flow_average_bank(1, D, row.shape[1])
    F[0, :FLOW] = row[:FLOW]
    for part in range(3):
        F[0, FLOW + part * D:FLOW + part * D + deg] = row[FLOW + part * deg:FLOW + (part + 1) * deg]
    return F[0]


def _order(order: list[int]) -> np.ndarray:
    out = np.full((1, D), -1, np.int64)
    out[0, :len(order)] = order
    return out


SCENARIOS = {
    "fault-free": ([], 0.0, 0, 0),
    # neighbours first heard out of id order, stale x_j later on; degrees 3 and 4 (two terms commute) in a graph
    # that is not complete (whose x_j agree exactly), so that the order of the spread's sum reaches its bits
    "lossy-chords": (['graph.topology="explicit"', "graph.edges=[[0,1],[1,2],[2,3],[3,4],[0,2],[2,4],[1,3]]"],
                     0.4, 400, 3),
}


@pytest.fixture(scope="module", params=list(SCENARIOS))
def recorded(request) -> tuple[str, list[tuple]]:  # noqa: ANN001
    return request.param, _record(*SCENARIOS[request.param])


@pytest.fixture
def recs(recorded) -> list[tuple]:  # noqa: ANN001
    return recorded[1]


def test_the_channels_are_the_phase_s():
    assert (K.CH_MN, K.CH_MW, K.CH_JN, K.CH_JW) == (DP.CH_MN, DP.CH_MW, DP.CH_JN, DP.CH_JW)


def test_the_recording_covers_the_branches(recorded):
    name, recs = recorded
    assert len(recs) > 2000
    if name == "lossy-chords":
        assert sum(r[1] != sorted(r[1]) for r in recs) > 1000  # first heard: not in id order
        # and the id order instead of the first-heard one would change a spread's bits (6 records of 17,000)
        assert any(repr(K.spread_sd(0, F[X, num] / F[X, wch], F[None], _order(sorted(order)), num, wch)) != repr(s)
                   for F, order, *_, spreads in recs for (num, wch), s in zip(PAIRS, spreads, strict=True)
                   if s is not None)
    outs = [r[4] for r in recs]
    assert any(math.isnan(m) for m, _ in outs) and any(not math.isnan(j) for _, j in outs)  # NaN until offered
    F = np.array([r[0] for r in recs])
    # a spread over two or more neighbours with a positive weight and a local sd: the whole formula
    assert any(len(r[1]) >= 2 and r[2] == r[2] and (F[i, FLOW + 2 * D + np.array(r[1]), K.CH_MW] > 0.0).all()
               for i, r in enumerate(recs))


def test_kernel_equals_the_python_phase(recs):
    for F, order, m_sd, j_sd, out, spreads in recs:
        got = K.uncertainties(0, F[None], _order(order), m_sd, j_sd)
        assert repr(got) == repr(out), (order, m_sd, j_sd)
        for (num, wch), s in zip(PAIRS, spreads, strict=True):
            if s is not None:
                assert repr(K.spread_sd(0, F[X, num] / F[X, wch], F[None], _order(order), num, wch)) == repr(s)


def test_compiled_equals_interpreted(recs):
    for F, order, m_sd, j_sd, *_ in recs[::7]:
        args = (0, F[None], _order(order), m_sd, j_sd)
        assert repr(K.uncertainties(*args)) == repr(K.uncertainties.py_func(*args))
        for num, wch in PAIRS:
            own = F[X, num] / F[X, wch] if F[X, wch] > 0.0 else 0.0
            args = (0, own, F[None], _order(order), num, wch)
            assert repr(K.spread_sd(*args)) == repr(K.spread_sd.py_func(*args))


def test_a_batch_of_n_equals_n_batches_of_one(recs):
    rows = recs[::5]
    F = np.array([r[0] for r in rows])
    order = np.concatenate([_order(r[1]) for r in rows])
    for b, (_, _, m_sd, j_sd, out, _) in enumerate(rows):
        assert repr(K.uncertainties(b, F, order, m_sd, j_sd)) == repr(out)


def test_spread_skips_unweighted_and_nan_values_and_stops_at_the_order_s_end():
    F, _ = flow_average_bank(1, 3, K.CH_JW + 1)
    nx = FLOW + 2 * 3
    F[0, X, K.CH_MN], F[0, X, K.CH_MW] = 2.0, 2.0  # own m = 1
    F[0, nx + 0, K.CH_MN], F[0, nx + 0, K.CH_MW] = 2.0, 1.0  # 2: counted
    F[0, nx + 1, K.CH_MN], F[0, nx + 1, K.CH_MW] = 5.0, 0.0  # no weight: skipped
    F[0, nx + 2, K.CH_MN], F[0, nx + 2, K.CH_MW] = math.nan, 1.0  # NaN: skipped
    for fn in (K.spread_sd, K.spread_sd.py_func):
        assert fn(0, 1.0, F, np.array([[2, 1, 0]]), K.CH_MN, K.CH_MW) == 1.0
        assert fn(0, 1.0, F, np.array([[1, -1, 0]]), K.CH_MN, K.CH_MW) == 0.0  # slot 0 is past the end
    m, j = K.uncertainties(0, F, np.array([[2, 1, 0]]), 0.75, 0.5)
    assert m == 1.25 and math.isnan(j)  # hypot(0.75, 1.0); J's weight is 0
    F[0, X, K.CH_JN], F[0, X, K.CH_JW] = 3.0, 1.0
    F[0, nx + 0, K.CH_JN], F[0, nx + 0, K.CH_JW] = 1.0, 1.0
    assert K.uncertainties(0, F, np.array([[0, -1, -1]]), math.nan, math.nan) == (1.0, 2.0)  # NaN sd: the spread
