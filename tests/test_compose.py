"""The container deployment, tested without a Docker engine: the generated compose file parses, names
explicit endpoints and liveliness health checks, and its very commands run as local processes."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from coload.runs.compose import check_alive, compose_spec, write_compose
from net.zenoh_transport import free_tcp_port
from tests.conftest import ROOT

N = 3


def test_compose_file_parses_and_is_explicit(tmp_path):
    path = write_compose(tmp_path / "compose.yaml", N, "config/scenarios/quick.toml", run="c1")
    doc = yaml.safe_load(path.read_text())
    assert doc == json.loads(json.dumps(compose_spec(N, "config/scenarios/quick.toml", run="c1")))
    services = doc["services"]
    assert set(services) == {"router", "sim", *(f"agent-{i}" for i in range(N))}
    assert {s["image"] for s in services.values()} == {"coload:latest"}  # one image, every role
    for i in range(N):
        agent = services[f"agent-{i}"]
        cmd = agent["command"]
        assert cmd[:4] == ["coload", "agent", "--id", str(i)]
        assert cmd[cmd.index("--connect") + 1] == "tcp/router:7447"  # no multicast scouting needed
        assert agent["depends_on"] == {"router": {"condition": "service_healthy"}}
        assert agent["healthcheck"]["test"][-1] == f"coload/c1/alive/agent/{i}"
    assert services["sim"]["healthcheck"]["test"][-1] == "coload/c1/alive/sim/0"


def test_compose_needs_a_team(tmp_path, capsys):
    from coload.cli import main

    for bad in ("0", "1"):
        assert main(["compose", "--agents", bad, "--out", str(tmp_path / "c.yaml")]) == 2
        assert "--agents must be at least 2" in capsys.readouterr().err
    assert not (tmp_path / "c.yaml").exists()


def test_dockerfile_copies_every_package():
    """Every package pyproject.toml installs is in the image (else `pip install .` skips it quietly)."""
    import tomllib

    text = (ROOT / "docker" / "Dockerfile").read_text()
    include = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]["find"]["include"]
    packages = [p.rstrip("*") for p in include]
    assert "hinf" in packages and "coload" in packages
    for package in packages:
        assert f"COPY {package} {package}" in text


def _local(cmd: list[str], endpoint: str, runs: Path) -> list[str]:
    """A compose command as a local process: same arguments, loopback endpoint, local run dir."""
    out = [sys.executable, "-m", "coload"]
    for arg in cmd[1:]:
        arg = arg.replace("tcp/router:7447", endpoint).replace("tcp/0.0.0.0:7447", endpoint)
        arg = arg.replace("tcp/127.0.0.1:7447", endpoint)
        out.append(str(runs) + arg[len("/runs"):] if arg.startswith("/runs") else arg)
    return out


def _wait(cond, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():  # each check itself waits up to its own timeout on the router
            return True
    return False


@pytest.mark.zenoh
def test_compose_commands_run_as_local_processes(tmp_path, processes):
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    services = compose_spec(N, str(ROOT / "config" / "scenarios" / "quick.toml"), run="c2")["services"]
    extra = ["--set", "duration=2.0"]
    def start(name: str, argv: list[str]) -> subprocess.Popen:
        return processes.start(name, argv, cwd=ROOT)

    try:
        start("router", _local(services["router"]["command"], endpoint, tmp_path))
        router_health = _local(services["router"]["healthcheck"]["test"][1:], endpoint, tmp_path)
        assert _wait(lambda: subprocess.run(router_health, capture_output=True).returncode == 0, 30)
        agents = [start(f"agent-{i}", _local(services[f"agent-{i}"]["command"], endpoint, tmp_path) + extra)
                  for i in range(N)]
        key = services["agent-0"]["healthcheck"]["test"][-1]
        assert _wait(lambda: check_alive([endpoint], key, 1.0), 30), "agent 0 never became healthy"
        assert not check_alive([endpoint], "coload/c2/alive/agent/99", 0.5)
        sim = start("sim", _local(services["sim"]["command"], endpoint, tmp_path) + extra)
        assert sim.wait(120) == 0
        for a in agents:
            assert a.wait(30) == 0
        assert not check_alive([endpoint], key, 0.5)  # gone with its daemon
    finally:
        processes.kill_all()
    summary = json.loads((tmp_path / "c2" / "summary.json").read_text())
    assert summary["agents_reported"] == list(range(N))
    assert summary["n"] == N
