"""Accuracy and wall time of the centralized batch fit (ident.batch_fit) on engine recordings.

Records paper-fig4 runs with the in-process engine (cached under --cache), fits each one from its
samples.csv alone, and scores the fit against truth.csv. Prints one line per run and a median row
per configuration. The numbers in docs/batch-fit.md come from

    python bench/bench_batch_fit.py --sigma 0.3 0.1 0.01 --seeds 1 2 3
    python bench/bench_batch_fit.py --sigma 0.3 --seeds 1 2 3 --set control.force=5
    python bench/bench_batch_fit.py --sigma 0.3 --seeds 1 --duration 200
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from coload.analysis.yardstick import fit_run_dir
from coload.rundir.format import read_run
from ident.batch_fit import FitOptions


def record(cache: Path, scenario: str, overrides: list[str]) -> Path:
    """Run the engine once per distinct (scenario, overrides); reuse the run directory afterwards."""
    from coload.runs.engine import run_inproc
    from config.loader import load_scenario

    key = hashlib.sha1(repr((scenario, overrides)).encode()).hexdigest()[:12]
    run_dir = cache / key
    if not (run_dir / "summary.json").exists():
        run_inproc(load_scenario(scenario, overrides), run_dir)
        (run_dir / "overrides.txt").write_text("\n".join(overrides) + "\n")
    return run_dir


def score(run_dir: Path, options: FitOptions) -> dict[str, float]:
    """Fit the run and compare with its truth; errors relative (m, J) or RMS over recorded ticks."""
    run = read_run(run_dir)
    tr = run.truth
    t0 = time.perf_counter()
    fit = fit_run_dir(run_dir, options=options)
    wall = time.perf_counter() - t0
    m, J = float(tr.columns["mass"][0]), float(tr.columns["inertia"][0])
    k = np.rint(tr.t / run.dt).astype(int)
    zc = np.stack((tr.columns["zc_x"], tr.columns["zc_y"]), axis=1)
    vc = np.stack((tr.columns["vc_x"], tr.columns["vc_y"]), axis=1)
    rms = lambda e: float(np.sqrt(np.mean(np.sum(e**2, axis=-1))))
    return {
        "m_rel": (fit.m.value - m) / m,
        "m_ci_rel": fit.m.ci95 / m,
        "m_covered": abs(fit.m.value - m) <= fit.m.ci95,
        "J_rel": (fit.J.value - J) / J,
        "J_ci_rel": fit.J.ci95 / J,
        "J_covered": abs(fit.J.value - J) <= fit.J.ci95,
        "zi_rms": rms(fit.zi[k] - tr.zi),
        "zc_rms": rms(fit.zc[k] - zc),
        "omega_rms": float(np.sqrt(np.mean((fit.omega[k] - tr.columns["omega"]) ** 2))),
        "vc_rms": rms(fit.v_c[k] - vc),
        "res_rms": fit.residual_rms,
        "wall_s": wall,
    }


COLS = ("m_rel", "m_ci_rel", "J_rel", "J_ci_rel", "zi_rms", "zc_rms", "omega_rms", "vc_rms", "res_rms", "wall_s")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="config/scenarios/paper-fig4.toml")
    ap.add_argument("--sigma", type=float, nargs="+", default=[0.3, 0.1, 0.01])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="extra scenario override")
    ap.add_argument("--cache", type=Path, default=Path("runs/bench-batch-fit"))
    args = ap.parse_args(argv)
    opts = FitOptions()
    print(f"{'sigma':>6} {'seed':>4} " + " ".join(f"{c:>10}" for c in COLS) + "  covered(m,J)")
    for sigma in args.sigma:
        rows = []
        for seed in args.seeds:
            ov = [f"duration={args.duration}", f"noise.sigma_v={sigma}", f"seed={seed}", *args.set]
            r = score(record(args.cache, args.scenario, ov), opts)
            rows.append(r)
            print(f"{sigma:>6} {seed:>4} " + " ".join(f"{r[c]:>10.2e}" for c in COLS)
                  + f"  {int(r['m_covered'])},{int(r['J_covered'])}", flush=True)  # fmt: skip
        med = {c: float(np.median([abs(r[c]) for r in rows])) for c in COLS}
        cov = (sum(r["m_covered"] for r in rows), sum(r["J_covered"] for r in rows))
        print(f"{sigma:>6} {'med':>4} " + " ".join(f"{med[c]:>10.2e}" for c in COLS)
              + f"  {cov[0]}/{len(rows)},{cov[1]}/{len(rows)}  (median of |.|)", flush=True)  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
