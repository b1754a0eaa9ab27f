"""A team's keys: a run CA, one key and certificate per role, and the manifest the policy is built from.

``init_team`` writes into a directory ``ca.pem``/``ca.key`` (the team's certificate authority),
``{role}.pem``/``{role}.key`` for the router, the simulator, the monitor (read-only) and every agent,
``team.json`` (the run name the policy is for, the graph, every role's current generation and
the router's endpoint) and ``{role}.json5``, each role's Zenoh config (for ``-c``, or Zenoh's own
tools; absolute paths to the files). ``add_agent`` issues a certificate for a late joiner or replaces an agent's:
the replacement's common name carries the next generation, and the policy (built from ``team.json``)
names only current generations, so the replaced certificate may do nothing once the router runs the
new policy. Certificates expire after ``days``. The clock is an argument; keys come from the OS's
randomness. See docs/security.md.
"""

from __future__ import annotations

import datetime as dt
import ipaddress
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from net import access_policy as ap

MANIFEST: Final = "team.json"
CA_KEY: Final = "ca.key"
FORMAT: Final = 1
DEFAULT_HOSTS: Final = ("localhost", "127.0.0.1", "router")
"""Names the router's certificate is valid for (``router``: the compose service)."""


class KeysError(ValueError):
    """A keys directory that cannot be used as asked (one line, for the CLI)."""


@dataclass
class Team:
    """What ``team.json`` holds."""

    run: str
    neighbours: list[list[int]]
    generations: dict[str, int]
    endpoint: str
    hosts: list[str] = field(default_factory=lambda: list(DEFAULT_HOSTS))
    days: float = 30.0

    @property
    def n(self) -> int:
        return len(self.neighbours)

    def common_names(self) -> dict[str, str]:
        return {role: ap.common_name(role, g) for role, g in self.generations.items()}

    def to_json(self) -> str:
        return json.dumps({"format": FORMAT, "run": self.run, "neighbours": self.neighbours,
                           "generations": self.generations, "endpoint": self.endpoint, "hosts": self.hosts,
                           "days": self.days}, indent=1) + "\n"


def role_config(tls_dir: str | Path, team: Team, role: str) -> dict[str, Any]:
    """A role's whole Zenoh config: client (or router), the team's endpoint, no scouting, mutual TLS
    and, for the router, the access-control list."""
    router = role == ap.ROUTER
    conf: dict[str, Any] = {
        "mode": "router" if router else "client",
        "connect": {"endpoints": [] if router else [team.endpoint]},
        "listen": {"endpoints": [team.endpoint] if router else []},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"link": {"tls": ap.tls_block(tls_dir, role)}},
    }
    if router:
        conf["access_control"] = ap.access_control(team.run, team.neighbours, team.common_names())
    return conf


def _write_configs(tls_dir: Path, team: Team) -> None:
    for role in team.generations:
        text = json.dumps(role_config(tls_dir, team, role), indent=1) + "\n"
        _write(tls_dir / f"{role}.json5", text.encode(), private=False)


def load_team(tls_dir: str | Path) -> Team:
    path = Path(tls_dir) / MANIFEST
    try:
        raw = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise KeysError(f"{path}: cannot read it ({exc.strerror}); make it with `coload keys init`") from None
    except ValueError as exc:
        raise KeysError(f"{path}: not JSON ({exc})") from None
    if not isinstance(raw, dict) or raw.get("format") != FORMAT:
        raise KeysError(f"{path}: not a coload team manifest (format {FORMAT})")
    try:
        return Team(run=str(raw["run"]), neighbours=[[int(j) for j in nb] for nb in raw["neighbours"]],
                    generations={str(k): int(v) for k, v in raw["generations"].items()},
                    endpoint=str(raw["endpoint"]), hosts=[str(h) for h in raw["hosts"]], days=float(raw["days"]))
    except (KeyError, TypeError, ValueError) as exc:
        raise KeysError(f"{path}: field {exc} missing or of the wrong type") from None


def _write(path: Path, data: bytes, private: bool) -> None:
    tmp = path.with_name(path.name + ".tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600 if private else 0o644)
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    os.replace(tmp, path)


def _new_key() -> ec.EllipticCurvePrivateKey:
    return ec.generate_private_key(ec.SECP256R1())


def _key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def _validity(builder: x509.CertificateBuilder, now: dt.datetime, days: float) -> x509.CertificateBuilder:
    # a few minutes back: hosts whose clocks differ slightly still accept a fresh certificate
    return builder.not_valid_before(now - dt.timedelta(minutes=5)).not_valid_after(now + dt.timedelta(days=days))


def _make_ca(tls_dir: Path, now: dt.datetime, days: float) -> None:
    key = _new_key()
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "coload team CA")])
    usage = x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True, content_commitment=False,
                          key_encipherment=False, data_encipherment=False, key_agreement=False,
                          encipher_only=False, decipher_only=False)
    cert = (_validity(x509.CertificateBuilder(), now, days).subject_name(name).issuer_name(name)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(usage, critical=True)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
            .sign(key, hashes.SHA256()))
    _write(tls_dir / CA_KEY, _key_pem(key), private=True)
    _write(tls_dir / ap.CA_CERT, cert.public_bytes(serialization.Encoding.PEM), private=False)


def _issue(tls_dir: Path, role: str, cn: str, hosts: Sequence[str], now: dt.datetime, days: float) -> None:
    ca_key = serialization.load_pem_private_key((tls_dir / CA_KEY).read_bytes(), password=None)
    ca = x509.load_pem_x509_certificate((tls_dir / ap.CA_CERT).read_bytes())
    key = _new_key()
    alt: list[x509.GeneralName] = []
    for h in hosts if role == ap.ROUTER else ():
        try:
            alt.append(x509.IPAddress(ipaddress.ip_address(h)))
        except ValueError:
            alt.append(x509.DNSName(h))
    builder = (_validity(x509.CertificateBuilder(), now, days)
               .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)]))
               .issuer_name(ca.subject).public_key(key.public_key()).serial_number(x509.random_serial_number())
               .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
               .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH if role == ap.ROUTER
                                                     else ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
               .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()),
                              critical=False))
    if alt:
        builder = builder.add_extension(x509.SubjectAlternativeName(alt), critical=False)
    cert = builder.sign(ca_key, hashes.SHA256())
    _write(ap.key_path(tls_dir, role), _key_pem(key), private=True)
    _write(ap.cert_path(tls_dir, role), cert.public_bytes(serialization.Encoding.PEM), private=False)


def init_team(tls_dir: str | Path, neighbours: Sequence[Sequence[int]], *, run: str = "*",
              endpoint: str = "tls/127.0.0.1:7447", hosts: Sequence[str] = DEFAULT_HOSTS, days: float = 30.0,
              now: dt.datetime) -> Team:
    """Make a team's CA, every role's key and certificate and ``team.json`` in ``tls_dir`` (which
    must not hold a team already)."""
    d = Path(tls_dir)
    if (d / MANIFEST).exists() or (d / CA_KEY).exists():
        raise KeysError(f"{d} holds a team already (replace an agent with `coload keys add`)")
    if len(neighbours) < 1:
        raise KeysError("a team needs at least one agent")
    if days <= 0:
        raise KeysError(f"--days must be positive (got {days})")
    if run != "*":
        from net import keys

        keys.validate_run(run)
    d.mkdir(parents=True, exist_ok=True)
    team = Team(run=run, neighbours=[sorted(int(j) for j in nb) for nb in neighbours],
                generations={role: 1 for role in ap.roles(len(neighbours))}, endpoint=endpoint,
                hosts=list(hosts), days=float(days))
    _make_ca(d, now, days)
    for role, cn in team.common_names().items():
        _issue(d, role, cn, team.hosts, now, days)
    _write(d / MANIFEST, team.to_json().encode(), private=False)
    _write_configs(d, team)
    return team


def add_agent(tls_dir: str | Path, i: int, *, neighbours: Sequence[Sequence[int]] | None = None,
              now: dt.datetime) -> Team:
    """Issue agent ``i``'s certificate: a replacement (next generation: the old one is revoked by the
    policy) or, for ``i == n``, a late joiner (``neighbours``: the grown team's graph)."""
    d = Path(tls_dir)
    team = load_team(d)
    if neighbours is not None:
        if len(neighbours) < max(team.n, i + 1):
            raise KeysError(f"the scenario has {len(neighbours)} agents: no agent {i}")
        team.neighbours = [sorted(int(j) for j in nb) for nb in neighbours]
    if not 0 <= i < team.n:
        raise KeysError(f"agent {i} is not in the team (0..{team.n - 1}); give the grown team's --scenario")
    role = ap.agent_role(i)
    joined = [ap.agent_role(j) for j in range(team.n) if ap.agent_role(j) not in team.generations]
    for r in joined:
        team.generations[r] = 0
    for r in {role, *joined}:
        team.generations[r] += 1  # a joiner's first generation, a replacement's next
        _issue(d, r, ap.common_name(r, team.generations[r]), team.hosts, now, team.days)
    _write(d / MANIFEST, team.to_json().encode(), private=False)
    _write_configs(d, team)
    return team


def certificate_info(path: str | Path) -> dict[str, Any]:
    """Common name and validity of a certificate file (for ``coload keys`` output and tests)."""
    cert = x509.load_pem_x509_certificate(Path(path).read_bytes())
    cn = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value
    return {"cn": cn, "not_after": cert.not_valid_after_utc.isoformat(), "serial": cert.serial_number}
