"""A simulator written from docs/wire.md alone, in the test (plain zenoh + msgpack), against real
`coload agent` processes on loopback.

* tests/wire_plant.py, a plant with its own integrator and its own load (not the scenario's), runs a
  secure team of five agents (`coload keys init`, the simulator's `sim.json5`) through Algorithm 1:
  the agents' J, m, z_i, z_C against the plant's own truth.

What such a program plausibly gets wrong must be said, not silently dropped or waited out:

* a measurement with an extra field, a tick sent as 5.0, a control notice whose `ticks` is not the
  agent's scenario's: each dropped and counted (the report's `drops`), and the first one of each kind
  and reason said in the agent's log with the decoder's detail (before: counted only, so an agent fed
  nothing but such messages sat idle without a word);
* a simulator without the liveliness token `alive/sim/0` that stops without `done`: the agent gives up
  after `timing.sim_lost_timeout_s` without a measurement, reports and exits 1 (before: it waited for
  ever, silently).
"""

from __future__ import annotations

import subprocess
import threading
import time
from contextlib import contextmanager
from pathlib import Path

import msgpack
import pytest
import zenoh

from net.zenoh_transport import free_tcp_port, zenoh_config
from tests.conftest import Processes, coload_cmd
from tests.wire_plant import run_plant

pytestmark = pytest.mark.zenoh

TICKS = 400  # quick with duration 4 s


def _put(session, key: str, kind: str, body: dict) -> None:
    session.put(key, msgpack.packb([kind, 1, body]), congestion_control=zenoh.CongestionControl.BLOCK)


def _wait_for(cond, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.05)


class Plant:
    """The test's foreign simulator: hears agent 0's token, wrenches and report."""

    def __init__(self, session, run: str) -> None:
        self.run = run
        self.cv = threading.Condition()
        self.agent_up = False
        self.wrench_ticks: list[int] = []
        self.report: dict | None = None
        self._subs = [
            session.declare_subscriber(f"coload/{run}/agent/0/wrench", self._on_wrench),
            session.declare_subscriber(f"coload/{run}/agent/0/report", self._on_report),
            session.liveliness().declare_subscriber(f"coload/{run}/alive/agent/0", self._on_alive, history=True),
        ]

    def _on_wrench(self, s) -> None:
        _, _, body = msgpack.unpackb(s.payload.to_bytes(), strict_map_key=False)
        with self.cv:
            self.wrench_ticks.append(body["tick"])
            self.cv.notify_all()

    def _on_report(self, s) -> None:
        _, _, body = msgpack.unpackb(s.payload.to_bytes(), strict_map_key=False)
        with self.cv:
            self.report = body
            self.cv.notify_all()

    def _on_alive(self, s) -> None:
        with self.cv:
            self.agent_up = s.kind == zenoh.SampleKind.PUT
            self.cv.notify_all()

    def wait(self, cond, timeout: float, what: str) -> None:
        with self.cv:
            assert self.cv.wait_for(cond, timeout), f"timed out waiting for {what}"


def _team(tmp_path: Path, *sets: str):
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    run = f"foreign{free_tcp_port()}"
    procs = Processes(tmp_path)
    router = procs.start("router", coload_cmd("router", "--listen", endpoint), stdout=subprocess.PIPE)
    assert router.stdout.readline().decode().startswith("ready")
    args = ["quick", "--connect", endpoint, "--run", run, "--set", "duration=4.0",
            "--set", "timing.neighbour_timeout_s=0.2"]
    for s in sets:
        args += ["--set", s]
    agent = procs.start("agent0", coload_cmd("agent", "--id", "0", *args))
    return procs, endpoint, run, agent


@contextmanager
def _foreign_sim(endpoint: str, run: str, *, token: bool):
    """A plain zenoh session playing the simulator (with its liveliness token or without), once agent 0 is up."""
    with zenoh.open(zenoh_config(mode="client", connect=[endpoint])) as session:
        plant = Plant(session, run)
        alive = session.liveliness().declare_token(f"coload/{run}/alive/sim/0") if token else None
        plant.wait(lambda: plant.agent_up, 60, "agent 0's token")
        yield session, plant
        if alive is not None:
            alive.undeclare()


def test_a_foreign_plant_runs_a_secure_team_and_its_load_is_learnt(tmp_path):
    endpoint = f"tls/127.0.0.1:{free_tcp_port()}"
    run, team, n = "foreign-plant", tmp_path / "team", 5
    procs = Processes(tmp_path)
    try:
        subprocess.run(coload_cmd("keys", "init", str(team), "--agents", str(n), "--scenario", "quick-dynamics",
                                  "--run", run, "--endpoint", endpoint), check=True, capture_output=True)
        router = procs.start("router", coload_cmd("router", "--tls-dir", str(team)), stdout=subprocess.PIPE)
        assert router.stdout.readline().decode().startswith("ready")
        agents = [procs.start(f"agent{i}", coload_cmd("agent", "--id", str(i), "quick-dynamics", "--tls-dir",
                                                      str(team), "--run", run)) for i in range(n)]
        res = run_plant(zenoh.Config.from_file(str(team / "sim.json5")), run, n, 3400)  # 34 s, the scenario's
        for a in agents:
            assert a.wait(30) == 0
    finally:
        procs.kill_all()
    assert res["wrench_timeouts"] == 0
    assert sorted(res["reports"]) == list(range(n))
    for rep in res["reports"].values():
        assert rep["drops"] == {} and rep["timeouts"] == 0 and rep["ticks"] == 3400
    est = res["estimates"]
    assert sorted(est) == list(range(n))
    for e in est.values():  # measured: J +0.49 %, m -0.29 %, z_i 6-22 mm, z_C 3-11 mm, omega 1 mrad/s
        assert e["tick"] == 3390 and e["phase"] == 6.0
        assert abs(e["J_rel"]) < 0.02 and abs(e["m_rel"]) < 0.01
        assert e["zi_err"] < 0.05 and e["zc_err"] < 0.03 and abs(e["omega_err"]) < 0.01


def test_malformed_input_from_a_foreign_simulator_is_said_once_and_counted(tmp_path):
    procs, endpoint, run, agent = _team(tmp_path)
    log = tmp_path / "agent0.log"
    try:
        with _foreign_sim(endpoint, run, token=True) as (session, plant):
            meas = f"coload/{run}/agent/0/meas"
            ctl = f"coload/{run}/sim/control"
            for k in range(3):  # three of each: said once, counted three times
                _put(session, meas, "meas", {"tick": k, "agent": 0, "vx": 0.0, "vy": 0.0, "stamp": 1.5})
                _put(session, meas, "meas", {"tick": float(k), "agent": 0, "vx": 0.0, "vy": 0.0})
                _put(session, ctl, "control", {"kind": "start", "tick": 0, "ticks": 3400})
            _wait_for(lambda: log.read_text().count("dropped a") >= 3, 30, "the agent's log lines")
            text = log.read_text()
            assert text.count("dropped a") == 3, text  # each said once
            assert "agent 0: dropped a meas on coload/" in text
            assert "('stamp',): Extra inputs are not permitted" in text
            assert "('tick',): Input should be a valid integer" in text
            assert ("'start' says the run has ticks=3400; this agent's scenario has 400 (duration / dt)" in text)
            # a valid done ends the agent: its report counts every drop
            _put(session, ctl, "control", {"kind": "done", "tick": TICKS, "ticks": TICKS})
            plant.wait(lambda: plant.report is not None, 30, "agent 0's report")
            assert plant.report["drops"] == {"bad_schema": 6, "bad_control": 3}
            assert plant.wrench_ticks == []  # it never stepped: nothing it got was a measurement
            assert agent.wait(30) == 0
    finally:
        procs.kill_all()


def test_an_agent_whose_tokenless_simulator_stops_without_done_gives_up(tmp_path):
    procs, endpoint, run, agent = _team(tmp_path, "timing.sim_lost_timeout_s=3.0")
    log = tmp_path / "agent0.log"
    try:
        with _foreign_sim(endpoint, run, token=False) as (session, plant):  # no liveliness token, on purpose
            _put(session, f"coload/{run}/sim/control", "control", {"kind": "start", "tick": 0, "ticks": TICKS})
            for k in range(20):
                _put(session, f"coload/{run}/agent/0/meas", "meas", {"tick": k, "agent": 0, "vx": 0.0, "vy": 0.0})
                plant.wait(lambda k=k: k in plant.wrench_ticks, 30, f"agent 0's wrench of tick {k}")
            # the simulator stops here, without done: the agent gives up once 3 s pass without a measurement
            assert agent.wait(60) == 1
            plant.wait(lambda: plant.report is not None, 10, "agent 0's report")
            assert plant.report["ticks"] == 20
    finally:
        procs.kill_all()
    text = log.read_text()
    assert f"the simulator's liveliness token coload/{run}/alive/sim/0 is not there" in text
    assert "giving up at tick 20" in text


def test_a_simulator_that_numbers_its_ticks_from_1_is_joined_and_nothing_is_counted_as_dropped(tmp_path):
    """Ticks numbered from 1 (a MATLAB habit): after the start notice the agent holds tick 1 back as a
    possible forgery, then rejoins at it (`timing.rejoin_after_s`, said in its log). The held measurement was
    counted as `future` and taken back: the report does not list it (before: `"future": 0`)."""
    procs, endpoint, run, agent = _team(tmp_path)
    try:
        with _foreign_sim(endpoint, run, token=True) as (session, plant):
            ctl = f"coload/{run}/sim/control"
            _put(session, ctl, "control", {"kind": "start", "tick": 0, "ticks": TICKS})
            # the start notice is handled before the first measurement (not a late joiner's start): a notice
            # of another run behind it on the same subscription, and its log line, say it was
            _put(session, ctl, "control", {"kind": "progress", "tick": 0, "ticks": 1})
            log = tmp_path / "agent0.log"
            _wait_for(lambda: "dropped a control" in log.read_text(), 30, "the agent's log line")
            for k in range(1, 6):
                _put(session, f"coload/{run}/agent/0/meas", "meas", {"tick": k, "agent": 0, "vx": 0.0, "vy": 0.0})
                plant.wait(lambda k=k: k in plant.wrench_ticks, 30, f"agent 0's wrench of tick {k}")
            _put(session, ctl, "control", {"kind": "done", "tick": TICKS, "ticks": TICKS})
            plant.wait(lambda: plant.report is not None, 30, "agent 0's report")
            assert plant.report["drops"] == {"bad_control": 1}
            assert plant.report["ticks"] == 5
            assert agent.wait(30) == 0
    finally:
        procs.kill_all()
    assert "measurements 0..0 never came; rejoining at tick 1" in (tmp_path / "agent0.log").read_text()


def test_on_a_secure_team_a_simulator_subscribed_wider_than_its_keys_hears_nothing(tmp_path):
    """docs/security.md (the Zenoh details): an agent sends its wrench only once the router has told it of a
    subscriber on `agent/*/wrench`, and its policy lets it learn of exactly that expression. A simulator whose
    only subscription is `coload/R/agent/**` therefore hears no wrench, without an error anywhere; once an
    exact subscriber is there, the wide one gets the wrenches too."""
    endpoint = f"tls/127.0.0.1:{free_tcp_port()}"
    run, team = "wide-sub", tmp_path / "team"
    procs = Processes(tmp_path)
    cv = threading.Condition()
    heard: dict[str, list[int]] = {"wide": [], "exact": [], "monitor": []}

    def hear(name: str, kind: str):
        def on(sample) -> None:
            if str(sample.key_expr).endswith(kind):
                with cv:
                    heard[name].append(msgpack.unpackb(sample.payload.to_bytes(), strict_map_key=False)[2]["tick"])
                    cv.notify_all()
        return on

    def wait(cond, what: str) -> None:
        with cv:
            assert cv.wait_for(cond, 60), f"timed out waiting for {what}: {heard}"

    try:
        subprocess.run(coload_cmd("keys", "init", str(team), "--agents", "5", "--scenario", "quick", "--run", run,
                                  "--endpoint", endpoint), check=True, capture_output=True)
        router = procs.start("router", coload_cmd("router", "--tls-dir", str(team)), stdout=subprocess.PIPE)
        assert router.stdout.readline().decode().startswith("ready")
        with zenoh.open(zenoh.Config.from_file(str(team / "sim.json5"))) as sim, \
                zenoh.open(zenoh.Config.from_file(str(team / "monitor.json5"))) as monitor:
            plant = Plant(monitor, run)  # its liveliness watch only (the monitor may watch; it hears no wrench)
            wide = sim.declare_subscriber(f"coload/{run}/agent/**", hear("wide", "/wrench"))
            seen = monitor.declare_subscriber(f"coload/{run}/agent/*/estimate", hear("monitor", "/estimate"))
            token = sim.liveliness().declare_token(f"coload/{run}/alive/sim/0")
            agent = procs.start("agent0", coload_cmd("agent", "--id", "0", "quick", "--tls-dir", str(team), "--run",
                                                     run, "--set", "timing.neighbour_timeout_s=0.2"))
            plant.wait(lambda: plant.agent_up, 60, "agent 0's token")
            _put(sim, f"coload/{run}/sim/control", "control", {"kind": "start", "tick": 0, "ticks": 2000})
            _put(sim, f"coload/{run}/agent/0/meas", "meas", {"tick": 0, "agent": 0, "vx": 0.0, "vy": 0.0})
            wait(lambda: 0 in heard["monitor"], "agent 0's estimate of tick 0")  # it stepped tick 0
            exact = sim.declare_subscriber(f"coload/{run}/agent/*/wrench", hear("exact", "/wrench"))
            _put(sim, f"coload/{run}/agent/0/meas", "meas", {"tick": 1, "agent": 0, "vx": 0.0, "vy": 0.0})
            wait(lambda: 1 in heard["exact"] and 1 in heard["wide"], "agent 0's wrench of tick 1")
            # the wrench of tick 0 was never sent: the agent knew of no subscriber it may learn of
            assert heard["wide"] == [1] and heard["exact"] == [1]
            assert agent.poll() is None
            del wide, seen, exact, token
    finally:
        procs.kill_all()
