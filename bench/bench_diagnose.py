"""Multi-seed measurement of ``coload diagnose`` on simulated recordings with one hidden plant effect.

For each effect and seed: record with the in-process engine (quick.toml: n = 5, sigma = 0.1 m/s, a
3 N common force per agent; the effect in [plant], unknown to agents and diagnosis), diagnose from
samples.csv + run.toml, and compare with the truth. Prints one row per effect:

    python bench/bench_diagnose.py --seeds 1 2 3 [--duration 30] [--effects viscous_friction ...]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from coload.runs.engine import run_inproc  # noqa: E402
from config.loader import load_scenario  # noqa: E402
from ident.diagnose import diagnose_dir  # noqa: E402

# row label -> (override, named effect expected (None: none), truth value)
CASES = {
    "viscous_friction": ("plant.friction.viscous=5.0", "viscous_friction", 5.0),
    "coulomb_friction": ("plant.friction.coulomb=2.0", "coulomb_friction", 2.0),
    "rotational_damping": ("plant.friction.rotational=8.0", "rotational_damping", 8.0),
    "measurement_delay": ("plant.sensor.delay=0.1", "measurement_delay", 0.1),
    "force_bias": ("plant.external_force=[0.5, -0.3]", "force_bias", (0.5, -0.3)),
    "velocity_bias": ("plant.sensor.velocity_bias=[0.05, -0.03]", None, None),
    "actuator_gain (0.9)": ("plant.actuator_gain=0.9", None, None),
    "none (clean)": ("", None, None),
    "load change (unexplained)": ("plant.load_changes=[{t = 15.0, mass = 40.0, inertia = 70.0}]", "unexplained", None),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--effects", nargs="+", default=list(CASES), help="row labels (default: all)")
    args = ap.parse_args()
    print("| effect | seeds | named correctly | value error (median, max) | m error before -> after (median) "
          "| J error before -> after (median) | after <= before/3 or < 1 % | whiteness p before / after (median) | wall s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for label in args.effects:
        override, expect, truth = CASES[label]
        ok, verr, mb, ma, jb, ja, good, pb, pa, wall = 0, [], [], [], [], [], 0, [], [], []
        for seed in args.seeds:
            sets = ["duration=%g" % args.duration, "control.force=3", f"seed={seed}"] + ([override] if override else [])
            with tempfile.TemporaryDirectory() as tmp:
                rec = Path(tmp) / "rec"
                run_inproc(load_scenario(ROOT / "config/scenarios/quick.toml", sets), rec)
                t0 = time.perf_counter()
                r = diagnose_dir(rec)
                wall.append(time.perf_counter() - t0)
            names = [e["name"] for e in r.effects]
            if expect == "unexplained":
                ok += r.unexplained and not names
            elif expect is None:
                ok += not names and not r.unexplained
            else:
                ok += names == [expect] and not r.unexplained
                if names == [expect]:
                    verr.append(float(np.max(np.abs(np.asarray(r.effects[0]["value"]) - truth) / np.abs(truth))))
            mb.append(abs(r.nominal.m_rel_err))
            ma.append(abs(r.augmented.m_rel_err))
            jb.append(abs(r.nominal.J_rel_err))
            ja.append(abs(r.augmented.J_rel_err))
            good += all(a <= b / 3 or a < 0.01 for a, b in ((ma[-1], mb[-1]), (ja[-1], jb[-1])))
            pb.append(r.nominal.whiteness_p)
            pa.append(r.augmented.whiteness_p)
            print(f"  {label} seed {seed}: named {names or '-'} unexplained {r.unexplained} "
                  f"m {100 * mb[-1]:.2f}->{100 * ma[-1]:.2f} % J {100 * jb[-1]:.2f}->{100 * ja[-1]:.2f} % "
                  f"p {pb[-1]:.2g}/{pa[-1]:.2g} {wall[-1]:.0f} s", file=sys.stderr, flush=True)  # fmt: skip
        k = len(args.seeds)
        ve = f"{100 * np.median(verr):.1f} %, {100 * max(verr):.1f} %" if verr else "-"
        print(f"| {label} | {k} | {ok}/{k} | {ve} | {100 * np.median(mb):.2f} % -> {100 * np.median(ma):.2f} % "
              f"| {100 * np.median(jb):.2f} % -> {100 * np.median(ja):.2f} % | {good}/{k} "
              f"| {np.median(pb):.2g} / {np.median(pa):.2g} | {np.median(wall):.0f} |", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
