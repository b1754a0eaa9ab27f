"""``coload diagnose`` on independent continuous-time recordings: a table over sample rates, noise levels and effects.

Each recording comes from tests/ctplant.py (a rigid-body ODE integrated with scipy, sharing no code
with the simulator or the diagnosis), is written in the measured-data format to a temporary
directory and diagnosed through the public CLI (``coload diagnose DIR --json OUT``); the JSON is
judged against the plant's truth. One markdown row per (rate, noise, effect) over the seeds:

    python bench/bench_ident.py --quick                  # 50 Hz, 0.02 m/s, clean + each single effect, 1 seed
    python bench/bench_ident.py --seeds 1 2 3            # the full grid (5 rates x 3 noise levels x 9 cases)
    python bench/bench_ident.py --rates 50 200 --sigmas 0.02 --effects clean viscous_friction
    python bench/bench_ident.py --time                   # the time case: 120 s, 10 agents, 100 Hz
    python bench/bench_ident.py --bound --rates 50 200   # what an ideal estimator could do (Cramer-Rao)

Columns: named correctly (the effect alone; none for clean and for velocity_bias from velocities
alone, which equals an initial velocity; ``unexplained`` and none for the effects outside the
vocabulary), the value's relative error, m and J relative errors before (nominal) -> after
(augmented), whether after <= before/3 or < 1 % for both, the nominal (clean) or augmented residual
over the estimated noise floor, how many residuals are white (Ljung-Box p > 0.01), the wall time.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

import ctplant  # noqa: E402

VOCAB = ["viscous_friction", "coulomb_friction", "rotational_damping", "force_bias", "measurement_delay",
         "velocity_bias"]  # fmt: skip
CASES = ["clean", *VOCAB, "periodic_force", "load_change"]
RATES = [20, 50, 100, 200, 500]
SIGMAS = [0.001, 0.02, 0.3]
ALPHA_WHITE = 0.01


def expected(case: str) -> list[str] | str:
    """The effects the diagnosis should name, or "unexplained"."""
    if case in ("clean", "velocity_bias"):
        return []
    return "unexplained" if case in ctplant.OUTSIDE else [case]


def run_diagnose(rec: Path) -> tuple[dict[str, Any], float]:
    out = rec / "diagnosis.json"
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "coload", "diagnose", str(rec), "--json", str(out), "--quiet"],
                          capture_output=True, text=True, cwd=ROOT)  # fmt: skip
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"coload diagnose failed ({proc.returncode}): {proc.stderr.strip()[-500:]}")
    return json.loads(out.read_text()), wall


def floor_of(d: dict[str, Any]) -> float:
    nf = d.get("noise_floor", d.get("noise_sigma"))
    if isinstance(nf, dict):
        nf = nf.get("velocity")
    return float(nf) if nf is not None else math.nan


def rel(est: Any, true: float) -> float:
    return abs(est / true - 1.0) if isinstance(est, (int, float)) and math.isfinite(est) else math.inf


def one(case: str, rate: float, sigma: float, seed: int, n: int, duration: float) -> dict[str, Any]:
    """Generate, diagnose and score one recording."""
    effects = [] if case == "clean" else [case]
    with tempfile.TemporaryDirectory() as tmp:
        rec = Path(tmp) / "rec"
        truth = ctplant.make_recording(rec, n=n, rate_hz=rate, duration_s=duration, sigma_v=sigma, seed=seed,
                                       effects=effects)  # fmt: skip
        try:
            d, wall = run_diagnose(rec)
        except RuntimeError as exc:  # counted as a failure of the row, not the end of the grid
            print(f"  {rate:g} Hz {sigma:g} m/s {case} seed {seed}: {exc}", file=sys.stderr, flush=True)
            nan = math.nan
            return {"ok": False, "names": ["error"], "unexplained": False, "verr": nan, "mb": nan, "ma": nan,
                    "jb": nan, "ja": nan, "good": False, "ratio": nan, "white": False, "floor_err": nan,
                    "wall": nan}  # fmt: skip
    names = sorted(e["name"] for e in d["effects"])
    exp = expected(case)
    ok = (d["unexplained"] and not names) if exp == "unexplained" else (names == exp and not d["unexplained"])
    verr = math.nan
    if isinstance(exp, list) and exp and names == exp:
        est = np.atleast_1d(np.asarray(d["effects"][0]["value"], dtype=float))
        true = np.atleast_1d(np.asarray(truth["effects"][case], dtype=float))
        verr = float(np.linalg.norm(est - true) / np.linalg.norm(true))
    nom, aug = d["nominal"], d["augmented"]
    mb, ma = rel(nom["m"], truth["m"]), rel(aug["m"], truth["m"])
    jb, ja = rel(nom["J"], truth["J"]), rel(aug["J"], truth["J"])
    final = aug if names else nom
    return {
        "ok": bool(ok), "names": names, "unexplained": d["unexplained"], "verr": verr, "mb": mb, "ma": ma, "jb": jb,
        "ja": ja, "good": all(a <= b / 3 or a < 0.01 for a, b in ((ma, mb), (ja, jb))),
        "ratio": final["residual_rms"] / floor_of(d), "white": final["whiteness_p"] > ALPHA_WHITE,
        "floor_err": floor_of(d) / sigma - 1.0, "wall": d.get("wall_s") or wall,
    }  # fmt: skip


def pct(xs: list[float]) -> str:
    xs = [x for x in xs if not math.isnan(x)]
    if not xs:
        return "-"
    return f"{100 * float(np.median(xs)):.2g} / {100 * max(xs):.2g}"


def row(rate: float, sigma: float, case: str, rs: list[dict[str, Any]]) -> str:
    k = len(rs)
    med = lambda key: float(np.nanmedian([r[key] for r in rs]))  # noqa: E731
    return (f"| {rate:g} | {sigma:g} | {case} | {sum(r['ok'] for r in rs)}/{k} | {pct([r['verr'] for r in rs])} "
            f"| {100 * med('mb'):.2g} -> {100 * med('ma'):.2g} | {100 * med('jb'):.2g} -> {100 * med('ja'):.2g} "
            f"| {sum(r['good'] for r in rs)}/{k} | {med('ratio'):.3g} | {sum(r['white'] for r in rs)}/{k} "
            f"| {100 * med('floor_err'):+.2g} | {med('wall'):.1f} |")  # fmt: skip


HEADER = ("| rate Hz | sigma m/s | effect | named correctly | value error % (median / max) | m error % before -> after "
          "(median) | J error % before -> after (median) | after <= before/3 or < 1 % | residual / noise floor "
          "(median) | white | noise floor error % (median) | wall s (median) |\n"
          "|---|---|---|---|---|---|---|---|---|---|---|---|")  # fmt: skip


def ideal_half_width(truth: dict[str, Any], name: str, sigma: float) -> tuple[float, float, float]:
    """Cramer-Rao bound of an estimator that knows the true model structure: 95 % half-widths relative to
    the truth of the effect's value, m and J, from the plant's own sensitivities (finite differences of
    the parameters m, J, contacts, initial heading and velocities and the effect's values)."""
    load, inp, traj, t = truth["load"], truth["inputs"], truth["trajectory"], truth["t"]
    t0 = traj.breaks[0]
    x0 = traj.state(np.array([t0]))[0]
    ev = np.atleast_1d(np.asarray(truth["effects"][name], dtype=float))
    n = load.n

    def predict(p: np.ndarray) -> np.ndarray:
        eff = dict(truth["effects"])
        eff[name] = p[6 + 2 * n :].tolist() if ev.size > 1 else float(p[-1])
        e = ctplant.Effects.from_dict(eff)
        ld = dataclasses.replace(load, m=p[0], J=p[1], r=p[6 : 6 + 2 * n].reshape(n, 2))
        x = np.array([x0[0], x0[1], *p[2:6]])
        _, v = ctplant.simulate(ld, inp, e, x, t0, float(t[-1]) + 0.01, 0.02).contacts(t - e.delay)
        return (v + np.asarray(e.vbias)).ravel()

    p = np.concatenate(([load.m, load.J], x0[2:6], load.r.ravel(), ev))
    y0 = predict(p)
    cols = []
    for k in range(p.size):
        q = p.copy()
        q[k] += 1e-5 * max(abs(p[k]), 1e-2)
        cols.append((predict(q) - y0) / (q[k] - p[k]))
    jac = np.array(cols).T
    norm = np.linalg.norm(jac, axis=0)
    _, sv, vh = np.linalg.svd(jac / norm, full_matrices=False)
    sd = sigma * np.sqrt(np.diag(np.linalg.pinv(jac.T @ jac)))
    # a direction the data do not see (e.g. a velocity offset against the initial velocity, without
    # velocity-dependent forces): the parameters in it are not identifiable (the finite differences
    # leave ~1e-5 of a column, so a relative singular value below 1e-4 counts as zero)
    for s_, v_ in zip(sv, vh, strict=True):
        if s_ < 1e-4 * sv[0]:
            sd[np.abs(v_) > 1e-3] = math.inf
    k = 6 + 2 * n
    return (1.96 * float(np.linalg.norm(sd[k:]) / np.linalg.norm(ev)), 1.96 * sd[0] / load.m, 1.96 * sd[1] / load.J)


def bound_table(args: argparse.Namespace) -> None:
    print("| rate Hz | sigma m/s | effect | ideal 95 % half-width %: value, m, J (median over seeds) |")
    print("|---|---|---|---|")
    for rate in args.rates:
        for sigma in args.sigmas:
            for case in args.effects:
                if case == "clean" or case in ctplant.OUTSIDE:
                    continue
                hw = np.median([ideal_half_width(ctplant.make_recording(
                    None, n=args.n, rate_hz=rate, duration_s=args.duration, sigma_v=sigma, seed=seed, effects=[case]),
                    case, sigma) for seed in args.seeds], axis=0)  # fmt: skip
                print(f"| {rate:g} | {sigma:g} | {case} | {100 * hw[0]:.2g}, {100 * hw[1]:.2g}, {100 * hw[2]:.2g} |",
                      flush=True)  # fmt: skip


def time_case(seed: int) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        rec = Path(tmp) / "rec"
        t0 = time.perf_counter()
        truth = ctplant.make_recording(rec, n=10, rate_hz=100, duration_s=120.0, sigma_v=0.02, seed=seed)
        gen = time.perf_counter() - t0
        d, wall = run_diagnose(rec)
    print(f"time case (120 s, 10 agents, 100 Hz, sigma 0.02 m/s, seed {seed}): generation {gen:.1f} s, "
          f"coload diagnose {wall:.1f} s wall (JSON wall_s {d.get('wall_s', 0):.1f} s); named "
          f"{[e['name'] for e in d['effects']] or 'none'}, unexplained {d['unexplained']}, m error "
          f"{100 * rel(d['nominal']['m'], truth['m']):.2f} %, J error "
          f"{100 * rel(d['nominal']['J'], truth['J']):.2f} %, "
          f"residual / floor {d['nominal']['residual_rms'] / floor_of(d):.3f}")  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rates", type=float, nargs="+", default=RATES, help="sample rates, Hz (default: %(default)s)")
    ap.add_argument("--sigmas", type=float, nargs="+", default=SIGMAS,
                    help="velocity noise levels, m/s (default: %(default)s)")  # fmt: skip
    ap.add_argument("--effects", nargs="+", default=CASES, choices=CASES, metavar="CASE",
                    help=f"cases (default: all): {', '.join(CASES)}")  # fmt: skip
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--n", type=int, default=4, help="agents (default: %(default)s)")
    ap.add_argument("--duration", type=float, default=20.0, help="recording length, s (default: %(default)s)")
    ap.add_argument("--quick", action="store_true", help="50 Hz, 0.02 m/s, clean and each vocabulary effect, seed 1")
    ap.add_argument("--time", action="store_true", help="only the time case: 120 s, 10 agents, 100 Hz")
    ap.add_argument("--bound", action="store_true",
                    help="no diagnosis: the Cramer-Rao half-widths an estimator with the true model structure gets")
    args = ap.parse_args(argv)
    if args.time:
        time_case(args.seeds[0])
        return 0
    if args.quick:
        args.rates, args.sigmas, args.effects, args.seeds = [50.0], [0.02], ["clean", *VOCAB[:5]], [1]
    if args.bound:
        bound_table(args)
        return 0
    print(HEADER, flush=True)
    for rate in args.rates:
        for sigma in args.sigmas:
            for case in args.effects:
                rs = []
                for seed in args.seeds:
                    r = one(case, rate, sigma, seed, args.n, args.duration)
                    rs.append(r)
                    print(f"  {rate:g} Hz {sigma:g} m/s {case} seed {seed}: named {r['names'] or '-'} unexplained "
                          f"{r['unexplained']} m {100 * r['mb']:.2f}->{100 * r['ma']:.2f} % J {100 * r['jb']:.2f}->"
                          f"{100 * r['ja']:.2f} % res/floor {r['ratio']:.3g} {r['wall']:.1f} s",
                          file=sys.stderr, flush=True)  # fmt: skip
                print(row(rate, sigma, case, rs), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
