"""Is a numba-compiled scalar kernel bit-identical to the same source run by CPython, and what does each cost?

Runs bench/filter_candidates.py's numba filter kernels (update + predict, d = 8) compiled and through their
``py_func`` (the same source, interpreted) on random inputs (B rows, NaN rate measurements included) and
counts the output arrays that differ in any bit; then the same for the transcendental functions of ``math``
that a kernel would call (compiled against CPython's ``math``); then the cost per call at the daemon's
batch of one. numba is a dependency of coload (the agent's compiled core). Docs: docs/agent-step.md ("Compiled
against interpreted").
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
from filter_candidates import NUMBA


def _random_rows(rng: np.random.Generator, B: int, d: int) -> tuple[tuple, tuple]:
    S = rng.normal(size=(B, d))
    A = rng.normal(size=(B, d, d))
    P = A @ A.transpose(0, 2, 1) * 0.01 + np.eye(d) * 0.1
    u = rng.normal(size=B)
    u[::7] = np.nan  # no rate measurement on those rows: the 2-measurement update
    upd = (S, P, rng.uniform(0.01, 0.1, B), rng.normal(size=B), rng.normal(size=B), u, rng.uniform(0, 0.1, B),
           rng.normal(size=B), rng.normal(size=B), rng.uniform(size=B))
    pre = (S, P, rng.normal(size=B), rng.normal(size=B), rng.normal(size=B), np.full(B, 0.01),
           rng.uniform(0, 1e-3, (B, 5)), rng.uniform(0, 1e-3, B), rng.uniform(0, 1e-3, (B, 2)))
    return upd, pre


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and np.array_equal(a.view(np.int64), b.view(np.int64))


MATH = {"sin": lambda v: math.sin(v), "cos": lambda v: math.cos(v), "atan2": lambda v: math.atan2(v, 0.3 + v * v),
        "exp": lambda v: math.exp(-abs(v)), "sqrt": lambda v: math.sqrt(abs(v)), "log1p": lambda v: math.log1p(abs(v)),
        "hypot": lambda v: math.hypot(v, 1.7), "abs(complex)": lambda v: abs(complex(v, 1.7)),
        "sqrt(x*x+y*y)": lambda v: math.sqrt(v * v + 1.7 * 1.7), "a*b+c": lambda v: v * 1.1 + 0.3 * v * v}


def _over(kernel):  # noqa: ANN001, ANN202
    """A compiled loop applying the compiled scalar ``kernel`` to every element."""
    import numba

    @numba.njit
    def apply(x):  # noqa: ANN001, ANN202
        out = np.empty(x.size)
        for i in range(x.size):
            out[i] = kernel(x[i])
        return out

    return apply


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trials", type=int, default=30, help="random input sets (default 30)")
    ap.add_argument("--rows", type=int, default=64, help="rows per set (default 64)")
    ap.add_argument("--points", type=int, default=200_000, help="arguments per math function (default 200000)")
    args = ap.parse_args()
    if NUMBA is None:
        raise SystemExit("numba is not installed: pip install numba")
    import numba

    update, predict = NUMBA
    rng = np.random.default_rng(1)
    differ = total = 0
    for _ in range(args.trials):
        upd, pre = _random_rows(rng, args.rows, 8)
        for f, a in ((update, upd), (predict, pre)):
            for x, y in zip(f(*a), f.py_func(*a)):
                total += 1
                differ += not _same_bits(x, y)
    print(f"filter kernels: {differ} of {total} output arrays differ, compiled against interpreted")

    fns = list(MATH.values())

    def table(x: np.ndarray) -> np.ndarray:
        return np.array([[f(v) for f in fns] for v in x])

    x = rng.normal(scale=30.0, size=args.points)
    out = np.empty((x.size, len(fns)))
    for k, f in enumerate(fns):
        out[:, k] = _over(numba.njit(f))(x)
    ref = table(x)
    for k, name in enumerate(MATH):
        n = int((out[:, k].view(np.int64) != ref[:, k].view(np.int64)).sum())
        print(f"math {name:13s}: {n} of {x.size} results differ")

    upd, pre = _random_rows(rng, 1, 8)
    for name, f, a, reps in (("update compiled", update, upd, 20000), ("update interpreted", update.py_func, upd, 300),
                             ("predict compiled", predict, pre, 20000),
                             ("predict interpreted", predict.py_func, pre, 300)):
        f(*a)
        t0 = time.perf_counter()
        for _ in range(reps):
            f(*a)
        print(f"{name:20s} B = 1: {(time.perf_counter() - t0) / reps * 1e6:8.1f} us per call")


if __name__ == "__main__":
    main()
