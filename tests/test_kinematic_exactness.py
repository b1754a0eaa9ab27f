"""The pair estimator's kernels compute exactly (bit for bit) what their plain forms do.

The unrolled 3x3 solver (compiled) against the textbook pivoting loop; the compiled pair kernels against
their own source run by the interpreter (``py_func``: CPython's arithmetic) on a long input with
spin-up, bridged and window-restarting gaps and late samples; a batch of several pairs against each pair
on its own bank.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import agents.kernels.pair as pair
from agents.kernels.pair import pair_bank, pair_checkpoints, pair_predict, pair_sample, set_pair_params, solve3
from config.agent_params import EstimatorSpec


def _solve3_loop(a: list[list[float]], b: list[float]) -> tuple[float, float, float] | None:
    """The textbook Gaussian elimination with partial pivoting (the former implementation)."""
    m = [a[0][:] + [b[0]], a[1][:] + [b[1]], a[2][:] + [b[2]]]
    scale = max(abs(v) for row in a for v in row) or 1.0
    for c in range(3):
        p = max(range(c, 3), key=lambda r: abs(m[r][c]))
        if abs(m[p][c]) <= 1e-13 * scale:
            return None
        if p != c:
            m[c], m[p] = m[p], m[c]
        piv = m[c][c]
        for r in range(c + 1, 3):
            f = m[r][c] / piv
            if f != 0.0:
                for k in range(c, 4):
                    m[r][k] -= f * m[c][k]
    x2 = m[2][3] / m[2][2]
    x1 = (m[1][3] - m[1][2] * x2) / m[1][1]
    x0 = (m[0][3] - m[0][1] * x1 - m[0][2] * x2) / m[0][0]
    return x0, x1, x2


def _solve3_kernel(a: list[list[float]], b: list[float]) -> tuple[float, float, float] | None:
    ok, x0, x1, x2 = solve3(*a[0], b[0], *a[1], b[1], *a[2], b[2])
    return (x0, x1, x2) if ok else None


def _outcome(fn, a, b):  # type: ignore[no-untyped-def]
    try:
        return repr(fn(a, b))
    except ZeroDivisionError:
        return "ZeroDivisionError"


@pytest.mark.parametrize("kind", ["gauss", "special", "small-int"])
def test_unrolled_solve3_is_bit_identical_to_the_loop(kind: str) -> None:
    rng = np.random.default_rng(7)
    special = [0.0, -0.0, 1.0, -1.0, 1e-14, 2.0, 3.0, math.nan, math.inf]
    for _ in range(20_000):
        if kind == "gauss":
            vals = rng.normal(size=12).tolist()
        elif kind == "special":
            vals = [special[i] for i in rng.integers(0, len(special), 12)]
        else:
            vals = rng.integers(-2, 3, 12).astype(float).tolist()
        a = [vals[0:3], vals[3:6], vals[6:9]]
        b = vals[9:12]
        assert _outcome(_solve3_kernel, a, b) == _outcome(_solve3_loop, a, b), (a, b)


_KERNELS = [name for name, v in vars(pair).items() if hasattr(v, "py_func")]


@pytest.fixture
def interpreted(monkeypatch: pytest.MonkeyPatch):  # type: ignore[no-untyped-def]
    """The pair module with every kernel replaced by its Python source (callees too); the compiled
    dispatchers are returned as they were, compiled first so that patched globals cannot reach them."""
    pair.warm()
    compiled = {name: getattr(pair, name) for name in _KERNELS}
    for name in _KERNELS:
        monkeypatch.setattr(pair, name, compiled[name].py_func)
    return compiled


def _bank(B: int, D: int, axis: list[bool], sigma: list[float]):  # type: ignore[no-untyped-def]
    e = EstimatorSpec()
    P, cps, prm = pair_bank(B, D, pair_checkpoints(e.fit_min_ticks, e.fit_max_ticks, e.fit_check_ticks))
    for b in range(B):
        set_pair_params(
            P, prm, b, dt=0.01, sigma_v=sigma[b], fit_arc=e.fit_arc, fit_min_ticks=e.fit_min_ticks,
            fit_max_ticks=e.fit_max_ticks, fit_check_ticks=e.fit_check_ticks, max_gap_ticks=e.max_gap_ticks,
            angle_walk=e.angle_walk, gate_snr=e.gate_snr, angle_meas="axis" if axis[b] else "linear",
        )  # fmt: skip
    return P, cps, prm


def _inputs(seed: int, sigma: float, ticks: int = 7500):  # type: ignore[no-untyped-def]
    """Rest (noise only: windows rejected), spin-up, lost samples (gaps bridged and gaps longer than
    max_gap_ticks), late samples (back != 1 every 7th tick): yields (t, w, lag); the driver turns lag
    into back with its omega_hat."""
    rng = np.random.default_rng(seed)
    z = 1.2 - 0.4j
    dt = 0.01
    t = 0
    while t < ticks:
        om = min(1.2, 0.002 * max(0, t - 2000))
        z *= complex(math.cos(om * dt), math.sin(om * dt))
        if rng.random() < 0.004 and t >= 2000:
            t += int(rng.integers(1, 40))
            continue
        w = 1j * om * z + complex(*rng.normal(0.0, sigma * math.sqrt(2), 2))
        yield t, w, (1 + t % 3 if t % 7 == 0 else 0)
        t += 1


class _Driver:
    """One pair (b, k) of a bank driven as KinematicPhase drives it: omega_hat seeded by the first fit."""

    def __init__(self, P, cps, prm, b: int, k: int) -> None:  # type: ignore[no-untyped-def]
        self.P, self.cps, self.prm, self.b, self.k = P, cps, prm, b, k
        self.om_hat = 0.0

    def step(self, sample, predict, t: int, w: complex, lag: int) -> None:  # type: ignore[no-untyped-def]
        dt = 0.01
        a = self.om_hat * dt * lag
        back = complex(math.cos(a), -math.sin(a)) if lag else 1 + 0j
        sample(self.P, self.cps, self.prm, self.b, self.k, t, w, back, self.om_hat, dt)
        row = self.P[self.b, self.k]
        if row["ready"] and self.om_hat == 0.0:
            self.om_hat = float(row["omega_fit"])
        a = self.om_hat * dt
        predict(self.P, self.b, self.k, complex(math.cos(a), math.sin(a)))


@pytest.mark.parametrize("axis", [False, True])
def test_compiled_pair_kernels_equal_their_python_source(interpreted, axis: bool) -> None:  # type: ignore[no-untyped-def]
    banks = [_bank(1, 1, [axis], [0.3]) for _ in range(2)]
    comp, interp = (_Driver(*bank, 0, 0) for bank in banks)
    for t, w, lag in _inputs(11, 0.3):
        comp.step(interpreted["pair_sample"], interpreted["pair_predict"], t, w, lag)
        interp.step(pair.pair_sample, pair.pair_predict, t, w, lag)
        assert comp.P.tobytes() == interp.P.tobytes(), t
    assert comp.cps.tobytes() == interp.cps.tobytes()
    row = comp.P[0, 0]
    assert row["ready"] and row["windows"] >= 3 and row["rejected"] >= 1


def test_a_batch_of_pairs_equals_each_pair_alone() -> None:
    """B = 3 agents (linear and axis forms, three noise levels) x D = 2 pairs, stepped interleaved."""
    axis, sigma = [False, True, False], [0.3, 0.1, 0.8]
    P, cps, prm = _bank(3, 2, axis, sigma)
    batch = {(b, k): _Driver(P, cps, prm, b, k) for b in range(3) for k in range(2)}
    alone = {(b, k): _Driver(*_bank(1, 1, [axis[b]], [sigma[b]]), 0, 0) for b in range(3) for k in range(2)}
    streams = {bk: list(_inputs(100 + 2 * bk[0] + bk[1], sigma[bk[0]], 4000)) for bk in batch}
    for i in range(max(len(s) for s in streams.values())):
        for bk in sorted(batch, key=lambda bk: (i * 7 + bk[0] * 3 + bk[1]) % 6):  # a varying order
            if i < len(streams[bk]):
                batch[bk].step(pair_sample, pair_predict, *streams[bk][i])
                alone[bk].step(pair_sample, pair_predict, *streams[bk][i])
    for (b, k), d in alone.items():
        assert P[b, k].tobytes() == d.P[0, 0].tobytes(), (b, k)
        assert cps[b, k].tobytes() == d.cps[0, 0].tobytes(), (b, k)
    assert sum(int(P[b, k]["windows"]) for b, k in batch) >= 6
