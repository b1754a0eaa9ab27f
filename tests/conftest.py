"""Shared fixtures: scenario files and run-directory comparison; the hypothesis profiles."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import settings

# CI: the same examples on every run (derandomized, a fixed budget), so a property failure seen once
# comes back every time until it is fixed, and no run fails by the luck of its draw. Locally the
# default profile keeps exploring new examples. A test's own @settings(max_examples=...) still applies.
settings.register_profile("ci", derandomize=True, max_examples=100, deadline=None, print_blob=True)
if os.environ.get("CI", "").lower() == "true":
    settings.load_profile("ci")

ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = ROOT / "config" / "scenarios"


def pytest_configure(config: pytest.Config) -> None:
    """The compiled core is compiled once, in the controller (or the only process), before the xdist
    workers and the tests' daemons start: they load its cache instead of compiling it each."""
    if not hasattr(config, "workerinput"):
        from agents.kernels import warm

        warm()


@pytest.fixture
def scenarios_dir() -> Path:
    return SCENARIOS


def sorted_table(path: Path, keys: int) -> tuple[list[str], np.ndarray]:
    """A CSV of floats with its rows sorted by the first ``keys`` columns (arrival order differs by engine)."""
    header = path.read_text().splitlines()[0].split(",")
    data = np.genfromtxt(path, delimiter=",", skip_header=1, ndmin=2)  # an empty cell (no value) is NaN
    order = np.lexsort([data[:, c] for c in reversed(range(keys))])
    return header, data[order]


def max_table_difference(dir_a: Path, dir_b: Path, name: str, keys: int) -> float:
    ha, a = sorted_table(dir_a / name, keys)
    hb, b = sorted_table(dir_b / name, keys)
    assert ha == hb, f"{name}: headers differ"
    assert a.shape == b.shape, f"{name}: {a.shape} rows vs {b.shape}"
    both_nan = np.isnan(a) & np.isnan(b)
    diff = np.where(both_nan, 0.0, np.abs(a - b))
    return float(np.nanmax(np.where(np.isnan(diff), np.inf, diff))) if diff.size else 0.0


@pytest.fixture(autouse=True)
def _global_rng_untouched():
    """Every RNG must be a Generator derived from a run seed: nothing may draw from numpy's global one."""
    before = np.random.get_state()
    yield
    after = np.random.get_state()
    assert before[2] == after[2] and np.array_equal(before[1], after[1]), "numpy's global RNG was used"


def coload_cmd(*args: str) -> list[str]:
    """``coload ARGS`` with this interpreter (works without the console script on PATH)."""
    return [sys.executable, "-m", "coload", *args]


CONTROL_MONITOR = """
import sys, zenoh
sys.path.insert(0, {root!r})
from net import keys
from net.messages import Control
from net.schema import decode
from net.zenoh_transport import zenoh_config
def on(sample):
    m = decode(sample.payload.to_bytes(), Control)
    print(m.kind, m.tick, flush=True)
with zenoh.open(zenoh_config(mode="client", connect=[{endpoint!r}])) as s:
    s.declare_subscriber(keys.sim_control({run!r}), on)
    print("ready", flush=True)
    sys.stdin.read()
"""


def control_monitor_cmd(endpoint: str, run: str) -> list[str]:
    """A client that prints the simulator's control notices (``kind tick``), one per line, after ``ready``;
    it runs until its stdin closes."""
    return [sys.executable, "-c", CONTROL_MONITOR.format(root=str(ROOT), endpoint=endpoint, run=run)]


class Processes:
    """Real OS processes of one test, each logging to ``log_dir/NAME.log``; all killed at teardown."""

    def __init__(self, log_dir: Path) -> None:
        self.log_dir = log_dir
        self.procs: list[subprocess.Popen] = []
        self._logs: list = []

    def start(self, name: str, argv: list[str], **kw) -> subprocess.Popen:
        log = (self.log_dir / f"{name}.log").open("w")
        self._logs.append(log)
        kw.setdefault("stdout", log)
        kw.setdefault("stdin", subprocess.DEVNULL)
        p = subprocess.Popen(argv, stderr=log, **kw)
        self.procs.append(p)
        return p

    def kill_all(self) -> None:
        for p in self.procs:
            if p.poll() is None:
                p.kill()
            p.wait()
        for f in self._logs:
            f.close()


@pytest.fixture
def processes(tmp_path):
    procs = Processes(tmp_path)
    try:
        yield procs
    finally:
        procs.kill_all()
