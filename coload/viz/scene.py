"""What a viewer shows of a run: Foxglove-schema messages built from the truth and the estimates.

Pure: each function takes arrays and returns JSON-ready dicts; :mod:`coload.viz.mcap_export` writes
them to an MCAP file and :mod:`coload.viz.live` streams them to Foxglove's WebSocket server, so a
recorded run and a live one look the same. Topics and schemas: docs/viewers.md.

Geometry: the world frame is the plane's x, y (z = 0). The true contact points are
``p_G + z_i``; agent i's estimated contact point is drawn at ``p_G + z_i_hat`` and its estimated CoM
at ``p_G - z_C_hat``, both about the true geometric centre G, so the distance to the true marker is
the estimation error.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np

WORLD = "world"
LOAD_FRAME = "load"

# topic -> schema title (the schema itself is in SCHEMAS)
TF_TOPIC = "/tf"
POSE_TOPIC = "/load/pose"
SCENE_TOPIC = "/scene"
TRUTH_TOPIC = "/truth"
LINKS_TOPIC = "/links"


def estimate_topic(i: int) -> str:
    return f"/agent/{i}/estimate"


class Message(NamedTuple):
    """One message: log time (ns of simulated time), topic, JSON-ready body."""

    t_ns: int
    topic: str
    body: dict[str, Any]


# --- JSON schemas ---------------------------------------------------------------------------------
# Foxglove's well-known schemas (the names Foxglove's panels recognise), restricted to the fields
# written here; every field Foxglove's JSON schema lists is written, so a strict reader accepts them.
def _obj(title: str | None, props: Mapping[str, Any]) -> dict[str, Any]:
    schema: dict[str, Any] = {"type": "object", "properties": dict(props)}
    if title:
        schema["title"] = title
    return schema


_NUM = {"type": "number"}
_STR = {"type": "string"}
_BOOL = {"type": "boolean"}
_TIME = _obj(None, {"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0}})
_VEC3 = _obj(None, {"x": _NUM, "y": _NUM, "z": _NUM})
_QUAT = _obj(None, {"x": _NUM, "y": _NUM, "z": _NUM, "w": _NUM})
_POSE = _obj(None, {"position": _VEC3, "orientation": _QUAT})
_COLOR = _obj(None, {"r": _NUM, "g": _NUM, "b": _NUM, "a": _NUM})
_ARR = {"type": "array"}
_SPHERE = _obj(None, {"pose": _POSE, "size": _VEC3, "color": _COLOR})
_LINE = _obj(None, {
    "type": {"type": "integer", "description": "0 LINE_STRIP, 1 LINE_LOOP, 2 LINE_LIST"},
    "pose": _POSE, "thickness": _NUM, "scale_invariant": _BOOL, "points": {"type": "array", "items": _VEC3},
    "color": _COLOR, "colors": _ARR, "indices": _ARR,
})
_TEXT = _obj(None, {"pose": _POSE, "billboard": _BOOL, "font_size": _NUM, "scale_invariant": _BOOL,
                    "color": _COLOR, "text": _STR})
_ENTITY = _obj(None, {
    "timestamp": _TIME, "frame_id": _STR, "id": _STR, "lifetime": _TIME, "frame_locked": _BOOL,
    "metadata": _ARR, "arrows": _ARR, "cubes": _ARR, "spheres": {"type": "array", "items": _SPHERE},
    "cylinders": _ARR, "lines": {"type": "array", "items": _LINE}, "triangles": _ARR,
    "texts": {"type": "array", "items": _TEXT}, "models": _ARR,
})


def _values(title: str, description: str) -> dict[str, Any]:
    """A coload table row: named numbers, null where there is no value."""
    return {**_obj(title, {"t": _NUM}), "description": description,
            "additionalProperties": {"type": ["number", "null"]}}


SCHEMAS: dict[str, dict[str, Any]] = {
    "foxglove.FrameTransform": _obj("foxglove.FrameTransform", {
        "timestamp": _TIME, "parent_frame_id": _STR, "child_frame_id": _STR,
        "translation": _VEC3, "rotation": _QUAT}),
    "foxglove.PoseInFrame": _obj("foxglove.PoseInFrame", {"timestamp": _TIME, "frame_id": _STR, "pose": _POSE}),
    "foxglove.SceneUpdate": _obj("foxglove.SceneUpdate", {
        "deletions": _ARR, "entities": {"type": "array", "items": _ENTITY}}),
    "coload.Truth": _values("coload.Truth", "a truth.csv row (docs/run-directory.md)"),
    "coload.Estimate": _values("coload.Estimate", "an estimates.csv row of one agent (docs/run-directory.md)"),
    "coload.LinkStatistics": {**_obj("coload.LinkStatistics", {
        "links": {"type": "object"}, "drops": {"type": "object"}, "timeouts": {"type": "object"}}),
        "description": "summary.json's links, drops and timeouts (docs/run-directory.md)"},
}


def channels(n: int) -> dict[str, str]:
    """Topic -> schema title, in the order channels are declared."""
    out = {TF_TOPIC: "foxglove.FrameTransform", POSE_TOPIC: "foxglove.PoseInFrame",
           SCENE_TOPIC: "foxglove.SceneUpdate", TRUTH_TOPIC: "coload.Truth"}
    out.update({estimate_topic(i): "coload.Estimate" for i in range(n)})
    out[LINKS_TOPIC] = "coload.LinkStatistics"
    return out


# --- messages -------------------------------------------------------------------------------------
def t_ns(t: float) -> int:
    """Simulated seconds -> integer nanoseconds (rounded: 0.1 s is 100 000 000 ns, not one less)."""
    return int(round(t * 1e9))


def _time(ns: int) -> dict[str, int]:
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _vec(x: float, y: float, z: float = 0.0) -> dict[str, float]:
    return {"x": float(x), "y": float(y), "z": float(z)}


def _yaw(angle: float) -> dict[str, float]:
    return {"x": 0.0, "y": 0.0, "z": math.sin(0.5 * angle), "w": math.cos(0.5 * angle)}


_IDENTITY = {"position": _vec(0, 0), "orientation": _yaw(0.0)}


def _color(r: float, g: float, b: float, a: float = 1.0) -> dict[str, float]:
    return {"r": r, "g": g, "b": b, "a": a}


def agent_color(i: int, n: int) -> dict[str, float]:
    """A hue per agent around the colour wheel (HSV with s = 0.8, v = 0.9)."""
    h = (i / max(n, 1)) * 6.0
    k = int(h) % 6
    f = h - int(h)
    v, s = 0.9, 0.8
    p, q, u = v * (1 - s), v * (1 - s * f), v * (1 - s * (1 - f))
    r, g, b = [(v, u, p), (q, v, p), (p, v, u), (p, q, v), (u, p, v), (v, p, q)][k]
    return _color(r, g, b)


_TRUE = _color(0.1, 0.1, 0.1)
_OUTLINE = _color(0.2, 0.4, 1.0)


def _entity(ns: int, eid: str, **prims: list[dict[str, Any]]) -> dict[str, Any]:
    e = {"timestamp": _time(ns), "frame_id": WORLD, "id": eid, "lifetime": _time(0), "frame_locked": False,
         "metadata": [], "arrows": [], "cubes": [], "spheres": [], "cylinders": [], "lines": [],
         "triangles": [], "texts": [], "models": []}
    e.update(prims)
    return e


def _sphere(x: float, y: float, size: float, color: dict[str, float]) -> dict[str, Any]:
    return {"pose": {"position": _vec(x, y), "orientation": _yaw(0.0)}, "size": _vec(size, size, size),
            "color": color}


def _line(kind: int, points: Sequence[tuple[float, float]], color: dict[str, float],
          thickness: float = 0.04) -> dict[str, Any]:
    return {"type": kind, "pose": _IDENTITY, "thickness": thickness, "scale_invariant": False,
            "points": [_vec(x, y) for x, y in points], "color": color, "colors": [], "indices": []}


def _finite(*v: float) -> bool:
    return all(math.isfinite(x) for x in v)


def frame(ns: int, pose: tuple[float, float, float], pg: tuple[float, float], z_true: np.ndarray,
          outline_body: np.ndarray, estimates: Mapping[int, Mapping[str, float]], n: int) -> list[Message]:
    """The pose, the transform and the scene at one time.

    ``pose`` is the CoM's (x, y, angle); ``pg`` the geometric centre G; ``z_true`` (n, 2) the true
    z_i = p_Ci - p_G; ``outline_body`` the outline about G in the body frame; ``estimates`` agent ->
    its latest estimate row (``zi_x``, ``zi_y``, ``zc_x``, ``zc_y`` used when present and finite).
    """
    x, y, angle = pose
    gx, gy = pg
    c, s = math.cos(angle), math.sin(angle)
    outline = [(gx + c * bx - s * by, gy + s * bx + c * by) for bx, by in outline_body]
    tf = {"timestamp": _time(ns), "parent_frame_id": WORLD, "child_frame_id": LOAD_FRAME,
          "translation": _vec(x, y), "rotation": _yaw(angle)}
    pose_msg = {"timestamp": _time(ns), "frame_id": WORLD,
                "pose": {"position": _vec(x, y), "orientation": _yaw(angle)}}
    true_contacts = [(gx + float(zx), gy + float(zy)) for zx, zy in z_true]
    est_spheres, est_com, error_lines, labels = [], [], [], []
    for i in range(n):
        row = estimates.get(i)
        if row is None:
            continue
        col = agent_color(i, n)
        zx, zy = row.get("zi_x", math.nan), row.get("zi_y", math.nan)
        if _finite(zx, zy):
            ex, ey = gx + zx, gy + zy
            est_spheres.append(_sphere(ex, ey, 0.18, col))
            error_lines.append(_line(2, [true_contacts[i], (ex, ey)], col, 0.02))
        cx, cy = row.get("zc_x", math.nan), row.get("zc_y", math.nan)
        if _finite(cx, cy):
            est_com.append(_sphere(gx - cx, gy - cy, 0.14, col))
    for i, (px, py) in enumerate(true_contacts):
        labels.append({"pose": {"position": _vec(px, py, 0.3), "orientation": _yaw(0.0)}, "billboard": True,
                       "font_size": 14.0, "scale_invariant": True, "color": _TRUE, "text": str(i)})
    entities = [
        _entity(ns, "load", lines=[_line(1, outline, _OUTLINE, 0.06)],
                spheres=[_sphere(x, y, 0.25, _TRUE)], texts=[]),
        _entity(ns, "contacts/true", spheres=[_sphere(px, py, 0.22, _TRUE) for px, py in true_contacts],
                texts=labels),
        _entity(ns, "contacts/estimated", spheres=est_spheres, lines=error_lines),
        _entity(ns, "com/estimated", spheres=est_com),
    ]
    return [Message(ns, TF_TOPIC, tf), Message(ns, POSE_TOPIC, pose_msg),
            Message(ns, SCENE_TOPIC, {"deletions": [], "entities": entities})]


def outline_body(scenario: Any) -> np.ndarray:
    """The load's outline about its geometric centre G, body frame (m), from a scenario."""
    from simulator.plant import load_polygon_body

    return np.asarray(load_polygon_body(scenario), dtype=float) + np.asarray(scenario.load.com_offset, dtype=float)


def _row(t: float, names: Sequence[str], values: np.ndarray) -> dict[str, Any]:
    out: dict[str, Any] = {"t": float(t)}
    for name, v in zip(names, values):
        out[name] = float(v) if math.isfinite(v) else None
    return out


def run_messages(run: Any, outline_body: np.ndarray) -> Iterator[Message]:
    """Every message of a run directory read by ``coload.rundir.format.read_run``, in time order.

    Truth rows give the transform, pose, scene and /truth; estimate rows give /agent/i/estimate (an
    agent without a row at a time sends nothing then); the scene at a truth time shows each agent's
    latest estimate at or before it. summary.json's link statistics close the file at the last time.
    """
    n = run.n
    est = run.estimates
    names = [k for k in est.columns] if est is not None else []
    stacked = np.stack([est.columns[k] for k in names], axis=2) if names else None  # (T, n, C)
    present = ~np.all(np.isnan(stacked), axis=2) if stacked is not None else None  # (T, n)
    latest: dict[int, dict[str, float]] = {}
    ei = 0
    truth = run.truth
    tt = truth.t if truth is not None else np.empty(0)
    et = est.t if est is not None else np.empty(0)
    tcols = list(truth.columns) if truth is not None else []
    ti = 0
    last_ns = 0
    # merge the two time grids; at equal times the estimates come first so the scene shows them
    while ti < len(tt) or ei < len(et):
        if ei < len(et) and (ti >= len(tt) or et[ei] <= tt[ti] + 1e-9):
            ns = t_ns(et[ei])
            for i in np.flatnonzero(present[ei]):
                row = _row(et[ei], names, stacked[ei, i])
                row = {"t": row.pop("t"), "agent": int(i), **row}
                latest[int(i)] = {k: (math.nan if v is None else v) for k, v in row.items()}
                yield Message(ns, estimate_topic(int(i)), row)
            ei += 1
            last_ns = max(last_ns, ns)
            continue
        cols = truth.columns
        ns = t_ns(tt[ti])
        yield Message(ns, TRUTH_TOPIC, _row(tt[ti], tcols, np.array([cols[k][ti] for k in tcols])))
        yield from frame(ns, (cols["x"][ti], cols["y"][ti], cols["angle"][ti]),
                         (cols["pg_x"][ti], cols["pg_y"][ti]), truth.zi[ti], outline_body, latest, n)
        ti += 1
        last_ns = max(last_ns, ns)
    summary = run.summary or {}
    if any(k in summary for k in ("links", "drops", "timeouts")):
        yield Message(last_ns, LINKS_TOPIC, {k: summary.get(k, {}) for k in ("links", "drops", "timeouts")})
