"""The agreement kernels (agents/kernels/agreement.py): compiled == interpreted bit for bit, a batch of n rows ==
n batches of one."""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from agents.kernels import agreement as K

SETTINGS = settings(derandomize=True, max_examples=60, deadline=None)
# values with signed zeros, exact ties and NaN: the cases where a changed operation order shows
FLOATS = st.one_of(st.sampled_from([0.0, -0.0, 1.0, -1.0, 0.5, math.nan]), st.floats(-1e3, 1e3))
COMPLEX = st.builds(complex, FLOATS, FLOATS)


def _bits(*arrays: np.ndarray) -> list[bytes]:
    return [a.tobytes() for a in arrays]


@SETTINGS
@given(st.one_of(st.tuples(FLOATS, FLOATS, FLOATS, st.one_of(st.none(), FLOATS)),
                 st.tuples(COMPLEX, COMPLEX, FLOATS, st.one_of(st.none(), COMPLEX))))
def test_flow_step_compiled_equals_interpreted(args):
    a, b = K.flow_step(*args), K.flow_step.py_func(*args)
    assert type(a) is type(b)
    assert repr(a) == repr(b)  # repr: the sign of a zero and NaN count


def _random_flow_bank(rng: np.random.Generator, B: int, D: int, nch: int) -> tuple[np.ndarray, np.ndarray]:
    F, I = K.flow_average_bank(B, D, nch)
    F[:] = rng.choice([0.0, -0.0, 1.0], size=F.shape) * rng.standard_normal(F.shape)
    for b in range(B):
        deg = int(rng.integers(0, D + 1))
        I[b, K.DEG] = deg
        I[b, K.HEARD:K.HEARD + deg] = rng.integers(0, 2, deg)
        I[b, K.HEARD + D:K.HEARD + D + deg] = rng.integers(1, 6, deg)
    return F, I


def _row_alone(F: np.ndarray, I: np.ndarray, b: int) -> tuple[np.ndarray, np.ndarray]:
    """Row b of a bank as a bank of one with exactly its own slots (another layout, the same values)."""
    D = (F.shape[1] - K.FLOW) // 3
    deg = int(I[b, K.DEG])
    F1, I1 = K.flow_average_bank(1, deg, F.shape[2])
    F1[0, :K.FLOW] = F[b, :K.FLOW]
    for part in range(3):
        F1[0, K.FLOW + part * deg:K.FLOW + (part + 1) * deg] = F[b, K.FLOW + part * D:K.FLOW + part * D + deg]
    I1[0, K.DEG] = deg
    I1[0, K.HEARD:K.HEARD + deg] = I[b, K.HEARD:K.HEARD + deg]
    I1[0, K.HEARD + deg:] = I[b, K.HEARD + D:K.HEARD + D + deg]
    return F1, I1


@SETTINGS
@given(st.integers(0, 2**32 - 1), st.integers(1, 6), st.integers(0, 4), st.integers(1, 12), st.integers(1, 4))
def test_flow_average_update_compiled_equals_interpreted_and_rows_are_independent(seed, B, D, nch, ticks):
    rng = np.random.default_rng(seed)
    F, I = _random_flow_bank(rng, B, D, nch)
    Fp = F.copy()
    alone = [_row_alone(F, I, b) for b in range(B)]
    for _ in range(ticks):
        for b in range(B):
            K.flow_average_update(b, F, I)
            K.flow_average_update.py_func(b, Fp, I)
            K.flow_average_update(0, *alone[b])
    assert _bits(F) == _bits(Fp)
    for b in range(B):
        deg = int(I[b, K.DEG])
        assert _bits(F[b, K.U:K.FLOW + deg]) == _bits(alone[b][0][0, K.U:K.FLOW + deg])


@SETTINGS
@given(st.integers(2, 7), st.integers(0, 2**32 - 1), st.integers(1, 5))
def test_flow_average_views_over_one_bank_equal_views_over_their_own(n, seed, nch):
    """A team's FlowAverage views on the rows of one bank (the engine's layout) step bit for bit like views on
    banks of one (the daemon's), on a ring with random losses."""
    from agents.consensus import FlowAverage

    rng = np.random.default_rng(seed)
    nbrs = [sorted({(i - 1) % n, (i + 1) % n} - {i}) for i in range(n)]
    bank = K.flow_average_bank(n, max(map(len, nbrs)), nch)
    teams = [[FlowAverage(nbrs[i], nch, bank, i) for i in range(n)], [FlowAverage(nbrs[i], nch) for i in range(n)]]
    for _ in range(20):
        u = rng.standard_normal((n, nch)).tolist()
        lost = rng.random((n, n)) < 0.3
        for team in teams:
            sent = [(a.x, a.flow) for a in team]
            for i, a in enumerate(team):
                for j in nbrs[i]:
                    if not lost[i, j]:
                        a.receive(j, sent[j][0], sent[j][1][i], len(nbrs[j]))
                a.u[:] = u[i]
                a.update()
        assert [repr(a.x) for a in teams[0]] == [repr(a.x) for a in teams[1]]
