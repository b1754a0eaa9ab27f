"""Hand-made run directories with known truth, for testing metrics and the report.

A rectangular load translates at constant velocity while spinning at a constant rate; agents hold
it at evenly spaced perimeter points. Estimates are truth plus errors chosen by the test, so every
metric has an answer known in closed form.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from coload.rundir import format as rf


@dataclass(frozen=True)
class SyntheticSpec:
    n: int = 4
    dt: float = 0.1
    duration: float = 30.0
    omega: float = 0.3
    v_c: tuple[float, float] = (0.05, -0.02)
    com_offset: tuple[float, float] = (0.2, -0.1)
    width: float = 4.0
    height: float = 2.2
    mass: float = 50.0
    inertia: float = 86.89
    edges: tuple[tuple[int, int], ...] | None = None  # default: line graph
    every: int = 1  # record estimates/pairs every this many ticks
    extra_estimates: bool = False  # also write J, m, zc_x, zc_y, vc_x, vc_y
    seed: int = 0
    name: str = "synthetic"
    shuffle: bool = True  # write rows in random order, as a real engine may
    drop: Sequence[tuple[int, float, float]] = field(default=())  # (agent, t_from, t_to): no rows


def contact_points(n: int, width: float, height: float) -> np.ndarray:
    """n points evenly along the rectangle's outline, body frame about its centre G, shape (n, 2)."""
    per = 2 * (width + height)
    s = (np.arange(n) + 0.5) * per / n
    pts = []
    for d in s:
        if d < width:
            pts.append((-width / 2 + d, -height / 2))
        elif d < width + height:
            pts.append((width / 2, -height / 2 + d - width))
        elif d < 2 * width + height:
            pts.append((width / 2 - (d - width - height), height / 2))
        else:
            pts.append((-width / 2, height / 2 - (d - 2 * width - height)))
    return np.array(pts)


def _rot(theta: np.ndarray) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)  # (T, 2, 2)


@dataclass(frozen=True)
class Truth:
    t: np.ndarray  # (T,)
    zi: np.ndarray  # (T, n, 2)
    omega: np.ndarray  # (T,)
    zc: np.ndarray  # (T, 2)  p_G - p_C
    vc: np.ndarray  # (T, 2)
    pc: np.ndarray  # (T, 2)
    angle: np.ndarray  # (T,)


def truth_of(spec: SyntheticSpec) -> Truth:
    ticks = int(round(spec.duration / spec.dt))
    t = np.arange(ticks + 1) * spec.dt
    angle = spec.omega * t
    rot = _rot(angle)
    b = contact_points(spec.n, spec.width, spec.height)
    zi = np.einsum("tab,nb->tna", rot, b)
    zc = -np.einsum("tab,b->ta", rot, np.array(spec.com_offset))
    vc = np.tile(np.array(spec.v_c), (len(t), 1))
    pc = np.outer(t, spec.v_c)
    return Truth(t=t, zi=zi, omega=np.full(len(t), spec.omega), zc=zc, vc=vc, pc=pc, angle=angle)


ErrorFn = Callable[[np.ndarray], np.ndarray]


def _zero_err(shape: tuple[int, ...]) -> ErrorFn:
    return lambda t: np.zeros((len(t),) + shape)


def write_run(
    run_dir: Path,
    spec: SyntheticSpec = SyntheticSpec(),
    *,
    zi_err: ErrorFn | None = None,
    omega_err: ErrorFn | None = None,
    pair_scale: Callable[[np.ndarray], np.ndarray] | None = None,
    extra_err: Callable[[np.ndarray], dict[str, np.ndarray]] | None = None,
) -> Truth:
    """Write a complete run directory and return its truth.

    ``zi_err(t) -> (T, n, 2)`` is added to z_i; ``omega_err(t) -> (T, n)`` to omega;
    ``pair_scale(t) -> (T,)`` multiplies every true z_ij to give the pair estimates (default 1, exact);
    ``extra_err(t)`` returns additive errors by column name for J, m, zc_x, ... (default exact).
    """
    run_dir.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(spec.seed)
    tr = truth_of(spec)
    n = spec.n
    edges = spec.edges if spec.edges is not None else tuple((i, i + 1) for i in range(n - 1))
    t = tr.t
    (run_dir / rf.RUN_TOML).write_text(
        f'name = "{spec.name}"\nn = {n}\ndt = {spec.dt}\nduration = {spec.duration}\nseed = {spec.seed}\n'
        f'mode = "lockstep"\nedges = [{", ".join(f"[{i}, {j}]" for i, j in edges)}]\n\n'
        f"[load]\nmass = {spec.mass}\ninertia = {spec.inertia}\n\n[noise]\nsigma_v = 0.0\n"
    )

    # truth
    with (run_dir / rf.TRUTH_CSV).open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(rf.truth_header(n))
        pg = tr.pc + tr.zc
        for k in range(len(t)):
            w.writerow(
                [f"{t[k]:.6f}", pg[k, 0], pg[k, 1], tr.angle[k], tr.vc[k, 0], tr.vc[k, 1], tr.omega[k],
                 tr.zc[k, 0], tr.zc[k, 1], pg[k, 0], pg[k, 1], spec.mass, spec.inertia]
                + list(tr.zi[k].ravel())
            )

    # samples: exact rigid-body contact velocities plus small noise, arbitrary wrench
    pci = pg[:, None, :] + tr.zi
    rel = pci - tr.pc[:, None, :]
    v = tr.vc[:, None, :] + tr.omega[:, None, None] * np.stack([-rel[..., 1], rel[..., 0]], -1)
    v = v + rng.normal(0, 0.01, v.shape)
    f = rng.normal(0, 5.0, (len(t), n, 2))
    rows = [
        [f"{t[k]:.6f}", i, v[k, i, 0], v[k, i, 1], f[k, i, 0], f[k, i, 1], 0.0]
        for k in range(len(t)) for i in range(n)
    ]
    _write(run_dir / rf.SAMPLES_CSV, rf.SAMPLES_HEADER, rows, rng, spec.shuffle)

    # estimates
    keep = np.arange(0, len(t), spec.every)
    te = t[keep]
    zi_hat = tr.zi[keep] + (zi_err or _zero_err((n, 2)))(te)
    om_hat = tr.omega[keep][:, None] + (omega_err or _zero_err((n,)))(te)
    phase = np.where(te < spec.duration / 3, 0, np.where(te < 2 * spec.duration / 3, 1, 2))
    header = [*rf.ESTIMATES_KEY, "phase", "omega", "zi_x", "zi_y"]  # the kinematic phase's columns
    extra: dict[str, np.ndarray] = {}
    if spec.extra_estimates:
        errs = extra_err(te) if extra_err else {}
        base = {
            "J": np.full(len(te), spec.inertia), "m": np.full(len(te), spec.mass),
            "zc_x": tr.zc[keep, 0], "zc_y": tr.zc[keep, 1], "vc_x": tr.vc[keep, 0], "vc_y": tr.vc[keep, 1],
        }
        for name, val in base.items():
            extra[name] = val[:, None] + errs.get(name, np.zeros((len(te), n)))
        header += list(extra)
    rows = []
    for k in range(len(te)):
        for i in range(n):
            if _dropped(spec, i, te[k]):
                continue
            rows.append(
                [f"{te[k]:.6f}", i, int(phase[k]), om_hat[k, i], zi_hat[k, i, 0], zi_hat[k, i, 1]]
                + [extra[name][k, i] for name in extra]
            )
    _write(run_dir / rf.ESTIMATES_CSV, header, rows, rng, spec.shuffle)

    # pairs
    scale = pair_scale(te) if pair_scale else np.ones(len(te))
    rows = []
    for k in range(len(te)):
        for a, b in edges:
            for i, j in ((a, b), (b, a)):
                if _dropped(spec, i, te[k]):
                    continue
                z = scale[k] * (tr.zi[keep[k], i] - tr.zi[keep[k], j])
                rows.append([f"{te[k]:.6f}", i, j, z[0], z[1]])
    _write(run_dir / rf.PAIRS_CSV, rf.PAIRS_HEADER, rows, rng, spec.shuffle)

    (run_dir / rf.SUMMARY_JSON).write_text(json.dumps({"engine": "synthetic", "n": n, "seed": spec.seed}))
    (run_dir / rf.LOGS_DIR).mkdir(exist_ok=True)
    return tr


def _dropped(spec: SyntheticSpec, agent: int, t: float) -> bool:
    return any(a == agent and lo <= t < hi for a, lo, hi in spec.drop)


def _write(path: Path, header: Sequence[str], rows: list[list], rng: np.random.Generator, shuffle: bool) -> None:
    if shuffle:
        rows = [rows[k] for k in rng.permutation(len(rows))]
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)
