"""Wire codec: exact round trips, and every malformed payload rejected with DecodeError only."""

from __future__ import annotations

import math
import struct

import msgpack
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from net.hinf_messages import HinfInput, HinfMeas, HinfState
from net.messages import AgentReport, Control, Estimate, LoadPose, Measurement, StateMsg, Wrench
from net.schema import (
    KIND,
    MAX_AGENT_ID,
    MAX_NAMES,
    MAX_PAIRS,
    MAX_PAIR_LEN,
    MAX_PAYLOAD,
    MAX_TICK,
    REASONS,
    SCHEMA_VERSION,
    DecodeError,
    decode,
    encode,
    is_finite_message,
)

TYPES = [Measurement, Wrench, StateMsg, Estimate, Control, AgentReport, LoadPose, HinfMeas, HinfState, HinfInput]

finite = st.floats(allow_nan=False, allow_infinity=False)
ticks = st.integers(0, MAX_TICK)
ids = st.integers(0, MAX_AGENT_ID)
names = st.text(min_size=1, max_size=64)

measurements = st.builds(Measurement, tick=ticks, agent=ids, vx=finite, vy=finite)
wrenches = st.builds(Wrench, tick=ticks, agent=ids, fx=finite, fy=finite, tau=finite)
states = st.builds(
    StateMsg,
    tick=ticks,
    sender=ids,
    vx=finite,
    vy=finite,
    phase=st.integers(0, 65_535),
    shared=st.dictionaries(names, finite, max_size=8),
    pair=st.dictionaries(ids, st.tuples(finite, finite, finite) | st.lists(finite, max_size=16).map(tuple), max_size=8),
)
estimates = st.builds(
    Estimate,
    tick=ticks,
    agent=ids,
    values=st.dictionaries(names, finite | st.just(math.nan), max_size=16),
    pairs=st.dictionaries(ids, st.tuples(finite, finite), max_size=8),
)
counts = st.integers(0, 2**63 - 1)
controls = st.builds(Control, kind=st.sampled_from(["start", "progress", "stop", "done"]), tick=ticks, ticks=ticks)
reports = st.builds(
    AgentReport,
    agent=ids,
    links=st.dictionaries(ids, st.dictionaries(names, counts, max_size=6), max_size=6),
    drops=st.dictionaries(names, counts, max_size=6),
    timeouts=counts,
    ticks=ticks,
)
vectors = st.lists(finite, max_size=8).map(tuple)
poses = st.builds(LoadPose, tick=ticks, x=finite, y=finite, angle=finite, pg_x=finite, pg_y=finite, z=vectors)
hinf_meas = st.builds(HinfMeas, tick=ticks, agent=ids, z=vectors)
hinf_states = st.builds(HinfState, tick=ticks, sender=ids, xhat=vectors, u=vectors, zeta=vectors)
hinf_inputs = st.builds(HinfInput, tick=ticks, agent=ids, u=vectors, xhat=vectors, zeta=vectors)
messages = st.one_of(measurements, wrenches, states, estimates, controls, reports, poses, hinf_meas, hinf_states,
                     hinf_inputs)


def _same(a: object, b: object) -> bool:
    """Exact equality that tells -0.0 from 0.0 and equates NaNs (repr round-trips every float)."""
    return repr(a) == repr(b)


@given(messages)
def test_round_trip_is_exact(msg: Measurement | Wrench | StateMsg | Estimate) -> None:
    out = decode(encode(msg), type(msg))
    assert type(out) is type(msg)
    assert _same(out, msg)


@given(messages)
def test_decoding_as_another_type_is_wrong_kind(msg: Measurement | Wrench | StateMsg | Estimate) -> None:
    payload = encode(msg)
    for other in TYPES:
        if other is not type(msg):
            with pytest.raises(DecodeError) as e:
                decode(payload, other)
            assert e.value.reason == "wrong_kind"


def test_ints_given_for_floats_travel_as_floats() -> None:
    out = decode(encode(Wrench(tick=1, agent=0, fx=1, fy=0, tau=-2)), Wrench)  # type: ignore[arg-type]
    assert all(type(v) is float for v in (out.fx, out.fy, out.tau))


def test_encode_refuses_non_messages_and_oversized() -> None:
    with pytest.raises(TypeError):
        encode({"tick": 1})  # type: ignore[arg-type]
    big = StateMsg(0, 0, 0.0, 0.0, pair={j: (1.0,) * 16 for j in range(1000)})
    with pytest.raises(ValueError, match="MAX_PAYLOAD"):
        encode(big)


def test_estimate_values_may_be_nan() -> None:
    """NaN in an estimate means "not available this tick"; estimates are recorded, not computed with."""
    out = decode(encode(Estimate(3, 1, {"omega": 0.5, "omega_local": math.nan})), Estimate)
    assert out.values["omega"] == 0.5 and math.isnan(out.values["omega_local"])


def test_is_finite_message() -> None:
    assert is_finite_message(StateMsg(0, 0, 0.0, 0.0, shared={"a": 1.0}, pair={1: (2.0,)}))
    assert not is_finite_message(StateMsg(0, 0, 0.0, 0.0, pair={1: (math.nan,)}))
    assert not is_finite_message(Estimate(0, 0, {"m": math.inf}))
    assert is_finite_message(Control("done", 3, 3))


# ---------------------------------------------------------------------------------------------
# Rejection


def _payload(kind: str, body: dict, version: int = SCHEMA_VERSION) -> bytes:
    return msgpack.packb((kind, version, body), use_bin_type=True)


GOOD = {
    Measurement: {"tick": 1, "agent": 2, "vx": 0.5, "vy": -0.5},
    Wrench: {"tick": 1, "agent": 2, "fx": 1.0, "fy": 2.0, "tau": 3.0},
    StateMsg: {"tick": 1, "sender": 2, "vx": 0.1, "vy": 0.2, "phase": 0, "shared": {"a": 1.0}, "pair": {3: (1.0, 2.0)}},
    Estimate: {"tick": 1, "agent": 2, "values": {"m": 50.0}, "pairs": {3: (0.1, 0.2)}},
    Control: {"kind": "progress", "tick": 5, "ticks": 100},
    AgentReport: {"agent": 2, "links": {1: {"sent": 3, "dropped": 1}}, "drops": {"stale": 2}, "timeouts": 0,
                  "ticks": 100},
    LoadPose: {"tick": 1, "x": 0.5, "y": -0.5, "angle": 0.1, "pg_x": 0.4, "pg_y": -0.3, "z": (1.0, 2.0, -1.0, -2.0)},
    HinfMeas: {"tick": 1, "agent": 2, "z": (0.1, -0.2)},
    HinfState: {"tick": 1, "sender": 2, "xhat": (1.0, 2.0), "u": (0.5,), "zeta": ()},
    HinfInput: {"tick": 1, "agent": 2, "u": (0.5,), "xhat": (1.0, 2.0), "zeta": (0.1,)},
}


def _reject(payload: object, typ: type, reason: str) -> None:
    with pytest.raises(DecodeError) as e:
        decode(payload, typ)  # type: ignore[arg-type]
    assert e.value.reason == reason, str(e.value)


@pytest.mark.parametrize("typ", TYPES)
def test_good_bodies_decode(typ: type) -> None:
    assert type(decode(_payload(KIND[typ], GOOD[typ]), typ)) is typ


@pytest.mark.parametrize("typ", TYPES)
def test_truncations_are_rejected(typ: type) -> None:
    payload = _payload(KIND[typ], GOOD[typ])
    for n in range(len(payload)):
        with pytest.raises(DecodeError):
            decode(payload[:n], typ)
    _reject(payload + b"\x00", typ, "not_msgpack")


@pytest.mark.parametrize("typ", TYPES)
def test_missing_and_unknown_fields_are_bad_schema(typ: type) -> None:
    for field in GOOD[typ]:
        body = {k: v for k, v in GOOD[typ].items() if k != field}
        _reject(_payload(KIND[typ], body), typ, "bad_schema")
    _reject(_payload(KIND[typ], {**GOOD[typ], "extra": 1}), typ, "bad_schema")


@pytest.mark.parametrize(
    "typ, field, value",
    [
        (Measurement, "tick", "1"),
        (Measurement, "tick", 1.0),
        (Measurement, "tick", True),
        (Measurement, "agent", None),
        (Measurement, "vx", "0.5"),
        (Measurement, "vx", True),
        (Measurement, "vx", b"\x00" * 8),
        (Wrench, "tau", [1.0]),
        (StateMsg, "shared", [("a", 1.0)]),
        (StateMsg, "shared", {"a": "1.0"}),
        (StateMsg, "shared", {7: 1.0}),
        (StateMsg, "pair", {"3": (1.0,)}),
        (StateMsg, "pair", {3: 1.0}),
        (StateMsg, "pair", {3: ("x",)}),
        (Estimate, "pairs", {3: (1.0,)}),
        (Estimate, "pairs", {3: (1.0, 2.0, 3.0)}),
        (Control, "kind", "teleport"),
        (Control, "kind", 1),
        (Control, "ticks", 1.0),
        (AgentReport, "links", {1: {"sent": 1.5}}),
        (AgentReport, "links", {"1": {"sent": 1}}),
        (AgentReport, "drops", {"stale": True}),
        (AgentReport, "timeouts", None),
    ],
)
def test_wrong_types_are_bad_schema(typ: type, field: str, value: object) -> None:
    _reject(_payload(KIND[typ], {**GOOD[typ], field: value}), typ, "bad_schema")


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize(
    "typ, field, make",
    [
        (Measurement, "vy", lambda x: x),
        (Wrench, "fx", lambda x: x),
        (StateMsg, "vx", lambda x: x),
        (StateMsg, "shared", lambda x: {"a": 1.0, "b": x}),
        (StateMsg, "pair", lambda x: {1: (0.0, x)}),
        (Estimate, "values", lambda x: {"m": x}),
        (Estimate, "pairs", lambda x: {1: (x, 0.0)}),
    ],
)
def test_non_finite_floats_are_rejected(typ: type, field: str, make: object, bad: float) -> None:
    payload = _payload(KIND[typ], {**GOOD[typ], field: make(bad)})  # type: ignore[operator]
    if typ is Estimate and field == "values" and math.isnan(bad):
        assert math.isnan(decode(payload, Estimate).values["m"])  # NaN = "not available": allowed
        return
    _reject(_payload(KIND[typ], {**GOOD[typ], field: make(bad)}), typ, "non_finite")  # type: ignore[operator]


@pytest.mark.parametrize(
    "typ, field, value",
    [
        (Measurement, "tick", -1),
        (Measurement, "tick", MAX_TICK + 1),
        (Wrench, "agent", -1),
        (Wrench, "agent", MAX_AGENT_ID + 1),
        (StateMsg, "phase", -3),
        (StateMsg, "pair", {-1: (1.0,)}),
        (StateMsg, "pair", {1: (1.0,) * (MAX_PAIR_LEN + 1)}),
        (StateMsg, "shared", {f"n{i}": 1.0 for i in range(MAX_NAMES + 1)}),
        (StateMsg, "shared", {"x" * 65: 1.0}),
        (Estimate, "values", {"": 1.0}),
        (Control, "tick", -1),
        (AgentReport, "timeouts", -1),
        (AgentReport, "drops", {"stale": -2}),
        (AgentReport, "links", {1: {f"c{i}": 1 for i in range(MAX_NAMES + 1)}}),
        (Estimate, "pairs", {j: (1.0, 2.0) for j in range(MAX_PAIRS + 1)}),
    ],
)
def test_out_of_range_values_are_rejected(typ: type, field: str, value: object) -> None:
    _reject(_payload(KIND[typ], {**GOOD[typ], field: value}), typ, "out_of_range")


def test_huge_ints_do_not_escape() -> None:
    """uint64 max is the largest int msgpack can carry."""
    _reject(_payload("meas", {**GOOD[Measurement], "tick": 2**64 - 1}), Measurement, "out_of_range")
    _reject(_payload("meas", {**GOOD[Measurement], "agent": -(2**63)}), Measurement, "out_of_range")


@pytest.mark.parametrize(
    "obj",
    [
        None,
        1,
        "state",
        {"kind": "state"},
        ("state", SCHEMA_VERSION),
        ("state", SCHEMA_VERSION, GOOD[StateMsg], 0),
        ("state", SCHEMA_VERSION, [1, 2]),
        (7, SCHEMA_VERSION, GOOD[StateMsg]),
        ("state", True, GOOD[StateMsg]),
        ("state", "1", GOOD[StateMsg]),
    ],
)
def test_bad_envelopes(obj: object) -> None:
    _reject(msgpack.packb(obj, use_bin_type=True), StateMsg, "bad_envelope")


def test_unknown_kind_and_version() -> None:
    _reject(_payload("teleport", GOOD[StateMsg]), StateMsg, "wrong_kind")
    _reject(_payload("state", GOOD[StateMsg], version=SCHEMA_VERSION + 1), StateMsg, "bad_version")


def test_oversized_rejected_before_unpacking() -> None:
    _reject(b"\x00" * (MAX_PAYLOAD + 1), StateMsg, "oversized")
    # A well-formed but too-large message is refused on size, not parsed.
    body = {**GOOD[StateMsg], "shared": {f"k{i}": 1.0 for i in range(6000)}}
    payload = _payload("state", body)
    assert len(payload) > MAX_PAYLOAD
    _reject(payload, StateMsg, "oversized")


def test_non_bytes_and_odd_msgpack() -> None:
    _reject("not bytes", StateMsg, "not_msgpack")
    _reject(None, StateMsg, "not_msgpack")
    _reject(b"", StateMsg, "not_msgpack")
    _reject(b"\xc1", StateMsg, "not_msgpack")  # the one never-used msgpack byte
    _reject(b"\x91" * 5000 + b"\xc0", StateMsg, "not_msgpack")  # nested deeper than msgpack's stack
    _reject(b"\x91" * 100 + b"\xc0", StateMsg, "bad_envelope")  # nested, but valid msgpack
    _reject(b"\x81\x81\xc0\xc0\xc0", StateMsg, "not_msgpack")  # a map used as a map key: unhashable
    _reject(b"\xd4\x05\x00", StateMsg, "bad_envelope")  # ext type
    _reject(b"\xd6\xff" + struct.pack(">I", 0), StateMsg, "bad_envelope")  # msgpack timestamp
    _reject(b"\x93\xa5state\x01\xc7\x00\x05", StateMsg, "bad_envelope")  # ext in body slot
    _reject(b"\xa3\xff\xfe\xfd", StateMsg, "not_msgpack")  # invalid utf-8 in a str
    assert decode(bytearray(_payload("state", GOOD[StateMsg])), StateMsg).sender == 2
    assert decode(memoryview(_payload("state", GOOD[StateMsg])), StateMsg).sender == 2


def test_reasons_are_documented() -> None:
    import net.schema as schema

    for r in REASONS:
        assert f"``{r}``" in (schema.__doc__ or "")


@pytest.mark.parametrize("typ", TYPES)
@settings(max_examples=300, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.binary(max_size=512))
def test_fuzz_random_bytes_raise_only_decode_error(typ: type, data: bytes) -> None:
    try:
        decode(data, typ)
    except DecodeError as e:
        assert e.reason in REASONS


msgpack_values = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**63), 2**64 - 1) | st.floats() | st.text(max_size=8)
    | st.binary(max_size=8),
    lambda inner: st.lists(inner, max_size=4)
    | st.dictionaries(st.text(max_size=4) | st.integers(-5, 5), inner, max_size=4),
    max_leaves=8,
)


@pytest.mark.parametrize("typ", TYPES)
@settings(max_examples=100, suppress_health_check=[HealthCheck.too_slow])
@given(body=st.dictionaries(st.sampled_from(["tick", "agent", "sender", "vx", "vy", "fx", "fy", "tau", "phase",
                                              "shared", "pair", "values", "pairs", "kind", "ticks",
                                              "links", "drops", "timeouts", "z", "xhat", "u", "zeta", "x"]),
                                msgpack_values))
def test_fuzz_structured_bodies_raise_only_decode_error(typ: type, body: dict) -> None:
    """Well-formed envelopes with arbitrary bodies: valid or DecodeError, nothing else."""
    try:
        out = decode(_payload(KIND[typ], body), typ)
    except DecodeError as e:
        assert e.reason in REASONS
    else:
        assert type(out) is typ


@pytest.mark.parametrize("typ", TYPES)
@settings(max_examples=200)
@given(data=st.data(), value=msgpack_values)
def test_fuzz_one_field_replaced_raises_only_decode_error(typ: type, data: st.DataObject, value: object) -> None:
    """A good body with one field set to any msgpack value: valid or DecodeError, nothing else."""
    field = data.draw(st.sampled_from(sorted(GOOD[typ])))
    try:
        out = decode(_payload(KIND[typ], {**GOOD[typ], field: value}), typ)
    except DecodeError as e:
        assert e.reason in REASONS
    else:
        assert type(out) is typ


@given(messages, st.data())
def test_fuzz_corrupted_messages_raise_only_decode_error(msg: object, data: st.DataObject) -> None:
    """Flip, drop or insert bytes of valid payloads: valid or DecodeError, nothing else."""
    payload = bytearray(encode(msg))  # type: ignore[arg-type]
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(payload) - 1))
        op = data.draw(st.sampled_from(["flip", "drop", "insert"]))
        if op == "flip":
            payload[i] ^= data.draw(st.integers(1, 255))
        elif op == "drop" and len(payload) > 1:
            del payload[i]
        else:
            payload.insert(i, data.draw(st.integers(0, 255)))
    try:
        decode(bytes(payload), type(msg))
    except DecodeError as e:
        assert e.reason in REASONS


def test_envelope_and_key_problems_are_named() -> None:
    """What a client in another language plausibly gets wrong is named in the drop's detail (said in the
    daemon's log): strings packed as msgpack bin, an envelope as a map, a version as a string."""
    good = {"tick": 0, "agent": 0, "vx": 0.0, "vy": 0.0}
    cases = [
        ([b"meas", 1, good], "bad_envelope", "kind must be a msgpack str, got bin (bytes)"),
        (["meas", 1, {k.encode(): v for k, v in good.items()}], "bad_schema",
         "the body's keys are msgpack bin (bytes): field names must be msgpack str"),
        ({"kind": "meas", "version": 1, "body": good}, "bad_envelope",
         "expected an array [kind, version, body], got a map"),
        (["meas", "1", good], "bad_envelope", "version must be the msgpack int 1, got str"),
        (["meas", 1, good, 0], "bad_envelope", "expected an array of 3 [kind, version, body], got 4 elements"),
        (["meas", 1, [0, 0, 0.0, 0.0]], "bad_envelope", "body must be a msgpack map, got array"),
    ]
    for obj, reason, detail in cases:
        with pytest.raises(DecodeError) as exc:
            decode(msgpack.packb(obj, use_bin_type=True), Measurement)
        assert exc.value.reason == reason and str(exc.value) == f"{reason}: {detail}"
