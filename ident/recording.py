"""Recordings in the measured-data format: ``samples.csv`` + ``run.toml`` (docs/diagnose.md, "Input").

:func:`read_recording` reads a directory into a :class:`Recording` (stamps, per-agent measured contact
velocities and/or positions, applied wrenches); :func:`recording_from_arrays` builds one from arrays.
Stamps may be irregular and have gaps; a missing value is an empty cell. Bad input raises
:class:`RecordingError` with file, line and field.
"""

from __future__ import annotations

import csv
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ident.tables import RunFormatError, _check_text, _cut_warning, _ends_cut

RUN_TOML = "run.toml"
SAMPLES_CSV = "samples.csv"
TRUTH_CSV = "truth.csv"
WRENCH = ("fx", "fy", "tau")
HOLDS = ("cubic", "foh", "zoh")
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
FAST = 50.0  # m/s: a contact speed above this is read as a unit mistake (a warning, nothing else)


class RecordingError(ValueError):
    """The recording cannot be read; the message names the file, line and field."""


@dataclass
class Recording:
    """One recording. ``t`` (T,) increasing stamps (s, the union over agents); per stamp and agent
    ``vel``, ``pos`` (T, n, 2) measured contact velocity/position (NaN = not measured; None = no such
    columns) and ``wrench`` (T, n, 3) [fx, fy, tau] applied (gaps interpolated, see ``warnings``).
    ``t`` counts from the first stamp, which is ``t0`` on the recording's own clock: a logger's epoch
    stamps (~1.7e9 s) resolve 0.2 us only, too coarse for the delay's derivative."""

    t: np.ndarray
    n: int
    wrench: np.ndarray
    vel: np.ndarray | None = None
    pos: np.ndarray | None = None
    dt: float | None = None  # nominal sample period from run.toml (informative only)
    hold: str = "foh"  # how the applied wrench varies between stamps: cubic, first-order ("foh") or held ("zoh")
    hold_source: str = "declared"  # "declared", "default" (run.toml silent) or why it was inferred
    truth: dict[str, float] | None = None
    warnings: list[str] = field(default_factory=list)
    t0: float = 0.0
    wrench_logged: np.ndarray | None = None  # (T, n): where each agent's fx, fy are its own (not interpolated)

    @property
    def T(self) -> int:
        return int(self.t.size)


def recording_from_arrays(t, wrench, vel=None, pos=None, *, hold: str = "foh", dt: float | None = None,
                          truth: dict[str, float] | None = None) -> Recording:  # fmt: skip
    """Check shapes and fill wrench gaps; raises :class:`RecordingError`."""
    t = np.asarray(t, float)
    w = np.array(wrench, float)
    if t.ndim != 1 or t.size < 10:
        raise RecordingError(f"need at least 10 stamps, got {t.size}")
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise RecordingError("stamps must be finite and strictly increasing")
    if w.ndim != 3 or w.shape[0] != t.size or w.shape[2] != 3:
        raise RecordingError(f"wrench must have shape (T={t.size}, n, 3), got {w.shape}")
    n = w.shape[1]
    arrs = []
    for name, a in (("vel", vel), ("pos", pos)):
        if a is not None:
            a = np.array(a, float)  # a copy: an axis measured nowhere is filled in place
            if a.shape != (t.size, n, 2):
                raise RecordingError(f"{name} must have shape ({t.size}, {n}, 2), got {a.shape}")
            if np.isinf(a).any():
                raise RecordingError(f"{name} contains inf")
        arrs.append(a)
    warns = []
    for k, name in ((0, "velocities (vx,vy)"), (1, "positions (x,y)")):
        if arrs[k] is not None and np.isnan(arrs[k]).all():
            arrs[k] = None
            warns.append(f"no {name} in any row: not used")
    vel, pos = arrs
    if vel is None and pos is None:
        raise RecordingError("no measurements: need vx,vy and/or x,y columns")
    if hold not in HOLDS:
        raise RecordingError(f"input_hold must be one of {HOLDS}, got {hold!r}")
    for c, axis in enumerate("xy"):
        warns += _one_axis(c, axis, w, vel, pos)
    miss = np.isnan(w)
    none = miss.all(axis=0)  # (n, 3): a column with no value for an agent at all
    for c, name in enumerate(WRENCH):
        if none[:, c].any():
            who = ",".join(str(i) for i in np.flatnonzero(none[:, c]))
            warns.append(f"column {name}: no value in any row of agent(s) {who}: taken as 0")
    unknown, gaps = _wrench_gaps(t, miss & ~none)
    if unknown.any():
        keep = ~unknown
        if keep.sum() < 10:
            raise RecordingError(f"fewer than 10 stamps with every agent's wrench known ({'; '.join(gaps)})")
        warns.append(f"the total force is unknown where an agent's wrench is missing for longer than {WRENCH_GAP:g} "
                     f"of its sample periods ({'; '.join(gaps)}): {int(unknown.sum())} stamps left out")
        t, w, miss = t[keep], w[keep], miss[keep]
        vel, pos = (None if a is None else a[keep] for a in (vel, pos))
    part = miss & ~none
    if part.any():
        # a wrench logged in rows of its own (mostly not at a velocity's stamp) is a stream of its own, not gaps
        measured = np.isfinite(vel).all(axis=2) if vel is not None else np.zeros(part.shape[:2], bool)
        own = measured.any() and (measured & ~part.any(axis=2)).sum() < 0.5 * measured.sum()
        warns.append(f"{int(part.any(axis=2).sum())} agent-stamps without a (complete) wrench: interpolated in time"
                     + (" (the wrench is logged at stamps of its own, the velocities at others)" if own else ""))
    for i in range(n):
        for c in range(3):
            m = miss[:, i, c]
            if m.all():
                w[:, i, c] = 0.0
            elif m.any():
                w[m, i, c] = np.interp(t[m], t[~m], w[~m, i, c])
    t0 = float(t[0])
    return Recording(t=t - t0, n=n, wrench=w, vel=vel, pos=pos, dt=dt, hold=hold, truth=truth, warnings=warns, t0=t0,
                     wrench_logged=~miss[..., :2].any(axis=2))


WRENCH_GAP = 5.0  # a wrench missing for more than this many of the agent's own sample periods is unknown


def _wrench_gaps(t: np.ndarray, miss: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """The stamps where an agent's wrench is unknown: a run of missing values longer than ``WRENCH_GAP`` of
    that agent's median interval between known values (a logger that dropped out; a force logged at a lower
    rate than the velocities leaves shorter runs, which are interpolated). The mask (T,) and one phrase per
    gap. ``miss`` (T, n, 3) is True where a value is missing in a column the agent logs at all."""
    unknown = np.zeros(t.size, bool)
    spans: dict[tuple[int, int], set[int]] = {}
    for i in range(miss.shape[1]):
        for c in range(miss.shape[2]):
            known = np.flatnonzero(~miss[:, i, c])
            if known.size == t.size:
                continue
            med = float(np.median(np.diff(t[known]))) if known.size > 1 else math.inf
            edges = np.r_[-1, known, t.size]  # a virtual known value just outside each end
            for a, b in zip(edges[:-1], edges[1:]):
                if b - a < 2:
                    continue
                ta = t[a] if a >= 0 else t[0] - med
                tb = t[b] if b < t.size else t[-1] + med
                if not tb - ta <= WRENCH_GAP * med:
                    unknown[a + 1 : b] = True
                    spans.setdefault((a + 1, b - 1), set()).add(i)
    gaps = [f"agent {','.join(map(str, sorted(who)))} from {t[a] - t[0]:.6g} s to {t[b] - t[0]:.6g} s"
            for (a, b), who in sorted(spans.items())]
    return unknown, gaps


def _one_axis(c: int, axis: str, w: np.ndarray, vel: np.ndarray | None, pos: np.ndarray | None) -> list[str]:
    """An axis measured in no row (a recording along the other axis, with the column empty or absent)
    carries no motion to fit: with no force on it either, its component is set to 0 in place (as a rail's
    logger writes it), so every row keeps the other axis' value and the fit leaves the axis out
    (ident/fit.py); with a force on it, the recording cannot be fitted. Returns the warning."""
    have = [a for a in (vel, pos) if a is not None]
    if any(not np.isnan(a[..., c]).all() for a in have):
        return []
    if np.nan_to_num(w[..., c]).any():
        f = "fx" if c == 0 else "fy"
        raise RecordingError(f"column {f} applies a force along {axis}, but no row measures the {axis} motion "
                             f"(v{axis} or {axis}): cannot fit it")
    for a in have:
        a[..., c] = 0.0  # a row without the other axis' value stays unused (the fit needs both)
    w[..., c] = 0.0
    return [f"axis {axis}: no measurement and no force in any row: a recording along the other axis only"]


def _header_hint(header: list[str]) -> str:
    """What a header that does not start t,agent most likely is, for the error's text."""
    first = header[0] if header else ""
    if first.startswith("#"):
        return ": the first line is a comment; the format has none (the header is the first line)"
    if ";" in first or "\t" in first:
        sep = "';'" if ";" in first else "a tab"
        return f": the columns are separated by {sep}; the format's separator is ',' (and '.' the decimal point)"
    if first.split("[")[0].split("(")[0].strip() == "t" and first != "t":
        return ": column names carry no units (t is in s, velocities in m/s, forces in N, torques in N m)"
    return ""


def _num(cell: str, where: str, name: str) -> float:
    if cell.strip() == "":
        return math.nan
    try:
        v = float(cell)
    except ValueError:
        raise RecordingError(f"{where}: column '{name}': {cell!r} is not a number") from None
    if math.isinf(v):
        raise RecordingError(f"{where}: column '{name}': {cell!r} is not finite")
    return v


def default_hold(cfg: dict) -> str:
    """The wrench's hold when run.toml does not say: a coload scenario (a ``[load]`` table: the recording
    of coload's simulator, whose step holds each tick's wrench) is held; anything else is taken as a
    smooth force sampled, the cubic through the samples (docs/diagnose.md, "Model")."""
    return "zoh" if isinstance(cfg.get("load"), dict) else "cubic"


HELD_SHARE = 0.5  # a wrench repeating its value this often between consecutive own samples is held


def held_share(wrench: np.ndarray) -> float:
    """The share of consecutive samples (each agent's own, per varying wrench column) that repeat the value
    before them: ~0 for a smooth force sampled, ~1 - f_c/f_s for a controller's output held at a rate
    f_c below the logging rate f_s. NaN where no column varies."""
    same = pairs = 0
    for i in range(wrench.shape[1]):
        for c in range(wrench.shape[2]):
            x = wrench[:, i, c]
            x = x[~np.isnan(x)]
            if x.size > 2 and np.ptp(x) > 0:
                same += int((x[1:] == x[:-1]).sum())
                pairs += x.size - 1
    return same / pairs if pairs else math.nan


def read_config(path: Path) -> dict:
    """run.toml: ``n`` (positive integer) is required; ``dt``, ``edges``, ``input_hold``, ``time_unit`` optional."""
    if not path.exists():
        raise RecordingError(f"{path}: missing (a recording needs {RUN_TOML} with at least n)")
    try:
        cfg = tomllib.loads(path.read_text(encoding="utf-8-sig"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise RecordingError(f"{path}: invalid TOML: {exc}") from None
    n = cfg.get("n")
    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
        raise RecordingError(f"{path}: field 'n': expected a positive integer (number of agents), got {n!r}")
    dt = cfg.get("dt")
    if dt is not None and (isinstance(dt, bool) or not isinstance(dt, (int, float)) or not dt > 0):
        raise RecordingError(f"{path}: field 'dt': expected a positive number (s), got {dt!r}")
    unit = cfg.get("time_unit", "s")
    if unit not in TIME_UNITS:
        raise RecordingError(f"{path}: field 'time_unit': expected one of {list(TIME_UNITS)} (the stamps' unit), "
                             f"got {unit!r}")
    hold = cfg.get("input_hold", default_hold(cfg))
    if hold not in HOLDS:
        raise RecordingError(f"{path}: field 'input_hold': expected one of {list(HOLDS)}, got {hold!r}")
    return cfg


def read_recording(path: str | Path) -> Recording:
    """Read a recording directory (``run.toml`` + ``samples.csv``; ``truth.csv`` only for errors)."""
    path = Path(path)
    if not path.is_dir():
        raise RecordingError(f"{path}: not a directory (a recording is a directory with run.toml and samples.csv)")
    cfg = read_config(path / RUN_TOML)
    n = int(cfg["n"])
    csv_path = path / SAMPLES_CSV
    if not csv_path.exists():
        raise RecordingError(f"{csv_path}: missing (a recording needs {SAMPLES_CSV})")
    t, agent, cols, lines, read_warns = _read_samples(csv_path, n)
    t, notes = _stamps_in_seconds(t, cfg, csv_path)
    has_v = "vx" in cols and "vy" in cols
    has_p = "x" in cols and "y" in cols
    stamps, inv = np.unique(t, return_inverse=True)
    T = stamps.size
    silent = sorted(set(range(n)) - set(np.unique(agent).tolist()))
    if silent and len(silent) < n:
        # an agent that never logged (a robot switched off) carries no data: the others are the recording
        alive = np.array([i for i in range(n) if i not in silent])
        agent = np.searchsorted(alive, agent)
        n = alive.size
        notes.append(f"{csv_path}: run.toml says n = {alive.size + len(silent)}, but agent(s) {silent} have no "
                     f"row: left out; the recording's agents are {alive.tolist()}, numbered 0..{n - 1} here")

    def grid(names):
        # Rows of one agent at one stamp are one sample (a logger writing each topic in its own row, the
        # velocity's and the wrench's with the same stamp): their cells merge, and two values for one cell
        # that differ are an error.
        out = np.full((T, n, len(names)), np.nan)
        for j, c in enumerate(names):
            v = cols[c]
            ok = ~np.isnan(v)
            out[inv[ok], agent[ok], j] = v[ok]
            clash = ok & (out[inv, agent, j] != v)
            if clash.any():
                r = int(np.flatnonzero(clash)[0])
                k, i = inv[r], agent[r]
                same = np.flatnonzero((inv == k) & (agent == i) & ok)  # in file order
                a, b = same[0], same[v[same] != v[same[0]]][0]
                raise RecordingError(f"{csv_path}:{lines[b]}: column '{c}': agent {i} has two rows at "
                                     f"t = {float(stamps[k])!r} with different values (line {lines[a]}: "
                                     f"{float(v[a])!r}, here: {float(v[b])!r})")
        return out

    wrench = grid(WRENCH)
    vel = grid(("vx", "vy")) if has_v else None
    pos = grid(("x", "y")) if has_p else None
    if T < 10:
        raise RecordingError(f"{csv_path}: {T} distinct stamps, need at least 10")
    truth = None
    warns = list(read_warns) + notes
    tpath = path / TRUTH_CSV
    if tpath.exists():
        truth, w = _read_truth(tpath)
        warns += w
    hold, source = cfg.get("input_hold"), "declared"
    if hold is None:
        hold, source = default_hold(cfg), "default"
        share = held_share(wrench)
        if hold == "cubic" and share >= HELD_SHARE:
            hold, source = "zoh", "inferred: the wrench repeats its value"
            warns.append(f"run.toml has no input_hold and the wrench repeats its previous value at {share:.0%} "
                         "of consecutive samples: read as held between samples (input_hold = \"zoh\"); "
                         "declare input_hold in run.toml to say otherwise")
    rec = recording_from_arrays(stamps, wrench, vel, pos, hold=hold,
                                dt=float(cfg["dt"]) if "dt" in cfg else None, truth=truth)  # fmt: skip
    rec.hold_source = source
    rec.warnings[:0] = warns
    if vel is not None and np.isfinite(vel).any():
        top = float(np.nanmax(np.abs(vel)))
        if top > FAST:
            # a team pushing a load moves at walking speeds: a speed of this order is a unit (mm/s logged as m/s)
            rec.warnings.append(f"a contact speed of {top:.3g} m/s in samples.csv: the velocities are read in m/s "
                                "(the format's unit); a logger writing mm/s or cm/s makes m and J that factor off")
    if rec.dt is not None:
        periods = {"all stamps": float(np.median(np.diff(stamps))),
                   **_stream_periods(stamps, {"velocities": vel, "positions": pos, "wrenches": wrench})}
        if all(abs(p - rec.dt) > 0.01 * rec.dt for p in periods.values()):
            own = ", ".join(f"{name}: every {p:.6g} s" for name, p in periods.items())
            rec.warnings.append(f"run.toml dt = {rec.dt:g} s is no logged stream's sample period ({own}): "
                                "the stamps are used")
    return rec


def agent_period(rec: Recording) -> float:
    """The recording's sample period: the median interval between the stamps of one agent's own rows (a
    measured velocity or position, or its own wrench), the median over the agents. Robots that log on their
    own clocks interleave their stamps: the union's median interval is a fraction of any robot's period, and
    one robot's jitter makes intervals of the union several times that median that are no gap in any
    robot's stream. With one stamp per sample for all agents it is the union's median interval."""
    own = np.zeros((rec.T, rec.n), bool)
    for arr in (rec.vel, rec.pos):
        if arr is not None:
            own |= np.isfinite(arr).all(axis=2)
    if rec.wrench_logged is not None:
        own |= rec.wrench_logged
    period = _own_period(rec.t, own)
    return float(np.median(np.diff(rec.t))) if period is None else period


def _own_period(stamps: np.ndarray, have: np.ndarray) -> float | None:
    """The median over the agents of the median interval between the stamps at which each agent has a value
    (``have`` (T, n)); None where no agent has two."""
    per_agent = [np.median(np.diff(stamps[h])) for h in have.T if h.sum() > 1]
    return float(np.median(per_agent)) if per_agent else None


def _stream_periods(stamps: np.ndarray, streams: dict[str, np.ndarray | None]) -> dict[str, float]:
    """Each logged stream's sample period: the median interval of the stamps at which one agent logged it,
    the median over the agents. A logger writing velocities and forces in rows of their own (a 120 Hz
    mocap beside 100 Hz force sensors) has stamps at the union of both rates, which is neither's period."""
    periods = {name: _own_period(stamps, np.isfinite(a).all(axis=2)) for name, a in streams.items() if a is not None}
    return {name: p for name, p in periods.items() if p is not None}


def _stamps_in_seconds(t: np.ndarray, cfg: dict, path: Path) -> tuple[np.ndarray, list[str]]:
    """The stamps in seconds: scaled by run.toml's ``time_unit``; without one, a median interval that is
    1000, 10^6 or 10^9 times run.toml's ``dt`` (within 2 %) is read as stamps in ms, us or ns (a logger
    writing integer milliseconds or a bag's nanoseconds), with a warning: dt is in seconds by the format, and
    no sample period in seconds is a power of 1000 times another that a recording could have meant."""
    unit = cfg.get("time_unit")
    if unit is not None:
        return t * TIME_UNITS[unit], []
    dt = cfg.get("dt")
    steps = np.diff(np.unique(t))
    if dt is None or steps.size == 0:
        return t, []
    ratio = float(np.median(steps)) / dt
    for name, scale in TIME_UNITS.items():
        if scale < 1 and abs(ratio * scale - 1) < 0.02:
            return t * scale, [f"{path}: stamps read in {name}: their median interval {ratio * dt:g} is {ratio:.4g} x "
                               f"run.toml's dt = {dt:g} s; declare time_unit in run.toml to say otherwise"]
    return t, []


def _read_samples(path: Path, n: int) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray], np.ndarray, list[str]]:
    """The rows' t, agent, the wanted columns (NaN where a cell is empty), their line numbers, warnings."""
    try:
        _check_text(path)  # a compressed or binary file is named as such
    except RunFormatError as exc:
        raise RecordingError(str(exc)) from None
    with path.open(newline="", encoding="utf-8-sig") as fh:
        rows = list(csv.reader(fh))
    warns = []
    if len(rows) > 1 and _ends_cut(path):  # a recorder killed mid-write: its last line may be cut mid-number
        warns.append(_cut_warning(path, len(rows), len(rows[-1]), len(rows[0])))
        rows.pop()
    if not rows:
        raise RecordingError(f"{path}:1: empty file (expected a header starting t,agent)")
    header = [h.strip() for h in rows[0]]
    if header[:2] != ["t", "agent"]:
        raise RecordingError(f"{path}:1: header must start with t,agent (got {','.join(header[:2])})"
                             + _header_hint(header))
    has_v, has_p = bool({"vx", "vy"} & set(header)), bool({"x", "y"} & set(header))
    if not (has_v or has_p):
        raise RecordingError(f"{path}:1: header lacks measured columns: need vx,vy and/or x,y")
    if not {"fx", "fy"} & set(header):
        raise RecordingError(f"{path}:1: header lacks column(s) fx,fy (the applied force)")
    # a column of a pair, or of the wrench, that the header lacks is an empty column; whether the
    # recording can do without it is decided on the data (read_recording)
    want = ["t", "agent", *WRENCH] + (["vx", "vy"] if has_v else []) + (["x", "y"] if has_p else [])
    absent = [c for c in want if c not in header]
    idx = {c: header.index(c) for c in want if c not in absent}
    body = [(k + 2, r) for k, r in enumerate(rows[1:]) if r and any(c.strip() for c in r)]
    if not body:
        raise RecordingError(f"{path}: no data rows")
    vals = {c: np.empty(len(body)) for c in want}
    width = len(header)
    nan_text: list[str] = []  # cells written as nan: missing values, said (the format's missing value is an empty cell)
    for j, (line, r) in enumerate(body):
        where = f"{path}:{line}"
        if len(r) != width:
            raise RecordingError(f"{where}: {len(r)} fields, header has {width}")
        for c in want:
            v = _num(r[idx[c]], where, c) if c in idx else math.nan
            if math.isnan(v):
                if c in ("t", "agent"):
                    raise RecordingError(f"{where}: column '{c}': {r[idx[c]].strip() or 'empty'} (expected a number)")
                if c in idx and r[idx[c]].strip():
                    nan_text.append(f"{where}: column '{c}'")
            vals[c][j] = v
        a = vals["agent"][j]
        if a != int(a) or not 0 <= a < n:
            raise RecordingError(f"{where}: column 'agent': agent {r[idx['agent']]} out of range 0..{n - 1} "
                                 f"(run.toml's n = {n}; agents are numbered from 0)")
    if nan_text:
        warns.append(f"{len(nan_text)} cell(s) written as nan read as missing values (as an empty cell), the first at "
                     f"{nan_text[0]}")
    cols = {c: vals[c] for c in want[2:]}
    for c in WRENCH:
        if c in absent:
            cols[c][:] = 0.0
    warns += _check_absent(path, absent, cols, n)
    return vals["t"], vals["agent"].astype(int), cols, np.array([line for line, _ in body]), warns


def _check_absent(path: Path, absent: list[str], cols: dict[str, np.ndarray], n: int) -> list[str]:
    """A wrench column the header lacks is no force only where no data need it: fx (fy) where the x (y)
    motion is measured nowhere, tau with one agent (whose rotation is not observed). The warnings."""
    def measured(axis: str) -> bool:
        return any(c in cols and not np.isnan(cols[c]).all() for c in (f"v{axis}", axis))

    need = [c for c, axis in (("fx", "x"), ("fy", "y")) if c in absent and measured(axis)]
    if "tau" in absent and n > 1:
        need.append("tau")
    if need:
        hint = ("; a robot on a point contact applies no torque of its own: write tau as 0 (the force's moment is "
                "the model's, from the contact's position)") if need == ["tau"] else ""
        raise RecordingError(f"{path}:1: header lacks column(s) {','.join(need)} (the motion they act on is "
                             f"measured){hint}")
    return [f"{path}: no column {c}: taken as 0" for c in WRENCH if c in absent]


def _read_truth(path: Path) -> tuple[dict[str, float] | None, list[str]]:
    try:
        with path.open(newline="") as fh:
            rd = csv.DictReader(fh)
            rows = [(float(r["mass"]), float(r["inertia"])) for r in rd]
    except (KeyError, ValueError, TypeError) as exc:
        return None, [f"truth.csv ignored: {exc}"]
    if not rows:
        return None, []
    a = np.array(rows)
    warns = []
    if np.ptp(a[:, 0]) > 0 or np.ptp(a[:, 1]) > 0:
        warns.append("truth: mass or inertia changes during the recording (the model assumes constant m and J); "
                     "errors are against the median")  # fmt: skip
    return {"m": float(np.median(a[:, 0])), "J": float(np.median(a[:, 1]))}, warns


def write_recording(path: str | Path, rec: Recording, *, extra: dict | None = None) -> Path:
    """Write ``rec`` as a recording directory (run.toml + samples.csv); all or nothing."""
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    cols = ["t", "agent"] + (["vx", "vy"] if rec.vel is not None else []) + (["x", "y"] if rec.pos is not None else [])
    cols += list(WRENCH)
    lines = [",".join(cols)]
    for k in range(rec.T):
        for i in range(rec.n):
            vals = [repr(float(rec.t0 + rec.t[k])), str(i)]
            for a in (rec.vel, rec.pos):
                if a is not None:
                    vals += ["" if math.isnan(v) else repr(float(v)) for v in a[k, i]]
            vals += [repr(float(v)) for v in rec.wrench[k, i]]
            lines.append(",".join(vals))
    toml = [f"n = {rec.n}", "edges = []"]
    if rec.dt is not None:
        toml.append(f"dt = {rec.dt!r}")
    toml.append(f'input_hold = "{rec.hold}"')
    for k, v in (extra or {}).items():
        toml.append(f"{k} = {v!r}" if not isinstance(v, str) else f'{k} = "{v}"')
    tmp_csv, tmp_toml = path / (SAMPLES_CSV + ".tmp"), path / (RUN_TOML + ".tmp")
    tmp_csv.write_text("\n".join(lines) + "\n")
    tmp_toml.write_text("\n".join(toml) + "\n")
    tmp_csv.replace(path / SAMPLES_CSV)
    tmp_toml.replace(path / RUN_TOML)
    return path
