"""The simulator daemon dies mid-run and is started again: it replays its journal (plant, sensor
noise, tables), the agents wait for it through its liveliness token and re-send what it may have
missed, and the run completes exactly as if nothing had happened (lockstep: bit-identical to the
in-process engine). Once over the in-memory transport, once as real processes over Zenoh with
SIGKILL."""

from __future__ import annotations

import asyncio
import json
import signal
import subprocess
from types import SimpleNamespace

import pytest

from agents.daemon import AgentDaemon
from coload.rundir.format import JOURNAL
from coload.rundir.recorder import Recorder
from coload.runs.engine import run_inproc
from config.loader import load_scenario
from net import keys
from net.memory import MemoryBus, MemoryTransport
from net.messages import Control
from net.schema import decode
from net.vocabulary import ESTIMATE_NAMES
from net.zenoh_transport import free_tcp_port
from simulator.daemon import SimDaemon
from tests.conftest import (
    ROOT,
    SCENARIOS,
    coload_cmd,
    control_monitor_cmd,
    max_table_difference,
)

SETS = ["duration=5.0", "record.every_ticks=5", "timing.wrench_timeout_s=5.0", "timing.neighbour_timeout_s=5.0"]


def _assert_same_as_inproc(tmp_path, run_dir, sc) -> None:
    run_inproc(sc, tmp_path / "inproc")
    for name, nkeys in (("samples.csv", 2), ("truth.csv", 1), ("estimates.csv", 2), ("pairs.csv", 3)):
        assert max_table_difference(run_dir, tmp_path / "inproc", name, nkeys) <= 1e-9, name


def _check_summary(summary: dict, sc, killed_after: int, others: tuple[str, ...] = ()) -> dict:
    restarts = [e for e in summary["events"] if e["event"] == "sim_restart"]
    assert len(restarts) == 1, summary["events"]
    assert killed_after <= restarts[0]["tick"] < sc.ticks
    assert restarts[0]["replayed_ticks"] == restarts[0]["tick"]
    # nobody came or went: the agents were waiting, not lost
    assert [e["event"] for e in summary["events"] if e["event"] != "sim_restart"] == list(others)
    assert summary["agents_reported"] == list(range(sc.n))
    assert summary["timeouts"] == {"wrench": 0, "neighbour": 0}
    # what was dropped is what the restart re-sent, nothing else
    assert set(summary["drops"]) <= {"resent", "duplicate"}, summary["drops"]
    return restarts[0]


async def _memory_run(tmp_path, sc, kill_at: int):
    loop = asyncio.get_running_loop()
    bus, run, run_dir = MemoryBus(), "simrestart", tmp_path / "run"
    agent_ts = [MemoryTransport(bus, loop) for _ in range(sc.n)]
    agents = [asyncio.ensure_future(AgentDaemon(sc.agent_view(i), agent_ts[i], run).run()) for i in range(sc.n)]
    reached = loop.create_future()
    observer = MemoryTransport(bus, loop)

    def on_control(_key: str, payload: bytes) -> None:
        if decode(payload, Control).tick >= kill_at and not reached.done():
            reached.set_result(None)

    observer.subscribe(keys.sim_control(run), on_control)
    sim_t = MemoryTransport(bus, loop)
    sim = asyncio.ensure_future(SimDaemon(sc, sim_t, run, Recorder(run_dir, sc, ESTIMATE_NAMES), engine="memory").run())
    try:
        await asyncio.wait_for(reached, 60)
        sim.cancel()  # the process dies: its subscriptions and token go with it
        sim_t.close()
        await asyncio.gather(sim, return_exceptions=True)
        assert (run_dir / JOURNAL).exists()
        sim_t = MemoryTransport(bus, loop)
        summary = await asyncio.wait_for(SimDaemon(sc, sim_t, run, Recorder(run_dir, sc, ESTIMATE_NAMES), engine="memory").run(), 120)
        await asyncio.wait_for(asyncio.gather(*agents), 30)
    finally:
        for t in [*agents, sim]:
            t.cancel()
        for t in [*agent_ts, observer, sim_t]:
            t.close()
    return summary


@pytest.mark.parametrize("partition", [False, True], ids=["plain", "partition"])
def test_simulator_restart_in_memory_resumes_exactly(tmp_path, partition):
    """With a link-model partition open when it dies (1 s to 3 s, killed at 2 s), too: its events
    are recorded once each, and the cut goes on across the restart."""
    extra = ["link.partitions=[{start=1.0, end=3.0, groups=[[0, 1]]}]"] if partition else []
    sc = load_scenario(SCENARIOS / "quick.toml", SETS + extra)
    summary = asyncio.run(_memory_run(tmp_path, sc, kill_at=200))
    _check_summary(summary, sc, 200, ("partition_start", "partition_end") if partition else ())
    assert not (tmp_path / "run" / JOURNAL).exists()  # deleted once the run completed
    _assert_same_as_inproc(tmp_path, tmp_path / "run", sc)


def test_journal_of_another_run_is_not_resumed(tmp_path):
    """A journal left by another run name (or scenario) must not be replayed into this one."""
    sc = load_scenario(SCENARIOS / "quick.toml", ["duration=0.2"])
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / JOURNAL).write_text('{"journal":1,"run":"other","scenario":"x"}\n{"k":0,"w":[]}\n')
    sim = SimDaemon(sc, None, "this", SimpleNamespace(journal_path=run_dir / JOURNAL))  # only reads the journal
    assert sim._read_journal() is None


@pytest.mark.zenoh
def test_simulator_killed_and_restarted_over_zenoh(tmp_path, processes):
    """Router, simulator and 5 agents as processes; the simulator is SIGKILLed mid-run and started
    again with the same command line."""
    scenario = tmp_path / "s.toml"
    scenario.write_text((SCENARIOS / "quick.toml").read_text())
    sets = [a for s in SETS for a in ("--set", s)]
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    run = "simrestart"
    router = processes.start("router", coload_cmd("router", "--listen", endpoint), stdout=subprocess.PIPE, cwd=ROOT)
    assert router.stdout.readline().decode().startswith("ready")
    monitor = processes.start("monitor", control_monitor_cmd(endpoint, run), stdout=subprocess.PIPE,
                              stdin=subprocess.PIPE, cwd=ROOT)
    assert monitor.stdout.readline().decode().startswith("ready")
    common = [str(scenario), *sets, "--connect", endpoint, "--run", run]
    agents = [processes.start(f"agent{i}", coload_cmd("agent", "--id", str(i), *common), cwd=ROOT) for i in range(5)]
    sim_argv = coload_cmd("sim", *common, "--out", str(tmp_path / "run"))
    sim = processes.start("sim", sim_argv, cwd=ROOT)
    while True:  # progress notices, every 5 ticks
        line = monitor.stdout.readline().decode()
        assert line, "the monitor stopped"
        if int(line.split()[1]) >= 200:
            break
    sim.send_signal(signal.SIGKILL)
    assert sim.wait(10) == -signal.SIGKILL
    assert all(a.poll() is None for a in agents)  # the agents wait for it
    sim2 = processes.start("sim2", sim_argv, cwd=ROOT)
    assert sim2.wait(120) == 0
    for a in agents:
        assert a.wait(30) == 0
    monitor.stdin.close()
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    _check_summary(summary, load_scenario(scenario, SETS), 200)
    assert not (tmp_path / "run" / JOURNAL).exists()
    _assert_same_as_inproc(tmp_path, tmp_path / "run", load_scenario(scenario, SETS))


