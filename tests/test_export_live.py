"""The live view: the simulator's pose notices and the agents' estimates, over real Zenoh processes,
become the same messages as the MCAP export (checked against the run's CSVs)."""

from __future__ import annotations

import asyncio
import csv
import math
import re
import subprocess
import time

import pytest

from conftest import coload_cmd
from config.loader import load_scenario
from net.zenoh_transport import ZenohTransport, free_tcp_port, zenoh_config

pytest.importorskip("foxglove", reason="the viz extra (foxglove-sdk) is not installed")

from coload.viz.live import LiveScene, watch  # noqa: E402
from coload.viz.scene import outline_body  # noqa: E402

pytestmark = pytest.mark.zenoh


def _rows(path):
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def test_a_live_watcher_sees_every_recorded_pose_and_estimate(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    out = tmp_path / "run"
    run = subprocess.Popen(coload_cmd("run", "quick", "--set", "duration=3", "--listen", endpoint, "--out", str(out),
                                      "--no-report", "--no-batch-fit", "--quiet"),
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        line = ""
        while time.monotonic() < deadline and "router" not in line:
            line = run.stderr.readline()
        name = re.search(r"keys coload/([^/]+)/\*\*", line).group(1)
        sc = load_scenario("quick")
        scene = LiveScene(sc.n, sc.dt, outline_body(sc))
        got: list = []

        async def go():
            transport = ZenohTransport(zenoh_config(mode="client", connect=[endpoint]))
            try:
                stop = asyncio.Event()
                return await asyncio.wait_for(watch(transport, name, scene, got.extend, stop), 120)
            finally:
                transport.close()

        counts = asyncio.run(go())
        assert run.wait(timeout=120) == 0
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    truth = _rows(out / "truth.csv")
    assert counts["pose"] == len(truth) == 30 and counts["dropped"] == 0
    assert counts["estimate"] == len(_rows(out / "estimates.csv"))
    poses = [m for m in got if m.topic == "/load/pose"]
    row, (_, _, msg) = truth[12], poses[12]
    assert msg["pose"]["position"] == {"x": float(row["x"]), "y": float(row["y"]), "z": 0.0}
    q = msg["pose"]["orientation"]
    assert math.isclose(math.remainder(2 * math.atan2(q["z"], q["w"]) - float(row["angle"]), 2 * math.pi), 0.0,
                        abs_tol=1e-12)


def test_run_view_streams_the_whole_run(tmp_path):
    """`coload run --view PORT`: the Foxglove server is up before the run and got every pose notice."""
    port = free_tcp_port()
    out = tmp_path / "run"
    done = subprocess.run(coload_cmd("run", "quick", "--set", "duration=3", "--view", str(port), "--out", str(out),
                                     "--no-report", "--no-batch-fit", "--quiet"),
                          capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stderr
    assert f"coload run: live view on ws://127.0.0.1:{port}" in done.stderr
    n_est = len(_rows(out / "estimates.csv"))
    assert f"coload run: live view sent 30 poses and {n_est} estimates" in done.stderr


def test_view_is_for_the_zenoh_engine(tmp_path):
    done = subprocess.run(coload_cmd("run", "quick", "--engine", "inproc", "--view", "--out", str(tmp_path / "r")),
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert done.stderr == ("coload run: --view is for --engine zenoh (the live view listens on the run's "
                           "router)\n")
    assert not (tmp_path / "r").exists()
