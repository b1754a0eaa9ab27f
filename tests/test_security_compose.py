"""The secure compose deployment, without a Docker engine: ``coload compose`` makes the team's keys,
the file names TLS endpoints and mounts into each service only the CA, ``team.json``, the service's
own key and the monitor's (for its health check); the very commands then run as local processes,
each seeing only what its mounts give it, and the health checks and the run work."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from coload.cli import main
from net.zenoh_transport import free_tcp_port
from tests.conftest import ROOT

N = 3
SCENARIO = str(ROOT / "config" / "scenarios" / "quick.toml")


def _wait(cond, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():  # each check itself waits on the router
            return True
    return False


def _mount(service: dict, base: Path, into: Path) -> Path:
    """The service's /keys as it would see it: only the files its compose volumes mount."""
    into.mkdir(parents=True)
    for vol in service.get("volumes", []):
        src, dst, *_ = vol.split(":")
        if dst.startswith("/keys/"):
            shutil.copy(base / src, into / Path(dst).name)
    return into


def _local(cmd: list[str], endpoint: str, runs: Path, keys: Path) -> list[str]:
    out = [sys.executable, "-m", "coload"]
    for arg in cmd[1:]:
        for far in ("tls/router:7447", "tls/0.0.0.0:7447", "tls/127.0.0.1:7447"):
            arg = arg.replace(far, endpoint)
        arg = str(keys) if arg == "/keys" else arg
        out.append(str(runs) + arg[len("/runs"):] if arg.startswith("/runs") else arg)
    return out


def test_secure_compose_file_names_tls_and_mounts_per_service_keys(tmp_path, capsys):
    path = tmp_path / "compose.yaml"
    assert main(["compose", "--agents", str(N), "--scenario", SCENARIO, "--run", "c3", "--out", str(path)]) == 0
    services = yaml.safe_load(path.read_text())["services"]
    assert "tls/router:7447" in services["agent-0"]["command"]
    assert not any(a.startswith("tcp/") for s in services.values() for a in s["command"])
    assert services["agent-1"]["volumes"] == [f"./keys/{f}:/keys/{f}:ro" for f in
                                              ("ca.pem", "team.json", "agent-1.pem", "agent-1.key", "monitor.pem",
                                               "monitor.key")]
    assert not any("ca.key" in v for s in services.values() for v in s.get("volumes", []))
    assert services["sim"]["healthcheck"]["test"][3:5] == ["--tls-dir", "/keys"]
    # again: the keys are kept; another team's size is refused with one line
    assert main(["compose", "--agents", str(N), "--scenario", SCENARIO, "--run", "c3", "--out", str(path)]) == 0
    capsys.readouterr()
    assert main(["compose", "--agents", "4", "--scenario", SCENARIO, "--run", "c3", "--out", str(path)]) == 2
    assert "holds the keys of another team" in capsys.readouterr().err


@pytest.mark.zenoh
def test_secure_compose_commands_run_as_local_processes(tmp_path, processes):
    path = tmp_path / "compose.yaml"
    assert main(["compose", "--agents", str(N), "--scenario", SCENARIO, "--run", "c3", "--out", str(path)]) == 0
    services = yaml.safe_load(path.read_text())["services"]
    endpoint = f"tls/127.0.0.1:{free_tcp_port()}"
    keys = {name: _mount(s, tmp_path, tmp_path / "mounts" / name) for name, s in services.items()}
    extra = ["--set", "duration=2.0"]

    def cmd(name: str, which: list[str]) -> list[str]:
        return _local(which, endpoint, tmp_path, keys[name])

    def healthy(name: str, timeout: float = 30) -> bool:
        test = cmd(name, services[name]["healthcheck"]["test"][1:])
        return _wait(lambda: subprocess.run(test, capture_output=True, cwd=ROOT).returncode == 0, timeout)

    try:
        processes.start("router", cmd("router", services["router"]["command"]), cwd=ROOT)
        assert healthy("router")
        agents = [processes.start(f"agent-{i}", cmd(f"agent-{i}", services[f"agent-{i}"]["command"]) + extra, cwd=ROOT)
                  for i in range(N)]
        assert healthy("agent-0"), "agent 0 never became healthy"
        sim = processes.start("sim", cmd("sim", services["sim"]["command"]) + extra, cwd=ROOT)
        assert sim.wait(120) == 0
        for a in agents:
            assert a.wait(30) == 0
        assert not healthy("agent-0", 1.0)  # gone with its daemon
    finally:
        processes.kill_all()
    summary = json.loads((tmp_path / "c3" / "summary.json").read_text())
    assert summary["agents_reported"] == list(range(N))
    assert summary["timeouts"] == {"wrench": 0, "neighbour": 0}
