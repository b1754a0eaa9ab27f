"""Agent step cost with online detection on, over off (docs/online-detection.md).

    OPENBLAS_NUM_THREADS=1 python bench/detection_step_cost.py [--n 10] [--duration 40] [--repeat 3] [--set K=V]

The campaign's scenario (``coload.analysis.campaign.campaign_scenario`` of paper-fig4, sigma 0.3, seed
12345) on the in-process engine, ``--repeat`` times each of detection off and on, alternating (off, on,
off, on, ...) so that a shared machine's load weighs on both alike. Prints the engine's counter of the
time inside ``AgentCore.step`` per agent per tick (us) of every run, the best of each and their ratio;
and the process CPU time of each whole run, whose difference per agent per tick is the detection's
extra cost without the waits a loaded machine adds to the wall-clock counter. ``--set`` overrides the
detection-on runs' scenario (``dynamics.online_force_bias=true``: the slope a candidate, and its twin filter).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from coload.analysis.campaign import campaign_scenario
from coload.runs.engine import run_inproc
from config.loader import load_scenario, resolve_scenario_path


def one(n: int, duration: float, detect: bool, extra: tuple[str, ...] = ()) -> tuple[float, float, int]:
    """(us per agent per tick inside AgentCore.step, process CPU s, ticks) of one campaign run; ``extra``:
    scenario overrides."""
    base = load_scenario(resolve_scenario_path("paper-fig4"),
                         [f"dynamics.online_detection={str(detect).lower()}", *extra])
    scn = campaign_scenario(base, n, 0.3, 12345).model_copy(update={"duration": duration})
    with tempfile.TemporaryDirectory() as tmp:
        cpu = time.process_time()
        us = float(run_inproc(scn, Path(tmp) / "run")["agent_step_us"])
        return us, time.process_time() - cpu, scn.ticks


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=10, help="team size (default 10)")
    ap.add_argument("--duration", type=float, default=40.0, help="simulated seconds (default 40)")
    ap.add_argument("--repeat", type=int, default=3, help="runs of each, alternating (default 3)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a scenario override for the detection-on runs")
    a = ap.parse_args()
    runs: dict[bool, list[float]] = {False: [], True: []}
    cpus: dict[bool, list[float]] = {False: [], True: []}
    ticks = 0
    for k in range(a.repeat):
        for detect in (False, True):
            us, cpu, ticks = one(a.n, a.duration, detect, tuple(a.set) if detect else ())
            runs[detect].append(us)
            cpus[detect].append(cpu)
            print(f"run {k + 1} detection {'on ' if detect else 'off'}: {us:.1f} us/agent/tick, CPU {cpu:.2f} s",
                  flush=True)
    off, on = min(runs[False]), min(runs[True])
    print(f"best: off {off:.1f}, on {on:.1f} us/agent/tick; on / off {on / off:.3f} ({100 * (on / off - 1):+.0f} %)")
    extra = (min(cpus[True]) - min(cpus[False])) / (a.n * ticks) * 1e6
    print(f"best CPU: off {min(cpus[False]):.2f} s, on {min(cpus[True]):.2f} s; detection's extra {extra:.1f} us per "
          f"agent per tick ({100 * extra / off:+.0f} % of the best step off)")


if __name__ == "__main__":
    main()
