"""Key expressions: builders and parsers agree, foreign keys parse to None, wildcards match as Zenoh's."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from net import keys
from net.keys import AGENT_KINDS, AgentKey, AliveKey

runs = st.text(
    alphabet=st.characters(blacklist_characters="/*$#?", blacklist_categories=("Zs", "Cc", "Cs", "Zl", "Zp")),
    min_size=1,
    max_size=40,
).filter(lambda s: s.isprintable() and not any(c.isspace() for c in s))


def test_layout_is_the_documented_one() -> None:
    assert keys.meas("r1", 0) == "coload/r1/agent/0/meas"
    assert keys.wrench("r1", 12) == "coload/r1/agent/12/wrench"
    assert keys.state("r1", 3) == "coload/r1/agent/3/state"
    assert keys.estimate("r1", 3) == "coload/r1/agent/3/estimate"
    assert keys.alive("r1", "agent", 3) == "coload/r1/alive/agent/3"
    assert keys.alive("r1", "sim", 0) == "coload/r1/alive/sim/0"
    assert keys.report("r1", 2) == "coload/r1/agent/2/report"
    assert keys.sim_control("r1") == "coload/r1/sim/control"
    assert keys.agent_all("r1", "estimate") == "coload/r1/agent/*/estimate"
    assert keys.agent_all("r1") == "coload/r1/agent/**"
    assert keys.alive_all("r1") == "coload/r1/alive/**"
    assert keys.alive_all("r1", "agent") == "coload/r1/alive/agent/*"
    assert keys.run_all("r1") == "coload/r1/**"


@given(runs, st.integers(0, 10**6), st.sampled_from(AGENT_KINDS))
def test_agent_keys_round_trip(run: str, i: int, kind: str) -> None:
    key = keys.agent(run, i, kind)  # type: ignore[arg-type]
    assert keys.parse_agent_key(key) == AgentKey(run, i, kind)
    assert keys.key_matches(keys.agent_all(run, kind), key)  # type: ignore[arg-type]
    assert keys.key_matches(keys.run_all(run), key)
    assert keys.parse_alive(key) is None


@given(runs, st.sampled_from(["agent", "sim", "recorder"]) | runs, st.integers(0, 10**6))
def test_alive_keys_round_trip(run: str, role: str, ident: int) -> None:
    key = keys.alive(run, role, ident)
    assert keys.parse_alive(key) == AliveKey(run, role, ident)
    assert type(keys.parse_alive(key).id) is int  # type: ignore[union-attr]
    assert keys.key_matches(keys.alive_all(run), key)
    assert keys.key_matches(keys.alive_all(run, role), key)
    assert keys.parse_agent_key(key) is None


@pytest.mark.parametrize(
    "key",
    [
        "",
        "coload",
        "coload/r/agent/1",
        "coload/r/agent/1/meas/x",
        "other/r/agent/1/meas",
        "coload/r/agents/1/meas",
        "coload/r/agent/01/meas",
        "coload/r/agent/-1/meas",
        "coload/r/agent/+1/meas",
        "coload/r/agent/1.0/meas",
        "coload/r/agent/\u0661/meas",  # Arabic-Indic digit one: isdigit() but not ASCII
        "coload/r/agent/x/meas",
        "coload/r/agent/1/velocity",
        "coload/*/agent/1/meas",
        "coload//agent/1/meas",
        "coload/r/sim/control",
    ],
)
def test_foreign_agent_keys_parse_to_none(key: str) -> None:
    assert keys.parse_agent_key(key) is None


@pytest.mark.parametrize(
    "key",
    [
        "coload/r/alive/agent",
        "coload/r/alive/agent/1/x",
        "coload/r/alive/*/1",
        "coload/r/alive//1",
        "coload/r/alive/agent/main",
        "coload/r/alive/agent/007",
        "coload/r/alive/agent/-1",
        "coload/*/alive/agent/1",
    ],
)
def test_foreign_alive_keys_parse_to_none(key: str) -> None:
    assert keys.parse_alive(key) is None


@pytest.mark.parametrize("run", ["", "a/b", "a*", "**", "$*", "a#b", "a?b", "a b", "a\tb", "a\nb", "\x00", "x" * 129])
def test_bad_run_names_are_refused(run: str) -> None:
    with pytest.raises(ValueError):
        keys.validate_run(run)
    with pytest.raises(ValueError):
        keys.state(run, 0)
    with pytest.raises(ValueError):
        keys.alive_all(run)


def test_bad_ids_roles_and_kinds_are_refused() -> None:
    for bad in (-1, True, 1.0, "1"):
        with pytest.raises(ValueError):
            keys.state("r", bad)  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        keys.agent("r", 1, "velocity")  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        keys.alive("r", "a/b", 1)
    with pytest.raises(ValueError):
        keys.alive("r", "agent", "*")  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        keys.alive("r", "agent", "0")  # type: ignore[arg-type]


@pytest.mark.parametrize(
    "expr, key, expected",
    [
        ("a/b/c", "a/b/c", True),
        ("a/b/c", "a/b", False),
        ("a/*/c", "a/b/c", True),
        ("a/*/c", "a/b/x/c", False),
        ("a/*", "a", False),
        ("a/**", "a", True),
        ("a/**", "a/b/c/d", True),
        ("**", "a/b", True),
        ("a/**/d", "a/d", True),
        ("a/**/d", "a/b/c/d", True),
        ("a/**/d", "a/b/c/e", False),
        ("a/**/c/**/e", "a/c/x/c/y/e", True),
        ("a/**/c/*", "a/b/c", False),
        ("a/b", "a/bb", False),
    ],
)
def test_key_matches(expr: str, key: str, expected: bool) -> None:
    assert keys.key_matches(expr, key) is expected


ids_text = st.one_of(st.text(max_size=12), st.from_regex(r"\A[0-9]{1,6000}\Z"), st.just("0" * 5000 + "1"))


@given(st.lists(st.one_of(st.text(max_size=12), ids_text, st.sampled_from(["coload", "agent", "alive", "hinf",
                                                                            "wrench", "sim", "r1"])),
                max_size=7))
def test_parsers_return_none_for_any_foreign_key(chunks: list[str]) -> None:
    """Whatever arrives on a wildcard subscription (a digit run longer than int() takes included),
    the parsers answer a key or None, never raise."""
    key = "/".join(chunks)
    for parse in (keys.parse_agent_key, keys.parse_alive, keys.parse_hinf_key):
        out = parse(key)
        assert out is None or isinstance(out, tuple)


def test_an_over_long_agent_id_is_foreign() -> None:
    assert keys.parse_agent_key("coload/r1/agent/" + "9" * 5000 + "/wrench") is None
    assert keys.parse_agent_key("coload/r1/agent/123456789/wrench") is not None
