"""A ``coload run`` stopped from outside leaves nothing behind: SIGTERM is handled like Ctrl-C (the
router, the simulator and the agents are stopped, "terminated" is said, exit status 143), and even a SIGKILLed
supervisor takes its daemons with it (they ask the kernel for a parent-death signal)."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

from tests.conftest import coload_cmd

pytestmark = pytest.mark.zenoh

N = 5  # quick.toml: a router, the simulator and 5 agents


def _children(pid: int) -> set[int]:
    kids: set[int] = set()
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            kids |= {int(k) for k in (task / "children").read_text().split()}
        except OSError:
            pass
    return kids


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"  # a zombie has exited; only its parent's wait is missing


def _wait(cond, timeout: float, what: str):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = cond()
        if value:
            return value
        time.sleep(0.05)  # polling a condition with a deadline, not a sleep as synchronisation
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


@pytest.fixture
def started_run(tmp_path):
    if not Path(f"/proc/{os.getpid()}/task/{os.getpid()}/children").exists():
        pytest.skip("needs /proc/PID/task/TID/children")
    proc = subprocess.Popen(
        coload_cmd("run", "quick", "--engine", "zenoh", "--out", str(tmp_path / "run"), "--no-report",
                   "--no-batch-fit", "--set", "duration=600"),
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True,
    )
    def all_started() -> set[int] | None:
        kids = _children(proc.pid)
        return kids if len(kids) == N + 2 else None

    kids = _wait(all_started, 60, "router, sim and agents")
    # the run is under way once the simulator has recorded ticks
    _wait(lambda: (tmp_path / "run" / "logs" / "sim.log").exists(), 60, "the simulator's log")
    yield proc, kids
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    for k in kids:
        try:
            os.kill(k, signal.SIGKILL)
        except ProcessLookupError:
            pass
    proc.wait()


def test_sigterm_stops_every_daemon_and_says_so(started_run):
    proc, kids = started_run
    proc.send_signal(signal.SIGTERM)  # the supervisor only, as `kill PID` does
    code = proc.wait(timeout=30)
    err = proc.stderr.read()
    assert code == 143, err
    assert "terminated (SIGTERM)" in err
    left = {k: _describe(k) for k in kids if _alive(k)}
    assert left == {}


def _describe(pid: int) -> str:
    try:
        cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()[-120:]
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[:2]
        return f"{cmd} state {state}"
    except OSError:
        return "gone"


def test_a_sigkilled_supervisor_takes_its_daemons_with_it(started_run):
    proc, kids = started_run
    proc.kill()
    proc.wait(timeout=10)
    _wait(lambda: not any(_alive(k) for k in kids), 30, "the daemons to exit after their parent died")
