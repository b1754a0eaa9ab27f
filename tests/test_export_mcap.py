"""`coload export RUN_DIR --mcap`: a short paper-fig4 run read back with the mcap reader, against its CSVs."""

from __future__ import annotations

import csv
import json
import math
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from conftest import coload_cmd
from coload.viz import scene

mcap_reader = pytest.importorskip("mcap.reader", reason="the viz extra (mcap) is not installed")

N = 10  # paper-fig4's team


def _rows(path):
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def _cell(s: str) -> float | None:
    return None if s in ("", "nan") else float(s)


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    base = tmp_path_factory.mktemp("fig4")
    run = base / "run"
    done = subprocess.run(coload_cmd("run", "paper-fig4", "--engine", "inproc", "--set", "duration=3", "--quiet",
                                     "--no-report", "--no-batch-fit", "--out", str(run)),
                          capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stderr
    out = base / "fig4.mcap"
    done = subprocess.run(coload_cmd("export", str(run), "--mcap", str(out)), capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    assert f"mcap: {out}" in done.stdout
    messages: dict[str, list[tuple[int, dict]]] = {}
    with out.open("rb") as f:
        reader = mcap_reader.make_reader(f)
        summary = reader.get_summary()
        for schema, channel, msg in reader.iter_messages(log_time_order=True):
            messages.setdefault(channel.topic, []).append((msg.log_time, json.loads(msg.data)))
    return run, summary, messages


def test_channels_and_schemas(exported):
    _, summary, _ = exported
    got = {c.topic: (summary.schemas[c.schema_id].name, c.message_encoding, summary.schemas[c.schema_id].encoding)
           for c in summary.channels.values()}
    want = {"/tf": "foxglove.FrameTransform", "/load/pose": "foxglove.PoseInFrame", "/scene": "foxglove.SceneUpdate",
            "/truth": "coload.Truth", "/links": "coload.LinkStatistics",
            **{f"/agent/{i}/estimate": "coload.Estimate" for i in range(N)}}
    assert got == {topic: (name, "json", "jsonschema") for topic, name in want.items()}
    for s in summary.schemas.values():
        assert json.loads(s.data)["title"] == s.name


def test_message_counts_match_the_csvs(exported):
    run, summary, messages = exported
    truth = _rows(run / "truth.csv")
    est = _rows(run / "estimates.csv")
    counts = {c.topic: summary.statistics.channel_message_counts[c.id] for c in summary.channels.values()}
    for topic in ("/tf", "/load/pose", "/scene", "/truth"):
        assert counts[topic] == len(truth) == 30, topic  # 3 s at dt 0.01: ticks 0, 10, ..., 290
    for i in range(N):
        assert counts[f"/agent/{i}/estimate"] == sum(1 for r in est if r["agent"] == str(i))
    assert counts["/links"] == 1
    assert sum(counts.values()) == summary.statistics.message_count


def test_one_pose_and_one_estimate_against_the_csvs(exported):
    run, _, messages = exported
    k = 17
    row = _rows(run / "truth.csv")[k]
    t_ns, pose = messages["/load/pose"][k]
    assert t_ns == round(float(row["t"]) * 1e9)
    p, q = pose["pose"]["position"], pose["pose"]["orientation"]
    assert (p["x"], p["y"], p["z"]) == (float(row["x"]), float(row["y"]), 0.0)
    angle = 2.0 * math.atan2(q["z"], q["w"])
    assert math.isclose(math.remainder(angle - float(row["angle"]), 2 * math.pi), 0.0, abs_tol=1e-12)
    _, tf = messages["/tf"][k]
    assert (tf["parent_frame_id"], tf["child_frame_id"]) == ("world", "load")
    assert tf["translation"] == p and tf["rotation"] == q

    est = [r for r in _rows(run / "estimates.csv") if r["agent"] == "3"]
    t_ns, msg = messages["/agent/3/estimate"][k]
    assert t_ns == round(float(est[k]["t"]) * 1e9)
    assert msg["agent"] == 3
    for name, cell in est[k].items():
        if name != "agent":
            assert msg[name] == _cell(cell), name

    # the scene: agent 3's estimated contact point is drawn at p_G + z_3_hat
    _, upd = next(m for m in messages["/scene"] if m[0] == t_ns)
    grow = next(r for r in _rows(run / "truth.csv") if round(float(r["t"]) * 1e9) == t_ns)
    ent = {e["id"]: e for e in upd["entities"]}
    spheres = ent["contacts/estimated"]["spheres"]
    assert len(spheres) == N
    pos = spheres[3]["pose"]["position"]
    assert pos["x"] == pytest.approx(float(grow["pg_x"]) + float(est[k]["zi_x"]), abs=1e-12)
    assert pos["y"] == pytest.approx(float(grow["pg_y"]) + float(est[k]["zi_y"]), abs=1e-12)
    true3 = ent["contacts/true"]["spheres"][3]["pose"]["position"]
    assert true3["x"] == pytest.approx(float(grow["pg_x"]) + float(grow["z3_x"]), abs=1e-12)


def test_export_needs_the_viz_extra(tmp_path):
    """Without the mcap package: one line naming the extra, exit 2, no file."""
    code = ("import sys; sys.modules['mcap'] = None; from coload.cli import main; "
            f"sys.exit(main(['export', {str(tmp_path)!r}, '--mcap', {str(tmp_path / 'x.mcap')!r}]))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert done.stderr == "coload export: needs the Python package(s) mcap: pip install 'coload[viz]'\n"
    assert not (tmp_path / "x.mcap").exists()


@given(angle=st.floats(-20.0, 20.0), gx=st.floats(-50, 50), gy=st.floats(-50, 50),
       w=st.floats(0.1, 10), h=st.floats(0.1, 10))
def test_the_outline_is_the_body_outline_moved_rigidly(angle, gx, gy, w, h):
    body = np.array([(-w / 2, -h / 2), (w / 2, -h / 2), (w / 2, h / 2), (-w / 2, h / 2)])
    msgs = scene.frame(0, (gx, gy, angle), (gx, gy), np.zeros((1, 2)), body, {}, 1)
    upd = next(m.body for m in msgs if m.topic == scene.SCENE_TOPIC)
    pts = np.array([(p["x"], p["y"]) for p in upd["entities"][0]["lines"][0]["points"]])
    d_world = np.linalg.norm(pts[:, None] - pts[None], axis=2)
    d_body = np.linalg.norm(body[:, None] - body[None], axis=2)
    np.testing.assert_allclose(d_world, d_body, atol=1e-9)
    np.testing.assert_allclose(pts.mean(axis=0), (gx, gy), atol=1e-9)
    # the first side keeps its direction relative to the load's angle
    side = pts[1] - pts[0]
    assert math.isclose(math.remainder(math.atan2(side[1], side[0]) - angle, 2 * math.pi), 0.0, abs_tol=1e-9)


def test_summary_records_what_produced_the_run(exported):
    run, _, _ = exported
    versions = json.loads((run / "summary.json").read_text())["versions"]
    assert set(versions) == {"coload", "commit", "numpy", "scipy", "pymunk", "eclipse-zenoh"}
    assert versions["numpy"] == np.__version__ and versions["pymunk"].split(".")[0] == "7"
    assert versions["commit"] is None or len(versions["commit"].removesuffix("+dirty")) == 40
