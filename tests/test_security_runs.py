"""Secure runs beyond `coload run --secure`'s own tables (tests/test_security_attacks.py): the live
view joins a secure run with the monitor's certificate (read-only), and the paper-003 runtime runs
under the same kind of team (its ``hinf/`` keys in the policy). See docs/security.md."""

from __future__ import annotations

import csv
import json
import subprocess

import numpy as np
import pytest

from coload.certificates import certificate_info
from coload.runs.hinf_run import load_trace, run_processes
from hinf import load_spec, run_design
from hinf import runtime as R
from hinf.report import load_run_dir, prepare_run_dir
from net.zenoh_transport import free_tcp_port
from tests.conftest import ROOT, coload_cmd

pytestmark = [pytest.mark.zenoh, pytest.mark.slow]

HINF_EXAMPLE = ROOT / "config" / "hinf" / "sec5-cyclic.toml"


def test_run_view_streams_a_secure_run(tmp_path):
    """`coload run --secure --view PORT`: the watcher holds the monitor's certificate and still gets
    every pose notice and every estimate (the policy lets the monitor hear them and nothing else)."""
    pytest.importorskip("foxglove", reason="the viz extra (foxglove-sdk) is not installed")
    port = free_tcp_port()
    out = tmp_path / "run"
    done = subprocess.run(coload_cmd("run", "quick", "--secure", "--set", "duration=3", "--view", str(port), "--out",
                                     str(out), "--no-report", "--no-batch-fit", "--quiet"),
                          capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stderr
    assert "router tls/127.0.0.1:" in done.stderr
    with (out / "estimates.csv").open(newline="") as f:
        n_est = len(list(csv.DictReader(f)))
    assert f"coload run: live view sent 30 poses and {n_est} estimates" in done.stderr, done.stderr


@pytest.mark.filterwarnings("ignore:Solution may be inaccurate")
def test_secure_hinf_run_equals_in_process(tmp_path):
    """Router, simulator and four estimators as processes over mutual TLS under the default-deny policy
    (each estimator hears only the states of its in-neighbours in the spec's graph): the run finishes
    with nothing dropped and equals the in-process engine bit for bit."""
    pytest.importorskip("cvxpy", reason="the hinf extra (cvxpy) is not installed")
    spec = load_spec(HINF_EXAMPLE, ["run.duration=6"])
    prepare_run_dir(tmp_path / "z", spec, json.loads(json.dumps(run_design(spec))))
    su = load_run_dir(tmp_path / "z")
    assert run_processes(su, tmp_path / "z", quiet=True, secure=True)
    assert certificate_info(tmp_path / "z" / "keys" / "router.pem")["cn"] == "router.g1"
    team = json.loads((tmp_path / "z" / "keys" / "team.json").read_text())
    assert team["neighbours"] == [sorted(su.nbrs(k)) for k in range(su.N)]
    s = json.loads((tmp_path / "z" / "summary.json").read_text())
    assert s["inputs_missing"] == 0
    assert s["messages"]["timeouts"] == {"input": 0, "neighbour": 0} and s["messages"]["drops"] == {}
    ref, _ = R.run_inproc(su)
    got = load_trace(tmp_path / "z")
    for k, v in ref.arrays().items():
        assert np.array_equal(v, got.arrays()[k], equal_nan=True), f"{k} differs"
