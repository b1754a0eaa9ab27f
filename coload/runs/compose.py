"""``coload compose``: a docker-compose file for one run: a Zenoh router, the simulator and n agents.

One image serves every role (``docker/Dockerfile``). Endpoints are explicit (``tls/router:7447``);
nothing relies on multicast scouting. Health checks use Zenoh itself: the router is healthy once a
client session opens, the simulator and each agent once their liveliness token is visible.

Secure by default (``keys_dir``): every service speaks mutual TLS with its own certificate, mounted
read-only with the team's CA certificate and ``team.json`` (the router builds its access-control list
from it); the health checks use the monitor's read-only certificate. Without ``keys_dir``: plain TCP
(docs/security.md).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

ROUTER_PORT = 7447


KEYS_MOUNT = "/keys"


def compose_spec(n: int, scenario: str, run: str = "compose", image: str = "coload:latest",
                 runs_dir: str = "./runs", keys_dir: str | None = None) -> dict[str, Any]:
    """The compose document as plain data. ``scenario`` is a path inside the image (or a mounted one);
    ``keys_dir`` (relative to the compose file) holds the team's keys (``coload keys init``)."""
    if n < 2:
        raise ValueError(f"--agents must be at least 2, a team (got {n})")
    proto = "tls" if keys_dir is not None else "tcp"
    endpoint = f"{proto}/router:{ROUTER_PORT}"
    tls = ["--tls-dir", KEYS_MOUNT] if keys_dir is not None else []

    def mounts(role: str) -> list[str]:
        """The CA, team.json, the role's own key and the monitor's (for the health check), read-only."""
        if keys_dir is None:
            return []
        files = ["ca.pem", "team.json", f"{role}.pem", f"{role}.key", "monitor.pem", "monitor.key"]
        return [f"{keys_dir}/{f}:{KEYS_MOUNT}/{f}:ro" for f in files]

    def alive(role: str, ident: int) -> dict[str, Any]:
        return {
            "test": ["CMD", "coload", "alive", *tls, "--connect", endpoint, "--key",
                     f"coload/{run}/alive/{role}/{ident}"],
            "interval": "5s", "timeout": "4s", "retries": 12, "start_period": "10s",
        }

    common = {"image": image, "restart": "no"}
    after_router = {"router": {"condition": "service_healthy"}}
    services: dict[str, Any] = {
        "router": {
            **common,
            **({"volumes": mounts("router")} if keys_dir is not None else {}),
            "build": {"context": "..", "dockerfile": "docker/Dockerfile"},
            "command": ["coload", "router", *tls, "--listen", f"{proto}/0.0.0.0:{ROUTER_PORT}"],
            "healthcheck": {
                "test": ["CMD", "coload", "alive", *tls, "--connect", f"{proto}/127.0.0.1:{ROUTER_PORT}"],
                "interval": "2s", "timeout": "4s", "retries": 15,
            },
        },
        "sim": {
            **common,
            "command": ["coload", "sim", scenario, "--set", f"n={n}", *tls, "--connect", endpoint, "--run", run,
                        "--out", f"/runs/{run}"],
            "volumes": [f"{runs_dir}:/runs", *mounts("sim")],
            "depends_on": after_router,
            "healthcheck": alive("sim", 0),
        },
    }
    for i in range(n):
        services[f"agent-{i}"] = {
            **common,
            "command": ["coload", "agent", "--id", str(i), scenario, "--set", f"n={n}", *tls, "--connect", endpoint,
                        "--run", run],
            **({"volumes": mounts(f"agent-{i}")} if keys_dir is not None else {}),
            "depends_on": after_router,
            "healthcheck": alive("agent", i),
        }
    return {"name": "coload", "services": services}


def to_yaml(doc: Any, indent: int = 0) -> str:
    """A small YAML emitter for the compose document (mappings, lists, scalars; strings JSON-quoted)."""
    pad = "  " * indent
    lines: list[str] = []
    if isinstance(doc, dict):
        for key, value in doc.items():
            if isinstance(value, (dict, list)) and value and not _inline(value):
                lines.append(f"{pad}{key}:")
                lines.append(to_yaml(value, indent + 1))
            else:
                lines.append(f"{pad}{key}: {_scalar(value)}")
    elif isinstance(doc, list):
        for item in doc:
            if isinstance(item, dict):
                body = to_yaml(item, indent + 1).lstrip()
                lines.append(f"{pad}- {body}")
            else:
                lines.append(f"{pad}- {_scalar(item)}")
    else:
        lines.append(pad + _scalar(doc))
    return "\n".join(lines)


def _inline(value: Any) -> bool:
    return isinstance(value, list) and all(isinstance(v, (str, int, float)) for v in value)


def _scalar(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, (list, dict)):
        return json.dumps(value)  # flow style: JSON is valid YAML
    return json.dumps(str(value))


def write_compose(path: Path, n: int, scenario: str, run: str = "compose", keys_dir: str | None = None) -> Path:
    """Write the compose file; ``keys_dir`` (relative to it) must hold the team's keys."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    secure = (f"; mutual TLS with the keys in {keys_dir}/ (coload keys init, made by coload compose)"
              if keys_dir is not None else "; plain TCP (--insecure)")
    header = (f"# Generated by `coload compose --agents {n}`: a Zenoh router, the simulator and {n} agents{secure}.\n"
              "# From the repository root: docker compose -f docker/compose.yaml up --build\n")
    path.write_text(header + to_yaml(compose_spec(n, scenario, run, keys_dir=keys_dir)) + "\n", encoding="utf-8")
    return path


def check_alive(connect: list[str] | Any, key: str | None, timeout: float) -> bool:
    """True if a client session opens on ``connect`` (endpoints, or a finished zenoh.Config: TLS)
    and, when ``key`` is given, a token matches it."""
    import zenoh

    from net.zenoh_transport import zenoh_config

    conf = zenoh_config(mode="client", connect=connect) if isinstance(connect, list) else connect
    try:
        session = zenoh.open(conf)
    except zenoh.ZError:
        return False
    with session:
        if key is None:
            return True
        return any(reply.ok is not None for reply in session.liveliness().get(key, timeout=timeout))
