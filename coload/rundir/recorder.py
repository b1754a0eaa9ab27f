"""Writes a run directory as the run goes (see docs/run-directory.md).

Rows are buffered and flushed in blocks so that recording stays a small share of a tick (the samples, a
row per agent every tick, are kept as numbers in a preallocated block and formatted a block at a time); floats
are written with ``repr`` so that they read back bit-identical (the engine-equality test relies on it), and
a missing value (NaN) as an empty cell. A recorder made with ``tables=False`` writes run.toml and summary.json
only and keeps the tables as numbers, read with :meth:`Recorder.held`: a campaign's runs, whose tables are
dropped, compute their summary from the same numbers without formatting and parsing them.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from coload.rundir import format as fmt
from config.loader import dump_scenario
from config.scenario import Scenario
from net.messages import Estimate

_FLUSH_ROWS = 20_000
_SAMPLE_TICKS = 2_000  # ticks of samples held as numbers before they are formatted


class _Table:
    def __init__(self, path: Path, header: list[str]) -> None:
        self._file = path.open("w", encoding="utf-8", newline="")
        self._file.write(",".join(header) + "\n")
        self._rows: list[str] = []

    def add(self, row: str) -> None:
        self._rows.append(row)
        if len(self._rows) >= _FLUSH_ROWS:
            self.flush()

    def add_rows(self, rows: list[str]) -> None:
        self._rows += rows
        if len(self._rows) >= _FLUSH_ROWS:
            self.flush()

    def flush(self) -> None:
        if self._rows:
            self._file.write("\n".join(self._rows) + "\n")
            self._rows.clear()
        self._file.flush()

    def close(self) -> None:
        self.flush()
        self._file.close()


def _cell(x: float) -> str:
    """A Python float's cell: no value (NaN) is an empty cell, which every CSV reader takes for missing (a
    "nan" cell turns a column into strings for some); repr reads back bit-identical."""
    return repr(x) if x == x else ""


def _f(x: float) -> str:
    """Any number's cell (:func:`_cell` of it as a Python float)."""
    return _cell(float(x))


class Recorder:
    """One run directory. ``estimate_names`` fixes the columns of estimates.csv; ``tables=False`` keeps the
    tables in memory instead of writing their CSV files (module docstring)."""

    def __init__(self, run_dir: Path, scenario: Scenario, estimate_names: tuple[str, ...], tables: bool = True) -> None:
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        (self.run_dir / "logs").mkdir(exist_ok=True)
        self.scenario = scenario
        self.dt = scenario.dt
        self.every = scenario.record.every_ticks
        self.estimate_names = estimate_names
        for name in fmt.DERIVED_FILES:  # a previous run's, in a re-used directory
            (self.run_dir / name).unlink(missing_ok=True)
        (self.run_dir / fmt.RUN_TOML).write_text(dump_scenario(scenario), encoding="utf-8")
        self._headers = {fmt.SAMPLES_CSV: fmt.SAMPLES_HEADER, fmt.ESTIMATES_CSV: ("t", "agent", *estimate_names),
                         fmt.PAIRS_CSV: fmt.PAIRS_HEADER, fmt.TRUTH_CSV: fmt.truth_header(scenario.n)}
        self.files = tables
        self._tables: tuple[_Table, ...] = ()
        if tables:
            self._samples, self._estimates, self._pairs, self._truth = self._tables = tuple(
                _Table(self.run_dir / name, list(header)) for name, header in self._headers.items())
        else:
            for name in self._headers:  # a previous run's, which would contradict this one's summary
                (self.run_dir / name).unlink(missing_ok=True)
        # tables=False: each table's rows as float64 blocks (a block of samples ticks, a recorded tick's rows)
        self._held: dict[str, list[Any]] = {name: [] for name in self._headers}
        self._sample_ticks: list[int] = []  # the ticks in _sample_block, not yet formatted
        self._sample_block: np.ndarray | None = None  # (_SAMPLE_TICKS, agents, vx vy fx fy tau), on first use
        self.estimates_recorded = 0
        self._closed = False
        self.ticks_done = 0  # ticks whose samples are recorded

    def keeps(self, tick: int) -> bool:
        return tick % self.every == 0

    def samples(self, tick: int, velocities: Any, wrenches: Any) -> None:
        """One tick of measured data: every agent's measured velocity (agents, 2) and applied wrench (agents, 3),
        arrays or sequences of floats."""
        self.ticks_done = tick + 1
        velocities = np.asarray(velocities, dtype=float)
        if self._sample_block is None:
            self._sample_block = np.empty((_SAMPLE_TICKS, len(velocities), 5))
        row = self._sample_block[len(self._sample_ticks)]
        row[:, :2] = velocities
        row[:, 2:] = wrenches
        self._sample_ticks.append(tick)
        if len(self._sample_ticks) == _SAMPLE_TICKS:
            self._format_samples()

    def _format_samples(self) -> None:
        """The held ticks of samples as rows of samples.csv (``tolist`` gives Python floats, whose repr is
        the number's shortest round-trip text)."""
        ticks = self._sample_ticks
        if not ticks:
            return
        dt = self.dt
        if not self.files:
            n = self._sample_block.shape[1]  # type: ignore[union-attr]
            block = np.empty((len(ticks), n, 7))
            block[:, :, 0] = (np.array(ticks) * dt)[:, None]  # the products repr(tick * dt) writes
            block[:, :, 1] = np.arange(n)
            block[:, :, 2:] = self._sample_block[: len(ticks)]  # type: ignore[index]
            self._held[fmt.SAMPLES_CSV].append(block.reshape(-1, 7))
            ticks.clear()
            return
        rows: list[str] = []
        for tick, agents in zip(ticks, self._sample_block[: len(ticks)].tolist(), strict=True):  # type: ignore[index]
            t = repr(tick * dt)
            rows += [f"{t},{agent},{vx!r},{vy!r},{fx!r},{fy!r},{tau!r}"
                     for agent, (vx, vy, fx, fy, tau) in enumerate(agents)]
        self._samples.add_rows(rows)
        ticks.clear()

    def truth(self, truth: Any) -> None:
        if not self.keeps(truth.tick):
            return
        row = [float(v) for v in (
            truth.t, truth.x, truth.y, truth.angle, truth.vc[0], truth.vc[1], truth.omega,
            truth.zc[0], truth.zc[1], truth.pg[0], truth.pg[1], truth.mass, truth.inertia)]
        row += [float(c) for z in truth.zi for c in z]
        if self.files:
            self._truth.add(",".join([_cell(x) for x in row]))
        else:
            self._held[fmt.TRUTH_CSV].append(np.array([row]))

    def estimate(self, est: Estimate) -> None:
        vals = est.values
        self.estimate_rows(est.tick, [est.agent], [[float(vals.get(name, math.nan)) for name in self.estimate_names]],
                           [sorted((j, float(x), float(y)) for j, (x, y) in est.pairs.items())])

    def estimate_rows(
        self,
        tick: int,
        agents: Sequence[int],
        values: Sequence[Sequence[float]],
        pairs: Sequence[Sequence[tuple[int, float, float]]],
    ) -> None:
        """Estimates of one tick as rows (agents/team.py ``TeamCore.estimate_rows``): agent ``agents[i]``'s
        ``values[i]`` in the order of ``estimate_names`` (NaN: none) and ``pairs[i]`` (neighbour, z_ij x,
        z_ij y) by neighbour, all Python floats."""
        if not self.keeps(tick):
            return
        self.estimates_recorded += len(values)
        if not self.files:  # a block of float64 rows per tick (8 bytes a value, where a list holds ~32)
            if not values:
                return
            t = float(tick * self.dt)
            est = np.empty((len(values), len(self.estimate_names) + 2))
            est[:, 0] = t
            est[:, 1] = agents
            est[:, 2:] = np.array(values, dtype=float).reshape(len(values), -1)
            self._held[fmt.ESTIMATES_CSV].append(est)
            pr = [[t, agent, j, x, y]
                  for agent, agent_pairs in zip(agents, pairs, strict=True) for j, x, y in agent_pairs]
            if pr:
                self._held[fmt.PAIRS_CSV].append(np.array(pr, dtype=float))
            return
        t = _f(tick * self.dt)
        for agent, row, agent_pairs in zip(agents, values, pairs, strict=True):
            self._estimates.add(f"{t},{agent}," + ",".join([_cell(x) for x in row]))
            for j, x, y in agent_pairs:
                self._pairs.add(f"{t},{agent},{j},{_f(x)},{_f(y)}")

    def flush(self) -> None:
        self._format_samples()
        for table in self._tables:
            table.flush()

    def abort(self, reason: str) -> None:
        """The run stops before its end: the tables keep every tick so far (flushed, closed) and
        ``interrupted.json`` says where (the first tick without samples) and why; no summary.json,
        so nothing reads it as finished."""
        if self._closed:
            return
        self._closed = True
        tick = self.ticks_done
        self._format_samples()
        for table in self._tables:
            table.close()
        (self.run_dir / fmt.INTERRUPTED_JSON).write_text(json.dumps(
            {"tick": tick, "t": tick * self.dt, "reason": reason, "duration": self.scenario.duration}, indent=1) + "\n",
            encoding="utf-8")

    def held(self) -> fmt.RunData:
        """The run as :func:`coload.rundir.format.read_run` reads it, from the tables held in memory (a
        recorder made with ``tables=False``, after :meth:`close`)."""
        if self.files or not self._closed:
            raise RuntimeError("held(): only a closed recorder made with tables=False holds its tables")
        tables = {}
        for name, header in self._headers.items():
            rows = self._held[name]
            tables[name] = (header, np.concatenate(rows) if rows else np.empty((0, len(header))))
        summary = json.loads((self.run_dir / fmt.SUMMARY_JSON).read_text(encoding="utf-8"))
        return fmt.run_from_rows(self.run_dir, tables, summary)

    @property
    def journal_path(self) -> Path:
        """Where the simulator daemon keeps its restart journal (in the run directory)."""
        return self.run_dir / fmt.JOURNAL

    def close(self, summary: dict[str, Any]) -> dict[str, Any]:
        """Closes the tables and writes ``summary`` as summary.json; the application adds the error
        metrics afterwards (coload.analysis.summary)."""
        self._closed = True
        self._format_samples()
        for table in self._tables:
            table.close()
        write_summary(self.run_dir, summary)
        return summary


def write_summary(run_dir: Path, summary: dict[str, Any]) -> None:
    path = Path(run_dir) / fmt.SUMMARY_JSON
    path.write_text(json.dumps(summary, indent=2, sort_keys=False, default=_json_default) + "\n", encoding="utf-8")


def _json_default(obj: Any) -> Any:
    if hasattr(obj, "as_dict"):
        return obj.as_dict()
    if hasattr(obj, "tolist"):
        return obj.tolist()
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")
