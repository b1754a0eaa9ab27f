"""Cost of the in-process agent step (AgentCore.step, whole Algorithm 1) on the campaign's scenarios.

    OPENBLAS_NUM_THREADS=1 python bench/agent_step.py [--n 5 10 20] [--duration S] [--profile N]

Runs the campaign's scenario (``coload.analysis.campaign.campaign_scenario`` of paper-fig4, sigma 0.3, seed
12345) on the in-process engine for each team size and prints the engine's own counter of the time
spent inside ``AgentCore.step`` per agent per tick (us), the wall time of the run and the ratio of the
per-agent cost at the largest n to the smallest (the graph is a line, so an agent has <= 2 neighbours
whatever n: the ratio shows what grows with n). ``--duration`` shortens the runs (the stage mix then
differs from the campaign's: fewer dynamical-phase ticks); ``--profile N`` writes a cProfile dump of the
n = N run to agent_step.prof in the current directory. Timings are of a shared machine: compare runs
made back to back, and take the better of two.
"""

from __future__ import annotations

import argparse
import cProfile
import tempfile
import time
from pathlib import Path

from coload.analysis.campaign import campaign_scenario
from coload.runs.engine import run_inproc
from config.loader import load_scenario, resolve_scenario_path


def one(n: int, duration: float | None, profile: bool) -> tuple[float, float, float | None]:
    """(us per agent per tick inside AgentCore.step, wall s, J relative error) of one campaign run."""
    base = load_scenario(resolve_scenario_path("paper-fig4"))
    scn = campaign_scenario(base, n, 0.3, 12345)
    if duration is not None:
        scn = scn.model_copy(update={"duration": duration})
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        t0 = time.perf_counter()
        if profile:
            prof = cProfile.Profile()
            s = prof.runcall(run_inproc, scn, out)
            prof.dump_stats("agent_step.prof")
        else:
            s = run_inproc(scn, out)
        wall = time.perf_counter() - t0
    err = s.get("errors")
    return s["agent_step_us"], wall, err.get("J_rel") if isinstance(err, dict) else None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, nargs="+", default=[5, 10, 20], help="team sizes")
    ap.add_argument("--duration", type=float, default=None, help="simulated seconds (default: the scenario's)")
    ap.add_argument("--profile", type=int, default=None, help="cProfile the run of this n")
    a = ap.parse_args()
    per: dict[int, float] = {}
    print(f"{'n':>4} {'us/agent/tick':>14} {'wall s':>8} {'J_rel':>10}")
    for n in a.n:
        us, wall, jrel = one(n, a.duration, a.profile == n)
        per[n] = us
        jr = f"{jrel:.4g}" if isinstance(jrel, float) else "-"
        print(f"{n:>4} {us:>14.1f} {wall:>8.1f} {jr:>10}", flush=True)
    lo, hi = min(per), max(per)
    if lo != hi:
        print(f"ratio us/agent/tick n={hi} / n={lo}: {per[hi] / per[lo]:.2f}")


if __name__ == "__main__":
    main()
