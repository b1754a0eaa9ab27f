"""A team's keys and policy against a real Zenoh router on loopback (docs/security.md).

The router runs the config ``--tls-dir`` builds (mutual TLS, the team's default-deny access-control
list); clients open sessions with role certificates, a replaced agent's old certificate, an expired
one, one from another CA, none, or plain TCP. What passes is checked with a subscriber that may hear
it, so a refusal is never mistaken for a slow link.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import shutil
import stat
import subprocess
import threading
from pathlib import Path

import pytest
import zenoh

from coload import certificates as certs
from coload.zenoh_flags import config_file, insecure_endpoints, parse_cfg, zenoh_conf
from net import access_policy as ap
from net import keys
from net.zenoh_transport import close_session, free_tcp_port, open_session, zenoh_config
from tests.conftest import coload_cmd

pytestmark = pytest.mark.zenoh

NOW = dt.datetime.now(dt.timezone.utc)
RUN = "k"
LINE = [[1], [0, 2], [1]]


def _args(tls_dir: Path | None = None, **kw) -> argparse.Namespace:
    base = {"connect": None, "listen": None, "zenoh_config": None, "cfg": [], "tls_dir": tls_dir, "zenoh_mode": None}
    return argparse.Namespace(**{**base, **kw})


def _client(tls: dict | None, endpoint: str) -> zenoh.Session:
    conf = zenoh_config("client", connect=[endpoint])
    conf.insert_json5("connect/timeout_ms", "1500")
    if tls is not None:
        conf.insert_json5("transport/link/tls", json.dumps(tls))
    return open_session(conf)


class Team:
    def __init__(self, d: Path) -> None:
        self.dir = d
        self.endpoint = f"tls/127.0.0.1:{free_tcp_port()}"
        certs.init_team(d, LINE, run=RUN, endpoint=self.endpoint, now=NOW)
        self.router = None

    def start(self) -> None:
        self.router = open_session(zenoh_conf(_args(self.dir), "router", mode="router"))

    def session(self, role: str, **swap: str) -> zenoh.Session:
        tls = ap.tls_block(self.dir, role)
        tls.update(swap)
        return _client(tls, self.endpoint)

    def close(self) -> None:
        if self.router is not None:
            close_session(self.router)


@pytest.fixture
def team(tmp_path):
    t = Team(tmp_path / "keys")
    yield t
    t.close()


def _collector(session: zenoh.Session, key_expr: str):
    got: list[bytes] = []
    cond = threading.Condition()

    def on(sample) -> None:
        with cond:
            got.append(sample.payload.to_bytes())
            cond.notify_all()

    session.declare_subscriber(key_expr, on)

    def wait_for(payload: bytes, timeout: float = 5.0) -> bool:
        with cond:
            return cond.wait_for(lambda: payload in got, timeout)

    return got, wait_for


def test_init_writes_a_ca_a_certificate_per_role_and_private_keys(tmp_path):
    t = certs.init_team(tmp_path / "k", LINE, run=RUN, now=NOW)
    assert set(t.generations) == {"router", "sim", "monitor", "agent-0", "agent-1", "agent-2"}
    for role in t.generations:
        assert certs.certificate_info(ap.cert_path(tmp_path / "k", role))["cn"] == f"{role}.g1"
        assert stat.S_IMODE(ap.key_path(tmp_path / "k", role).stat().st_mode) == 0o600
    assert stat.S_IMODE((tmp_path / "k" / certs.CA_KEY).stat().st_mode) == 0o600
    assert certs.load_team(tmp_path / "k").neighbours == LINE
    with pytest.raises(certs.KeysError, match="holds a team already"):
        certs.init_team(tmp_path / "k", LINE, now=NOW)


def test_policy_is_default_deny_and_names_only_current_generations(tmp_path):
    certs.init_team(tmp_path / "k", LINE, run=RUN, now=NOW)
    t = certs.add_agent(tmp_path / "k", 1, now=NOW)
    acl = ap.access_control(t.run, t.neighbours, t.common_names())
    assert acl["default_permission"] == "deny"
    names = {s["id"]: s["cert_common_names"] for s in acl["subjects"]}
    assert names["agent-1"] == ["agent-1.g2"] and names["agent-0"] == ["agent-0.g1"]
    rules = {r["id"]: r for r in acl["rules"]}
    own = ("wrench", "state", "estimate", "report")
    hinf_own = ("input", "state", "report")  # the paper-003 runtime's keys: the same roles
    assert rules["agent-0/put"]["key_exprs"] == sorted([*(keys.agent(RUN, 0, k) for k in own),
                                                        *(keys.hinf(RUN, 0, k) for k in hinf_own)])
    assert rules["agent-0/hear"]["key_exprs"] == sorted([keys.meas(RUN, 0), keys.state(RUN, 1), keys.sim_control(RUN),
                                                         keys.hinf(RUN, 0, "meas"), keys.hinf(RUN, 1, "state"),
                                                         keys.hinf_control(RUN)])
    assert rules["agent-1/hear"]["key_exprs"] == sorted([keys.meas(RUN, 1), keys.state(RUN, 0), keys.state(RUN, 2),
                                                         keys.sim_control(RUN), keys.hinf(RUN, 1, "meas"),
                                                         keys.hinf(RUN, 0, "state"), keys.hinf(RUN, 2, "state"),
                                                         keys.hinf_control(RUN)])
    assert rules["monitor/hear"]["key_exprs"] == sorted([keys.agent_all(RUN, "estimate"), keys.sim_control(RUN),
                                                         keys.sim_pose(RUN), keys.hinf_control(RUN)])
    assert "monitor/put" not in rules
    assert rules["sim/put"]["key_exprs"] == sorted([keys.agent_all(RUN, "meas"), keys.sim_control(RUN),
                                                    keys.sim_pose(RUN), keys.hinf_all(RUN, "meas"),
                                                    keys.hinf_control(RUN)])
    # a late joiner: agent 3 with the grown graph
    t = certs.add_agent(tmp_path / "k", 3, neighbours=[[1], [0, 2], [1, 3], [2]], now=NOW)
    assert t.generations["agent-3"] == 1 and t.n == 4
    with pytest.raises(certs.KeysError, match="not in the team"):
        certs.add_agent(tmp_path / "k", 9, now=NOW)


def test_the_router_lets_each_role_say_only_its_own(team):
    team.start()
    sim, a0, a1, mon = (team.session(r) for r in ("sim", "agent-0", "agent-1", "monitor"))
    try:
        meas0, meas0_has = _collector(a0, keys.meas(RUN, 0))
        st1, st1_has = _collector(a0, keys.state(RUN, 1))
        ctl, ctl_has = _collector(a0, keys.sim_control(RUN))
        wr, wr_has = _collector(sim, keys.agent_all(RUN, "wrench"))
        est, est_has = _collector(mon, keys.agent_all(RUN, "estimate"))
        # the monitor's own put loops back to its own subscriber: the simulator's tells what passed
        sim_est, sim_est_has = _collector(sim, keys.agent_all(RUN, "estimate"))
        sneak, _ = _collector(mon, keys.agent_all(RUN, "meas"))  # the monitor may not hear measurements
        sneak1, _ = _collector(a1, keys.meas(RUN, 0))  # nor agent 1 agent 0's
        # forgeries first: each from a certificate that may not say it
        a1.put(keys.meas(RUN, 0), b"forged-meas")
        a1.put("coload/k/agent/*/meas", b"forged-wide-meas")
        a1.put(keys.sim_control(RUN), b"forged-done")
        a1.put(keys.wrench(RUN, 0), b"forged-wrench")
        mon.put(keys.estimate(RUN, 0), b"forged-estimate")
        # then the genuine ones, each awaited (same publisher order: a forgery would be here by now)
        for session, key, payload, wait in ((sim, keys.meas(RUN, 0), b"meas", meas0_has),
                                            (a1, keys.state(RUN, 1), b"state", st1_has),
                                            (sim, keys.sim_control(RUN), b"done", ctl_has)):
            for _ in range(3):  # the first put may race the subscriber's declaration
                session.put(key, payload)
                if wait(payload, 2.0):
                    break
            assert wait(payload), key
        for k in range(3):  # wildcard subscribers get every sample, not only the first
            a0.put(keys.wrench(RUN, 0), b"wrench%d" % k)
            a0.put(keys.estimate(RUN, 0), b"est%d" % k)
        assert wr_has(b"wrench2") and est_has(b"est2")
        sim.put(keys.meas(RUN, 0), b"meas-again")
        assert meas0_has(b"meas-again")
        assert set(meas0) == {b"meas", b"meas-again"}
        assert b"forged-done" not in ctl and b"forged-wrench" not in wr and b"forged-estimate" not in sim_est
        assert sim_est_has(b"est2") and b"forged-estimate" not in est[1:]
        assert wr == [b"wrench0", b"wrench1", b"wrench2"] and st1 == [b"state"] * len(st1)
        assert sneak == [] and b"meas" not in sneak1 and b"meas-again" not in sneak1  # its own puts loop back locally
    finally:
        for s in (sim, a0, a1, mon):
            close_session(s)


def test_replaced_expired_foreign_missing_and_plain_certificates_are_refused(team, tmp_path):
    old = tmp_path / "old"
    old.mkdir()
    for f in ("agent-0.pem", "agent-0.key"):
        shutil.copy(team.dir / f, old / f)
    certs.add_agent(team.dir, 0, now=NOW)  # agent 0 replaced: its old certificate is revoked
    expired = tmp_path / "expired"
    expired.mkdir()
    shutil.copy(team.dir / certs.CA_KEY, expired / certs.CA_KEY)
    shutil.copy(team.dir / ap.CA_CERT, expired / ap.CA_CERT)
    certs._issue(expired, "agent-2", "agent-2.g1", [], NOW - dt.timedelta(days=40), 30)
    foreign = tmp_path / "foreign"
    certs.init_team(foreign, LINE, run=RUN, now=NOW)
    team.start()
    sim = team.session("sim")
    try:
        wr, wr_has = _collector(sim, keys.agent_all(RUN, "wrench"))
        new0 = team.session("agent-0")
        stale0 = team.session("agent-0", connect_certificate=str(old / "agent-0.pem"),
                              connect_private_key=str(old / "agent-0.key"))  # connects: the CA signed it
        stale0.put(keys.wrench(RUN, 0), b"old-generation")
        for _ in range(3):
            new0.put(keys.wrench(RUN, 0), b"new-generation")
            if wr_has(b"new-generation", 2.0):
                break
        stale0.put(keys.wrench(RUN, 0), b"old-generation")
        new0.put(keys.wrench(RUN, 0), b"after")
        assert wr_has(b"after")
        assert b"old-generation" not in wr
        for s in (new0, stale0):
            close_session(s)
        refused = {
            "expired": dict(connect_certificate=str(ap.cert_path(expired, "agent-2")),
                            connect_private_key=str(ap.key_path(expired, "agent-2"))),
            "another CA": dict(connect_certificate=str(ap.cert_path(foreign, "agent-2")),
                               connect_private_key=str(ap.key_path(foreign, "agent-2"))),
        }
        for what, swap in refused.items():
            with pytest.raises(zenoh.ZError):
                team.session("agent-2", **swap)
                pytest.fail(f"a session with the {what} certificate opened")
        with pytest.raises(zenoh.ZError):  # TLS, but no client certificate
            _client({"root_ca_certificate": str(team.dir / ap.CA_CERT)}, team.endpoint)
        with pytest.raises(zenoh.ZError):  # plain TCP on the TLS port
            _client(None, team.endpoint.replace("tls/", "tcp/"))
    finally:
        close_session(sim)


def test_zenoh_flags(tmp_path, monkeypatch, caplog):
    assert parse_cfg(["transport/link/tx/lease:5000", "mode:\"peer\""]) == [("transport/link/tx/lease", "5000"),
                                                                             ("mode", '"peer"')]
    with pytest.raises(ValueError, match="expected KEY:VALUE"):
        parse_cfg(["lease"])
    endpoints = ["tcp/127.0.0.1:7447", "tcp/localhost:1", "tls/10.0.0.2:7447", "tcp/10.0.0.2:7447", "tcp/[::1]:7447",
                 "udp/robot.local:7447"]
    assert insecure_endpoints(endpoints) == ["tcp/10.0.0.2:7447", "udp/robot.local:7447"]
    f = tmp_path / "z.json5"
    f.write_text('{ mode: "client", connect: { endpoints: ["tcp/127.0.0.1:7001"] } }')
    monkeypatch.setenv("ZENOH_CONFIG", str(f))
    assert config_file(_args()) == f
    conf = zenoh_conf(_args(cfg=["transport/link/tx/lease:4321"]), "sim")
    assert json.loads(conf.get_json("connect/endpoints")) == ["tcp/127.0.0.1:7001"]
    assert json.loads(conf.get_json("transport/link/tx/lease")) == 4321
    with pytest.raises(ValueError, match="--cfg transport/link/tx/lease"):
        zenoh_conf(_args(cfg=["transport/link/tx/lease:\"soon\""]), "sim")
    monkeypatch.delenv("ZENOH_CONFIG")
    with caplog.at_level("WARNING"):
        zenoh_conf(_args(connect=["tcp/192.0.2.7:7447"]), "sim")
    assert "tcp/192.0.2.7:7447 is not loopback and not TLS" in caplog.text


def test_keys_cli(tmp_path):
    d = tmp_path / "team"
    out = subprocess.run(coload_cmd("keys", "init", str(d), "--agents", "5", "--scenario", "quick", "--run", "demo"),
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert certs.load_team(d).neighbours == [[1], [0, 2], [1, 3], [2, 4], [3]]
    again = subprocess.run(coload_cmd("keys", "init", str(d), "--agents", "5"), capture_output=True, text=True,
                           timeout=60)
    assert again.returncode == 2 and again.stderr.strip().count("\n") == 0 and "holds a team already" in again.stderr
    add = subprocess.run(coload_cmd("keys", "add", str(d), "--agent", "2"), capture_output=True, text=True, timeout=60)
    assert add.returncode == 0 and "agent-2 generation 2" in add.stdout
    bad = subprocess.run(coload_cmd("router", "--tls-dir", str(tmp_path / "none")), capture_output=True, text=True,
                         timeout=60)
    assert bad.returncode == 2 and "team.json: cannot read it" in bad.stderr and bad.stderr.count("\n") == 1


def test_generated_role_configs_work_with_plain_config_flags(tmp_path):
    """``DIR/ROLE.json5`` alone (``-c``, no ``--tls-dir``) gives the same secure team."""
    endpoint = f"tls/127.0.0.1:{free_tcp_port()}"
    d = tmp_path / "keys"
    certs.init_team(d, LINE, run=RUN, endpoint=endpoint, now=NOW)
    router = open_session(zenoh_conf(_args(zenoh_config=d / "router.json5"), "router", mode="router"))
    sessions = []
    try:
        sim, a0, a2 = (open_session(zenoh_conf(_args(zenoh_config=d / f"{r}.json5"), r)) for r in ("sim", "agent-0",
                                                                                                    "agent-2"))
        sessions = [sim, a0, a2]
        wr, wr_has = _collector(sim, keys.agent_all(RUN, "wrench"))
        for _ in range(3):
            a0.put(keys.wrench(RUN, 0), b"w0")
            if wr_has(b"w0", 2.0):
                break
        a2.put(keys.wrench(RUN, 0), b"forged")  # agent 2 speaking for agent 0
        a0.put(keys.wrench(RUN, 0), b"w0-again")
        assert wr_has(b"w0-again") and b"forged" not in wr
    finally:
        for s in sessions:
            close_session(s)
        close_session(router)
