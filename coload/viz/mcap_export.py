"""``coload export RUN_DIR --mcap [FILE]``: a run directory as one MCAP file for Foxglove and Rerun.

JSON-encoded channels with JSON schemas (:data:`coload.viz.scene.SCHEMAS`); message log and publish
times are the simulated time in ns. Needs the ``viz`` extra (the ``mcap`` package). docs/viewers.md.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from coload.rundir import format as rf
from coload.extras import require
from coload.viz.scene import SCHEMAS, channels, outline_body, run_messages
from config.loader import load_scenario

PROFILE = ""  # no ROS profile: plain JSON channels


def default_path(run_dir: Path) -> Path:
    return run_dir / "run.mcap"


def export_mcap(run_dir: Path, out: Path) -> dict[str, int]:
    """Write ``out`` from ``run_dir``; return messages per topic. The file appears only when complete."""
    require("viz", "mcap")
    from mcap.writer import CompressionType, Writer

    run = rf.read_run(run_dir)
    if run.truth is None:
        raise rf.RunFormatError(f"{run_dir / rf.TRUTH_CSV}: missing (the viewer's scene is drawn from the truth)")
    outline = outline_body(load_scenario(run_dir / rf.RUN_TOML))
    counts: dict[str, int] = {}
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    try:
        with tmp.open("wb") as fh:
            writer = Writer(fh, compression=CompressionType.ZSTD)
            writer.start(profile=PROFILE, library="coload")
            schema_ids = {name: writer.register_schema(name=name, encoding="jsonschema",
                                                       data=json.dumps(schema).encode())
                          for name, schema in SCHEMAS.items()}
            channel_ids = {topic: writer.register_channel(topic=topic, message_encoding="json",
                                                          schema_id=schema_ids[name])
                           for topic, name in channels(run.n).items()}
            seq: dict[str, int] = {}
            for msg in run_messages(run, outline):
                k = seq.get(msg.topic, 0)
                writer.add_message(channel_id=channel_ids[msg.topic], log_time=msg.t_ns, publish_time=msg.t_ns,
                                   data=json.dumps(msg.body, separators=(",", ":")).encode(), sequence=k)
                seq[msg.topic] = k + 1
            writer.finish()
        tmp.replace(out)
        counts = seq
    finally:
        tmp.unlink(missing_ok=True)
    return counts
