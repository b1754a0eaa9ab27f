"""Estimate trust on paper-fig4: which runs end with m or J flagged untrusted, and how far off they are.

    python bench/estimate_trust.py [--seeds 1,2,3] [--jobs 1] [--conditions ff,stale-j]

In-process engine, paper-fig4 as it is (120 s, Algorithm 1; its J excitation stage runs from ~61 s to
~81 s, the J average to ~84 s). Conditions: fault-free; 20 % loss + 100 ms delay (+0-50 ms jitter);
every link's states too old to use (``drop = "stale_age"``) through the J excitation stage (62-78 s),
or through its first half (62-70 s); a partition cutting every link over 62-78 s. For each run: the
final J and m relative errors, ``finished_s`` and the trust block of summary.json (untrusted agents,
poorest fresh fraction, largest sd). One run is ~1 min of CPU.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from coload.runs.engine import run_inproc  # noqa: E402
from config.loader import load_scenario  # noqa: E402

FIG4 = ROOT / "config" / "scenarios" / "paper-fig4.toml"
ALONE = "[[0], [1], [2], [3], [4], [5], [6], [7], [8]]"  # every agent its own group: every link


def _window(start: float, end: float, drop: str) -> list[str]:
    return [f'link.partitions=[{{start={start}, end={end}, groups={ALONE}, drop="{drop}"}}]']


CONDITIONS: dict[str, tuple[str, list[str]]] = {
    "ff": ("fault-free", []),
    "loss20+delay100": ("loss 20 % + delay 100 ms (+0-50 ms)",
                        ['link.loss.model="bernoulli"', "link.loss.p=0.2", "link.delay_ticks=10",
                         "link.jitter_ticks=5"]),
    "stale-j": ("stale J stage (62-78 s, every link)", _window(62.0, 78.0, "stale_age")),
    "stale-j-half": ("stale first half of the J stage (62-70 s)", _window(62.0, 70.0, "stale_age")),
    "cut-j": ("partition of every link, 62-78 s", _window(62.0, 78.0, "partitioned")),
}


def one(cond: str, seed: int) -> dict:
    sc = load_scenario(FIG4, [f"seed={seed}", *CONDITIONS[cond][1]])
    with tempfile.TemporaryDirectory() as d:
        s = run_inproc(sc, Path(d) / "run")
    e, tr = s["errors"], s.get("trust", {})
    return {"cond": cond, "seed": seed, "J": e.get("J_rel"), "m": e.get("m_rel"), "finished": e.get("finished_s"),
            "trust": {k: (v["untrusted_agents"], v["fresh_min"], v["sd_max"]) for k, v in tr.items()}}


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * abs(x):.2f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="1,2,3", help="comma-separated seeds (default 1,2,3)")
    ap.add_argument("--jobs", type=int, default=1, help="parallel runs (default 1)")
    ap.add_argument("--conditions", default=",".join(CONDITIONS), help="comma-separated, of: " + ", ".join(CONDITIONS))
    a = ap.parse_args()
    conds = a.conditions.split(",")
    bad = [c for c in conds if c not in CONDITIONS]
    if bad:
        ap.error(f"unknown condition {bad[0]!r}: expected one of {', '.join(CONDITIONS)}")
    seeds = [int(s) for s in a.seeds.split(",")]
    jobs = [(c, s) for c in conds for s in seeds]
    with ProcessPoolExecutor(a.jobs) as ex:
        rows = list(ex.map(one, *zip(*jobs)))
    print("| condition | seed | J err (%) | m err (%) | finished (s) | J untrusted at | J fresh min | J sd max "
          "| m untrusted at | m fresh min |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        j = r["trust"].get("J", (None, None, None))
        m = r["trust"].get("m", (None, None, None))
        fmt = lambda v, spec: "-" if v is None else format(v, spec)  # noqa: E731
        print(f"| {CONDITIONS[r['cond']][0]} | {r['seed']} | {_pct(r['J'])} | {_pct(r['m'])} | {fmt(r['finished'], '.1f')} "
              f"| {j[0] or 'none'} | {fmt(j[1], '.2f')} | {fmt(j[2], '.3g')} | {m[0] or 'none'} | {fmt(m[1], '.2f')} |")


if __name__ == "__main__":
    main()
