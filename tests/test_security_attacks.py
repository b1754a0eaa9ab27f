"""The attacks of docs/security.md against real teams: router, simulator and five agents as separate
processes on loopback, an attacker with plain zenoh + msgpack in the test.

Secure team (``--tls-dir``: mutual TLS, default-deny access control): the attacker holds agent 1's
certificate (a compromised robot), agent 4's replaced one, none at all, or speaks plain TCP. It
eavesdrops and forges measurements, states, wrenches, estimates and ``done`` for other agents, on
exact and on wider key expressions, and floods. Zenoh refuses every one at the router (nothing
reaches a daemon: its only counted drop is the far-future state agent 1's own certificate may put
on agent 1's own key, refused by both neighbours); the run's tables are bit-identical to an
in-process run of the same scenario.

Insecure team (plain TCP on loopback): the same forgeries on wider key expressions reach the daemons,
which refuse each one as ``wrong_key`` (counted per receiving subscription); tables bit-identical.
"""

from __future__ import annotations

import datetime as dt
import json
import shutil
import subprocess
import threading
from collections import Counter
from pathlib import Path

import pytest
import zenoh

from coload import certificates as certs
from coload.runs.engine import run_inproc
from config.loader import load_scenario
from net import access_policy as ap
from net import keys
from net.messages import Control, Estimate, Measurement, StateMsg, Wrench
from net.schema import DecodeError, decode, encode
from net.zenoh_transport import client_session, free_tcp_port, zenoh_config
from tests.conftest import SCENARIOS, Processes, coload_cmd, max_table_difference

pytestmark = [pytest.mark.zenoh, pytest.mark.slow]

OVERRIDES = ["duration=6.0", "timing.neighbour_timeout_s=60.0", "timing.wrench_timeout_s=60.0",
             'link.loss.model="bernoulli"', "link.loss.p=0.1", "link.jitter_ticks=1"]
FLOOD = 2_000
FAR = 10**6


def _state(tick: int, sender: int) -> StateMsg:
    return StateMsg(tick=tick, sender=sender, vx=5.0, vy=-5.0, phase=0, shared={"w": 9.0}, pair={})


def forgeries(run: str, now: int, ticks: int) -> list[tuple[str, bytes]]:
    """Well-formed lies for the next ticks, on exact keys of other members and on wider key expressions."""
    nxt = now + 1
    out = [
        (keys.meas(run, 0), encode(Measurement(nxt, 0, 9.0, 9.0))),
        (keys.state(run, 2), encode(_state(nxt, 2))),
        (keys.wrench(run, 2), encode(Wrench(nxt, 2, 1e3, 1e3, 1e3))),
        (keys.estimate(run, 3), encode(Estimate(now, 3, {"omega": 42.0}, {}))),
        (keys.sim_control(run), encode(Control("done", ticks, ticks))),
        (f"coload/{run}/agent/*/meas", encode(Measurement(nxt, 0, 9.0, 9.0))),
        (f"coload/{run}/agent/*/state", encode(_state(nxt, 0))),
        (f"coload/{run}/**", encode(Control("done", ticks, ticks))),
    ]
    out += [(keys.meas(run, 0), encode(Measurement(nxt, 0, 9.0, 9.0)))] * FLOOD
    return out


def wide_forgeries(run: str, now: int, ticks: int) -> list[tuple[str, bytes]]:
    return [p for p in forgeries(run, now, ticks)[:8] if "*" in p[0]]


class Watch:
    """The simulator's progress, heard with the monitor's certificate (or none)."""

    def __init__(self, ticks: int) -> None:
        self.ticks = ticks
        self.tick = -1
        self.cond = threading.Condition()

    def on_control(self, sample) -> None:
        try:
            msg = decode(sample.payload.to_bytes(), Control)
        except DecodeError:
            return
        if msg.kind in ("start", "progress") and msg.ticks == self.ticks:
            with self.cond:
                self.tick = max(self.tick, msg.tick)
                self.cond.notify_all()

    def wait(self, t: int, timeout: float) -> int:
        with self.cond:
            assert self.cond.wait_for(lambda: self.tick >= t, timeout), f"the run never reached tick {t}"
            return self.tick


def _run_team(tmp_path: Path, tls_dir: Path | None, endpoint: str, run: str, attack) -> dict:
    sc = load_scenario(SCENARIOS / "quick.toml", OVERRIDES)
    sc_path = tmp_path / "scenario.toml"
    sc_path.write_text((SCENARIOS / "quick.toml").read_text())
    sets = [x for o in OVERRIDES for x in ("--set", o)]
    secure = ["--tls-dir", str(tls_dir)] if tls_dir else ["--connect", endpoint]
    common = [str(sc_path), *sets, "--run", run, *secure]
    out = tmp_path / "run"
    procs = Processes(tmp_path)
    try:
        router = procs.start("router", coload_cmd("router", *(secure if tls_dir else ["--listen", endpoint])),
                             stdout=subprocess.PIPE)
        assert router.stdout.readline().decode().startswith("ready")
        sim = procs.start("sim", coload_cmd("sim", *common, "--out", str(out)))
        agents = [procs.start(f"agent{i}", coload_cmd("agent", "--id", str(i), *common)) for i in range(sc.n)]
        attack(sc)
        assert sim.wait(180) == 0
        for a in agents:
            assert a.wait(30) == 0
    finally:
        procs.kill_all()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["agents_reported"] == list(range(sc.n))
    assert summary["timeouts"] == {"wrench": 0, "neighbour": 0}
    ref = tmp_path / "inproc"
    run_inproc(sc, ref)
    for name, nkeys in (("samples.csv", 2), ("estimates.csv", 2), ("pairs.csv", 3), ("truth.csv", 1)):
        assert max_table_difference(out, ref, name, nkeys) == 0.0, name
    assert summary["links"] == json.loads((ref / "summary.json").read_text())["links"]
    return summary


def test_secure_team_refuses_every_forgery_and_eavesdropper(tmp_path):
    run = "sec-attack"
    sc = load_scenario(SCENARIOS / "quick.toml", OVERRIDES)
    tls_dir = tmp_path / "keys"
    endpoint = f"tls/127.0.0.1:{free_tcp_port()}"
    certs.init_team(tls_dir, sc.neighbours(), run=run, endpoint=endpoint, now=dt.datetime.now(dt.timezone.utc))
    revoked = tmp_path / "revoked"
    revoked.mkdir()
    for f in ("agent-4.pem", "agent-4.key"):
        shutil.copy(tls_dir / f, revoked / f)
    certs.add_agent(tls_dir, 4, now=dt.datetime.now(dt.timezone.utc))  # agent 4 runs its second generation
    heard: Counter = Counter()
    mine: set[bytes] = set()

    def attack(sc) -> None:
        watch = Watch(sc.ticks)
        estimates = Counter()
        with client_session(endpoint, ap.tls_block(tls_dir, ap.MONITOR)) as monitor:
            monitor.declare_subscriber(keys.sim_control(run), watch.on_control)
            monitor.declare_subscriber(keys.agent_all(run, "estimate"), lambda s: estimates.update([str(s.key_expr)]))
            compromised = client_session(endpoint, ap.tls_block(tls_dir, "agent-1"))
            old = ap.tls_block(tls_dir, "agent-4")
            old.update(connect_certificate=str(revoked / "agent-4.pem"),
                       connect_private_key=str(revoked / "agent-4.key"))
            replaced = client_session(endpoint, old)  # the CA signed it: it connects, and may do nothing
            for who, s in (("compromised", compromised), ("replaced", replaced)):
                for ke in (f"coload/{run}/**", keys.meas(run, 0), keys.agent_all(run, "estimate")):
                    s.declare_subscriber(ke, lambda smp, who=who: heard.update(
                        [who] if smp.payload.to_bytes() not in mine else []))
            for tls in (None, {"root_ca_certificate": str(tls_dir / ap.CA_CERT)}):  # plain TCP, TLS without a cert
                with pytest.raises(zenoh.ZError):
                    client_session(endpoint if tls else endpoint.replace("tls/", "tcp/"), tls, 1500).close()
            now = watch.wait(30, 120)
            lies = forgeries(run, now, sc.ticks)
            mine.update(p for _, p in lies)
            for key, payload in lies:
                compromised.put(key, payload)
            own = (keys.wrench(run, 4), encode(Wrench(now + 1, 4, 1e3, 1e3, 1e3)))  # its own key, old generation
            mine.add(own[1])
            for key, payload in [*lies[:8], own]:
                replaced.put(key, payload)
            far = encode(_state(FAR, 1))  # agent 1's own key: the policy lets it through, the daemons do not
            mine.add(far)
            compromised.put(keys.state(run, 1), far)
            after = watch.wait(now + 1, 60)
            assert after < sc.ticks - 100, f"the run outpaced the attacker (tick {after} of {sc.ticks})"
            watch.wait(sc.ticks, 180)
            compromised.close()
            replaced.close()
        assert sorted(estimates) == [keys.estimate(run, i) for i in range(sc.n)]  # the monitor hears estimates

    summary = _run_team(tmp_path, tls_dir, endpoint, run, attack)
    assert heard == Counter(), "an eavesdropper heard the team"
    assert summary["drops"] == {"future": 2}  # the far-future state of agent 1, at agents 0 and 2


def test_insecure_team_refuses_wider_key_expressions(tmp_path):
    """Without TLS anyone on the network may put; the daemons still refuse puts on wider key
    expressions, one ``wrong_key`` per subscription the put matched."""
    run = "wide-attack"
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    expected: Counter = Counter()

    def attack(sc) -> None:
        watch = Watch(sc.ticks)
        with zenoh.open(zenoh_config(mode="client", connect=[endpoint])) as s:
            s.declare_subscriber(keys.sim_control(run), watch.on_control)
            now = watch.wait(30, 120)
            for key, payload in wide_forgeries(run, now, sc.ticks):
                s.put(key, payload)
            watch.wait(sc.ticks, 180)
        degrees = sum(len(nb) for nb in sc.neighbours())
        # agent/*/meas: 5 agents' measurement subscriptions; agent/*/state: every agent's neighbour-state
        # subscriptions; coload/run/**: all of those, the 5 control subscriptions and the simulator's 3
        expected[keys.WRONG_KEY] = sc.n + degrees + (sc.n + degrees + sc.n + 3)

    summary = _run_team(tmp_path, None, endpoint, run, attack)
    assert summary["drops"] == dict(expected)


def test_run_secure_is_bit_identical_to_inproc(tmp_path):
    """``coload run --secure``: keys in the run directory, every member over mutual TLS under the
    policy, and the same tables as the in-process engine."""
    sets = ["--set", "duration=3.0"]
    out = subprocess.run(coload_cmd("run", "quick", "--secure", *sets, "--out", str(tmp_path / "sec"), "--no-report",
                                    "--no-batch-fit", "--quiet"), capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert "router tls/127.0.0.1:" in out.stderr
    assert certs.certificate_info(tmp_path / "sec" / "keys" / "router.pem")["cn"] == "router.g1"
    ref = subprocess.run(coload_cmd("run", "quick", "--engine", "inproc", *sets, "--out", str(tmp_path / "ref"),
                                    "--no-report", "--no-batch-fit", "--quiet"), capture_output=True, text=True,
                         timeout=300)
    assert ref.returncode == 0, ref.stderr
    for name, nkeys in (("samples.csv", 2), ("estimates.csv", 2), ("pairs.csv", 3), ("truth.csv", 1)):
        assert max_table_difference(tmp_path / "sec", tmp_path / "ref", name, nkeys) == 0.0, name


def test_run_exits_1_naming_the_agents_that_did_not_report(tmp_path, monkeypatch, capsys):
    import coload.runs.orchestrate as orchestrate
    from coload.cli import main

    def fake(scenario, run_dir, **kw):
        return {"agents_reported": [0, 1, 3], "n": scenario.n}

    monkeypatch.setattr(orchestrate, "run_processes", fake)
    assert main(["run", "quick", "--out", str(tmp_path / "r"), "--no-report", "--no-batch-fit", "--quiet"]) == 1
    assert "agents 2, 4 did not report at the end" in capsys.readouterr().err


def test_realtime_far_future_tick_neither_blinds_nor_cuts(tmp_path):
    """Real time, insecure team: a measurement for agent 2 and a state of agent 2, each 5000 ticks
    (50 s) ahead, well inside MAX_TICK_LEAD. Both are refused (three ``future`` drops: agent 2, and
    agents 1 and 3 for the state); agent 2 goes on estimating and its links keep delivering."""
    run = "rt-attack"
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    overrides = ['mode="realtime"', "duration=5.0"]
    sc = load_scenario(SCENARIOS / "quick.toml", overrides)
    sets = [x for o in overrides for x in ("--set", o)]
    common = [str(SCENARIOS / "quick.toml"), *sets, "--run", run, "--connect", endpoint]
    out = tmp_path / "run"
    procs = Processes(tmp_path)
    attacked = {}
    try:
        router = procs.start("router", coload_cmd("router", "--listen", endpoint), stdout=subprocess.PIPE)
        assert router.stdout.readline().decode().startswith("ready")
        watch = Watch(sc.ticks)
        with zenoh.open(zenoh_config(mode="client", connect=[endpoint])) as s:
            s.declare_subscriber(keys.sim_control(run), watch.on_control)
            sim = procs.start("sim", coload_cmd("sim", *common, "--out", str(out)))
            agents = [procs.start(f"agent{i}", coload_cmd("agent", "--id", str(i), *common)) for i in range(sc.n)]
            now = watch.wait(100, 120)
            attacked["tick"] = now
            s.put(keys.meas(run, 2), encode(Measurement(now + 5000, 2, 9.0, 9.0)))
            s.put(keys.state(run, 2), encode(_state(now + 5000, 2)))
            assert sim.wait(120) == 0
        for a in agents:
            assert a.wait(30) == 0
    finally:
        procs.kill_all()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["agents_reported"] == list(range(sc.n))
    assert summary["drops"].get("future") == 3, summary["drops"]
    links = summary["links"]
    for cut in ("2->1", "2->3"):
        assert links[cut]["delivered"] >= 0.9 * links["0->1"]["delivered"], (cut, links)
    rows = [line.split(",") for line in (out / "estimates.csv").read_text().splitlines()[1:]]
    late = [r for r in rows if float(r[1]) == 2 and float(r[0]) > (attacked["tick"] + 200) * sc.dt]  # t, agent
    assert late, "agent 2 stopped estimating after the forged measurement"
