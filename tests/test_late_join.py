"""A late joiner over Zenoh: the simulator starts without agent 4 (its start-up wait runs out), and
the agent daemon, started as a process while the run is going, joins at the simulator's current
tick, estimates, and ends the run with the others (the in-memory crash-and-replace case is
tests/test_restart.py)."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

from config.loader import load_scenario
from net.zenoh_transport import free_tcp_port
from tests.conftest import ROOT, SCENARIOS, coload_cmd, control_monitor_cmd

pytestmark = pytest.mark.zenoh

LATE = 4
JOIN_AFTER = 200  # ticks
# the joiner's process needs ~1 s of CPU to start (Python, numba, the kernels' cache) and several on a
# loaded machine, during which the team goes on: 18 s leave it 9 s or more to estimate after it is up
SETS = ["duration=18.0", "timing.startup_timeout_s=2.0", "timing.neighbour_timeout_s=0.5",
        "timing.wrench_timeout_s=5.0"]


def test_late_joiner_over_zenoh(tmp_path, processes):
    scenario = tmp_path / "s.toml"
    scenario.write_text((SCENARIOS / "quick.toml").read_text())
    sc = load_scenario(scenario, SETS)
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    run = "latejoin"
    router = processes.start("router", coload_cmd("router", "--listen", endpoint), stdout=subprocess.PIPE, cwd=ROOT)
    assert router.stdout.readline().decode().startswith("ready")
    monitor = processes.start("monitor", control_monitor_cmd(endpoint, run), stdout=subprocess.PIPE,
                              stdin=subprocess.PIPE, cwd=ROOT)
    assert monitor.stdout.readline().decode().startswith("ready")
    common = [str(scenario), *[a for s in SETS for a in ("--set", s)], "--connect", endpoint, "--run", run]
    agents = [processes.start(f"agent{i}", coload_cmd("agent", "--id", str(i), *common), cwd=ROOT)
              for i in range(sc.n) if i != LATE]
    sim = processes.start("sim", coload_cmd("sim", *common, "--out", str(tmp_path / "run")), cwd=ROOT)
    while True:  # progress notices
        line = monitor.stdout.readline().decode()
        assert line, "the monitor stopped"
        if int(line.split()[1]) >= JOIN_AFTER:
            break
    agents.append(processes.start(f"agent{LATE}", coload_cmd("agent", "--id", str(LATE), *common), cwd=ROOT))
    assert sim.wait(120) == 0
    for a in agents:
        assert a.wait(30) == 0
    monitor.stdin.close()

    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    events = summary["events"]
    assert events[0] == {"tick": 0, "t": 0.0, "event": "start_without", "agents": [LATE]}
    joined = [e for e in events if e["event"] == "agent_up"]
    assert [e["agent"] for e in joined] == [LATE], events
    join_tick = joined[0]["tick"]
    assert JOIN_AFTER <= join_tick < sc.ticks
    assert summary["agents_reported"] == list(range(sc.n))
    # the simulator re-sends the current measurement to an agent that appears mid-tick, so the
    # joiner never made it wait in vain; its neighbour 3 waited once, at tick 1, for a state agent 4
    # could not send (it was not there)
    assert summary["timeouts"] == {"wrench": 0, "neighbour": 1}
    # samples: no wrench from the joiner before it joined, its own wrench (it pushes) from then on
    data = np.loadtxt(tmp_path / "run" / "samples.csv", delimiter=",", skiprows=1)
    mine = data[data[:, 1] == LATE]
    assert len(mine) == sc.ticks
    ticks = np.rint(mine[:, 0] / sc.dt).astype(int)
    wrench = np.abs(mine[:, 4:7]).sum(axis=1)
    assert np.all(wrench[ticks < join_tick] == 0)
    assert np.count_nonzero(wrench[ticks > join_tick]) > 0.9 * (sc.ticks - join_tick - 1)
    # it estimated: its z_i is reported at the end and is as good as its neighbours' are
    zi = summary["errors"]["zi_err_per_agent"]
    assert zi[LATE] is not None and zi[LATE] < 0.2, zi
