"""Key expressions of a run, built and parsed in one place.

Every key lives under ``coload/{run}/`` so that concurrent runs on one router never hear each other::

    coload/{run}/agent/{i}/meas       simulator -> agent i
    coload/{run}/agent/{i}/wrench     agent i -> simulator
    coload/{run}/agent/{i}/state      agent i -> neighbours
    coload/{run}/agent/{i}/estimate   agent i -> observers
    coload/{run}/alive/{role}/{id}    liveliness tokens
    coload/{run}/sim/control          simulator run notices (start / stop / done)

Builders validate their inputs (a ``*`` or ``/`` smuggled into a run name would silently widen a
subscription); parsers return ``None`` for keys that are not ours, so callers can drop and count them.
Agent ids are canonical decimals (``7``, never ``07``), so each agent has exactly one key.
"""

from __future__ import annotations

from typing import Final, Literal, NamedTuple

ROOT: Final = "coload"
AGENT_KINDS: Final = ("meas", "wrench", "state", "estimate")
AgentKind = Literal["meas", "wrench", "state", "estimate"]
MAX_CHUNK: Final = 128
_FORBIDDEN: Final = frozenset("/*$#?")


class AgentKey(NamedTuple):
    run: str
    agent: int
    kind: str


class AliveKey(NamedTuple):
    run: str
    role: str
    id: str


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


def validate_run(run: str) -> str:
    """Return ``run`` if it is a valid run name, else raise ``ValueError``."""
    return _check_chunk("run name", run)


def _check_agent(i: int) -> int:
    if type(i) is not int or i < 0:
        raise ValueError(f"agent id must be a non-negative int: {i!r}")
    return i


def _check_kind(kind: str) -> str:
    if kind not in AGENT_KINDS:
        raise ValueError(f"agent key kind must be one of {AGENT_KINDS}: {kind!r}")
    return kind


def agent_key(run: str, i: int, kind: AgentKind) -> str:
    """``coload/{run}/agent/{i}/{kind}``."""
    return f"{ROOT}/{validate_run(run)}/agent/{_check_agent(i)}/{_check_kind(kind)}"


def meas_key(run: str, i: int) -> str:
    return agent_key(run, i, "meas")


def wrench_key(run: str, i: int) -> str:
    return agent_key(run, i, "wrench")


def state_key(run: str, i: int) -> str:
    return agent_key(run, i, "state")


def estimate_key(run: str, i: int) -> str:
    return agent_key(run, i, "estimate")


def agent_wildcard(run: str, kind: AgentKind | None = None) -> str:
    """``coload/{run}/agent/*/{kind}`` (every agent's ``kind``), or ``coload/{run}/agent/**``."""
    if kind is None:
        return f"{ROOT}/{validate_run(run)}/agent/**"
    return f"{ROOT}/{validate_run(run)}/agent/*/{_check_kind(kind)}"


def parse_agent_key(key: str) -> AgentKey | None:
    """``coload/{run}/agent/{i}/{kind}`` -> ``AgentKey(run, i, kind)``; ``None`` for any other key."""
    parts = key.split("/")
    if len(parts) != 5 or parts[0] != ROOT or parts[2] != "agent" or parts[4] not in AGENT_KINDS:
        return None
    run, i = parts[1], parts[3]
    if not _is_chunk(run) or not i.isascii() or not i.isdigit() or (len(i) > 1 and i[0] == "0"):
        return None
    return AgentKey(run, int(i), parts[4])


def alive_key(run: str, role: str, id: int | str) -> str:
    """``coload/{run}/alive/{role}/{id}``: the liveliness token of one daemon."""
    ident = str(_check_agent(id)) if isinstance(id, int) else _check_chunk("id", id)
    return f"{ROOT}/{validate_run(run)}/alive/{_check_chunk('role', role)}/{ident}"


def alive_wildcard(run: str, role: str | None = None) -> str:
    """``coload/{run}/alive/**`` (every daemon) or ``coload/{run}/alive/{role}/*``."""
    if role is None:
        return f"{ROOT}/{validate_run(run)}/alive/**"
    return f"{ROOT}/{validate_run(run)}/alive/{_check_chunk('role', role)}/*"


def parse_alive_key(key: str) -> AliveKey | None:
    """``coload/{run}/alive/{role}/{id}`` -> ``AliveKey(run, role, id)``; ``None`` otherwise."""
    parts = key.split("/")
    if len(parts) != 5 or parts[0] != ROOT or parts[2] != "alive" or not all(map(_is_chunk, parts[1:])):
        return None
    return AliveKey(parts[1], parts[3], parts[4])


def sim_control_key(run: str) -> str:
    """``coload/{run}/sim/control``: the simulator's run start / stop / done notices."""
    return f"{ROOT}/{validate_run(run)}/sim/control"


def run_wildcard(run: str) -> str:
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
