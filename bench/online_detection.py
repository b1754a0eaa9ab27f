"""Online effect detection: which effect the team switches on, when, and m / J at the end against the nominal run.

    python bench/online_detection.py [--seeds 1-5] [--plants viscous,rotational,clean] [--jobs 1] [--no-nominal]
                                     [--faults] [--set KEY=VALUE ...]

In-process engine (lockstep: equal to a Zenoh run bit for bit), friction-online.toml (paper-fig4 geometry,
n = 10, line graph, sigma 0.3, J stage 40 s) with nothing declared (``dynamics.estimate_effects = []``)
and ``dynamics.online_detection = true``, run to 110 s (done at ~102 s). Plants: viscous friction
5 N s/m alone, rotational damping 8.69 N m s alone, clean. For each run: the switches, withdrawals and
ruled-out candidates the team agreed (summary.json ``effects``; the right decision counts what is on at the
end), the time from the m stage's start to the first switch, m and J relative errors at the end; and the
same plant and seed with the nominal model (detection off) for comparison.
``--set``: more scenario overrides for every run (e.g. ``dynamics.coulomb_speed=0.01``).
``--faults``: every link loses 20 % of the states (Bernoulli) and delays them by 10 ticks (100 ms).
``both``: the two together (friction-online's own plant); ``coulomb``: Coulomb friction 5 N (the plant's
smoothing speed 0.01 m/s); ``slope``: a constant 5 N force along x (``force_bias``); ``both_slope``: the slope
on friction-online's own plant. Out of the online vocabulary:
``periodic`` (a world-frame force 6 N sin(2 pi t / 10 s) along the m stage's force direction, 0.5 rad; the right
answer: nothing on at the end, windows ``unexplained``; its nominal twin runs too).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from coload.rundir import format as fmt  # noqa: E402
from coload.runs.engine import run_inproc  # noqa: E402
from config.loader import load_scenario  # noqa: E402
from net.vocabulary import M_EXCITE  # noqa: E402
from seed_list import parse_seeds  # noqa: E402  (bench/ is the script's own directory)

SCENARIO = ROOT / "config" / "scenarios" / "friction-online.toml"
BASE = ["dynamics.estimate_effects=[]", "duration=110"]
PLANTS = {
    "viscous": ["plant.friction={viscous=5.0}"],
    "rotational": ["plant.friction={rotational=8.69}"],
    "clean": ["plant.friction={}"],
    "both": ["plant.friction={viscous=5.0, rotational=8.69}"],
    "coulomb": ["plant.friction={coulomb=5.0}"],
    "slope": ["plant.friction={}", "plant.external_force=[5.0, 0.0]", "dynamics.online_force_bias=true"],
    "both_slope": ["plant.external_force=[5.0, 0.0]", "dynamics.online_force_bias=true"],
    "periodic": ["plant.friction={}", "plant.periodic_force={amplitude=6.0, period_s=10.0, direction_deg=28.6479}"],
}
FAULTS = ['link.loss={model="bernoulli", p=0.2}', "link.delay_ticks=10"]
TRUE = {"viscous": ["viscous_friction"], "rotational": ["rotational_damping"], "clean": [],
        "both": ["rotational_damping", "viscous_friction"], "coulomb": ["coulomb_friction"], "slope": ["force_bias"],
        "both_slope": ["force_bias", "rotational_damping", "viscous_friction"],
        "periodic": []}  # the right switches
NOMINAL = {"periodic"}  # plants out of the vocabulary whose nominal twin also runs (how far off the model is)


def one(plant: str, seed: int, detect: bool, faults: bool, extra: tuple[str, ...] = ()) -> dict:
    sc = load_scenario(SCENARIO, [*BASE, *PLANTS[plant], *(FAULTS if faults else []), *extra, f"seed={seed}",
                                  f"dynamics.online_detection={'true' if detect else 'false'}"])
    with tempfile.TemporaryDirectory() as d:
        s = run_inproc(sc, Path(d) / "run")
        c = fmt.read_run(Path(d) / "run").estimates.columns
    t = np.arange(len(c["phase"])) * sc.record.every_ticks * sc.dt
    m_start = t[np.flatnonzero(c["phase"][:, 0] >= M_EXCITE)[0]]
    eff = s.get("effects", {})
    return {"plant": plant, "seed": seed, "detect": detect, "m_rel": s["errors"].get("m_rel"),
            "J_rel": s["errors"].get("J_rel"), "b": float(c["b"][-1, 0]), "c": float(c["c"][-1, 0]),
            "fc": float(c["fc"][-1, 0]), "fb": (float(c["fb_x"][-1, 0]), float(c["fb_y"][-1, 0])),
            "events": eff.get("events", []), "on": eff.get("on", []),
            "unexplained": eff.get("unexplained_windows"),
            "m_start": float(m_start),
            "dt": sc.dt, "step_us": s.get("agent_step_us")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="1-5", help="seeds, a range A-B or a comma list (default 1-5)")
    ap.add_argument("--plants", default=",".join(PLANTS), help="comma-separated, of: " + ", ".join(PLANTS))
    ap.add_argument("--jobs", type=int, default=1, help="parallel runs (default 1)")
    ap.add_argument("--no-nominal", action="store_true", help="skip the nominal twins (detection off)")
    ap.add_argument("--faults", action="store_true", help="20 %% loss and a 100 ms delay on every link")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a scenario override for every run")
    a = ap.parse_args()
    seeds = parse_seeds(a.seeds)
    plants = a.plants.split(",")
    bad = [p for p in plants if p not in PLANTS]
    if bad:
        ap.error(f"unknown plant {bad[0]!r}: expected one of {', '.join(PLANTS)}")
    extra = tuple(a.set)
    jobs = [(p, s, True, a.faults, extra) for p in plants for s in seeds]
    if not a.no_nominal:
        jobs += [(p, s, False, a.faults, extra) for p in plants if TRUE[p] or p in NOMINAL for s in seeds]
    out = []
    with ProcessPoolExecutor(a.jobs) as ex:
        for r in ex.map(one, *zip(*jobs)):  # each run as it ends (a long bench shows its progress)
            out.append(r)
            print("run", {k: v for k, v in r.items() if k != "dt"}, flush=True)
    nominal = {(r["plant"], r["seed"]): r for r in out if not r["detect"]}
    print("| plant | seed | switched, withdrawn or ruled out (tick: effect, z) | from m stage start to the first "
          "switch (s) | unexplained windows | m err | J err | nominal m err | nominal J err | b | c | F_c | f (N) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for p in plants:
        right = 0
        for r in (r for r in out if r["detect"] and r["plant"] == p):
            ev = r["events"]
            right += sorted(r["on"]) == TRUE[p]  # on at the end: a switch withdrawn counts for nothing
            kind = {"effect_withdrawn": " withdrawn", "effect_ruled_out": " ruled out"}
            stat = lambda e: "declared" if e["statistic"] is None else f"{e['statistic']:.2f}"  # noqa: E731
            sw = "; ".join(f"{e['tick']}: {e['effect']}{kind.get(e.get('event'), '')}, {stat(e)}" for e in ev) or "none"
            first = [e for e in ev if e.get("event") == "effect_switch" and e["tick"] >= 0][:1]
            dt0 = f"{first[0]['tick'] * r['dt'] - r['m_start']:.1f}" if first else "-"
            nom = nominal.get((p, r["seed"]), {})
            f = lambda v: "-" if v is None or v != v else f"{100 * v:.2f} %"  # noqa: E731
            print(f"| {p} | {r['seed']} | {sw} | {dt0} | {r['unexplained']} | {f(r['m_rel'])} | {f(r['J_rel'])} "
                  f"| {f(nom.get('m_rel'))} | {f(nom.get('J_rel'))} | {r['b']:.3f} | {r['c']:.3f} | {r['fc']:.3f} "
                  f"| ({r['fb'][0]:.3f}, {r['fb'][1]:.3f}) |")
        n = sum(1 for r in out if r["detect"] and r["plant"] == p)
        print(f"\n{p}: the right decision ({', '.join(TRUE[p]) or 'nothing'}, and nothing else, on at the end) in "
              f"{right} of {n} seeds\n")


if __name__ == "__main__":
    main()
