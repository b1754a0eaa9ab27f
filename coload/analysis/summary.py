"""Completes a finished run's summary.json with what is computed from its files: the error metrics
and the centralized batch-fit yardstick (docs/run-directory.md, docs/batch-fit.md).

The recorder only records; every engine calls :func:`complete_summary` once the run directory is
closed.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from coload.analysis import yardstick
from coload.analysis.metrics import final_errors
from coload.provenance import versions
from coload.rundir import format as fmt
from coload.rundir.recorder import write_summary
from config.scenario import Scenario


def complete_summary(run_dir: Path, scenario: Scenario, summary: dict[str, Any]) -> dict[str, Any]:
    """Adds ``errors`` (and, with ``record.batch_fit``, the centralized blocks) and ``versions`` to
    ``summary`` and rewrites summary.json. A run too short to score still keeps its summary, with the reason."""
    run = None
    try:
        run = fmt.read_run(run_dir)
        summary["errors"] = final_errors(run)
    except (ValueError, OSError) as exc:
        summary["errors"] = {}
        summary.setdefault("warnings", []).append(f"errors not computed: {exc}")
    if scenario.record.batch_fit:
        summary.update(_centralized(run))
    summary["versions"] = versions()
    write_summary(Path(run_dir), summary)
    return summary


def _centralized(run: fmt.RunData | None) -> dict[str, Any]:
    """The batch-fit yardstick blocks (coload.analysis.yardstick.centralized_blocks); whatever goes wrong, the run
    still gets its summary, with null blocks and the reason."""
    try:
        if run is None:
            raise ValueError("the run directory could not be read")
        return yardstick.centralized_blocks(run)
    except Exception as exc:  # noqa: BLE001  the yardstick must never cost the run its summary
        reason = f"batch fit not run: {type(exc).__name__}: {exc}"
        return {"centralized": {**dict.fromkeys(yardstick.CENTRAL_KEYS), "flags": [], "reason": reason},
                "distributed_over_centralized": {**dict.fromkeys(yardstick.RATIO_KEYS), "reason": reason}}
