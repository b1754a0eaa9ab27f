"""Issue-3 targets of the dynamical phase, measured over seeds on the in-process engine.

    python bench/dynamics_targets.py [--seeds 10] [--jobs 2] [--scenarios paper-fig4 paper-fig5] [--batch-fit]

Prints, per scenario, the median and 90th percentile over seeds of the final relative errors of J and
m (after the averaging consensus, and each agent's own before it), the signed error of the team's mean J and
m (a bias shows as a median far from 0), z_C and v_C errors and the time at which every agent has finished
Algorithm 1 (``finished_s``); with a centralized batch fit in the summary, also the ratio distributed /
centralized. An in-process lockstep run equals the Zenoh
run bit for bit (tests/test_engines.py), so these are also the Zenoh numbers.
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from coload.runs.engine import run_inproc  # noqa: E402
from config.loader import load_scenario  # noqa: E402

KEYS = ("J_rel", "m_rel", "J_local_rel", "m_local_rel", "J_signed_rel", "m_signed_rel", "zC_rms", "vC_rms",
        "finished_s", "J_over_centralized", "m_over_centralized")


def one(args: tuple[str, int, list[str]]) -> tuple[str, int, dict]:
    name, seed, sets = args
    sc = load_scenario(ROOT / "config" / "scenarios" / f"{name}.toml", [f"seed={seed}", *sets])
    return name, seed, _errors(sc)


def _errors(sc) -> dict:
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        summary = run_inproc(sc, Path(d))
        err = dict(summary["errors"])
        err.update(_signed(Path(d)))
        ratio = summary.get("distributed_over_centralized") or {}
        for q in ("J", "m"):
            if ratio.get(q) is not None:
                err[f"{q}_over_centralized"] = ratio[q]
        return err


def _signed(run_dir: Path) -> dict:
    """Signed relative error of the agents' mean final J and m (the metrics' J_rel is an RMS over agents)."""
    import csv

    with open(run_dir / "estimates.csv") as f:
        rows = list(csv.DictReader(f))
    with open(run_dir / "truth.csv") as f:
        truth = {r["t"]: r for r in csv.DictReader(f)}
    t_end = rows[-1]["t"]
    last = [r for r in rows if r["t"] == t_end]
    out = {}
    for col, tcol in (("J", "inertia"), ("m", "mass")):
        vals = np.array([float(r[col] or "nan") for r in last])
        if np.isfinite(vals).all() and t_end in truth:
            out[f"{col}_signed_rel"] = float(vals.mean() / float(truth[t_end][tcol]) - 1.0)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=10, help="runs per scenario")
    ap.add_argument("--seed0", type=int, default=1, help="first seed")
    ap.add_argument("--jobs", type=int, default=2, help="parallel runs")
    ap.add_argument("--scenarios", nargs="+", default=["paper-fig4", "paper-fig5"], help="bundled scenario names")
    ap.add_argument("--set", action="append", default=[], help="scenario override key=value (repeatable)")
    ap.add_argument("--batch-fit", action="store_true",
                    help="also fit the centralized batch estimator to each run (record.batch_fit) and print the "
                         "median over seeds of distributed / centralized error (~+50 %% CPU)")
    a = ap.parse_args()
    sets = [*(["record.batch_fit=true"] if a.batch_fit else []), *a.set]
    work = [(s, a.seed0 + k, sets) for s in a.scenarios for k in range(a.seeds)]
    res: dict[str, list[dict]] = {s: [] for s in a.scenarios}
    with ProcessPoolExecutor(a.jobs) as ex:
        for name, seed, err in ex.map(one, work):
            res[name].append(err)
            vals = " ".join(f"{k}={err[k]:.5g}" if err.get(k) is not None else f"{k}=None" for k in KEYS)
            print(f"{name} seed {seed}: {vals}", flush=True)
    print()
    print(f"{'scenario':12s} {'quantity':12s} {'median':>10s} {'p90':>10s} {'max':>10s}")
    for name, errs in res.items():
        for k in KEYS:
            v = np.array([e.get(k) if e.get(k) is not None else np.nan for e in errs], dtype=float)
            if not np.isfinite(v).any():
                continue
            scale = 100.0 if k.endswith("_rel") else 1.0
            unit = "%" if k.endswith("_rel") else ("s" if k.endswith("_s") else "")
            print(f"{name:12s} {k:12s} {scale * np.nanmedian(v):10.3f} {scale * np.nanpercentile(v, 90):10.3f} "
                  f"{scale * np.nanmax(v):10.3f} {unit}  (n={np.isfinite(v).sum()})")


if __name__ == "__main__":
    main()
