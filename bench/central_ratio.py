"""Distributed-over-centralized error ratio (issue 3), measured over seeds on the in-process engine.

    python bench/central_ratio.py --seeds 1 2 3 4 5 --out DIR        # runs paper-fig4 per seed into DIR/seedS
    python bench/central_ratio.py --dirs DIR/seed1 DIR/seed2 ...     # only reads finished run directories

Each run is ``coload run paper-fig4 --engine inproc --seed S`` with the batch fit on (record.batch_fit):
summary.json's ``centralized`` (the batch fit of all of samples.csv) and ``distributed_over_centralized``
(median over agents of the final |x_i - x| / x, over |x_c - x| / x). Prints per seed the distributed and
centralized relative errors of J and m, the ratios, the centralized 95 % half-widths and the distributed
error over them, the run's and the fit's wall time and the CPU time of both, then the medians over seeds.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def run(seed: int, out: Path, scenario: str, sets: list[str]) -> Path:
    from coload.runs.engine import run_inproc
    from config.loader import load_scenario

    sc = load_scenario(ROOT / "config" / "scenarios" / f"{scenario}.toml", [f"seed={seed}", "record.batch_fit=true",
                                                                          *sets])  # fmt: skip
    d = out / f"seed{seed}"
    c0, w0 = time.process_time(), time.perf_counter()
    summary = run_inproc(sc, d)
    summary["bench"] = {"total_cpu_s": time.process_time() - c0, "total_wall_s": time.perf_counter() - w0}
    (d / "bench.json").write_text(json.dumps(summary["bench"]) + "\n")
    return d


def row(d: Path) -> dict:
    s = json.loads((d / "summary.json").read_text())
    c, r = s.get("centralized") or {}, s.get("distributed_over_centralized") or {}
    bench = json.loads((d / "bench.json").read_text()) if (d / "bench.json").exists() else {}
    return {
        "run": d.name, "seed": s.get("seed"),
        "J dist": r.get("J_dist_rel"), "J cen": c.get("J_rel"), "J ratio": r.get("J"), "J CI": _rel_ci(c, "J"),
        "J dist/CI": _over(r.get("J_dist_rel"), _rel_ci(c, "J")),
        "m dist": r.get("m_dist_rel"), "m cen": c.get("m_rel"), "m ratio": r.get("m"), "m CI": _rel_ci(c, "m"),
        "m dist/CI": _over(r.get("m_dist_rel"), _rel_ci(c, "m")),
        "run wall s": s.get("wall_s"), "fit wall s": c.get("fit_s"), "total cpu s": bench.get("total_cpu_s"),
        "reason": r.get("reason") or c.get("reason"),
    }  # fmt: skip


def _over(a: float | None, b: float | None) -> float | None:
    return None if a is None or not b else a / b


def _rel_ci(c: dict, name: str) -> float | None:
    if c.get(name) is None or c.get(f"{name}_ci95") is None:
        return None
    return c[f"{name}_ci95"] / (c[name] / (1 + c[f"{name}_rel"]))  # half-width over the truth


def _fmt(k: str, v) -> str:
    if v is None:
        return "-"
    if k.endswith(("dist", "cen", " CI")):
        return f"{100 * v:+.3f} %" if k.endswith("cen") else f"{100 * v:.3f} %"
    if isinstance(v, float):
        return f"{v:.3g}"
    return str(v)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="*", default=[1, 2, 3, 4, 5], help="seeds to run")
    ap.add_argument("--out", type=Path, help="directory for the runs (required unless --dirs)")
    ap.add_argument("--dirs", type=Path, nargs="*", help="finished run directories to read instead of running")
    ap.add_argument("--scenario", default="paper-fig4", help="bundled scenario name (default: %(default)s)")
    ap.add_argument("--set", dest="sets", action="append", default=[], help="scenario override, key=value")
    a = ap.parse_args()
    if a.dirs:
        dirs = a.dirs
    else:
        if a.out is None:
            ap.error("--out is required unless --dirs is given")
        dirs = [run(s, a.out, a.scenario, a.sets) for s in a.seeds]
    rows = [row(d) for d in dirs]
    keys = [k for k in rows[0] if k != "reason"]
    print("| " + " | ".join(keys) + " |")
    print("|" + "---|" * len(keys))
    for r in rows:
        print("| " + " | ".join(_fmt(k, r[k]) for k in keys) + " |")
    med = {}
    for k in keys[2:]:
        vals = [abs(r[k]) if k.endswith("cen") else r[k] for r in rows if r[k] is not None]
        med[k] = float(np.median(vals)) if vals else None
    print("| median | | " + " | ".join(_fmt(k.replace("cen", "CI") if k.endswith("cen") else k, med[k])
                                    for k in keys[2:]) + " |")  # fmt: skip
    for r in rows:
        if r["reason"]:
            print(f"{r['run']}: {r['reason']}")


if __name__ == "__main__":
    main()
