"""Key expressions of a run, built and parsed in one place.

Every key lives under ``coload/{run}/`` so that concurrent runs on one router never hear each other::

    coload/{run}/agent/{i}/meas       simulator -> agent i             meas(run, i)
    coload/{run}/agent/{i}/wrench     agent i -> simulator             wrench(run, i)
    coload/{run}/agent/{i}/state      agent i -> neighbours            state(run, i)
    coload/{run}/agent/{i}/estimate   agent i -> observers             estimate(run, i)
    coload/{run}/agent/{i}/report     agent i -> simulator, at the end report(run, i)
    coload/{run}/alive/{role}/{id}    liveliness tokens                alive(run, role, id)
    coload/{run}/sim/control          simulator run notices            sim_control(run)
    coload/{run}/sim/pose             simulator -> monitors: the load  sim_pose(run)
    coload/{run}/hinf/{k}/{kind}      paper-003 runtime (meas, input,  hinf(run, k, kind)
                                      state, report)
    coload/{run}/hinf/control         its simulator's run notices      hinf_control(run)

Builders validate their inputs (a ``*`` or ``/`` smuggled into a run name would silently widen a
subscription); parsers return ``None`` for keys that are not ours, so callers can drop and count them.
Ids are canonical decimals (``7``, never ``07``), so each daemon has exactly one key, and parse back
to ``int``.
"""

from __future__ import annotations

from typing import Final, Literal, NamedTuple

ROOT: Final = "coload"
AGENT_KINDS: Final = ("meas", "wrench", "state", "estimate", "report")
AgentKind = Literal["meas", "wrench", "state", "estimate", "report"]
MAX_CHUNK: Final = 128
WRONG_KEY: Final = "wrong_key"
"""Drop reason of a message that arrived on another key than its own: a put on a wider key expression
(``coload/{run}/agent/*/meas``, ``coload/{run}/**``) that a subscription matched. Zenoh delivers such
a put to every matching subscriber under the key it was put on; a daemon accepts a message only on
the exact key of its kind and sender, so a deny rule on an exact key cannot be bypassed that way."""
_FORBIDDEN: Final = frozenset("/*$#?")


class AgentKey(NamedTuple):
    run: str
    agent: int
    kind: str


class AliveKey(NamedTuple):
    run: str
    role: str
    id: int


def _check_chunk(what: str, s: str) -> str:
    """A chunk must be one non-empty, printable, wildcard-free key-expression chunk."""
    if not isinstance(s, str) or not s or len(s) > MAX_CHUNK:
        raise ValueError(f"{what} must be a non-empty string of at most {MAX_CHUNK} characters: {s!r}")
    if not s.isprintable() or any(c in _FORBIDDEN or c.isspace() for c in s):
        raise ValueError(f"{what} {s!r} may not contain '/', '*', '$', '#', '?', whitespace or control characters")
    return s


def _is_chunk(s: str) -> bool:
    try:
        _check_chunk("chunk", s)
    except ValueError:
        return False
    return True


def _parse_id(s: str) -> int | None:
    """Canonical non-negative decimal -> int; anything else (``07``, ``+1``, non-ASCII digits) -> None."""
    if len(s) > 9 or not s.isascii() or not s.isdigit() or (len(s) > 1 and s[0] == "0"):
        return None  # > 9 digits: no agent id is that large (and int() refuses > 4300 digits)
    return int(s)


def validate_run(run: str) -> str:
    """Return ``run`` if it is a valid run name, else raise ``ValueError``."""
    return _check_chunk("run name", run)


def _check_id(i: int) -> int:
    if type(i) is not int or i < 0:
        raise ValueError(f"id must be a non-negative int: {i!r}")
    return i


def _check_kind(kind: str) -> str:
    if kind not in AGENT_KINDS:
        raise ValueError(f"agent key kind must be one of {AGENT_KINDS}: {kind!r}")
    return kind


def agent(run: str, i: int, kind: AgentKind) -> str:
    """``coload/{run}/agent/{i}/{kind}``."""
    return f"{ROOT}/{validate_run(run)}/agent/{_check_id(i)}/{_check_kind(kind)}"


def meas(run: str, i: int) -> str:
    return agent(run, i, "meas")


def wrench(run: str, i: int) -> str:
    return agent(run, i, "wrench")


def state(run: str, i: int) -> str:
    return agent(run, i, "state")


def estimate(run: str, i: int) -> str:
    return agent(run, i, "estimate")


def report(run: str, i: int) -> str:
    return agent(run, i, "report")


def agent_all(run: str, kind: AgentKind | None = None) -> str:
    """``coload/{run}/agent/*/{kind}`` (every agent's ``kind``), or ``coload/{run}/agent/**``."""
    if kind is None:
        return f"{ROOT}/{validate_run(run)}/agent/**"
    return f"{ROOT}/{validate_run(run)}/agent/*/{_check_kind(kind)}"


def parse_agent_key(key: str) -> AgentKey | None:
    """``coload/{run}/agent/{i}/{kind}`` -> ``AgentKey(run, i, kind)``; ``None`` for any other key."""
    parts = key.split("/")
    if len(parts) != 5 or parts[0] != ROOT or parts[2] != "agent" or parts[4] not in AGENT_KINDS:
        return None
    i = _parse_id(parts[3])
    if i is None or not _is_chunk(parts[1]):
        return None
    return AgentKey(parts[1], i, parts[4])


def alive(run: str, role: str, i: int) -> str:
    """``coload/{run}/alive/{role}/{i}``: the liveliness token of one daemon (``role`` e.g. agent, sim)."""
    return f"{ROOT}/{validate_run(run)}/alive/{_check_chunk('role', role)}/{_check_id(i)}"


def alive_all(run: str, role: str | None = None) -> str:
    """``coload/{run}/alive/**`` (every daemon) or ``coload/{run}/alive/{role}/*``."""
    if role is None:
        return f"{ROOT}/{validate_run(run)}/alive/**"
    return f"{ROOT}/{validate_run(run)}/alive/{_check_chunk('role', role)}/*"


def parse_alive(key: str) -> AliveKey | None:
    """``coload/{run}/alive/{role}/{i}`` -> ``AliveKey(run, role, i)``; ``None`` otherwise."""
    parts = key.split("/")
    if len(parts) != 5 or parts[0] != ROOT or parts[2] != "alive":
        return None
    i = _parse_id(parts[4])
    if i is None or not _is_chunk(parts[1]) or not _is_chunk(parts[3]):
        return None
    return AliveKey(parts[1], parts[3], i)


def sim_control(run: str) -> str:
    """``coload/{run}/sim/control``: the simulator's run notices (start / progress / done)."""
    return f"{ROOT}/{validate_run(run)}/sim/control"


def sim_pose(run: str) -> str:
    """``coload/{run}/sim/pose``: the load's true pose on recorded ticks, for live views (monitoring only)."""
    return f"{ROOT}/{validate_run(run)}/sim/pose"


def run_all(run: str) -> str:
    """``coload/{run}/**``: everything of one run (recorders, debugging)."""
    return f"{ROOT}/{validate_run(run)}/**"


def key_matches(key_expr: str, key: str) -> bool:
    """True if the concrete ``key`` is matched by ``key_expr``.

    Supports the Zenoh wildcards coload uses: ``*`` matches exactly one chunk, ``**`` any number of
    chunks (zero included). Chunk-internal ``*`` (``ab*``) and the ``$*`` DSL are not supported and
    match literally. This is what :class:`net.memory.MemoryBus` routes with.
    """
    return _match(key_expr.split("/"), key.split("/"))


def _match(pat: list[str], chunks: list[str]) -> bool:
    # Iterative matcher with backtracking on the last '**' (glob-style), linear in practice.
    p = c = 0
    star_p = star_c = -1
    while c < len(chunks):
        if p < len(pat) and pat[p] == "**":
            star_p, star_c = p, c
            p += 1
        elif p < len(pat) and (pat[p] == "*" or pat[p] == chunks[c]):
            p += 1
            c += 1
        elif star_p >= 0:
            star_c += 1
            p, c = star_p + 1, star_c
        else:
            return False
    while p < len(pat) and pat[p] == "**":
        p += 1
    return p == len(pat)


# ---- paper 003 runtime (coload hinf run) ---------------------------------------------------------
HINF_KINDS: Final = ("meas", "input", "state", "report")
"""``meas`` simulator -> estimator k (z^(k)); ``input`` k -> simulator (u_k and the estimate);
``state`` k -> its out-neighbours; ``report`` k -> simulator at the end (receive-side counters)."""


def hinf(run: str, k: int, kind: str) -> str:
    """``coload/{run}/hinf/{k}/{kind}``."""
    if kind not in HINF_KINDS:
        raise ValueError(f"hinf key kind must be one of {HINF_KINDS}: {kind!r}")
    return f"{ROOT}/{validate_run(run)}/hinf/{_check_id(k)}/{kind}"


def hinf_all(run: str, kind: str) -> str:
    """``coload/{run}/hinf/*/{kind}``: that kind from every estimator."""
    if kind not in HINF_KINDS:
        raise ValueError(f"hinf key kind must be one of {HINF_KINDS}: {kind!r}")
    return f"{ROOT}/{validate_run(run)}/hinf/*/{kind}"


def parse_hinf_key(key: str) -> AgentKey | None:
    """``coload/{run}/hinf/{k}/{kind}`` -> ``AgentKey(run, k, kind)``; ``None`` for any other key."""
    parts = key.split("/")
    if len(parts) != 5 or parts[0] != ROOT or parts[2] != "hinf" or parts[4] not in HINF_KINDS:
        return None
    k = _parse_id(parts[3])
    if k is None or not _is_chunk(parts[1]):
        return None
    return AgentKey(parts[1], k, parts[4])


def hinf_control(run: str) -> str:
    """``coload/{run}/hinf/control``: the hinf simulator's run notices (start / progress / done)."""
    return f"{ROOT}/{validate_run(run)}/hinf/control"
