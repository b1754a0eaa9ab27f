"""Daemons on separate test hosts (network namespaces joined by veth pairs): a run across hosts
reproduces the in-process engine, and a real link cut is survived. Skipped where namespaces are not
permitted."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from coload.engine import run_inproc
from config.loader import load_scenario
from netns import Hosts, netns_available
from tests.conftest import ROOT, SCENARIOS, max_table_difference

REASON = netns_available()
pytestmark = [pytest.mark.zenoh, pytest.mark.skipif(REASON is not None, reason=REASON or "")]

PORT = 7447  # each namespace has its own port space


def _coload(*args: str) -> list[str]:
    return [sys.executable, "-m", "coload", *args]


def test_run_across_test_hosts_equals_inproc(tmp_path):
    """Router and simulator on the hub, agents spread over two leaf hosts, all over veth links."""
    scenario = tmp_path / "s.toml"
    scenario.write_text((SCENARIOS / "quick.toml").read_text())
    sets = ["--set", "duration=2.0", "--set", "record.every_ticks=1"]
    procs: list[subprocess.Popen] = []
    with Hosts(leaves=2) as hosts:
        def start(name: str, ns: str, argv: list[str], **kw) -> subprocess.Popen:
            log = (tmp_path / f"{name}.log").open("w")
            kw.setdefault("stdout", log)
            p = subprocess.Popen(hosts.argv(ns, argv), stderr=log, stdin=subprocess.DEVNULL, cwd=ROOT, **kw)
            procs.append(p)
            return p

        try:
            listen = [f"tcp/{hosts.hub_addr(k)}:{PORT}" for k in range(2)] + [f"tcp/127.0.0.1:{PORT}"]
            router = start("router", hosts.hub, _coload("router", *sum((["--listen", e] for e in listen), [])),
                           stdout=subprocess.PIPE)
            assert router.stdout.readline().decode().startswith("ready")
            agents = []
            for i in range(5):
                leaf = i % 2
                common = [str(scenario), *sets, "--connect", f"tcp/{hosts.hub_addr(leaf)}:{PORT}", "--run", "ns"]
                agents.append(start(f"agent{i}", hosts.leaf(leaf), _coload("agent", "--id", str(i), *common)))
            sim = start("sim", hosts.hub, _coload("sim", str(scenario), *sets, "--connect",
                                                 f"tcp/127.0.0.1:{PORT}", "--run", "ns", "--out", str(tmp_path / "run")))
            assert sim.wait(120) == 0
            for a in agents:
                assert a.wait(30) == 0
        finally:
            for p in procs:
                if p.poll() is None:
                    p.kill()
                p.wait()
    sc = load_scenario(scenario, ["duration=2.0", "record.every_ticks=1"])
    run_inproc(sc, tmp_path / "inproc")
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["agents_reported"] == [0, 1, 2, 3, 4]
    for name, nkeys in (("estimates.csv", 2), ("pairs.csv", 3), ("samples.csv", 2)):
        assert max_table_difference(tmp_path / "run", tmp_path / "inproc", name, nkeys) <= 1e-9, name
