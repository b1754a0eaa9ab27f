"""Kinematic-phase accuracy on paper-fig4 at several noise levels, over Zenoh or in-process.

    python bench/kinematic_targets.py [--engine zenoh|inproc] [--seeds 3] [--sigmas 0.01 0.1 0.3]

For each run: the worst agent's EERD share at the end (its edges' squared error over their initial
value), EERD at the end over its initial value, RMS over agents of |z_i_hat - z_i| at t = 60 s,
omega RMS error over the last 20 s, and when EERD first stays below 1 % of its initial value.
Issue targets: EERD < 1 % for every agent, z_i RMS <= 0.05 m, omega RMS <= 0.05 rad/s by 60 s.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from coload.runs.engine import run_inproc  # noqa: E402
from coload.runs.orchestrate import run_processes  # noqa: E402
from config.loader import load_scenario  # noqa: E402

KIN = 'dynamics.algorithm="none"'  # the kinematic phase alone, as the documented numbers
FIG4 = ROOT / "config" / "scenarios" / "paper-fig4.toml"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--engine", choices=["zenoh", "inproc"], default="zenoh")
    ap.add_argument("--seeds", type=int, default=3, help="seeds 1..N per noise level")
    ap.add_argument("--sigmas", type=float, nargs="+", default=[0.01, 0.1, 0.3])
    ap.add_argument("--duration", type=float, default=60.0)
    args = ap.parse_args()

    header = f"{'sigma':>6} {'seed':>4} {'EERD worst agent':>17} {'EERD ratio':>11} {'z_i RMS [m]':>12} " \
             f"{'omega RMS [rad/s]':>18} {'EERD<1% from [s]':>17} {'x real time':>11}"
    print(header)
    print("-" * len(header))
    ok = True
    with tempfile.TemporaryDirectory() as tmp:
        for sigma in args.sigmas:
            rows = []
            for seed in range(1, args.seeds + 1):
                sc = load_scenario(FIG4, [f"noise.sigma_v={sigma}", f"seed={seed}", f"duration={args.duration}", KIN])
                out = Path(tmp) / f"s{sigma}-{seed}"
                s = run_processes(sc, out, quiet=True) if args.engine == "zenoh" else run_inproc(sc, out)
                if s is None:
                    print(f"{sigma:6.2f} {seed:4d}  run failed (logs in {out / 'logs'})")
                    ok = False
                    continue
                e = s["errors"]
                worst = max(v for v in e["eerd_ratio_per_agent"] if v is not None)
                rows.append((worst, e["zi_rms"], e["omega_rms"]))
                conv = e["eerd_converge_s"]
                print(f"{sigma:6.2f} {seed:4d} {worst:17.2e} {e['eerd_ratio']:11.2e} {e['zi_rms']:12.4f} "
                      f"{e['omega_rms']:18.4f} {conv if conv is not None else float('nan'):17.2f} "
                      f"{s['sim_s'] / s['wall_s']:11.1f}", flush=True)
                ok &= worst < 0.01 and e["zi_rms"] <= 0.05 and e["omega_rms"] <= 0.05
            if rows:
                med = [statistics.median(c) for c in zip(*rows)]
                print(f"{sigma:6.2f} {'med':>4} {med[0]:17.2e} {'':>11} {med[1]:12.4f} {med[2]:18.4f}")
    print("all runs meet the targets" if ok else "SOME RUNS MISS THE TARGETS")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
