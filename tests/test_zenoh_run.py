"""Real Zenoh, real processes, loopback only.

* A lockstep run over Zenoh (router, simulator and agents as separate OS processes) reproduces the
  in-process engine to the last bit, with link faults on.
* Daemons started by hand through the per-agent CLI keep running when garbage is published on every
  key they listen to; every bad message is dropped and counted by reason in summary.json.
"""

from __future__ import annotations

import json
import subprocess
import threading

import pytest
import zenoh

from coload.runs.engine import run_inproc
from coload.runs.orchestrate import run_processes
from config.loader import load_scenario
from net import keys
from net.messages import Control
from net.schema import DecodeError, decode
from net.zenoh_transport import free_tcp_port, zenoh_config
from tests.conftest import SCENARIOS, Processes, coload_cmd, max_table_difference

pytestmark = pytest.mark.zenoh

FAULTS = ["link.delay_ticks=1", "link.jitter_ticks=2", 'link.loss.model="bernoulli"', "link.loss.p=0.15",
          "link.duplicate=0.05"]


def test_lockstep_over_zenoh_equals_inproc(tmp_path):
    sc = load_scenario(SCENARIOS / "quick.toml", ["duration=2.0", *FAULTS])
    zen = run_processes(sc, tmp_path / "zenoh", quiet=True)
    assert zen is not None, (tmp_path / "zenoh" / "logs").iterdir()
    run_inproc(sc, tmp_path / "inproc")
    assert zen["engine"] == "zenoh"
    assert zen["agents_reported"] == list(range(sc.n))
    assert zen["timeouts"] == {"wrench": 0, "neighbour": 0}
    for name, nkeys in (("samples.csv", 2), ("estimates.csv", 2), ("pairs.csv", 3), ("truth.csv", 1)):
        assert max_table_difference(tmp_path / "zenoh", tmp_path / "inproc", name, nkeys) <= 1e-9, name
    inproc_links = json.loads((tmp_path / "inproc" / "summary.json").read_text())["links"]
    assert zen["links"] == inproc_links


GARBAGE = [b"", b"\xc1", b"not msgpack at all", b"\x93\xa4meas\x01\x80", b"\x00" * 70_000,
           b"\x93\xa5state\x01\x87\xa4tick\xcb\x7f\xf8\x00\x00\x00\x00\x00\x00"]


def test_hand_started_daemons_drop_and_count_garbage(tmp_path):
    sc_path = tmp_path / "scenario.toml"
    sc_path.write_text((SCENARIOS / "quick.toml").read_text())
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    run, out = "garbage-test", tmp_path / "run"
    common = [str(sc_path), "--set", "duration=4.0", "--connect", endpoint, "--run", run]
    procs = Processes(tmp_path)
    try:
        router = procs.start("router", coload_cmd("router", "--listen", endpoint), stdout=subprocess.PIPE)
        ready = router.stdout.readline().decode()
        assert ready.startswith("ready"), ready
        started, done = threading.Event(), threading.Event()

        def on_control(sample) -> None:
            try:
                msg = decode(sample.payload.to_bytes(), Control)
            except DecodeError:
                return
            (started if msg.kind in ("start", "progress") else done).set()

        with zenoh.open(zenoh_config(mode="client", connect=[endpoint])) as session:
            session.declare_subscriber(keys.sim_control(run), on_control)
            sim = procs.start("sim", coload_cmd("sim", *common, "--out", str(out)))
            agents = [procs.start(f"agent{i}", coload_cmd("agent", "--id", str(i), *common)) for i in range(5)]
            assert started.wait(60), "the run never started"
            targets = [keys.meas(run, 0), keys.state(run, 1), keys.wrench(run, 2), keys.estimate(run, 3),
                       keys.sim_control(run)]
            for key in targets:
                for payload in GARBAGE:
                    session.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)
            assert sim.wait(120) == 0
        for a in agents:
            assert a.wait(30) == 0
    finally:
        procs.kill_all()

    summary = json.loads((out / "summary.json").read_text())
    assert summary["agents_reported"] == [0, 1, 2, 3, 4]
    drops = summary["drops"]
    # meas -> agent 0; state of 1 -> agents 0 and 2; wrench and estimate -> the simulator; control -> 5 agents
    expected = len(GARBAGE) * (1 + 2 + 1 + 1 + 5)
    assert sum(drops.values()) >= expected, drops
    assert set(drops) <= {"oversized", "not_msgpack", "bad_envelope", "bad_version", "wrong_kind", "bad_schema",
                          "non_finite", "out_of_range"}, drops
    assert summary["timeouts"]["wrench"] == 0
    samples = (out / "samples.csv").read_text().splitlines()
    assert len(samples) == 1 + 5 * 400  # every tick of every agent recorded
    assert all(v is not None for v in summary["errors"]["zi_err_per_agent"])
