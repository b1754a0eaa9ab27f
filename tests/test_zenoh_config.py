"""``--zenoh-config``: a user's Zenoh file is the base (its mode, endpoints, lease), the command
line overrides only what it names, and nothing ends up listening on every interface. Daemons that
cannot start say why in one line (exit status 2)."""

from __future__ import annotations

import json

import pytest
import zenoh

from coload.cli import main
from net.zenoh_transport import (
    close_session,
    free_tcp_port,
    open_router,
    open_session,
    router_config,
    router_endpoints,
    zenoh_config,
)


def _get(conf: zenoh.Config, key: str):
    return json.loads(conf.get_json(key))


@pytest.fixture
def endpoint() -> str:
    return f"tcp/127.0.0.1:{free_tcp_port()}"


def _write(path, text: str):
    path.write_text(text, encoding="utf-8")
    return path


def test_the_files_mode_endpoints_and_lease_are_kept(tmp_path, endpoint):
    f = _write(tmp_path / "z.json5", '{mode: "peer", connect: {endpoints: ["%s"]}, '
                                     'listen: {endpoints: ["tcp/127.0.0.1:0"]}, '
                                     'transport: {link: {tx: {lease: 1500}}}}' % endpoint)
    conf = zenoh_config(config_file=f)
    assert _get(conf, "mode") == "peer"
    assert _get(conf, "connect/endpoints") == [endpoint]
    assert _get(conf, "listen/endpoints") == ["tcp/127.0.0.1:0"]
    assert _get(conf, "transport/link/tx/lease") == 1500
    assert _get(conf, "scouting/multicast/enabled") is False
    over = zenoh_config(mode="client", connect=["tcp/127.0.0.1:1"], config_file=f)
    assert _get(over, "mode") == "client" and _get(over, "connect/endpoints") == ["tcp/127.0.0.1:1"]
    assert _get(over, "listen/endpoints") == ["tcp/127.0.0.1:0"]  # not named: the file's


def test_a_file_without_listen_endpoints_listens_nowhere(tmp_path):
    f = _write(tmp_path / "z.json5", '{mode: "peer"}')
    assert _get(zenoh_config(config_file=f), "listen/endpoints") == []  # Zenoh's default: every interface
    with pytest.raises(ValueError, match=r"listen\.endpoints in .*z\.json5"):
        router_config(None, config_file=f)


def test_a_bad_file_is_named(tmp_path):
    with pytest.raises(ValueError, match=r"nope\.json5: not a usable Zenoh config"):
        zenoh_config(config_file=tmp_path / "nope.json5")
    f = _write(tmp_path / "bad.json5", "{mode: ")
    with pytest.raises(ValueError, match=r"bad\.json5: not a usable Zenoh config"):
        zenoh_config(config_file=f)


def test_router_and_client_from_files_meet(tmp_path, endpoint):
    """A router whose endpoint is only in its file, and a client whose router is only in its file."""
    rf = _write(tmp_path / "router.json5", '{listen: {endpoints: ["%s"]}}' % endpoint)
    cf = _write(tmp_path / "client.json5", '{mode: "client", connect: {endpoints: ["%s"]}}' % endpoint)
    router = open_router(None, config_file=rf)
    try:
        client = open_session(zenoh_config(config_file=cf))
        try:
            assert list(client.info.routers_zid()) == [router.info.zid()]
        finally:
            close_session(client)
    finally:
        close_session(router)


def test_router_endpoints_reads_the_per_mode_form(tmp_path):
    f = _write(tmp_path / "z.json5", '{listen: {endpoints: {router: ["tcp/127.0.0.1:7001"], peer: []}}}')
    assert router_endpoints(zenoh_config("router", config_file=f)) == ["tcp/127.0.0.1:7001"]


def test_daemons_that_cannot_start_say_why(tmp_path, endpoint, capsys):
    quick = "config/scenarios/quick.toml"
    assert main(["agent", "--id", "7", quick, "--connect", endpoint, "--run", "x"]) == 2
    assert "--id 7 is not an agent of quick (0..4)" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:  # nothing listens at the endpoint
        main(["agent", "--id", "1", quick, "--connect", endpoint, "--run", "x"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "coload agent: cannot open the Zenoh session" in err and "is the router running" in err
    assert "Traceback" not in err
    with pytest.raises(SystemExit) as exc:
        main(["sim", quick, "--connect", endpoint, "--run", "x", "--out", str(tmp_path / "run"),
              "--zenoh-config", str(tmp_path / "nope.json5")])
    assert exc.value.code == 2 and "nope.json5: not a usable Zenoh config" in capsys.readouterr().err
    router = open_router([endpoint])
    try:
        assert main(["router", "--listen", endpoint]) == 2  # the port is taken
        assert f"coload router: cannot listen on {endpoint}" in capsys.readouterr().err
    finally:
        close_session(router)
    f = _write(tmp_path / "z.json5", "{}")
    assert main(["router", "--zenoh-config", str(f)]) == 2
    assert "needs at least one listen endpoint" in capsys.readouterr().err


def test_a_file_that_only_tunes_the_link_leaves_the_daemon_a_client(tmp_path):
    """The usual file sets a lease and nothing else: the daemon stays what the command line makes it
    (a client), not Zenoh's default peer."""
    f = _write(tmp_path / "z.json5", "{ transport: { link: { tx: { lease: 1000, keep_alive: 4 } } } }")
    conf = zenoh_config(connect=["tcp/127.0.0.1:7447"], config_file=f, mode_if_unset="client")
    assert _get(conf, "mode") == "client" and _get(conf, "transport/link/tx/lease") == 1000
    assert _get(zenoh_config(config_file=_write(tmp_path / "r.json5", '{mode: "router"}'),
                             mode_if_unset="client"), "mode") == "router"
    # a file that names Zenoh's default mode means it
    assert _get(zenoh_config(config_file=_write(tmp_path / "p.json5", '{"mode": "peer"}'),
                             mode_if_unset="client"), "mode") == "peer"
