"""The window statistics kernels (agents/kernels/window_stats.py): compiled == interpreted (``py_func``) bit
for bit, and a row of a batch of n == a batch of one, on random input sequences (NaN innovations, covariances
that are not positive definite, stale and reordered neighbour states, filter restarts included)."""

import array
import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import agents.kernels.window_stats as ws
from agents.innovation_monitor import window_pvalues
from net.vocabulary import BACKGROUND

COMPILED = SimpleNamespace(**{k: getattr(ws, k) for k in (
    "monitor_observe", "monitor_judge", "trust_observe", "trust_entries", "evidence_observe", "detect_observe",
    "evidence_clear", "evidence_restart")})
INTERPRETED = SimpleNamespace(**{k: getattr(ws, k).py_func for k in vars(COMPILED)})
N_PAR = 5
SEEDS = settings(derandomize=True, max_examples=15, deadline=None)


def same(a: tuple, b: tuple) -> bool:
    """Every array of ``a`` equals its twin in ``b`` byte for byte (NaN and the sign of zero included)."""
    return all(x.tobytes() == y.tobytes() for x, y in zip(a, b, strict=True))


# ----------------------------------------------------------------------------------------- inputs
def monitor_inputs(rng: np.random.Generator, ticks: int) -> list[tuple]:
    out = []
    for _ in range(ticks):
        e = complex(*rng.normal(size=2))
        if rng.random() < 0.05:
            e = complex(math.nan, 0.0)
        s00, s11 = rng.gamma(2.0, size=2)
        s01 = rng.normal() * math.sqrt(s00 * s11) * (1.5 if rng.random() < 0.1 else 0.9)  # sometimes not PD
        vc = complex(*rng.normal(size=2)) if rng.random() < 0.9 else 0j
        out.append((e, s00, s01, s11, vc, rng.normal(), complex(*rng.normal(size=2)),
                    complex(*rng.normal(size=2)) * (rng.random() < 0.7)))
    return out


def trust_inputs(rng: np.random.Generator, ticks: int, degree: int) -> list[tuple]:
    out = []
    stage = 0
    for tick in range(ticks):
        if rng.random() < 0.02:
            stage = int(rng.integers(0, BACKGROUND + 1))
        taken = [(j, tick - int(rng.integers(0, 12))) for j in range(degree) if rng.random() < 0.6]
        taken = array.array("q", [x for i in rng.permutation(len(taken)) for x in taken[i]])
        out.append((tick, stage, taken, *np.where(rng.random(4) < 0.1, math.nan, rng.normal(size=4)).tolist()))
    return out


def update_inputs(rng: np.random.Generator, ticks: int) -> list[tuple]:
    out = []
    for _ in range(ticks):
        innov = np.array([*rng.normal(size=2), 1.0 + rng.random(), 0.5 * rng.normal(), 1.0 + rng.random()])
        if rng.random() < 0.05:
            innov[0] = math.nan
        sens_h = rng.normal(size=2 * N_PAR + 2 * int(rng.random() < 0.8))
        out.append((innov, sens_h, rng.random() < 0.05, rng.random() < 0.1))  # window ends, filter restarts
    return out


# ----------------------------------------------------------------------------------------- drivers
def run_monitor(k: SimpleNamespace, rows: tuple, b: int, seq: list[tuple]) -> None:
    mon_k, mon_f, mon_ws = rows
    for x in seq:
        if k.monitor_observe(b, mon_k, mon_ws, *x):
            p = window_pvalues(np.ascontiguousarray(mon_ws[b, :, 0]), mon_ws[b, :, 1:], 2)
            k.monitor_judge(b, mon_f, np.array(p))


def run_trust(k: SimpleNamespace, rows: tuple, b: int, seq: list[tuple]) -> np.ndarray:
    tr_i, tr_f, tr_nb, trc, trr = rows
    out = np.empty((len(seq), 6))
    for i, (tick, stage, taken, m, m_sd, J, J_sd) in enumerate(seq):
        k.trust_observe(b, tr_i, tr_nb, trc, trr, tick, stage, taken)
        k.trust_entries(b, tr_f, trc, m, m_sd, J, J_sd, out[i])
    return out


def run_evidence(k: SimpleNamespace, rows: tuple, b: int, seq: list[tuple], scored: np.ndarray) -> np.ndarray:
    ev_i, ev_f, sw, sh, sg, acc, den, hist = rows
    snaps = []
    for i, (innov, sens_h, close, restart) in enumerate(seq):
        if i % 3:
            k.detect_observe(b, *rows, innov, sens_h, scored)
        else:  # the view's direct form (tests of effect_decision use it)
            k.evidence_observe(b, *rows, innov[0], innov[1], sens_h[:2 * N_PAR].reshape(N_PAR, 2), 0.0, -0.0)
        if close:
            snaps.append(np.concatenate([sw[b], sh[b], sg[b], acc[b], den[b], ev_f[b], ev_i[b].astype(float)]))
            k.evidence_clear(b, *rows[:7])
        if restart:
            k.evidence_restart(b, ev_i)
    snaps.append(np.concatenate([sw[b], sh[b], sg[b], acc[b], den[b], hist[b].ravel()]))
    return np.concatenate(snaps)


# ----------------------------------------------------------------------------------------- tests
@SEEDS
@given(st.integers(0, 2**32 - 1))
def test_monitor_compiled_equals_interpreted(seed):
    seq = monitor_inputs(np.random.default_rng(seed), 60)
    a, b = ws.monitor_rows(1, 9, 0.05), ws.monitor_rows(1, 9, 0.05)
    run_monitor(COMPILED, a, 0, seq)
    run_monitor(INTERPRETED, b, 0, seq)
    assert a[1][0, ws.ME_WINDOWS] >= 1.0 and same(a, b)


@SEEDS
@given(st.integers(0, 2**32 - 1))
def test_trust_compiled_equals_interpreted(seed):
    seq = trust_inputs(np.random.default_rng(seed), 300, 3)
    a, b = ws.trust_rows(1, 3, 5, 0.5, 2.33, 20), ws.trust_rows(1, 3, 5, 0.5, 2.33, 20)
    oa, ob = run_trust(COMPILED, a, 0, seq), run_trust(INTERPRETED, b, 0, seq)
    assert same(a, b) and oa.tobytes() == ob.tobytes()


@SEEDS
@given(st.integers(0, 2**32 - 1), st.integers(0, 2**N_PAR - 1))
def test_evidence_compiled_equals_interpreted(seed, mask):
    seq = update_inputs(np.random.default_rng(seed), 120)
    scored = np.array([(mask >> p) & 1 for p in range(N_PAR)], np.bool_)
    a, b = ws.evidence_rows(1, 3, N_PAR), ws.evidence_rows(1, 3, N_PAR)
    sa, sb = run_evidence(COMPILED, a, 0, seq, scored), run_evidence(INTERPRETED, b, 0, seq, scored)
    assert same(a, b) and sa.tobytes() == sb.tobytes()


@settings(derandomize=True, max_examples=5, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_a_row_of_a_batch_equals_a_batch_of_one(seed):
    """Three agents' rows filled in one batch, each row's inputs its own, against three batches of one."""
    rng = np.random.default_rng(seed)
    n = 3
    mon_seqs = [monitor_inputs(rng, 40) for _ in range(n)]
    tr_seqs = [trust_inputs(rng, 200, 2) for _ in range(n)]
    ev_seqs = [update_inputs(rng, 80) for _ in range(n)]
    scored = np.ones(N_PAR, np.bool_)
    mon_n, tr_n, ev_n = ws.monitor_rows(n, 7, 0.05), ws.trust_rows(n, 2, 5, 0.5, 2.33, 15), ws.evidence_rows(
        n, 2, N_PAR)
    for b in (2, 0, 1):  # the rows' order does not matter
        run_monitor(COMPILED, mon_n, b, mon_seqs[b])
    tr_out = {b: run_trust(COMPILED, tr_n, b, tr_seqs[b]) for b in (1, 2, 0)}
    ev_out = {b: run_evidence(COMPILED, ev_n, b, ev_seqs[b], scored) for b in (0, 2, 1)}
    for b in range(n):
        mon_1, tr_1, ev_1 = ws.monitor_rows(1, 7, 0.05), ws.trust_rows(1, 2, 5, 0.5, 2.33, 15), ws.evidence_rows(
            1, 2, N_PAR)
        run_monitor(COMPILED, mon_1, 0, mon_seqs[b])
        assert same(tuple(x[b:b + 1] for x in mon_n), mon_1)
        assert run_trust(COMPILED, tr_1, 0, tr_seqs[b]).tobytes() == tr_out[b].tobytes()
        assert same(tuple(x[b:b + 1] for x in tr_n), tr_1)
        assert run_evidence(COMPILED, ev_1, 0, ev_seqs[b], scored).tobytes() == ev_out[b].tobytes()
        assert same(tuple(x[b:b + 1] for x in ev_n), ev_1)


def test_trust_refuses_more_senders_than_its_degree():
    rows = ws.trust_rows(1, 1, 5, 0.5, 2.33, 0)
    with pytest.raises(ValueError, match="degree"):
        tr_i, _, tr_nb, trc, trr = rows
        ws.trust_observe(0, tr_i, tr_nb, trc, trr, 0, 2, array.array("q", (3, 0, 4, 0)))
