"""docs/wire.md is what a client of a run needs: its monitor example (plain zenoh + msgpack, no
coload import) is run as written against a real multi-process run, on the endpoint chosen with
``coload run --listen``, and sees every agent's estimates."""

from __future__ import annotations

import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

from net.zenoh_transport import free_tcp_port
from tests.conftest import coload_cmd

pytestmark = pytest.mark.zenoh

ROOT = Path(__file__).resolve().parents[1]


def _example() -> str:
    text = (ROOT / "docs" / "wire.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert len(blocks) == 1
    return blocks[0]


def test_the_documented_monitor_sees_every_agent(tmp_path):
    watch = tmp_path / "watch.py"
    watch.write_text(_example(), encoding="utf-8")
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    run = subprocess.Popen(
        coload_cmd("run", "quick", "--engine", "zenoh", "--listen", endpoint, "--out", str(tmp_path / "run"),
                   "--no-report", "--no-batch-fit", "--quiet"),
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True,
    )
    try:
        # the announced line, then the monitor (the router listens before it is printed)
        deadline = time.monotonic() + 60
        line = ""
        while time.monotonic() < deadline and "router" not in line:
            line = run.stderr.readline()
        assert f"coload run: router {endpoint}, keys coload/" in line
        out = subprocess.run([sys.executable, str(watch), endpoint, "60"], capture_output=True, text=True,
                             timeout=180, cwd=tmp_path)
        assert out.returncode == 0, out.stderr
        agents = {int(m) for m in re.findall(r"/agent/(\d+)/estimate t=", out.stdout)}
        assert agents == set(range(5))
        assert len(out.stdout.splitlines()) >= 60
        assert run.wait(timeout=120) == 0
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
