"""The Zenoh flags of every command that opens a session, as Zenoh's own tools spell them.

``-e/--connect``, ``-l/--listen``, ``-c/--config`` (a Zenoh JSON5 file; ``ZENOH_CONFIG`` when not
given), ``--cfg KEY:VALUE`` (one config field, a JSON5 value, applied last), and coload's
``--tls-dir DIR`` (a team's keys from ``coload keys init``: mutual TLS with the role's own
certificate; for the router also the team's access-control list). Without TLS, an endpoint that is
not loopback gets a warning: anyone on that network could read and forge the team's messages.
See docs/security.md.
"""

from __future__ import annotations

import argparse
import ipaddress
import json
import logging
import os
from pathlib import Path
from typing import Any

log = logging.getLogger("coload.zenoh")

CONFIG_ENV = "ZENOH_CONFIG"


def add_zenoh_args(p: argparse.ArgumentParser, router: bool = False, mode: bool = True) -> None:
    g = p.add_argument_group("zenoh")
    g.add_argument("-e", "--connect", action="append", metavar="ENDPOINT",
                   help="endpoint to connect to, e.g. tls/127.0.0.1:7447 (repeatable)"
                        + ("; other routers of a mesh" if router else ""))
    g.add_argument("-l", "--listen", action="append", metavar="ENDPOINT",
                   help="endpoint to listen on (repeatable)"
                        + ("; default tcp/127.0.0.1:7447, the --tls-dir team's endpoint, or the config file's "
                           "listen.endpoints" if router else ""))
    if mode and not router:
        g.add_argument("--zenoh-mode", choices=["client", "peer", "router"],
                       help="Zenoh session mode (default: client, or a mode other than peer that the "
                            "config file sets)")
    g.add_argument("-c", "--config", "--zenoh-config", dest="zenoh_config", type=Path, metavar="FILE",
                   help=f"a Zenoh JSON5 config file (default: ${CONFIG_ENV} if set); its mode and endpoints "
                        "are kept unless given here; multicast scouting stays off")
    g.add_argument("--cfg", action="append", default=[], metavar="KEY:VALUE",
                   help="set one Zenoh config field, a JSON5 value, e.g. --cfg 'transport/link/tx/lease:5000' "
                        "(repeatable; applied last)")
    g.add_argument("--tls-dir", type=Path, metavar="DIR",
                   help="a team's keys (`coload keys init`): mutual TLS with this role's certificate"
                        + (" and the team's access-control list" if router else "")
                        + "; endpoints default to the team's")


def config_file(args: argparse.Namespace) -> Path | None:
    """``-c FILE``, else ``$ZENOH_CONFIG``, else None."""
    if getattr(args, "zenoh_config", None) is not None:
        return args.zenoh_config
    env = os.environ.get(CONFIG_ENV)
    return Path(env) if env else None


def parse_cfg(items: list[str]) -> list[tuple[str, str]]:
    """``KEY:VALUE`` pairs; raises ValueError naming a malformed one."""
    out = []
    for item in items:
        key, sep, value = item.partition(":")
        if not sep or not key.strip() or not value.strip():
            raise ValueError(f"--cfg {item!r}: expected KEY:VALUE, e.g. transport/link/tx/lease:5000")
        out.append((key.strip().strip("/"), value.strip()))
    return out


def apply_cfg(conf: Any, items: list[str]) -> None:
    from net.zenoh_transport import zenoh_error_text

    for key, value in parse_cfg(items):
        try:
            conf.insert_json5(key, value)
        except Exception as exc:  # zenoh.ZError: an unknown field or a value of the wrong type
            raise ValueError(f"--cfg {key}:{value}: {zenoh_error_text(exc)}") from None


def _host(endpoint: str) -> str | None:
    """The host of ``proto/host:port[#...]``, or None if it has none."""
    _, sep, rest = endpoint.partition("/")
    if not sep:
        return None
    addr = rest.split("#", 1)[0].split("?", 1)[0]
    host = addr.rsplit(":", 1)[0] if ":" in addr else addr
    return host.strip("[]") or None


def is_loopback(endpoint: str) -> bool:
    host = _host(endpoint)
    if host is None or host == "localhost":
        return host == "localhost"
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # a name: it may resolve anywhere


def insecure_endpoints(endpoints: list[str]) -> list[str]:
    """The endpoints that carry the team's messages in clear text beyond this host (not ``tls/``
    and not loopback; unix sockets stay on the host)."""
    return [e for e in endpoints if not e.startswith(("tls/", "quic/", "unixsock-stream/")) and not is_loopback(e)]


def _endpoints(conf: Any, what: str) -> list[str]:
    value = json.loads(conf.get_json(f"{what}/endpoints"))
    if isinstance(value, dict):
        value = [e for v in value.values() for e in (v or [])]
    return [str(e) for e in value or []]


def zenoh_conf(args: argparse.Namespace, role: str, *, mode: str | None = None, mode_if_unset: str = "client",
               default_listen: list[str] | None = None) -> Any:
    """The session config a command's flags ask for; ``role`` names its certificate with ``--tls-dir``
    (``router``, ``sim``, ``agent-3``, ``monitor``). Raises ValueError (one line) on a bad file,
    manifest or ``--cfg``."""
    from net import access_policy as ap
    from net.zenoh_transport import zenoh_config

    connect, listen = args.connect, args.listen
    tls_dir = getattr(args, "tls_dir", None)
    team = None
    path = config_file(args)
    if tls_dir is not None:
        from coload.certificates import load_team

        team = load_team(tls_dir)
        if role == ap.ROUTER:
            listen = listen or ([team.endpoint] if path is None else None)
        else:
            connect = connect or ([team.endpoint] if path is None else None)
    if role == ap.ROUTER and listen is None and path is None:
        listen = default_listen
    conf = zenoh_config(mode=mode or getattr(args, "zenoh_mode", None), connect=connect, listen=listen,
                        config_file=path, mode_if_unset=mode_if_unset)
    if team is not None:
        if role not in team.generations:
            raise ValueError(f"{tls_dir}: the team has no {role} (coload keys add)")
        conf.insert_json5("transport/link/tls", json.dumps(ap.tls_block(tls_dir, role)))
        if role == ap.ROUTER:
            conf.insert_json5("access_control",
                              json.dumps(ap.access_control(team.run, team.neighbours, team.common_names())))
    apply_cfg(conf, list(getattr(args, "cfg", []) or []))
    bare = insecure_endpoints(_endpoints(conf, "connect") + _endpoints(conf, "listen"))
    if bare:
        log.warning("%s is not loopback and not TLS: anyone on that network can read and forge this team's "
                    "messages (use --tls-dir, docs/security.md)", ", ".join(bare))
    return conf
