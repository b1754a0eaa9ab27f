"""The dynamical phase at high noise: cells of the Monte Carlo grid (`coload campaign`) run again.

    python bench/high_noise.py [--ns 5 8 11 20] [--sigmas 0.9 1.0] [--runs 0] [--jobs 2] [--set KEY=VALUE]

Each run is the grid's own (paper-fig4 resized to n agents on a line, sigma_v, the campaign's seed for
run k with --seed0 0, so `coload campaign`'s run n5-s1-r0 is `--ns 5 --sigmas 1.0 --runs 0`), on the
in-process engine. Prints per run the final J and m errors (RMS over agents, %), omega_hat RMS and z_i
RMS (over the last 20 s, and z_i over the whole run) and when the team finished. The code before the
high-noise fix is `--set dynamics.filter_omega=false --set dynamics.u_bias_walk=0` (docs/high-noise.md).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from coload.analysis.campaign import campaign_scenario, run_seed  # noqa: E402
from coload.runs.engine import run_inproc  # noqa: E402
from config.loader import load_scenario  # noqa: E402

KEYS = ("J_rel", "m_rel", "omega_rms", "zi_rms_window", "zi_rms", "finished_s")


def one(args: tuple[int, float, int, int, float | None, list[str]]) -> tuple[str, dict]:
    n, sigma, k, seed0, duration, sets = args
    base = load_scenario(ROOT / "config" / "scenarios" / "paper-fig4.toml", sets)
    sc = campaign_scenario(base, n, sigma, run_seed(seed0, n, sigma, k))
    if duration is not None:
        sc = sc.model_copy(update={"duration": duration})
    with tempfile.TemporaryDirectory() as d:
        summary = run_inproc(sc, Path(d))
    return f"n{n}-s{sigma:g}-r{k}", dict(summary.get("errors") or {})


def _fmt(key: str, v: object) -> str:
    if not isinstance(v, (int, float)):
        return f"{key}=None"
    return f"{key}={100 * v:.3g}%" if key.endswith("_rel") else f"{key}={v:.4g}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ns", type=int, nargs="+", default=[5, 8, 11, 20], help="team sizes")
    ap.add_argument("--sigmas", type=float, nargs="+", default=[0.9, 1.0], help="velocity noise std (m/s)")
    ap.add_argument("--runs", type=int, nargs="+", default=[0], help="run indices k of each cell")
    ap.add_argument("--seed0", type=int, default=0, help="the campaign's --seed0")
    ap.add_argument("--duration", type=float, default=None,
                    help="simulated time (s); default the grid's 120 s (n = 20 at sigma >= 0.9 needs ~200 s "
                         "to finish: its kinematic stage is slow)")
    ap.add_argument("--jobs", type=int, default=2, help="parallel runs")
    ap.add_argument("--set", action="append", default=[], help="override on the base scenario (repeatable)")
    a = ap.parse_args()
    work = [(n, s, k, a.seed0, a.duration, a.set) for n in a.ns for s in a.sigmas for k in a.runs]
    with ProcessPoolExecutor(a.jobs) as ex:
        for name, err in ex.map(one, work):
            print(f"{name:12s} " + " ".join(_fmt(k, err.get(k)) for k in KEYS), flush=True)


if __name__ == "__main__":
    main()
