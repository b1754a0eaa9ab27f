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
    # every daemon is forked; the SIGTERM may land anywhere in start-up or the run, both must be clean
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


def test_an_interrupted_run_keeps_its_tables_and_says_where_it_stopped(tmp_path, capsys):
    """Ctrl-C at tick 250 of an in-process run: every tick up to there is on disk and readable, no
    summary.json (nothing mistakes it for a finished run), interrupted.json says where and why; a
    new run in the same directory removes that marker."""
    import json

    from coload.cli import main as cli_main
    from coload.rundir import format as rf
    from coload.runs.engine import run_inproc
    from config.loader import load_scenario

    scenario = load_scenario("quick", ["duration=20"])
    out = tmp_path / "run"

    def progress(done: int, total: int) -> None:
        if done > 250:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_inproc(scenario, out, progress=progress)
    stopped = json.loads((out / rf.INTERRUPTED_JSON).read_text())
    assert stopped["reason"] == "KeyboardInterrupt" and 250 < stopped["tick"] <= 300
    assert not (out / rf.SUMMARY_JSON).exists()
    run = rf.read_run(out)
    assert len(run.samples.t) == stopped["tick"]  # every tick before the stop, samples at full rate
    assert run.truth.t[-1] == pytest.approx((stopped["tick"] - 1) // 10 * 10 * scenario.dt)  # every 10 ticks
    assert cli_main(["report", str(out)]) == 0
    assert f"stopped at t = {stopped['t']} s of 20.0 s (KeyboardInterrupt)" in capsys.readouterr().err
    run_inproc(load_scenario("quick", ["duration=1"]), out)
    assert (out / rf.SUMMARY_JSON).exists() and not (out / rf.INTERRUPTED_JSON).exists()
