"""The measured-data format: ``run.toml`` and long per-agent tables (``samples.csv``, ``truth.csv``),
read strictly (docs/run-directory.md).

A malformed file raises :class:`RunFormatError` naming the file, line and column; content that real
recordings produce is accepted: extra columns are ignored, rows may come in any order, an empty
cell (or ``nan``) reads as NaN, and a last line without its newline (a write cut off) is dropped with
a warning, kept in the table's ``warnings``. ``coload diagnose`` reads a recording with these; the application's run
directory (coload.rundir.format) builds on them.
"""

from __future__ import annotations

import csv
import io
import json
import logging
import math
import tomllib
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from net.vocabulary import ESTIMATE_NAMES as KNOWN_ESTIMATE_NAMES

log = logging.getLogger(__name__)

# --- file names and headers ----------------------------------------------------------------------
RUN_TOML = "run.toml"
SAMPLES_CSV = "samples.csv"
TRUTH_CSV = "truth.csv"

SAMPLES_HEADER: tuple[str, ...] = ("t", "agent", "vx", "vy", "fx", "fy", "tau")
"""Measured data: one row per agent per tick (the input format of ``coload diagnose`` too)."""

TRUTH_BASE_HEADER: tuple[str, ...] = (
    "t", "x", "y", "angle", "vc_x", "vc_y", "omega", "zc_x", "zc_y", "pg_x", "pg_y", "mass", "inertia",
)
TRUTH_HEADER: list[str] = list(TRUTH_BASE_HEADER)
"""The base truth columns as a list (writers append the per-agent ``z{i}_x, z{i}_y``); prefer
:func:`truth_header`, which appends them for you. A fresh copy of the tuple, so mutating it harms no reader."""


def truth_header(n: int) -> tuple[str, ...]:
    """Full truth.csv header for ``n`` agents: the base columns, then ``z{i}_x, z{i}_y`` per agent."""
    return TRUTH_BASE_HEADER + tuple(f"z{i}_{c}" for i in range(n) for c in ("x", "y"))


TIME_DECIMALS = 9
"""Times are matched after rounding to this many decimals (1 ns), so that the same tick written by
different agents lands on one grid point despite float formatting."""


T = TypeVar("T")


class RunFormatError(ValueError):
    """A recording's or run directory's file is missing or malformed; the message names file, line and column."""


# --- data containers ---------------------------------------------------------------------------
@dataclass(frozen=True)
class AgentTable:
    """Long-format per-agent CSV pivoted onto a sorted time grid.

    ``columns[name]`` has shape ``(len(t), n)``; NaN where an agent has no row at that time.
    """

    t: np.ndarray
    columns: dict[str, np.ndarray]
    warnings: tuple[str, ...] = ()
    """What was read but not used (a cut last line), one line each with file and line."""

    def has(self, *names: str) -> bool:
        return all(name in self.columns for name in names)


@dataclass(frozen=True)
class TruthTable:
    """truth.csv: ``columns[name]`` shape ``(len(t),)``; ``zi`` shape ``(len(t), n, 2)`` (z_i = p_Ci - p_G)."""

    t: np.ndarray
    columns: dict[str, np.ndarray]
    zi: np.ndarray
    warnings: tuple[str, ...] = ()


def _read_json(path: Path) -> dict[str, Any]:
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise RunFormatError(f"{path}:{exc.lineno}:{exc.colno}: invalid JSON: {exc.msg}") from exc


def read_config(path: Path) -> dict[str, Any]:
    """Parse run.toml and check the keys analysis depends on (``n``, ``dt``, ``edges``)."""
    if not path.exists():
        raise RunFormatError(f"{path}: missing (every run directory needs {RUN_TOML})")
    try:
        config = tomllib.loads(path.read_text(encoding="utf-8-sig"))
    except tomllib.TOMLDecodeError as exc:
        raise RunFormatError(f"{path}: invalid TOML: {exc}") from exc
    except UnicodeDecodeError as exc:
        line = exc.object[: exc.start].count(b"\n") + 1
        raise RunFormatError(f"{path}:{line}: not UTF-8 text (TOML must be UTF-8)") from None
    for key in ("n", "dt", "edges"):
        if key not in config:
            raise RunFormatError(f"{path}: missing top-level key '{key}'")
    n = config["n"]
    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
        raise RunFormatError(f"{path}: 'n' must be a positive integer, got {n!r}")
    dt = config["dt"]
    if not isinstance(dt, (int, float)) or isinstance(dt, bool) or not dt > 0:
        raise RunFormatError(f"{path}: 'dt' must be a positive number, got {dt!r}")
    edges = config["edges"]
    if not isinstance(edges, list):
        raise RunFormatError(f"{path}: 'edges' must be a list of [i, j] pairs")
    for e in edges:
        ok = (
            isinstance(e, list)
            and len(e) == 2
            and all(isinstance(v, int) and not isinstance(v, bool) and 0 <= v < n for v in e)
            and e[0] != e[1]
        )
        if not ok:
            raise RunFormatError(f"{path}: 'edges' entry {e!r} is not a pair of distinct agents in 0..{n - 1}")
    return config


class _SlowPath(Exception):
    """The vectorised reader met something it cannot pinpoint; re-read cell by cell to name file and line."""


@dataclass(frozen=True)
class _Csv:
    """A CSV file, either as a float matrix (fast path, ``lines`` None) or as text rows with line numbers."""

    path: Path
    header: list[str]
    rows: list[list[str]] | None = None
    lines: list[int] | None = None
    matrix: np.ndarray | None = None
    warnings: tuple[str, ...] = ()

    def fail(self, r: int, message: str) -> None:
        """Raise a RunFormatError for row ``r``; on the fast path (no line numbers) fall back first."""
        if self.lines is None:
            raise _SlowPath
        raise RunFormatError(f"{self.path}:{self.lines[r]}: {message}")

    def column(self, name: str, *, integer: bool = False, allow_empty: bool = True) -> np.ndarray:
        """One column as floats (or ints), raising with file, line and column on the first bad cell."""
        k = self.header.index(name)
        if self.matrix is not None:
            values = self.matrix[:, k]
            if name == "t" and not np.all(np.isfinite(values)):
                raise _SlowPath
            if integer:
                if not (np.all(np.isfinite(values)) and np.all(values == np.round(values))):
                    raise _SlowPath
                return values.astype(int)
            return values
        assert self.rows is not None
        cells = [r[k].strip() for r in self.rows]
        out = np.empty(len(cells), dtype=int if integer else float)
        for r, cell in enumerate(cells):
            out[r] = self._parse(cell, r, name, integer=integer, allow_empty=allow_empty)
        return out

    def lenient_column(self, name: str) -> np.ndarray | None:
        """An extra (unspecified) column: floats if it is numeric, else None, i.e. ignored as the format allows."""
        try:
            return self.column(name)
        except RunFormatError:
            return None

    def _parse(self, cell: str, r: int, name: str, *, integer: bool, allow_empty: bool) -> float:
        assert self.lines is not None
        where = f"{self.path}:{self.lines[r]}: column '{name}'"
        if not cell:
            if allow_empty and not integer:  # an integer column (agent) has no "not measured"
                return math.nan
            raise RunFormatError(f"{where}: empty cell" + (", expected an integer" if integer else ""))
        try:
            value = float(cell)
        except ValueError:
            raise RunFormatError(f"{where}: {cell!r} is not a number") from None
        if integer:
            if not value.is_integer():
                raise RunFormatError(f"{where}: {cell!r} is not an integer")
            return int(value)
        if name == "t" and not math.isfinite(value):
            raise RunFormatError(f"{where}: time must be finite, got {cell!r}")
        return value


def _load_fast(path: Path, required: Sequence[str]) -> _Csv | None:
    """All-numeric, well-formed file in one C-speed ``np.loadtxt``; None if anything is unusual."""
    try:
        text = path.read_bytes().decode("utf-8-sig")
        header = [h.strip() for h in next(csv.reader(io.StringIO(text[: text.find("\n") + 1 or None])))]
    except (OSError, UnicodeDecodeError, StopIteration, csv.Error):  # another encoding -> the line reader
        return None
    if any(c not in header for c in required) or len(set(header)) != len(header):
        return None
    cut = ()
    if text and text[-1] not in "\r\n":
        end = text.rfind("\n") + 1
        cut = (_cut_warning(path, text.count("\n", 0, end) + 1, text[end:].count(",") + 1, len(header)),)
        text = text[:end]
    if ",," in text or ",\n" in text or ",\r" in text:  # empty cells: no value, read as NaN
        text = text.replace(",,", ",nan,").replace(",,", ",nan,").replace(",\r", ",nan\r").replace(",\n", ",nan\n")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # "input contained no data": header only
            matrix = np.loadtxt(io.StringIO(text), delimiter=",", skiprows=1, ndmin=2, dtype=float, comments=None)
    except ValueError:
        return None
    if matrix.size == 0:
        matrix = np.empty((0, len(header)))
    if matrix.shape[1] != len(header):
        return None
    return _Csv(path, header, matrix=matrix, warnings=cut)


def _cut_warning(path: Path, line: int, fields: int, expected: int) -> str:
    # a recorder killed mid-write leaves its last line without a newline, perhaps cut mid-number: the
    # whole lines are the recording, so they are read and the cut one is named, not made fatal
    return f"{path}:{line}: last line cut off ({fields} of {expected} fields, no newline): ignored"


_COMPRESSED = ((b"\x1f\x8b", "gzip", "gunzip -c FILE >"), (b"BZh", "bzip2", "bunzip2 -c FILE >"),
               (b"\xfd7zXZ\x00", "xz", "unxz -c FILE >"), (b"\x28\xb5\x2f\xfd", "zstd", "unzstd -c FILE >"),
               (b"PK\x03\x04", "zip", "unzip -p FILE >"))


def _check_text(path: Path) -> None:
    """A compressed or binary file is named as such, not parsed into a located but baffling error."""
    try:
        with path.open("rb") as fh:
            head = fh.read(4096)
    except OSError as exc:
        raise RunFormatError(f"{path}: cannot open: {exc.strerror}") from exc
    for magic, kind, command in _COMPRESSED:
        if head.startswith(magic):
            raise RunFormatError(f"{path}: {kind}-compressed data, not CSV text: decompress it first "
                                 f"({command} {path.name})")
    if b"\x00" in head:
        raise RunFormatError(f"{path}: binary data (a NUL byte in its first {len(head)} bytes), not CSV text")


def _read(path: Path, required: Sequence[str], build: Callable[[_Csv], T]) -> T:
    """Build a table from the fast reader, or from the line-tracking one when the file needs it."""
    _check_text(path)
    csvf = _load_fast(path, required)
    table = None
    if csvf is not None:
        try:
            table = build(csvf)
        except _SlowPath:
            pass
    if table is None:
        csvf = _read_csv(path, required)
        table = build(csvf)
    for message in csvf.warnings:
        log.warning("%s", message)
    return table


def from_rows(path: Path, header: Sequence[str], rows: np.ndarray, build: Callable[[_Csv], T]) -> T:
    """The table a file of ``header`` and the float ``rows`` (one per line, NaN for an empty cell) reads as,
    built without the file: a recorder's rows that nobody keeps as CSV (``path`` names them in errors).
    The build is the reader's, on the numbers the file's ``repr`` text parses back to, so the table is
    the one :func:`_read` gives."""
    csvf = _Csv(path, list(header), matrix=np.asarray(rows, dtype=float).reshape(-1, len(header)))
    try:
        return build(csvf)
    except _SlowPath:  # a time that is not finite or an agent that is not an integer
        raise RunFormatError(f"{path}: rows held in memory are not a valid table") from None


def _read_csv(path: Path, required: Sequence[str]) -> _Csv:
    # utf-8-sig: a byte-order mark (spreadsheet exports) is not part of the first column's name;
    # errors="replace": text in another encoding in an extra column is ignored as the format allows,
    # and in a numeric column it is a located "not a number"
    try:
        fh = path.open(newline="", encoding="utf-8-sig", errors="replace")
    except OSError as exc:
        raise RunFormatError(f"{path}: cannot open: {exc.strerror}") from exc
    with fh:
        reader = csv.reader(fh)
        try:
            header = [h.strip() for h in next(reader)]
        except StopIteration:
            raise RunFormatError(f"{path}:1: empty file, expected header {','.join(required)}") from None
        missing = [c for c in required if c not in header]
        if missing:
            raise RunFormatError(f"{path}:1: header lacks column(s) {', '.join(missing)}; got {','.join(header)}")
        if len(set(header)) != len(header):
            dup = sorted({h for h in header if header.count(h) > 1})
            raise RunFormatError(f"{path}:1: duplicate column(s) {', '.join(dup)}")
        rows: list[list[str]] = []
        lines: list[int] = []
        short: tuple[int, int] | None = None  # (line, fields) of a short row: an error unless it is a cut tail
        cut = _ends_cut(path)

        def wrong_count(line: int, got: int) -> RunFormatError:
            return RunFormatError(f"{path}:{line}: expected {len(header)} fields, got {got}")

        try:
            for row in reader:
                if not row or all(not c.strip() for c in row):
                    continue  # blank line, e.g. trailing newline
                if short is not None:  # rows after a short one: it was not the tail of a cut write
                    raise wrong_count(*short)
                if len(row) > len(header):
                    raise wrong_count(reader.line_num, len(row))
                if len(row) < len(header):
                    short = (reader.line_num, len(row))
                    continue
                rows.append(row)
                lines.append(reader.line_num)
        except csv.Error as exc:
            raise RunFormatError(f"{path}:{reader.line_num}: {exc}") from exc
    if short is not None and not cut:
        raise wrong_count(*short)
    warned: tuple[str, ...] = ()
    if cut and (short is not None or rows):
        line, fields = short if short is not None else (lines[-1], len(rows[-1]))
        warned = (_cut_warning(path, line, fields, len(header)),)
        if short is None:  # all its fields, but the last may be cut mid-number
            rows.pop()
            lines.pop()
    return _Csv(path, header, rows=rows, lines=lines, warnings=warned)


def _ends_cut(path: Path) -> bool:
    """Whether the file's last byte is not a line end (the tail of a write that was cut off)."""
    with path.open("rb") as fh:
        fh.seek(0, 2)
        if fh.tell() == 0:
            return False
        fh.seek(-1, 2)
        return fh.read(1) not in (b"\n", b"\r")


def _time_grid(csvf: _Csv) -> tuple[np.ndarray, np.ndarray]:
    """Sorted unique times and each row's index into them."""
    t = np.round(csvf.column("t", allow_empty=False), TIME_DECIMALS)
    grid, inverse = np.unique(t, return_inverse=True)
    return grid, inverse


def _check_agent(csvf: _Csv, values: np.ndarray, name: str, n: int) -> None:
    bad = np.flatnonzero((values < 0) | (values >= n))
    if len(bad):
        r = int(bad[0])
        csvf.fail(r, f"column '{name}': agent {values[r]} out of range 0..{n - 1}")


def read_agent_csv(path: Path, required: Sequence[str], n: int) -> AgentTable:
    """Read a ``t,agent,...`` long-format file; every column other than t and agent becomes a (T, n) array.

    Required columns and known estimate names must be numeric (empty = NaN); other extra columns are
    kept when numeric and ignored otherwise. Duplicate (t, agent) rows keep the later one in file
    order (a restarted agent re-reporting a tick).
    """
    return _read(path, required, agent_table(required, n))


def agent_table(required: Sequence[str], n: int) -> Callable[[_Csv], AgentTable]:
    """The builder of :func:`read_agent_csv` (for :func:`from_rows` too)."""
    strict = set(required) | set(KNOWN_ESTIMATE_NAMES)

    def build(csvf: _Csv) -> AgentTable:
        grid, ti = _time_grid(csvf)
        agent = csvf.column("agent", integer=True)
        _check_agent(csvf, agent, "agent", n)
        columns: dict[str, np.ndarray] = {}
        for name in csvf.header:
            if name in ("t", "agent"):
                continue
            values = csvf.column(name) if name in strict else csvf.lenient_column(name)
            if values is None:
                continue
            table = np.full((len(grid), n), np.nan)
            table[ti, agent] = values
            columns[name] = table
        return AgentTable(t=grid, columns=columns, warnings=csvf.warnings)

    return build


def read_truth_csv(path: Path, n: int) -> TruthTable:
    """Read truth.csv (one row per tick) sorted by time; requires the z_i columns of all n agents."""
    return _read(path, truth_header(n), truth_table(n))


def truth_table(n: int) -> Callable[[_Csv], TruthTable]:
    """The builder of :func:`read_truth_csv` (for :func:`from_rows` too)."""
    strict = set(truth_header(n))

    def build(csvf: _Csv) -> TruthTable:
        t = csvf.column("t", allow_empty=False)
        order = np.argsort(t, kind="stable")
        columns: dict[str, np.ndarray] = {}
        for name in csvf.header:
            values = csvf.column(name) if name in strict else csvf.lenient_column(name)
            if values is not None:
                columns[name] = values[order]
        zi = np.stack([np.stack([columns[f"z{i}_x"], columns[f"z{i}_y"]], axis=1) for i in range(n)], axis=1)
        return TruthTable(t=columns["t"], columns=columns, zi=zi.reshape(len(t), n, 2), warnings=csvf.warnings)

    return build
