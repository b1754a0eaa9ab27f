"""The dynamical-phase filter (RigidEKF predict + update) on its real inputs, through each candidate fast core.

    OPENBLAS_NUM_THREADS=1 python bench/filter_block.py [--n 10 40] [--duration 60] [--stride 20]
        [--set KEY=VALUE ...] [--jit-times]

Runs paper-fig4 in process at each team size n (the load scaled with n as bench/bench_engines.py does,
the whole Algorithm 1), recording the inputs and outputs of every ``RigidEKF.update`` and ``predict``
call of every ``stride``-th tick (restarts on trial included: a tick's batch is all its calls). Then it
replays those ticks through each candidate of bench/filter_candidates.py, the candidates interleaved
tick by tick in a rotating order so they share the machine's load:

- ``current``: the RigidEKF methods, one call per agent;
- ``numpy-B``: the batched numpy core, one call for the whole tick (B = n); ``numpy-1`` the same
  called once per agent (the daemon's batch of one); ``matrix-B``, ``matrix-1``: the same over the
  agent axis in the textbook matrix form (H, P H^T, stacked inverse of S);
- ``numba-B``, ``numba-1``: the compiled kernel (when numba is installed);
- ``python``: plain Python floats, one call per agent.

Printed per n: us per agent per tick (update + predict; the batch packing is not timed: in each design
the state lives in that form), the ratio of current over each candidate (> 1: faster), the max abs
difference of s, P (and nis, innovation) to the recorded RigidEKF outputs, and whether a candidate's
batch-of-one and batch-of-n results are bit-identical; for the largest n, the batched candidates' cost
per row when a tick's calls are tiled to B rows (many runs at once). ``--jit-times`` also times numba's first call in a
fresh process with a cold and with a warm cache. Docs: docs/agent-step.md, "Choosing the fast core:
measured".
"""

from __future__ import annotations

import argparse
import copy
import gc
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from agents.rigid_filter import RigidEKF  # noqa: E402
from bench.bench_engines import FIG4, scaled  # noqa: E402
from bench.filter_candidates import (  # noqa: E402
    NUMBA,
    predict_batch,
    predict_matrix,
    predict_py,
    update_batch,
    update_matrix,
    update_py,
)
from coload.runs.engine import run_inproc  # noqa: E402
from config.loader import load_scenario  # noqa: E402
from simulator.plant import Plant  # noqa: E402


def record(n: int, duration: float, stride: int, sets: list[str]) -> tuple[list, float]:
    """Per recorded tick: (update calls, predict calls); each call (filter copy, inputs, outputs)."""
    ticks: list = []
    state = {"k": -1}
    plain_u, plain_p, plain_m = RigidEKF.update, RigidEKF.predict, Plant.measure

    def measure(self, rng):  # noqa: ANN001, ANN202
        state["k"] += 1
        if state["k"] % stride == 0:
            ticks.append(([], []))
        return plain_m(self, rng)

    def update(self, v, u, u_var, u_dc=0.0, u_dw=0.0):  # noqa: ANN001, ANN202
        s, P, nis = self.s, self.P, self.nis
        plain_u(self, v, u, u_var, u_dc, u_dw)
        if state["k"] % stride == 0:
            ticks[-1][0].append((copy.copy(self), (s, P, nis, v, u, u_var, u_dc, u_dw),
                                 (self.s, self.P, self.nis, self.innov)))

    def predict(self, force, torque, dt):  # noqa: ANN001, ANN202
        s, P = self.s, self.P
        plain_p(self, force, torque, dt)
        if state["k"] % stride == 0:
            ticks[-1][1].append((copy.copy(self), (s, P, force, torque, dt), (self.s, self.P)))

    RigidEKF.update, RigidEKF.predict, Plant.measure = update, predict, measure
    try:
        sc = load_scenario(FIG4, [*scaled(n, duration), *sets])
        t0 = time.perf_counter()
        run_inproc(sc, None)
        wall = time.perf_counter() - t0
    finally:
        RigidEKF.update, RigidEKF.predict, Plant.measure = plain_u, plain_p, plain_m
    return [t for t in ticks if t[0] or t[1]], wall


def pack_update(calls: list) -> tuple:
    S = np.array([c[1][0] for c in calls])
    P = np.array([c[1][1] for c in calls])
    col = lambda k: np.array([float(c[1][k]) for c in calls])  # noqa: E731
    v = [c[1][3] for c in calls]
    r = np.array([c[0].r for c in calls])
    return (S, P, r, np.array([x.real for x in v]), np.array([x.imag for x in v]), col(4), col(5), col(6), col(7),
            col(2))


def pack_predict(calls: list) -> tuple:
    S = np.array([c[1][0] for c in calls])
    P = np.array([c[1][1] for c in calls])
    f = [c[1][2] for c in calls]
    qa = np.array([(c[0].aug[2], c[0].aug[3]) if c[0].aug is not None else (0.0, 0.0) for c in calls])
    return (S, P, np.array([x.real for x in f]), np.array([x.imag for x in f]), np.array([float(c[1][3]) for c in calls]),
            np.array([float(c[1][4]) for c in calls]), np.array([c[0].Qd for c in calls]),
            np.array([c[0].qb for c in calls]), qa)


def rows(packed: tuple) -> list[tuple]:
    """The batch split into batches of one (each a fresh contiguous array)."""
    return [tuple(np.ascontiguousarray(a[i:i + 1]) for a in packed) for i in range(len(packed[0]))]


def py_args(packed_u: tuple | None, packed_p: tuple | None) -> tuple[list, list]:
    """The batches as plain-Python arguments, one tuple per call."""
    ua: list = []
    pa: list = []
    for i in range(len(packed_u[0]) if packed_u else 0):
        S, P, *rest = (a[i] for a in packed_u)
        ua.append((S.tolist(), P.tolist(), *(float(x) for x in rest)))
    for i in range(len(packed_p[0]) if packed_p else 0):
        S, P, fr, fi, T, dt, qd, qb, qa = (a[i] for a in packed_p)
        pa.append((S.tolist(), P.tolist(), float(fr), float(fi), float(T), float(dt), qd.tolist(), float(qb), qa.tolist()))
    return ua, pa


def diff(out: tuple, ref: tuple) -> np.ndarray:
    """Max abs difference per output (s, P, nis, innov) over a batch."""
    return np.array([np.max(np.abs(np.asarray(o, dtype=float) - np.asarray(r, dtype=float)), initial=0.0)
                     for o, r in zip(out, ref)])


def candidates() -> dict:
    """name -> (kind, update, predict); kind: current, batch (the tick's calls at once), one (per call), python."""
    c = {
        "current": ("current", None, None),
        "numpy-B": ("batch", update_batch, predict_batch),
        "numpy-1": ("one", update_batch, predict_batch),
        "matrix-B": ("batch", update_matrix, predict_matrix),
        "matrix-1": ("one", update_matrix, predict_matrix),
        "python": ("python", update_py, predict_py),
    }
    if NUMBA is not None:
        c["numba-B"] = ("batch", *NUMBA)
        c["numba-1"] = ("one", *NUMBA)
    return c


def run_current(ucalls: list, pcalls: list) -> tuple[list, list]:
    ou, op = [], []
    for kf, (s, P, nis, v, u, uvar, udc, udw), _ in ucalls:
        kf.s, kf.P, kf.nis = s, P, nis
        kf.update(v, u, uvar, udc, udw)
        ou.append((kf.s, kf.P, kf.nis, kf.innov))
    for kf, (s, P, f, T, dt), _ in pcalls:
        kf.s, kf.P = s, P
        kf.predict(f, T, dt)
        op.append((kf.s, kf.P))
    return ou, op


def replay(ticks: list) -> dict:
    """Interleaved timing of every candidate on the recorded ticks; per candidate: seconds, max diffs."""
    cands = candidates()
    names = list(cands)
    secs = dict.fromkeys(names, 0.0)
    err_u = {k: np.zeros(4) for k in names}
    err_p = {k: np.zeros(2) for k in names}
    same = {k[:-2]: True for k in names if k.endswith("-B")}
    clock = time.perf_counter
    calls = 0
    for t, (ucalls, pcalls) in enumerate(ticks):
        calls += len(ucalls) + len(pcalls)
        pu = pack_update(ucalls) if ucalls else None
        pp = pack_predict(pcalls) if pcalls else None
        args = {"batch": (pu, pp), "one": (rows(pu) if pu else [], rows(pp) if pp else []),
                "python": py_args(pu, pp), "current": (ucalls, pcalls)}
        out: dict = {}
        order = names[t % len(names):] + names[:t % len(names)]
        gc.disable()
        for name in order:
            kind, upd, pre = cands[name]
            a_u, a_p = args[kind]
            c0 = clock()
            if kind == "current":
                res = run_current(a_u, a_p)
            elif kind == "batch":
                res = (upd(*a_u) if a_u else None, pre(*a_p) if a_p else None)
            else:
                res = ([upd(*a) for a in a_u], [pre(*a) for a in a_p])
            secs[name] += clock() - c0
            out[name] = res
        gc.enable()
        # accuracy against the recorded RigidEKF outputs (the same inputs), per call
        ref_u = [c[2] for c in ucalls]
        ref_p = [c[2] for c in pcalls]
        for name in names:
            kind = cands[name][0]
            ou, op = out[name]
            if kind == "batch":
                ou = [tuple(x[i] for x in ou) for i in range(len(ref_u))] if ou else []
                op = [tuple(x[i] for x in op) for i in range(len(ref_p))] if op else []
            elif kind == "one":
                ou = [tuple(x[0] for x in o) for o in ou]
                op = [tuple(x[0] for x in o) for o in op]
            for o, r in zip(ou, ref_u):
                err_u[name] = np.maximum(err_u[name], diff(o, r))
            for o, r in zip(op, ref_p):
                err_p[name] = np.maximum(err_p[name], diff(o, r))
            out[name] = (ou, op)
        for fam in same:
            for xs, ys in zip(out[f"{fam}-B"], out[f"{fam}-1"]):
                for x, y in zip(xs, ys):
                    if any(np.asarray(a1).tobytes() != np.asarray(a2).tobytes() for a1, a2 in zip(x, y)):
                        same[fam] = False
    return {"secs": secs, "err_u": err_u, "err_p": err_p, "same": same, "ticks": len(ticks), "calls": calls}


def batch_scaling(ticks: list, sizes: list[int], reps: int) -> dict:
    """us per row of the batched candidates when a tick's calls are tiled to B rows (many runs at once)."""
    cands = {k: v for k, v in candidates().items() if v[0] == "batch"}
    secs = {(k, b): 0.0 for k in cands for b in sizes}
    rowsn = {b: 0 for b in sizes}
    clock = time.perf_counter
    for t, (ucalls, pcalls) in enumerate(ticks[:reps]):
        if not (ucalls and pcalls):
            continue
        pu, pp = pack_update(ucalls), pack_predict(pcalls)
        for b in sizes:
            idx = np.arange(b) % len(ucalls)
            a_u = tuple(np.ascontiguousarray(x[idx]) for x in pu)
            idx = np.arange(b) % len(pcalls)
            a_p = tuple(np.ascontiguousarray(x[idx]) for x in pp)
            rowsn[b] += b
            names = list(cands)
            for name in names[t % len(names):] + names[:t % len(names)]:
                _, upd, pre = cands[name]
                c0 = clock()
                upd(*a_u)
                pre(*a_p)
                secs[(name, b)] += clock() - c0
    return {key: 1e6 * s / rowsn[key[1]] for key, s in secs.items()}


def jit_times() -> tuple[float, float]:
    """numba's first call (import + compile or cache load) in a fresh process: cold cache, warm cache."""
    code = ("import time, sys; sys.path.insert(0, %r); t0 = time.perf_counter(); import numpy as np; "
            "from bench.filter_candidates import NUMBA; u, p = NUMBA; d = 8; S = np.zeros((1, d)); "
            "P = np.eye(d)[None]; o = np.ones(1); z = np.zeros(1); u(S, P, o, z, z, z, o, z, z, o); "
            "p(S, P, z, z, z, o * 0.01, np.zeros((1, 5)), z, np.zeros((1, 2))); "
            "print(time.perf_counter() - t0)") % str(ROOT)
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        cold = float(subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                                    check=True).stdout)
        warm = float(subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                                    check=True).stdout)
    return cold, warm


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, nargs="+", default=[10, 40], help="team sizes")
    ap.add_argument("--duration", type=float, default=60.0, help="simulated seconds (Algorithm 1 ends at ~85 s)")
    ap.add_argument("--stride", type=int, default=20, help="record every stride-th tick")
    ap.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                    help="scenario override, e.g. 'dynamics.estimate_effects=[\"viscous_friction\",\"rotational_damping\"]'")
    ap.add_argument("--scaling-ticks", type=int, default=40, help="ticks timed per batch size in the scaling table")
    ap.add_argument("--jit-times", action="store_true", help="time numba's first call, cold and warm cache")
    a = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.1f}; numba {'on' if NUMBA is not None else 'not installed'}", flush=True)
    if NUMBA is not None:  # compile (or load the cache) before any timing
        jit0 = time.perf_counter()
        S = np.zeros((1, 8))
        P = np.eye(8)[None]
        o, z = np.ones(1), np.zeros(1)
        NUMBA[0](S, P, o, z, z, z, o, z, z, o)
        NUMBA[1](S, P, z, z, z, o * 0.01, np.zeros((1, 5)), z, np.zeros((1, 2)))
        print(f"numba first call in this process: {time.perf_counter() - jit0:.2f} s", flush=True)
    for n in a.n:
        ticks, wall = record(n, a.duration, a.stride, a.sets)
        d = len(ticks[-1][0][0][1][0]) if ticks and ticks[-1][0] else 0
        res = replay(ticks)
        k = res["ticks"]
        cur = res["secs"]["current"]
        print(f"\nn = {n}: recording run {wall:.1f} s wall; {k} ticks replayed ({res['calls']} calls), d = {d}")
        print(f"{'candidate':<10} {'us/agent/tick':>14} {'current/this':>13} {'max|ds|':>9} {'max|dP|':>9} "
              f"{'max|dnis|':>9} {'max|dinnov|':>11}")
        for name, sec in res["secs"].items():
            eu, ep = res["err_u"][name], res["err_p"][name]
            print(f"{name:<10} {1e6 * sec / (k * n):>14.2f} {cur / sec:>13.2f} {max(eu[0], ep[0]):>9.1e} "
                  f"{max(eu[1], ep[1]):>9.1e} {eu[2]:>9.1e} {eu[3]:>11.1e}")
        for fam, same in res["same"].items():
            if f"{fam}-B" in res["secs"]:
                print(f"{fam}: batch of one == batch of {n}, bit for bit: {'yes' if same else 'NO'}")
        if n == max(a.n):
            sizes = [1, 10, 40, 160, 640]
            sc = batch_scaling(ticks, sizes, a.scaling_ticks)
            print(f"\nus per row, one tick's calls tiled to B rows (many runs at once), {a.scaling_ticks} ticks of n = {n}:")
            names = sorted({k for k, _ in sc}, key=list(candidates()).index)
            print(f"{'B':>5} " + " ".join(f"{x:>9}" for x in names))
            for b in sizes:
                print(f"{b:>5} " + " ".join(f"{sc[(x, b)]:>9.2f}" for x in names))
    if a.jit_times and NUMBA is not None:
        cold, warm = jit_times()
        print(f"\nnumba import + first call, fresh process: cold cache {cold:.2f} s, warm cache {warm:.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
