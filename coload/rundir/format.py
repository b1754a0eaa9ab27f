"""The run directory: file names, CSV headers and a strict reader.

Engines import the constants below to write a run directory; analysis (:mod:`coload.analysis.metrics`,
:mod:`coload.analysis.report`, ``coload diagnose``) reads it back with :func:`read_run`. Keeping both sides on
the same constants is what stops the format from drifting. The format is documented for people in
``docs/run-directory.md``; the measured-data part (run.toml, samples.csv, truth.csv) is read by
:mod:`ident.tables`, which ``coload diagnose`` uses on any recording.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ident.tables import (  # noqa: F401  (re-exported: the run directory's format is one namespace)
    RUN_TOML,
    SAMPLES_CSV,
    SAMPLES_HEADER,
    TIME_DECIMALS,
    TRUTH_BASE_HEADER,
    TRUTH_CSV,
    TRUTH_HEADER,
    AgentTable,
    RunFormatError,
    TruthTable,
    _check_agent,
    _Csv,
    _read,
    _read_json,
    _time_grid,
    agent_table,
    from_rows,
    read_agent_csv,
    read_config,
    read_truth_csv,
    truth_header,
    truth_table,
)
from net.vocabulary import ESTIMATE_NAMES as AGENT_ESTIMATE_NAMES

# --- file names --------------------------------------------------------------------------------
ESTIMATES_CSV = "estimates.csv"
PAIRS_CSV = "pairs.csv"
SUMMARY_JSON = "summary.json"
LOGS_DIR = "logs"
REPORT_PNG = "report.png"
DIAGNOSIS_JSON = "diagnosis.json"
"""A run directory's diagnosis (``coload diagnose RUN_DIR --json RUN_DIR/diagnosis.json`` or
``coload report RUN_DIR --diagnose``); when present, the report adds :data:`RESIDUAL_PNG`."""
RESIDUAL_PNG = "residual.png"
JOURNAL = "sim.journal"
"""The simulator daemon's restart journal (deleted at the end of a completed run)."""
INTERRUPTED_JSON = "interrupted.json"
"""Written instead of summary.json by a run that was stopped (Ctrl-C, SIGTERM, an error): the tick
it reached and why. Its tables hold every tick up to there."""
DERIVED_FILES = (SUMMARY_JSON, INTERRUPTED_JSON, REPORT_PNG, DIAGNOSIS_JSON, RESIDUAL_PNG)
"""What a run writes besides its tables: a new run in the same directory removes the old ones, so
that nothing of a previous run is read as this one's."""

# --- headers -----------------------------------------------------------------------------------
ESTIMATES_KEY: tuple[str, ...] = ("t", "agent")
KNOWN_ESTIMATE_NAMES: tuple[str, ...] = AGENT_ESTIMATE_NAMES
"""The estimate columns the agents write (one list, the writer's: ``net.vocabulary.ESTIMATE_NAMES``);
a reader parses each of them strictly (a bad cell is an error naming file, line and column). Any
may be absent (an older run, a lab's own estimator); other columns are kept when numeric."""
ESTIMATES_HEADER: tuple[str, ...] = ESTIMATES_KEY + AGENT_ESTIMATE_NAMES

PAIRS_HEADER: tuple[str, ...] = ("t", "agent", "neighbour", "zij_x", "zij_y")


# --- data containers ---------------------------------------------------------------------------
@dataclass(frozen=True)
class PairTable:
    """pairs.csv pivoted: ``zij[(i, j)]`` is agent i's estimate of z_ij, shape ``(len(t), 2)``, NaN if absent."""

    t: np.ndarray
    zij: dict[tuple[int, int], np.ndarray]


@dataclass(frozen=True)
class RunData:
    """Everything in a run directory, as arrays. Files a recording may lack (lab data has no truth) are None."""

    path: Path
    config: dict[str, Any]
    n: int
    dt: float
    edges: tuple[tuple[int, int], ...]
    samples: AgentTable | None = None
    estimates: AgentTable | None = None
    pairs: PairTable | None = None
    truth: TruthTable | None = None
    summary: dict[str, Any] | None = None
    name: str = ""

    def truth_index(self, times: np.ndarray) -> np.ndarray:
        """Index of the truth row nearest to each of ``times`` (truth is kept every ``record.every_ticks``
        ticks, like the estimates, so an estimate's tick has its own truth row)."""
        if self.truth is None:
            raise RunFormatError(f"{self.path / TRUTH_CSV}: no truth recorded in this run")
        tt = self.truth.t
        if len(tt) == 0:
            raise RunFormatError(f"{self.path / TRUTH_CSV}: no rows")
        idx = np.clip(np.searchsorted(tt, times), 1, max(len(tt) - 1, 1))
        if len(tt) == 1:
            return np.zeros(len(times), dtype=int)
        left = tt[idx - 1]
        right = tt[idx]
        return np.where(np.abs(times - left) <= np.abs(right - times), idx - 1, idx)


# --- reading -----------------------------------------------------------------------------------
def read_run(run_dir: str | Path) -> RunData:
    """Read a run directory. ``run.toml`` and ``samples.csv`` are required; the rest is optional."""
    path = Path(run_dir)
    if not path.is_dir():
        raise RunFormatError(f"{path}: not a directory")
    config = read_config(path / RUN_TOML)
    n = config["n"]
    return _run(path, config,
                samples=read_agent_csv(path / SAMPLES_CSV, SAMPLES_HEADER, n),
                estimates=_optional(path / ESTIMATES_CSV, lambda p: read_agent_csv(p, ESTIMATES_KEY, n)),
                pairs=_optional(path / PAIRS_CSV, lambda p: read_pairs_csv(p, n)),
                truth=_optional(path / TRUTH_CSV, lambda p: read_truth_csv(p, n)),
                summary=_optional(path / SUMMARY_JSON, _read_json))


def run_from_rows(
    run_dir: str | Path, tables: dict[str, tuple[Sequence[str], np.ndarray]], summary: dict[str, Any] | None
) -> RunData:
    """The run :func:`read_run` reads from ``run_dir`` (its run.toml) if its CSV files held ``tables[file name]
    = (header, float rows)``, without the files: a recorder's tables that nobody keeps (``from_rows``).
    samples.csv is required; ``summary`` stands for summary.json."""
    path = Path(run_dir)
    config = read_config(path / RUN_TOML)
    n = config["n"]

    def table(name: str, build: Callable[[_Csv], Any]) -> Any:
        if name not in tables:
            return None
        header, rows = tables[name]
        return from_rows(path / name, header, rows, build)

    if SAMPLES_CSV not in tables:
        raise RunFormatError(f"{path / SAMPLES_CSV}: missing")
    return _run(path, config,
                samples=table(SAMPLES_CSV, agent_table(SAMPLES_HEADER, n)),
                estimates=table(ESTIMATES_CSV, agent_table(ESTIMATES_KEY, n)),
                pairs=table(PAIRS_CSV, pair_table(n)),
                truth=table(TRUTH_CSV, truth_table(n)),
                summary=summary)


def _run(path: Path, config: dict[str, Any], **tables: Any) -> RunData:
    return RunData(path=path, config=config, n=config["n"], dt=float(config["dt"]),
                   edges=tuple((int(i), int(j)) for i, j in config["edges"]),
                   name=str(config.get("name", path.name)), **tables)


def _optional(path: Path, reader: Any) -> Any:
    return reader(path) if path.exists() else None


def read_pairs_csv(path: Path, n: int) -> PairTable:
    """Read pairs.csv into one (T, 2) array per directed pair (agent, neighbour)."""
    return _read(path, PAIRS_HEADER, pair_table(n))


def pair_table(n: int) -> Callable[[_Csv], PairTable]:
    """The builder of :func:`read_pairs_csv` (for ``from_rows`` too)."""

    def build(csvf: _Csv) -> PairTable:
        grid, ti = _time_grid(csvf)
        agent = csvf.column("agent", integer=True)
        nb = csvf.column("neighbour", integer=True)
        _check_agent(csvf, agent, "agent", n)
        _check_agent(csvf, nb, "neighbour", n)
        same = np.flatnonzero(agent == nb)
        if len(same):
            r = int(same[0])
            csvf.fail(r, f"column 'neighbour': agent {agent[r]} paired with itself")
        xy = np.stack([csvf.column("zij_x"), csvf.column("zij_y")], axis=1)
        zij: dict[tuple[int, int], np.ndarray] = {}
        keys = agent * n + nb
        order = np.argsort(keys, kind="stable")
        uniq, starts = np.unique(keys[order], return_index=True)
        for key, rows in zip(uniq, np.split(order, starts[1:])):
            arr = np.full((len(grid), 2), np.nan)
            arr[ti[rows]] = xy[rows]
            zij[(int(key // n), int(key % n))] = arr
        return PairTable(t=grid, zij=zij)

    return build
