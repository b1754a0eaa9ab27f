"""Algorithm 2 (background observers) under a load change: settling of the median m and J estimates.

    python bench/algorithm2_settling.py RUN_DIR [--t-change 100] [--band 0.05]

RUN_DIR is a run of config/scenarios/paper-fig9.toml (``coload run ... --out RUN_DIR``). Prints, before
and after the change, the median over agents of m and J against the truth at each recorded time, the
settling time (first time after the change from which the median stays within ``band`` of the new
value) and the 90th percentile over agents and time of the relative error after settling.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--t-change", type=float, default=100.0)
    ap.add_argument("--band", type=float, default=0.05)
    a = ap.parse_args()
    est = list(csv.DictReader(open(a.run_dir / "estimates.csv")))
    tru = list(csv.DictReader(open(a.run_dir / "truth.csv")))
    truth = {r["t"]: (float(r["mass"]), float(r["inertia"])) for r in tru}
    times = sorted({r["t"] for r in est}, key=float)
    by_t: dict[str, list[dict]] = {}
    for r in est:
        by_t.setdefault(r["t"], []).append(r)
    t = np.array([float(x) for x in times])
    for col, k in (("m", 0), ("J", 1)):
        rel = [np.array([float(r[col] or "nan") for r in by_t[x]]) / truth[x][k] - 1.0 for x in times]
        med = np.array([np.nanmedian(v) if np.isfinite(v).any() else np.nan for v in rel])
        inside = np.abs(med) <= a.band
        after = t >= a.t_change
        settle = None
        for i in np.flatnonzero(after):
            if inside[i:].all():
                settle = t[i] - a.t_change
                break
        before = (t >= a.t_change - 20) & (t < a.t_change)
        print(f"{col}: median rel. error in the 20 s before the change {100 * np.nanmedian(np.abs(med[before])):.2f} %;"
              f" settles within {100 * a.band:.0f} % {settle if settle is None else f'{settle:.1f} s'} after it", end="")
        if settle is not None:
            sel = t >= a.t_change + settle
            allv = np.abs(np.concatenate([rel[i] for i in np.flatnonzero(sel)]))
            print(f"; then |error| p90 over agents and time {100 * np.nanpercentile(allv, 90):.2f} %,"
                  f" final median {100 * med[-1]:+.2f} %")
        else:
            print()


if __name__ == "__main__":
    main()
