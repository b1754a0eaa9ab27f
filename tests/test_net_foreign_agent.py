"""Agents written from docs/wire.md alone, in the test (plain zenoh + msgpack), against a real
`coload sim` process on loopback: what such a program plausibly gets wrong is said in the simulator's
log, not only counted or silently left out.

* a wrench with an extra field: dropped, counted (`bad_schema`) and said once with the decoder's detail;
  the same tick's wrench without it is then taken (no wrench timeout);
* estimate values under names estimates.csv has no column for: the rest is recorded, and the names
  left out are said once (before: left out without a word).
"""

from __future__ import annotations

import json
import subprocess
import threading

import msgpack
import pytest
import zenoh

from net.zenoh_transport import free_tcp_port, zenoh_config
from tests.conftest import Processes, coload_cmd

pytestmark = pytest.mark.zenoh


def test_a_foreign_agents_mistakes_are_said_in_the_simulators_log(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    run = f"fagent{free_tcp_port()}"
    out = tmp_path / "run"
    procs = Processes(tmp_path)
    reported = threading.Event()

    def put(session, key: str, kind: str, body: dict) -> None:
        session.put(key, msgpack.packb([kind, 1, body]), congestion_control=zenoh.CongestionControl.BLOCK)

    try:
        router = procs.start("router", coload_cmd("router", "--listen", endpoint), stdout=subprocess.PIPE)
        assert router.stdout.readline().decode().startswith("ready")
        with zenoh.open(zenoh_config(mode="client", connect=[endpoint])) as session:

            def on_meas(sample) -> None:
                _, _, b = msgpack.unpackb(sample.payload.to_bytes(), strict_map_key=False)
                i, k = b["agent"], b["tick"]
                wrench = {"tick": k, "agent": i, "fx": 1.0, "fy": 0.0, "tau": 0.0}
                if i == 1 and k == 0:  # a sequence number of its own: refused, then sent right
                    put(session, f"coload/{run}/agent/1/wrench", "wrench", {**wrench, "seq": 0})
                put(session, f"coload/{run}/agent/{i}/wrench", "wrench", wrench)
                if k % 10 == 0:
                    values = {"phase": 1.0, "omega": 0.25, "zi_x": 0.0, "zi_y": 0.0, "my_quality": 0.5}
                    put(session, f"coload/{run}/agent/{i}/estimate", "estimate",
                        {"tick": k, "agent": i, "values": values, "pairs": {}})

            def on_control(sample) -> None:
                _, _, b = msgpack.unpackb(sample.payload.to_bytes(), strict_map_key=False)
                if b["kind"] == "done":
                    for i in range(2):
                        put(session, f"coload/{run}/agent/{i}/report", "report",
                            {"agent": i, "links": {}, "drops": {}, "timeouts": 0, "ticks": b["tick"]})
                    reported.set()

            subs = [session.declare_subscriber(f"coload/{run}/agent/{i}/meas", on_meas) for i in range(2)]
            subs.append(session.declare_subscriber(f"coload/{run}/sim/control", on_control))
            tokens = [session.liveliness().declare_token(f"coload/{run}/alive/agent/{i}") for i in range(2)]
            sim = procs.start("sim", coload_cmd("sim", "quick", "--set", "n=2", "--set", "duration=0.5",
                                                "--set", "timing.wrench_timeout_s=30.0",
                                                "--connect", endpoint, "--run", run, "--out", str(out)))
            assert sim.wait(120) == 0
            assert reported.is_set()
            del subs, tokens
    finally:
        procs.kill_all()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["drops"] == {"bad_schema": 1}
    assert summary["timeouts"]["wrench"] == 0
    assert summary["agents_reported"] == [0, 1]
    log = (tmp_path / "sim.log").read_text()
    assert (f"simulator: dropped a wrench on coload/{run}/agent/1/wrench: bad_schema: 1 error(s); "
            "first at ('seq',): Extra inputs are not permitted") in log
    assert log.count("estimates.csv has no column for: my_quality") == 1
    rows = (out / "estimates.csv").read_text().splitlines()
    header = rows[0].split(",")
    assert "my_quality" not in header and len(rows) == 1 + 2 * 5  # ticks 0, 10, .., 40 of both agents
    assert rows[1].split(",")[header.index("omega")] == "0.25"
