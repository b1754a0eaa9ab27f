"""Wide time-series tables of a run directory: one row per time, ``t`` first, one column per scalar.

The engines that record whole state vectors per time (``coload hinf run``: trace.csv; ``coload
observer run``: series.csv) write them with :func:`write_series`, and read them back with
:func:`read_series`, bit-identical (floats are written with ``repr``). A 2-D array ``x`` of shape
``(T, k)`` becomes the columns ``x_0 .. x_{k-1}``; a 1-D array keeps its name. The layout is
documented in docs/run-directory.md ("Time-series tables").
"""

from __future__ import annotations

import csv
import re
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from ident.tables import RunFormatError

_INDEXED = re.compile(r"(?P<name>.+)_(?P<k>0|[1-9][0-9]*)")


def series_header(columns: Mapping[str, np.ndarray]) -> list[str]:
    header = ["t"]
    for name, arr in columns.items():
        if name == "t" or _INDEXED.fullmatch(name):
            raise ValueError(f"series column name {name!r}: 't' and names ending in _<digits> are reserved")
        a = np.asarray(arr)
        if a.ndim == 1:
            header.append(name)
        elif a.ndim == 2:
            header.extend(f"{name}_{k}" for k in range(a.shape[1]))
        else:
            raise ValueError(f"series column {name!r}: expected a 1-D or 2-D array, got shape {a.shape}")
    return header


def write_series(path: Path, t: np.ndarray, columns: Mapping[str, np.ndarray]) -> None:
    """Writes ``t`` and ``columns`` (each with ``len(t)`` rows) to ``path``; booleans as 0 and 1."""
    t = np.asarray(t, dtype=float)
    header = series_header(columns)
    blocks = [t[:, None]]
    for name, arr in columns.items():
        a = np.asarray(arr, dtype=float)
        if a.shape[0] != len(t):
            raise ValueError(f"series column {name!r}: {a.shape[0]} rows for {len(t)} times")
        blocks.append(a if a.ndim == 2 else a[:, None])
    table = np.hstack(blocks)
    with Path(path).open("w", encoding="utf-8", newline="") as f:
        f.write(",".join(header) + "\n")
        for row in table:
            f.write(",".join(map(repr, row.tolist())) + "\n")


def read_series(path: Path) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(t, columns) of a table written by :func:`write_series`: ``x_0 .. x_{k-1}`` come back as one
    ``(T, k)`` array ``x``. An empty cell reads as NaN. A malformed file raises
    :class:`~ident.tables.RunFormatError` naming file, line and column."""
    path = Path(path)
    try:
        with path.open(encoding="utf-8", newline="") as f:
            rows = list(csv.reader(f))
    except OSError as exc:
        raise RunFormatError(f"{path}: cannot read it ({exc.strerror})") from None
    if not rows or not rows[0] or rows[0][0] != "t":
        raise RunFormatError(f"{path}:1: expected a header starting with 't'")
    header = rows[0]
    data = np.empty((len(rows) - 1, len(header)))
    for r, row in enumerate(rows[1:], start=2):
        if len(row) != len(header):
            raise RunFormatError(f"{path}:{r}: {len(row)} fields, expected {len(header)}")
        for c, cell in enumerate(row):
            try:
                data[r - 2, c] = float(cell) if cell.strip() else np.nan
            except ValueError:
                raise RunFormatError(f"{path}:{r}: column {header[c]!r}: {cell!r} is not a number") from None
    out: dict[str, list[tuple[int, int]]] = {}
    for c, name in enumerate(header[1:], start=1):
        m = _INDEXED.fullmatch(name)
        key, k = (m.group("name"), int(m.group("k"))) if m else (name, -1)
        out.setdefault(key, []).append((k, c))
    columns: dict[str, np.ndarray] = {}
    for key, parts in out.items():
        if parts == [(-1, parts[0][1])]:
            columns[key] = data[:, parts[0][1]]
            continue
        ks = sorted(k for k, _ in parts)
        if ks != list(range(len(ks))):
            raise RunFormatError(f"{path}:1: columns {key}_k are not numbered 0..{len(ks) - 1}")
        columns[key] = data[:, [c for _, c in sorted(parts)]]
    return data[:, 0], columns
