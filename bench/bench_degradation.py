"""How Algorithm 1 degrades under link faults: paper-fig4, in-process engine, several seeds.

    python bench/bench_degradation.py [--seeds 3] [--jobs 1] [--conditions ff,loss20+delay100]
    python bench/bench_degradation.py --kinematic          # the kinematic phase alone, 60 s

Conditions (lockstep, dt = 0.01 s, so a delay D is D / dt ticks plus a uniform jitter of 0..D/2,
which reorders messages): Bernoulli loss 0 / 10 / 20 / 30 %, delay 0 / 50 / 100 / 200 ms, bursty
Gilbert-Elliott loss, and 20 % loss + 100 ms delay combined. paper-fig4 as it is (120 s, Algorithm 1:
kinematic phase, m and z_C, then J). For each: the median [max] over seeds of the final J and m
relative errors (after the averaging consensus), ``finished_s`` (every agent done with Algorithm 1),
the time from which EERD stays below 1 % of its initial value, z_i RMS at the end and omega RMS over
the last 20 s; then the ratios of the medians to the fault-free run's.
Issue target: 20 % loss + 100 ms delay within 1.5x of the fault-free run in error (J and m) and time
(finished_s). Exit status 0 if met (or not measured), 1 if missed.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from coload.runs.engine import run_inproc  # noqa: E402
from config.loader import load_scenario  # noqa: E402

KIN = 'dynamics.algorithm="none"'  # --kinematic: the kinematic phase alone
FIG4 = ROOT / "config" / "scenarios" / "paper-fig4.toml"
DT = 0.01
TARGET = "loss20+delay100"


def _loss(p: float) -> list[str]:
    return [] if p == 0 else ['link.loss.model="bernoulli"', f"link.loss.p={p}"]


def _delay(ms: float) -> list[str]:
    ticks = round(ms / 1000 / DT)
    return [] if ticks == 0 else [f"link.delay_ticks={ticks}", f"link.jitter_ticks={ticks // 2}"]


GE = ['link.loss.model="gilbert_elliott"', "link.loss.p_good_to_bad=0.05", "link.loss.p_bad_to_good=0.2",
      "link.loss.loss_good=0.0", "link.loss.loss_bad=0.8"]
"""Bursts of mean 5 messages, 20 % of the time in the bad state: ~16 % loss on average, in bursts."""

CONDITIONS: dict[str, tuple[str, list[str]]] = {
    "ff": ("fault-free", []),
    "loss10": ("loss 10 %", _loss(0.1)),
    "loss20": ("loss 20 %", _loss(0.2)),
    "loss30": ("loss 30 %", _loss(0.3)),
    "delay50": ("delay 50 ms (+0-20 ms)", _delay(50)),
    "delay100": ("delay 100 ms (+0-50 ms)", _delay(100)),
    "delay200": ("delay 200 ms (+0-100 ms)", _delay(200)),
    "ge": ("Gilbert-Elliott (~16 %, bursts of 5)", GE),
    TARGET: ("loss 20 % + delay 100 ms (+0-50 ms)", _loss(0.2) + _delay(100)),
}

KEYS = ("J", "m", "finished", "conv", "zi", "omega")


def _num(x: object) -> float:
    return float(x) if isinstance(x, (int, float)) and x is not None else math.nan


def run_one(key: str, seed: int, duration: float | None, kinematic: bool) -> dict[str, float]:
    """One run; NaN where a quantity does not exist (no J without the dynamical phase, never converged)."""
    sets = [f"seed={seed}", *CONDITIONS[key][1]]
    if duration is not None:
        sets.append(f"duration={duration}")
    if kinematic:
        sets.append(KIN)
    sc = load_scenario(FIG4, sets)
    with tempfile.TemporaryDirectory() as tmp:
        e = run_inproc(sc, Path(tmp) / "run")["errors"]
    return {"J": _num(e.get("J_rel")) * 100, "m": _num(e.get("m_rel")) * 100, "finished": _num(e.get("finished_s")),
            "conv": _num(e.get("eerd_converge_s")), "zi": _num(e.get("zi_rms")), "omega": _num(e.get("omega_rms"))}


def _med(rows: list[dict[str, float]], k: str) -> float:
    vals = [r[k] for r in rows]
    return math.nan if any(math.isnan(v) for v in vals) else statistics.median(vals)


def _max(rows: list[dict[str, float]], k: str) -> float:
    vals = [r[k] for r in rows]
    return math.nan if any(math.isnan(v) for v in vals) else max(vals)


def _cell(rows: list[dict[str, float]], k: str, fmt: str) -> str:
    return f"{_med(rows, k):{fmt}} [{_max(rows, k):{fmt}}]"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=3, help="seeds 1..N per condition (default 3)")
    ap.add_argument("--duration", type=float, default=None,
                    help="simulated time (s); default: the scenario's 120 s (60 s with --kinematic)")
    ap.add_argument("--conditions", default=",".join(CONDITIONS),
                    help=f"comma-separated subset of {', '.join(CONDITIONS)} (default: all; 'ff' is always run "
                         "first, as the reference of the ratios)")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes (default 1; one run is ~1 min CPU)")
    ap.add_argument("--kinematic", action="store_true",
                    help="pin dynamics.algorithm = none: the kinematic phase alone (no J, m, finished_s)")
    args = ap.parse_args()
    keys = [k.strip() for k in args.conditions.split(",") if k.strip()]
    unknown = [k for k in keys if k not in CONDITIONS]
    if unknown:
        ap.error(f"--conditions: unknown {', '.join(unknown)} (expected some of {', '.join(CONDITIONS)})")
    keys = ["ff"] + [k for k in keys if k != "ff"]
    duration = args.duration if args.duration is not None else (60.0 if args.kinematic else None)

    seeds = range(1, args.seeds + 1)
    what = "kinematic phase alone" if args.kinematic else "Algorithm 1"
    print(f"paper-fig4 ({what}), in-process, lockstep, seeds 1-{args.seeds}, "
          f"{f'{duration:g} s' if duration is not None else 'the scenario duration'}; median [max] over seeds", flush=True)
    # (key, format) of the value columns, then the ratios to fault-free
    cols = [("conv", ".1f"), ("zi", ".3f"), ("omega", ".3f")]
    rcols = ["conv", "zi", "omega"]
    if not args.kinematic:
        cols = [("J", ".2f"), ("m", ".2f"), ("finished", ".1f"), *cols]
        rcols = ["J", "m", "finished", "conv"]
    names = {"J": "J err (%)", "m": "m err (%)", "finished": "finished (s)", "conv": "EERD < 1 % from (s)",
             "zi": "z_i RMS (m)", "omega": "omega RMS (rad/s)"}
    rnames = {"J": "J", "m": "m", "finished": "finished", "conv": "EERD time", "zi": "z_i", "omega": "omega"}
    print("| condition | " + " | ".join(names[k] for k, _ in cols) + " | "
          + " | ".join(f"{rnames[k]} / ff" for k in rcols) + " |")
    print("|" + "---|" * (1 + len(cols) + len(rcols)), flush=True)
    ratios: dict[str, dict[str, float]] = {}
    with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        futures = {(k, s): pool.submit(run_one, k, s, duration, args.kinematic) for k in keys for s in seeds}
        base: dict[str, float] = {}
        for key in keys:  # rows as their runs finish, fault-free first
            r = [futures[(key, s)].result() for s in seeds]
            if key == "ff":
                base = {k: _med(r, k) for k in KEYS}
            rat = {k: _med(r, k) / base[k] if base[k] else math.nan for k in KEYS}
            ratios[key] = rat
            print(f"| {CONDITIONS[key][0]} | " + " | ".join(_cell(r, k, f) for k, f in cols) + " | "
                  + " | ".join(f"{rat[k]:.2f}" for k in rcols) + " |", flush=True)
    if TARGET not in ratios or args.kinematic:
        return 0
    t = ratios[TARGET]
    err, tim = max(t["J"], t["m"]), t["finished"]
    ok = err <= 1.5 and tim <= 1.5
    print(f"target (20 % loss + 100 ms within 1.5x of fault-free): error ratio {err:.2f} (max of J, m), "
          f"time ratio {tim:.2f} (finished_s): {'met' if ok else 'MISSED'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
