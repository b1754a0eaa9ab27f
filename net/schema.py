"""Wire codec: msgpack on the wire, pydantic at the edge, plain dataclasses inside.

Every payload is a msgpack array ``[kind, version, body]``: ``kind`` names the message type (so a
payload sent on the wrong key is recognised, not misread), ``version`` is :data:`SCHEMA_VERSION`
(so a daemon from another release is dropped, not misread) and ``body`` is a map of the dataclass
fields. :func:`decode` rejects anything that is not exactly that, raising :class:`DecodeError` with
one short, stable reason token so that callers can count drops per reason (principle 6); it never
raises anything else. The pure cores only ever see the plain dataclasses of :mod:`net.messages`.

Reason tokens (:data:`REASONS`):

``oversized``     payload longer than :data:`MAX_PAYLOAD` (checked before unpacking)
``not_msgpack``   not bytes, not valid msgpack, or trailing bytes after the message
``bad_envelope``  valid msgpack but not a ``[kind: str, version: int, body: map]`` array
``bad_version``   envelope with another schema version
``wrong_kind``    a well-formed message of another kind than the one expected
``bad_schema``    body fields missing, unknown or of the wrong type (details in the message)
``non_finite``    a float field holds NaN or +-inf (``Estimate.values`` alone may hold NaN,
                  meaning "not available": estimates are recorded, never computed with)
``out_of_range``  an integer out of bounds (negative tick, huge id) or a collection too large
"""

from __future__ import annotations

import math
from collections.abc import MutableMapping
from typing import Annotated, Any, Final, Literal, TypeVar, Union

import msgpack
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, StringConstraints, ValidationError
from pydantic_core import PydanticCustomError

from net.hinf_messages import HinfInput, HinfMeas, HinfState
from net.messages import AgentReport, Control, Estimate, LoadPose, Measurement, StateMsg, Wrench

SCHEMA_VERSION: Final = 1
MAX_PAYLOAD: Final = 64 * 1024
"""Largest payload accepted, in bytes. A complete graph of 1000 agents with 4-float pair values fits."""

MAX_AGENT_ID: Final = 65_535
MAX_TICK: Final = 2**53
MAX_PHASE: Final = 65_535
MAX_NAMES: Final = 64
"""Most entries in a by-name dict (``StateMsg.shared``, ``Estimate.values``)."""
MAX_NAME_LEN: Final = 64
MAX_PAIRS: Final = 1024
"""Most entries in a by-neighbour dict (``StateMsg.pair``, ``Estimate.pairs``)."""
MAX_PAIR_LEN: Final = 41
"""Most floats in one ``StateMsg.pair`` value (the dynamical phase with online detection sends 4 + 37: 15 channels
of the augmented model and 22 of the detection's pool)."""
MAX_COUNT: Final = 2**63 - 1
"""Largest counter in an ``AgentReport``."""
MAX_TEAM: Final = 1000
"""Most agents in a run (the scenario's bound on n): ``LoadPose.z`` holds two floats per agent."""
MAX_VEC: Final = 1024
"""Most floats in one vector of a paper-003 message (``HinfMeas.z``, ``HinfState.xhat``, ...)."""
CONTROL_KINDS: Final = ("start", "progress", "stop", "done")

REASONS: Final = (
    "oversized",
    "not_msgpack",
    "bad_envelope",
    "bad_version",
    "wrong_kind",
    "bad_schema",
    "non_finite",
    "out_of_range",
)

KIND: Final[dict[type, str]] = {
    Measurement: "meas",
    Wrench: "wrench",
    StateMsg: "state",
    Estimate: "estimate",
    Control: "control",
    AgentReport: "report",
    LoadPose: "pose",
    HinfMeas: "hinf_meas",
    HinfState: "hinf_state",
    HinfInput: "hinf_input",
}
"""Message-kind tag of each message type; the same words as the last chunk of its key expression."""
TYPE_OF_KIND: Final[dict[str, type]] = {v: k for k, v in KIND.items()}

Message = Union[Measurement, Wrench, StateMsg, Estimate, Control, AgentReport, LoadPose, HinfMeas, HinfState,
                HinfInput]
Msg = TypeVar("Msg", Measurement, Wrench, StateMsg, Estimate, Control, AgentReport, LoadPose, HinfMeas, HinfState,
              HinfInput)


class DecodeError(ValueError):
    """A payload was rejected; ``reason`` is one token of :data:`REASONS`, the message has details."""

    def __init__(self, reason: str, detail: str = "") -> None:
        assert reason in REASONS, reason
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason


# ---------------------------------------------------------------------------------------------
# Pydantic models: the edge. Strict (no str -> int coercion, no bool as int), finite floats only.

Tick = Annotated[int, Field(ge=0, le=MAX_TICK)]
AgentId = Annotated[int, Field(ge=0, le=MAX_AGENT_ID)]
Name = Annotated[str, StringConstraints(min_length=1, max_length=MAX_NAME_LEN)]


class _Body(BaseModel):
    model_config = ConfigDict(strict=True, allow_inf_nan=False, extra="forbid", frozen=True)


class _MeasurementBody(_Body):
    tick: Tick
    agent: AgentId
    vx: float
    vy: float


class _WrenchBody(_Body):
    tick: Tick
    agent: AgentId
    fx: float
    fy: float
    tau: float


class _StateBody(_Body):
    tick: Tick
    sender: AgentId
    vx: float
    vy: float
    phase: Annotated[int, Field(ge=0, le=MAX_PHASE)]
    shared: Annotated[dict[Name, float], Field(max_length=MAX_NAMES)]
    pair: Annotated[
        dict[AgentId, Annotated[tuple[float, ...], Field(max_length=MAX_PAIR_LEN)]],
        Field(max_length=MAX_PAIRS),
    ]


def _not_inf(x: float) -> float:
    if math.isinf(x):
        raise PydanticCustomError("finite_number", "Input should be a finite number or NaN")
    return x


NanOrFinite = Annotated[float, Field(allow_inf_nan=True), AfterValidator(_not_inf)]
"""An estimate value: NaN means 'not available this tick' (e.g. no sample yet); +-inf is refused."""


class _EstimateBody(_Body):
    tick: Tick
    agent: AgentId
    values: Annotated[dict[Name, NanOrFinite], Field(max_length=MAX_NAMES)]
    pairs: Annotated[dict[AgentId, tuple[float, float]], Field(max_length=MAX_PAIRS)]


Count = Annotated[int, Field(ge=0, le=MAX_COUNT)]


class _ControlBody(_Body):
    kind: Literal["start", "progress", "stop", "done"]
    tick: Tick
    ticks: Tick


class _ReportBody(_Body):
    agent: AgentId
    links: Annotated[dict[AgentId, Annotated[dict[Name, Count], Field(max_length=MAX_NAMES)]],
                     Field(max_length=MAX_PAIRS)]
    drops: Annotated[dict[Name, Count], Field(max_length=MAX_NAMES)]
    timeouts: Count
    ticks: Tick


Vec = Annotated[tuple[float, ...], Field(max_length=MAX_VEC)]


class _LoadPoseBody(_Body):
    tick: Tick
    x: float
    y: float
    angle: float
    pg_x: float
    pg_y: float
    z: Annotated[tuple[float, ...], Field(max_length=2 * MAX_TEAM)]


class _HinfMeasBody(_Body):
    tick: Tick
    agent: AgentId
    z: Vec


class _HinfStateBody(_Body):
    tick: Tick
    sender: AgentId
    xhat: Vec
    u: Vec
    zeta: Vec


class _HinfInputBody(_Body):
    tick: Tick
    agent: AgentId
    u: Vec
    xhat: Vec
    zeta: Vec


_BODY: Final[dict[type, type[_Body]]] = {
    Measurement: _MeasurementBody,
    Wrench: _WrenchBody,
    StateMsg: _StateBody,
    Estimate: _EstimateBody,
    Control: _ControlBody,
    AgentReport: _ReportBody,
    LoadPose: _LoadPoseBody,
    HinfMeas: _HinfMeasBody,
    HinfState: _HinfStateBody,
    HinfInput: _HinfInputBody,
}

# Pydantic error types -> reason token; anything else is bad_schema.
_NON_FINITE: Final = frozenset({"finite_number"})
_OUT_OF_RANGE: Final = frozenset(
    {"greater_than_equal", "less_than_equal", "greater_than", "less_than", "too_long", "too_short",
     "string_too_long", "string_too_short"}
)


# ---------------------------------------------------------------------------------------------
# Encoding. Floats are forced to float so that an int slipped in by a caller still travels as a
# msgpack float64 and decodes to a float (exact round trip, no type drift between engines).

def _enc_meas(m: Measurement) -> dict[str, Any]:
    return {"tick": m.tick, "agent": m.agent, "vx": float(m.vx), "vy": float(m.vy)}


def _enc_wrench(m: Wrench) -> dict[str, Any]:
    return {"tick": m.tick, "agent": m.agent, "fx": float(m.fx), "fy": float(m.fy), "tau": float(m.tau)}


def _enc_state(m: StateMsg) -> dict[str, Any]:
    return {
        "tick": m.tick,
        "sender": m.sender,
        "vx": float(m.vx),
        "vy": float(m.vy),
        "phase": m.phase,
        "shared": {k: float(v) for k, v in m.shared.items()},
        "pair": {j: tuple(float(x) for x in v) for j, v in m.pair.items()},
    }


def _enc_estimate(m: Estimate) -> dict[str, Any]:
    return {
        "tick": m.tick,
        "agent": m.agent,
        "values": {k: float(v) for k, v in m.values.items()},
        "pairs": {j: (float(v[0]), float(v[1])) for j, v in m.pairs.items()},
    }


def _enc_control(m: Control) -> dict[str, Any]:
    return {"kind": m.kind, "tick": m.tick, "ticks": m.ticks}


def _enc_report(m: AgentReport) -> dict[str, Any]:
    return {
        "agent": m.agent,
        "links": {j: dict(c) for j, c in m.links.items()},
        "drops": dict(m.drops),
        "timeouts": m.timeouts,
        "ticks": m.ticks,
    }


def _vec(v: tuple[float, ...]) -> tuple[float, ...]:
    return tuple(float(x) for x in v)


def _enc_pose(m: LoadPose) -> dict[str, Any]:
    return {"tick": m.tick, "x": float(m.x), "y": float(m.y), "angle": float(m.angle), "pg_x": float(m.pg_x),
            "pg_y": float(m.pg_y), "z": _vec(m.z)}


def _enc_hinf_meas(m: HinfMeas) -> dict[str, Any]:
    return {"tick": m.tick, "agent": m.agent, "z": _vec(m.z)}


def _enc_hinf_state(m: HinfState) -> dict[str, Any]:
    return {"tick": m.tick, "sender": m.sender, "xhat": _vec(m.xhat), "u": _vec(m.u), "zeta": _vec(m.zeta)}


def _enc_hinf_input(m: HinfInput) -> dict[str, Any]:
    return {"tick": m.tick, "agent": m.agent, "u": _vec(m.u), "xhat": _vec(m.xhat), "zeta": _vec(m.zeta)}


_ENCODERS: Final = {
    Measurement: _enc_meas,
    Wrench: _enc_wrench,
    StateMsg: _enc_state,
    Estimate: _enc_estimate,
    Control: _enc_control,
    AgentReport: _enc_report,
    LoadPose: _enc_pose,
    HinfMeas: _enc_hinf_meas,
    HinfState: _enc_hinf_state,
    HinfInput: _enc_hinf_input,
}


def encode(msg: Message) -> bytes:
    """Serialise one message as ``[kind, version, body]`` msgpack.

    Encoding does not validate values (receivers do, and count what they drop), but it refuses a
    payload larger than :data:`MAX_PAYLOAD`, because every receiver would silently drop it.
    Raises ``TypeError`` for an object that is not a message, ``ValueError`` if oversized.
    """
    try:
        body = _ENCODERS[type(msg)](msg)
    except KeyError:
        raise TypeError(f"not a wire message: {type(msg).__name__}") from None
    payload = msgpack.packb((KIND[type(msg)], SCHEMA_VERSION, body), use_bin_type=True)
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"{KIND[type(msg)]} message is {len(payload)} bytes > MAX_PAYLOAD = {MAX_PAYLOAD}")
    return payload


# ---------------------------------------------------------------------------------------------
# Decoding.

def _unpack(payload: bytes) -> Any:
    if not isinstance(payload, (bytes, bytearray, memoryview)):
        raise DecodeError("not_msgpack", f"payload is {type(payload).__name__}, not bytes")
    if len(payload) > MAX_PAYLOAD:
        raise DecodeError("oversized", f"{len(payload)} bytes > {MAX_PAYLOAD}")
    try:
        # use_list=False: arrays come back as tuples, what the strict tuple fields want.
        # strict_map_key=False: `pair` maps are keyed by int agent ids; sizes are bounded by
        # MAX_PAYLOAD (msgpack derives its max_*_len limits from the buffer length).
        return msgpack.unpackb(payload, raw=False, use_list=False, strict_map_key=False)
    except (ValueError, TypeError, msgpack.UnpackException, RecursionError) as e:
        # ValueError covers ExtraData, FormatError, StackError, UnicodeDecodeError; TypeError an
        # unhashable map key (a map used as a key).
        raise DecodeError("not_msgpack", f"{type(e).__name__}: {e}") from None


_FIXED_ARITY: Final = frozenset({"pairs"})
"""Fields whose values are fixed-length tuples: a wrong length there is a schema error, not a size."""


def _reason(err: ValidationError) -> str:
    errors = err.errors(include_url=False)
    types = {e["type"] for e in errors}
    if types & _NON_FINITE:
        return "non_finite"
    if types <= _OUT_OF_RANGE and not any(
        e["type"] in ("too_long", "too_short") and len(e["loc"]) == 2 and e["loc"][0] in _FIXED_ARITY
        for e in errors
    ):
        return "out_of_range"
    return "bad_schema"


_MSGPACK_TYPE: Final = {tuple: "array", list: "array", dict: "map", bytes: "bin (bytes)", str: "str", int: "int",
                        float: "float", bool: "bool", type(None): "nil"}


def _msgpack_type(x: Any) -> str:
    return _MSGPACK_TYPE.get(type(x), type(x).__name__)


def _envelope_problem(obj: Any) -> str:
    """What is wrong with a payload that is not ``[kind: str, version: int, body: map]``, for the log."""
    if not isinstance(obj, tuple):
        return f"expected an array [kind, version, body], got a {_msgpack_type(obj)}"
    if len(obj) != 3:
        return f"expected an array of 3 [kind, version, body], got {len(obj)} elements"
    kind, version, body = obj
    if not isinstance(kind, str):
        return f"kind must be a msgpack str, got {_msgpack_type(kind)}"
    if type(version) is not int:
        return f"version must be the msgpack int {SCHEMA_VERSION}, got {_msgpack_type(version)}"
    return f"body must be a msgpack map, got {_msgpack_type(body)}"


def decode(payload: bytes, expected: type[Msg]) -> Msg:
    """Validate ``payload`` as a message of type ``expected`` and return the plain dataclass.

    Raises :class:`DecodeError` (and nothing else) for any payload that is not exactly a valid
    ``expected`` message of this schema version.
    """
    if expected not in _BODY:
        raise TypeError(f"not a wire message type: {expected!r}")
    obj = _unpack(payload)
    if not (isinstance(obj, tuple) and len(obj) == 3 and isinstance(obj[0], str)
            and type(obj[1]) is int and isinstance(obj[2], dict)):
        raise DecodeError("bad_envelope", _envelope_problem(obj))
    kind, version, body = obj
    if version != SCHEMA_VERSION:
        raise DecodeError("bad_version", f"schema version {version}, this build speaks {SCHEMA_VERSION}")
    want = KIND[expected]
    if kind != want:
        raise DecodeError("wrong_kind", f"expected {want!r}, got {kind[:32]!r}")
    if any(isinstance(k, bytes) for k in body):
        raise DecodeError("bad_schema", "the body's keys are msgpack bin (bytes): field names must be msgpack str")
    try:
        m = _BODY[expected].model_validate(body)
    except ValidationError as e:
        first = e.errors(include_url=False)[0]
        detail = f"{e.error_count()} error(s); first at {first['loc']}: {first['msg']}"
        raise DecodeError(_reason(e), detail) from None
    return expected(**m.__dict__)


def decode_counted(payload: bytes, expected: type[Msg], drops: MutableMapping[str, int], link: Any = None,
                   said: FirstDrops | None = None, key: str = "") -> Msg | None:
    """:func:`decode` for a daemon: a rejected payload is counted in ``drops`` under its reason (and as
    ``malformed`` on ``link``, the sender's ``LinkStats``, when given) and comes back as None; the first
    one of each kind and reason is also said in the log by ``said`` (with the decoder's detail)."""
    try:
        return decode(payload, expected)
    except DecodeError as exc:
        drops[exc.reason] += 1
        if link is not None:
            link.malformed += 1
        if said is not None:
            said.drop(KIND[expected], exc.reason, str(exc), key)
        return None


class FirstDrops:
    """Says in the log, once per (message kind, reason, detail) and at most :attr:`LIMIT` times in all,
    that a daemon dropped a message that does not follow the wire (docs/wire.md): malformed, another
    agent's, another run's control notice, ... The drops stay counted by reason (the report,
    summary.json); the log line is what a user who wrote their own simulator or agent sees at once,
    instead of daemons that sit idle while every message they get is dropped. Tick discipline
    (``stale``, ``future``, ``duplicate``, ``resent``, ``off_grid``) happens in a healthy run on a lossy
    or restarted team and is only counted."""

    LIMIT: Final = 10

    def __init__(self, log: Any, who: str) -> None:
        self.log = log
        self.who = who
        self.said: set[tuple[str, str, str]] = set()

    def drop(self, kind: str, reason: str, detail: str = "", key: str = "") -> None:
        if len(self.said) > self.LIMIT or (kind, reason, detail) in self.said:
            return
        self.said.add((kind, reason, detail))
        if len(self.said) > self.LIMIT:
            self.log.warning("%s: more kinds of dropped messages: from now on only counted", self.who)
            return
        where = f" on {key}" if key else ""
        self.log.warning("%s: dropped a %s%s: %s (counted in drops[%r])", self.who, kind, where, detail or reason,
                         reason)


def is_finite_message(msg: Message) -> bool:
    """True if every float of ``msg`` is finite: a sender-side check for a diverging estimator."""
    vals: list[float] = []
    if isinstance(msg, Measurement):
        vals = [msg.vx, msg.vy]
    elif isinstance(msg, Wrench):
        vals = [msg.fx, msg.fy, msg.tau]
    elif isinstance(msg, StateMsg):
        vals = [msg.vx, msg.vy, *msg.shared.values(), *(x for v in msg.pair.values() for x in v)]
    elif isinstance(msg, Estimate):
        vals = [*msg.values.values(), *(x for v in msg.pairs.values() for x in v)]
    elif isinstance(msg, HinfMeas):
        vals = list(msg.z)
    elif isinstance(msg, (HinfState, HinfInput)):
        vals = [*msg.xhat, *msg.u, *msg.zeta]
    return all(math.isfinite(v) for v in vals)
