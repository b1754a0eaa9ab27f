"""Who may say and hear what in a team: the Zenoh access-control list and each role's TLS settings.

A team's roles are ``router``, ``sim``, ``agent-{i}`` and ``monitor`` (read-only). Each holds a key
and a certificate signed by the team's CA; the certificate's common name is ``{role}.g{generation}``
(a replaced agent gets the next generation, and the policy names only the current one, so the old
certificate is in no policy and may do nothing). :func:`access_control` is the router's
``access_control`` block: default deny, and per role an allow-list of what it may put and hear,
by exact key (the scenario's graph decides which states an agent hears), for coload's own run
and for the paper-003 runtime's keys (``hinf/``, the same roles). :func:`tls_block` is the
``transport/link/tls`` block of a role (mutual TLS; the router listens, the others connect).
See docs/security.md.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Final

from net import keys

ROUTER: Final = "router"
SIM: Final = "sim"
MONITOR: Final = "monitor"
CA_CERT: Final = "ca.pem"


def agent_role(i: int) -> str:
    return f"agent-{i}"


def roles(n: int) -> list[str]:
    """Every role of a team of ``n`` agents."""
    return [ROUTER, SIM, MONITOR, *(agent_role(i) for i in range(n))]


def common_name(role: str, generation: int) -> str:
    """``{role}.g{generation}``: the certificate common name the policy allows."""
    if generation < 1:
        raise ValueError(f"generation must be >= 1: {generation}")
    return f"{role}.g{generation}"


def cert_path(tls_dir: str | Path, role: str) -> Path:
    return Path(tls_dir) / f"{role}.pem"


def key_path(tls_dir: str | Path, role: str) -> Path:
    return Path(tls_dir) / f"{role}.key"


def tls_block(tls_dir: str | Path, role: str) -> dict[str, Any]:
    """The ``transport/link/tls`` block of ``role``: mutual TLS with the team's CA, the role's own
    key and certificate (as listener for the router, as connector for the others). The router's
    name is verified on connect (its certificate names the hosts it serves)."""
    d = Path(tls_dir).resolve()
    block: dict[str, Any] = {"root_ca_certificate": str(d / CA_CERT), "enable_mtls": True,
                             "verify_name_on_connect": True}
    side = "listen" if role == ROUTER else "connect"
    block[f"{side}_private_key"] = str(key_path(d, role))
    block[f"{side}_certificate"] = str(cert_path(d, role))
    return block


def _rule(rid: str, messages: Sequence[str], key_exprs: Sequence[str], flows: Sequence[str]) -> dict[str, Any]:
    return {"id": rid, "permission": "allow", "flows": list(flows), "messages": list(messages),
            "key_exprs": sorted(set(key_exprs))}


def _allow(rid: str, put: Sequence[str], hear: Sequence[str], tokens: Sequence[str],
           watch: Sequence[str], matched_by: Sequence[str] = ()) -> list[dict[str, Any]]:
    """The rules of one role: ``put`` keys it publishes, ``hear`` keys it subscribes to, liveliness
    ``tokens`` it declares and key expressions it ``watch``es tokens on. A publisher learns of the
    subscribers on its ``put`` keys and on ``matched_by`` (the wildcard subscriptions of other roles
    that match them): a Zenoh client sends a put only where it knows a subscriber."""
    rules = []
    if put:
        rules.append(_rule(f"{rid}/put", ["put"], put, ["ingress"]))
        rules.append(_rule(f"{rid}/put-match", ["declare_subscriber"], [*put, *matched_by], ["egress"]))
    if hear:
        rules.append(_rule(f"{rid}/hear", ["declare_subscriber"], hear, ["ingress"]))
        rules.append(_rule(f"{rid}/hear-data", ["put"], list(hear), ["egress"]))
    if tokens:
        rules.append(_rule(f"{rid}/token", ["liveliness_token"], tokens, ["ingress"]))
    if watch:
        rules.append(_rule(f"{rid}/watch", ["declare_liveliness_subscriber", "liveliness_query"], watch, ["ingress"]))
        rules.append(_rule(f"{rid}/watch-data", ["liveliness_token", "reply"], watch, ["egress"]))
    return rules


def role_rules(run: str, neighbours: Sequence[Sequence[int]]) -> dict[str, list[dict[str, Any]]]:
    """role -> its allow rules, for a run named ``run`` (``*``: any run) whose agent i hears the
    states of ``neighbours[i]``."""
    n = len(neighbours)
    r = run if run == "*" else keys.validate_run(run)
    root = f"{keys.ROOT}/{r}"

    def ak(i: int | str, kind: str) -> str:
        return f"{root}/agent/{i}/{kind}"

    alive_all = f"{root}/alive/**"
    control = f"{root}/sim/control"
    pose = f"{root}/sim/pose"
    hinf_control = f"{root}/hinf/control"

    def hk(k: int | str, kind: str) -> str:  # the paper-003 runtime (coload hinf run): the same roles
        return f"{root}/hinf/{k}/{kind}"

    out = {
        SIM: _allow(SIM, put=[ak("*", "meas"), control, pose, hk("*", "meas"), hinf_control],
                    hear=[ak("*", "wrench"), ak("*", "estimate"), ak("*", "report"), hk("*", "input"),
                          hk("*", "report")],
                    tokens=[f"{root}/alive/sim/0", f"{root}/alive/hinfsim/0"], watch=[alive_all]),
        MONITOR: _allow(MONITOR, put=[], hear=[ak("*", "estimate"), control, pose, hinf_control], tokens=[],
                        watch=[alive_all]),
    }
    for i in range(n):
        role = agent_role(i)
        out[role] = _allow(role, put=[*(ak(i, k) for k in ("wrench", "state", "estimate", "report")),
                                      *(hk(i, k) for k in ("input", "state", "report"))],
                           hear=[ak(i, "meas"), control, *(ak(j, "state") for j in neighbours[i]),
                                 hk(i, "meas"), hinf_control, *(hk(j, "state") for j in neighbours[i])],
                           tokens=[f"{root}/alive/agent/{i}", f"{root}/alive/hinf/{i}"], watch=[alive_all],
                           matched_by=[*(ak("*", k) for k in ("wrench", "estimate", "report")),
                                       *(hk("*", k) for k in ("input", "report"))])
    return out


def access_control(run: str, neighbours: Sequence[Sequence[int]], cns: Mapping[str, str]) -> dict[str, Any]:
    """The router's ``access_control`` block: default deny; each role in ``cns`` (role -> the
    certificate common name it holds now) gets its rules; a common name in no policy gets nothing."""
    rules: list[dict[str, Any]] = []
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    for role, rs in role_rules(run, neighbours).items():
        if role not in cns:
            continue
        rules += rs
        subjects.append({"id": role, "cert_common_names": [cns[role]]})
        policies.append({"id": role, "rules": [x["id"] for x in rs], "subjects": [role]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}
