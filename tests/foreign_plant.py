"""bench/foreign_recordings.py's plant (scipy, no code shared with ident/), loaded by its path for the tests:
``plant.record(DIR, ...)`` writes a recording and returns its truth."""

from __future__ import annotations

import importlib.util
from pathlib import Path

_spec = importlib.util.spec_from_file_location(
    "foreign_recordings", Path(__file__).resolve().parents[1] / "bench" / "foreign_recordings.py")
plant = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(plant)
