"""``coload campaign``: paper 000's Monte Carlo grid (its appendix B, Fig. 7 and Fig. 8).

A campaign runs one in-process engine run per (n, sigma, run index) in worker processes, local or
on a Dask cluster (:mod:`coload.runs.sweep`), and the driver (this process) leaves:

* ``OUT/runs/n{n}-s{sigma}-r{k}/``: an ordinary run directory per run (no report.png);
* ``OUT/campaign.csv``: one row per finished run (grid point, seed, geometry, every numeric error
  key of its summary, wall time), rewritten atomically after each run, so an interrupted campaign
  leaves a table of the runs it finished and nothing half written;
* ``OUT/campaign.png``: box plots per sigma and n, like Fig. 7; ``OUT/campaign-consensus.png``: the
  relative errors of J and m before and after the averaging consensus, like Fig. 8 (only when the
  runs' estimates carry the agents' local ``J_local``/``m_local``; :mod:`coload.analysis.campaign_plots`).

Resumable: a run whose directory holds a complete ``summary.json`` for the same resolved scenario
(``run.toml``) is read back, not redone; a run killed half way (no or a truncated summary, or a
changed scenario) is redone from scratch.

Geometry (:func:`campaign_scenario`): the paper sets m = 5 n "and J accordingly". The load grows
with the team so that the contacts stay as far apart as in the base scenario: every length of the
base load (outline, CoM offset) is scaled by s = n / n_base, the perimeter grows as n and the
spacing of the evenly spread contacts stays that of paper-fig4 (12.4 m / 10 = 1.24 m). J scales as
mass times length squared, J = J_base (m / m_base) s^2 (so as n^3): for a base without an explicit
J this is exactly the uniform lamina's J of the scaled outline (``simulator.plant.load_inertia``,
with its parallel-axis term for the CoM offset); for paper-fig4 it keeps the paper's
J = 86.89 kg m^2 at n = 10 (the lamina formula would give 93.33 there), so the n = 10 cell is
paper-fig4 itself. The agents' per-agent torques (spin-up,
regulation gain, saturation, the dynamical phase's torque dither) are scaled by (n / n_base)^2 so
that the team's angular acceleration, hence omega(t) and the kinematic signal |omega| |z_ij|, is the
same for every n: the sum of n torques over a J growing as n^3. Forces need no scaling: n forces
over m = 5 n, and the J stage's f_i = k_z z_i^perp makes a team torque that grows as J does. The
background observers' random walks of 1/m and 1/J scale with 1/m and 1/J (same relative walk).
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import tempfile
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from config.loader import dump_scenario, scenario_from_dict
from config.scenario import Scenario
from coload.analysis.campaign_plots import (  # noqa: F401  PLOT_NAME, CONSENSUS_PLOT_NAME: the outputs' names
    CONSENSUS_PLOT_NAME,
    FIG7_PANELS,
    FIG8_PANELS,
    PLOT_NAME,
    cell_values,
    plot_campaign,
)
from coload.runs.sweep import LOCAL, open_pool, pack_dir, sweep, unpack_dir

DEFAULT_BASE = Path(__file__).resolve().parents[2] / "config" / "scenarios" / "paper-fig4.toml"
"""The base scenario of the paper's campaign: paper-fig4 (n = 10, 4.0 m x 2.2 m, line graph)."""

PAPER_N = (5, 8, 11, 14, 17, 20)
"""The paper's team sizes (appendix B)."""

PAPER_SIGMA = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)
"""The paper's velocity-noise levels (m/s)."""

PAPER_RUNS_PER_CELL = 50
"""Independent runs per (n, sigma) in the paper."""

MASS_PER_AGENT = 5.0
"""m = 5 n kg (paper)."""

CSV_NAME = "campaign.csv"
LOG_NAME = "campaign-log.jsonl"
"""One JSON line per run finished by ``coload campaign``: the invocation (segment) it belongs to, its
name, and the segment's wall time when it finished. A grid run over several invocations (resumed) has
its wall time as the sum over segments of their last elapsed time (:func:`logged_wall`)."""
RUNS_DIR = "runs"

ID_COLUMNS = ("n", "sigma", "run", "seed", "duration", "width", "height", "mass", "inertia", "spacing", "z_rms")
"""Grid point, seed and the load's geometry (width/height empty for a polygon load)."""

ERROR_COLUMNS = (
    "eerd_ratio", "eerd_final", "eerd_initial", "eerd_converge_s",
    "zi_rms", "zi_rel", "zi_rms_window", "eec_final", "omega_rms",
    "J_local_rel", "J_rel", "m_local_rel", "m_rel", "zC_rms", "vC_rms",
    "t_final", "window_s",
)
"""The error keys a campaign always has a column for, in this order (empty when a run lacks one).
``zi_rel`` is derived here: zi_rms over the RMS |z_i| of the geometry (the paper's normalisation
across team sizes). Other numeric keys a run's errors block has are appended, sorted."""

CENTRAL_COLUMNS = ("central_J_rel", "central_m_rel", "central_J_in_ci95", "central_m_in_ci95",
                   "dist_over_central_J", "dist_over_central_m", "dist_over_ci95_J", "dist_over_ci95_m",
                   "central_fit_s")
"""The batch-fit yardstick (summary.json ``centralized`` and ``distributed_over_centralized``, see
docs/batch-fit.md); empty unless the runs fit it (``coload campaign --batch-fit``, off by default: the
fit costs about as much CPU as the run)."""
CENTRAL_SOURCES = {
    "central_J_rel": ("centralized", "J_rel"), "central_m_rel": ("centralized", "m_rel"),
    "central_J_in_ci95": ("centralized", "J_in_ci95"), "central_m_in_ci95": ("centralized", "m_in_ci95"),
    "dist_over_central_J": ("distributed_over_centralized", "J"),
    "dist_over_central_m": ("distributed_over_centralized", "m"), "central_fit_s": ("centralized", "fit_s"),
    "dist_over_ci95_J": ("distributed_over_centralized", "J_over_ci95"),
    "dist_over_ci95_m": ("distributed_over_centralized", "m_over_ci95"),
}  # fmt: skip

TAIL_COLUMNS = ("finished_s", "wall_s", "agent_step_us")
"""summary.json top-level: when the agents agreed they were done (if the scenario stops early),
the engine loop's wall time (s) and the mean cost of one agent step (us)."""

# --- the grid -----------------------------------------------------------------------------------


def campaign_scenario(
    base: Scenario, n: int, sigma: float, seed: int, mass_per_agent: float = MASS_PER_AGENT
) -> Scenario:
    """The base scenario resized for a team of ``n`` at noise ``sigma`` (see the module docstring).

    Lengths scale by ``s = n / base.n`` (rectangle sides or polygon vertices, CoM offset), so the
    contact spacing along the outline is the base's; m = ``mass_per_agent`` n; J = J_base (m /
    m_base) s^2; per-agent torques scale by s^2; the graph is a line; name and seed identify the run.
    """
    from simulator.plant import load_inertia

    if base.contacts.layout != "perimeter":
        raise ValueError("campaign: the base scenario needs contacts.layout = 'perimeter' (explicit points "
                         "cannot follow a changing n)")
    if n < 2:
        raise ValueError(f"campaign: n must be at least 2 (got {n})")
    if not (sigma >= 0 and math.isfinite(sigma)):
        raise ValueError(f"campaign: sigma must be a finite value >= 0 (got {sigma})")
    s = n / base.n
    data = base.model_dump(mode="python", exclude_none=True)
    load = data["load"]
    if base.load.shape == "rectangle":
        load["width"] = base.load.width * s
        load["height"] = base.load.height * s
    else:
        assert base.load.vertices is not None
        load["vertices"] = [(x * s, y * s) for x, y in base.load.vertices]
    load["com_offset"] = (base.load.com_offset[0] * s, base.load.com_offset[1] * s)
    load["mass"] = mass_per_agent * n
    load["inertia"] = load_inertia(base) * (load["mass"] / base.load.mass) * s * s
    ctl = data["control"]
    for key in ("spin_torque", "k_omega", "torque_max"):
        ctl[key] = getattr(base.control, key) * s * s
    dyn = data.get("dynamics")
    if dyn is not None:
        # the dynamical phase: its per-agent torque dither as the torques above; the background
        # observers' random walks of 1/m and 1/J in proportion to 1/m and 1/J (the same relative walk).
        # Its forces need nothing: n forces push m = 5n, and f_i = k_z z_i^perp gives a team torque
        # growing as n s^2 = n^3, as J does.
        if "dither_torque" in dyn:
            dyn["dither_torque"] *= s * s
        if "mu_walk" in dyn:
            dyn["mu_walk"] *= base.load.mass / load["mass"]
        if "iota_walk" in dyn:
            dyn["iota_walk"] *= load_inertia(base) / load["inertia"]
    data["graph"] = {"topology": "line"}
    data["noise"]["sigma_v"] = float(sigma)
    data["n"] = n
    data["seed"] = int(seed)
    data["name"] = f"{base.name}-n{n}-s{sigma:g}-seed{seed}"
    return scenario_from_dict(data, source=f"campaign cell n={n} sigma={sigma:g}")


def run_seed(seed0: int, n: int, sigma: float, k: int) -> int:
    """Seed of run ``k`` of cell (n, sigma): independent across runs and cells, and a function of
    the grid point alone, so a subset or a re-run of the grid meets the same seeds."""
    ss = np.random.SeedSequence(int(seed0), spawn_key=(int(n), round(sigma * 1e6), int(k)))
    return int(ss.generate_state(1, dtype=np.uint32)[0])


def run_name(n: int, sigma: float, k: int) -> str:
    return f"n{n}-s{sigma:g}-r{k}"


@dataclass(frozen=True)
class PlannedRun:
    """One run of the grid: its grid point, seed and directory; its scenario is derived from the base
    on demand, so a plan of thousands of runs holds one scenario, not thousands."""

    n: int
    sigma: float
    k: int
    seed: int
    base: Scenario
    run_dir: Path

    @property
    def scenario(self) -> Scenario:
        """The resolved scenario of this run (:func:`campaign_scenario`)."""
        return campaign_scenario(self.base, self.n, self.sigma, self.seed)


def plan(
    base: Scenario, out: Path, ns: Sequence[int], sigmas: Sequence[float], runs_per_cell: int, seed0: int = 0
) -> list[PlannedRun]:
    """Every run of the grid, cell by cell (n outer, sigma inner), ``runs_per_cell`` per cell.
    Raises ValueError for a grid the base cannot be resized to."""
    if runs_per_cell < 1:
        raise ValueError(f"campaign: runs per cell must be at least 1 (got {runs_per_cell})")
    if len(set(ns)) != len(ns) or len(set(sigmas)) != len(sigmas):
        raise ValueError("campaign: the n and sigma lists must not repeat a value")
    runs = []
    for n in ns:
        for sigma in sigmas:
            campaign_scenario(base, n, sigma, 0)  # the cell's errors now, not when its runs are due
            for k in range(runs_per_cell):
                seed = run_seed(seed0, n, sigma, k)
                runs.append(PlannedRun(n, float(sigma), k, seed, base, Path(out) / RUNS_DIR / run_name(n, sigma, k)))
    return runs


def geometry(scenario: Scenario) -> dict[str, float | None]:
    """The load a campaign run pushes: size, m, J, contact spacing and RMS |z_i| (the z_i scale)."""
    from simulator.plant import contact_points_body, load_inertia, load_polygon_body

    outline = np.asarray(load_polygon_body(scenario))
    perimeter = float(np.sum(np.hypot(*(np.roll(outline, -1, axis=0) - outline).T)))
    c = np.asarray(contact_points_body(scenario))
    z = c - c.mean(axis=0)  # z_i = p_Ci - p_G, G the contacts' centroid
    rect = scenario.load.shape == "rectangle"
    return {
        "width": scenario.load.width if rect else None,
        "height": scenario.load.height if rect else None,
        "mass": scenario.load.mass,
        "inertia": load_inertia(scenario),
        "spacing": perimeter / scenario.n,
        "z_rms": float(np.sqrt(np.mean(np.sum(z * z, axis=1)))),
    }


def geometry_table(base: Scenario, ns: Sequence[int]) -> str:
    """A markdown table n -> size, m, J, spacing, RMS |z_i| (as stated in docs/campaign.md)."""
    lines = ["| n | width x height (m) | CoM offset (m) | m (kg) | J (kg m^2) | spacing (m) | RMS \\|z_i\\| (m) |",
             "|---|---|---|---|---|---|---|"]
    for n in ns:
        scn = campaign_scenario(base, n, base.noise.sigma_v, base.seed)
        g = geometry(scn)
        size = f"{g['width']:.2f} x {g['height']:.2f}" if g["width"] is not None else "polygon"
        off = scn.load.com_offset
        lines.append(f"| {n} | {size} | ({off[0]:.3f}, {off[1]:.3f}) | {g['mass']:.0f} | {g['inertia']:.1f} "
                     f"| {g['spacing']:.3f} | {g['z_rms']:.3f} |")
    return "\n".join(lines)


# --- run directories ----------------------------------------------------------------------------


def finished_summary(run: PlannedRun) -> dict[str, Any] | None:
    """The run's summary if its directory holds a finished run of this very scenario, else None.

    summary.json is the last file a run writes; a killed run has none or a truncated one, and a
    run.toml that differs means the directory is from another campaign setting.
    """
    try:
        toml = (run.run_dir / "run.toml").read_text(encoding="utf-8")
        summary = json.loads((run.run_dir / "summary.json").read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return None
    if toml != dump_scenario(run.scenario) or not isinstance(summary, dict) or "errors" not in summary:
        return None
    return summary


def run_task(scenario: Scenario, keep_data: bool = False) -> dict[str, bytes]:
    """Worker: one in-process run in a private temporary directory; returns the run directory as
    data (:func:`coload.runs.sweep.pack_dir`), for the driver to write: a worker needs no filesystem shared
    with the driver. The CSV tables only with ``keep_data``: otherwise the run never writes them (its summary
    comes from the tables in memory): the full grid would fill ~90 GB with them, and any run is reproduced
    bit for bit by ``coload run OUT/runs/NAME/run.toml --engine inproc``."""
    from coload.runs.engine import run_inproc

    with tempfile.TemporaryDirectory(prefix="coload-campaign-") as tmp:
        path = Path(tmp) / "run"
        run_inproc(scenario, path, tables=keep_data)
        return pack_dir(path)


def _scalar(x: Any) -> float | None:
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        return None
    return float(x) if math.isfinite(x) else None


def row_of(run: PlannedRun, summary: dict[str, Any]) -> dict[str, Any]:
    """One CSV row: grid point, seed, geometry, every numeric error key, finished_s and wall time."""
    row: dict[str, Any] = {"n": run.n, "sigma": run.sigma, "run": run.k, "seed": run.seed,
                           "duration": run.scenario.duration}
    g = geometry(run.scenario)
    row.update(g)
    errors = summary.get("errors") or {}
    for key, value in errors.items():
        v = _scalar(value)
        if v is not None:
            row[key] = v
    if row.get("zi_rms") is not None and g["z_rms"]:
        row["zi_rel"] = row["zi_rms"] / g["z_rms"]
    for col, (block, key) in CENTRAL_SOURCES.items():
        value = (summary.get(block) or {}).get(key)
        v = float(value) if isinstance(value, bool) else _scalar(value)  # in_ci95: 1 / 0
        if v is not None:
            row[col] = v
    for key in TAIL_COLUMNS:
        v = _scalar(summary.get(key))
        if v is not None:
            row[key] = v
    return row


def columns_of(rows: Iterable[dict[str, Any]]) -> list[str]:
    """Fixed columns first, then any other error keys the runs have (sorted), then the tail."""
    return _columns({k for r in rows for k in r})


def _columns(keys: set[str]) -> list[str]:
    fixed = (*ID_COLUMNS, *ERROR_COLUMNS, *CENTRAL_COLUMNS, *TAIL_COLUMNS)
    extra = sorted(keys - set(fixed))
    return [*ID_COLUMNS, *ERROR_COLUMNS, *CENTRAL_COLUMNS, *extra, *TAIL_COLUMNS]


class Table:
    """campaign.csv of a running campaign: its rows by run name, each formatted once (again only
    when a run brings a new column), the file rewritten whole after each run at the cost of joining
    the lines, not of formatting every number of every row again."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.rows: dict[str, dict[str, Any]] = {}
        self._keys: set[str] = set()
        self._cols: list[str] = []
        self._lines: dict[str, str] = {}

    def put(self, name: str, row: dict[str, Any]) -> None:
        self.rows[name] = row
        self._lines.pop(name, None)
        self._keys.update(row)  # a new column reformats every line at the next write

    def write(self) -> None:
        """Writes the table atomically (a temporary file renamed over the old one): never half a table."""
        cols = _columns(self._keys)
        if cols != self._cols:
            self._cols, self._lines = cols, {}
        order = sorted(self.rows.items(), key=lambda item: (item[1]["n"], item[1]["sigma"], item[1]["run"]))
        text = _line(cols) + "".join(self._line_of(name, cols) for name, _ in order)
        tmp = self.path.with_name(self.path.name + ".tmp")
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, self.path)

    def _line_of(self, name: str, cols: list[str]) -> str:
        line = self._lines.get(name)
        if line is None:
            r = self.rows[name]
            line = self._lines[name] = _line(["" if r.get(c) is None else (repr(r[c]) if isinstance(r[c], float)
                                                                           else r[c]) for c in cols])
        return line


def _line(cells: Sequence[Any]) -> str:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow(cells)
    return buf.getvalue()


def write_csv(path: Path, rows: Sequence[dict[str, Any]]) -> None:
    """Writes ``rows`` as the table at ``path``, sorted by (n, sigma, run), atomically (:class:`Table`)."""
    table = Table(path)
    for i, r in enumerate(rows):
        table.put(str(i), r)
    table.write()


def read_csv(path: Path) -> list[dict[str, Any]]:
    """campaign.csv back as rows of floats (ints for n, run, seed); empty cells are absent."""
    rows = []
    with open(path, encoding="utf-8", newline="") as f:
        reader = csv.DictReader(f)
        lacking = [c for c in ("n", "sigma", "run") if c not in (reader.fieldnames or [])]
        if lacking:
            raise ValueError(f"{path}, line 1: the header lacks the column(s) {', '.join(lacking)}")
        for rec in reader:
            row: dict[str, Any] = {}
            for k, v in rec.items():
                if v == "" or v is None or k is None:
                    continue
                try:
                    row[k] = int(v) if k in ("n", "run", "seed") else float(v)
                except ValueError:
                    raise ValueError(f"{path}, line {reader.line_num}, column {k}: expected "
                                     f"{'an integer' if k in ('n', 'run', 'seed') else 'a number'}, "
                                     f"got {v!r}") from None
            if any(c not in row for c in ("n", "sigma", "run")):
                raise ValueError(f"{path}, line {reader.line_num}: n, sigma and run must not be empty")
            rows.append(row)
    return rows


# --- the runner ---------------------------------------------------------------------------------


@dataclass
class CampaignResult:
    """What a campaign did: rows of every finished run, and counts of this invocation."""

    rows: list[dict[str, Any]]
    planned: int
    reused: int  # finished before, read back
    ran: int  # run now
    failed: list[tuple[str, str]] = field(default_factory=list)  # (run name, error)
    wall_s: float = 0.0
    plots: list[Path] = field(default_factory=list)

    total_wall_s: float = 0.0  # over every invocation that worked on this directory (campaign-log.jsonl)
    total_ran: int = 0  # runs those invocations finished

    @property
    def runs_per_min(self) -> float | None:
        return 60.0 * self.ran / self.wall_s if self.ran and self.wall_s > 0 else None


def logged_wall(path: Path) -> tuple[float, int, int]:
    """(wall seconds, runs, segments) of a campaign log: per segment the elapsed time at its last
    finished run (a killed segment counts up to there; the run it was in is redone and counted then).
    A run logged twice (killed after its line, before its files landed) counts once."""
    last: dict[str, float] = {}
    runs: set[str] = set()
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except OSError:
        return 0.0, 0, 0
    for line in lines:
        try:
            rec = json.loads(line)
            seg, el, run = str(rec["segment"]), float(rec["elapsed_s"]), str(rec["run"])
        except (ValueError, KeyError, TypeError):
            continue  # a line cut by a kill
        last[seg] = el
        runs.add(run)
    return sum(last.values()), len(runs), len(last)


def run_campaign(
    runs: Sequence[PlannedRun],
    out: Path,
    jobs: int | None = None,
    progress: Callable[..., None] | None = None,
    plots: bool = True,
    keep_data: bool = False,
    executor: str = LOCAL,
    task: Callable[[Scenario, bool], dict[str, bytes]] = run_task,
) -> CampaignResult:
    """Runs what is not finished yet, run index by run index over the cells, on ``executor``
    (``"local"``: ``jobs`` worker processes, ``jobs = 1`` this process; ``"dask://HOST:PORT"``: the
    workers of that Dask scheduler, see :mod:`coload.runs.sweep`); writes every run directory, the CSV and
    the plots here, in the driver.

    ``keep_data`` keeps each run's CSV tables (otherwise only run.toml, summary.json and logs/ stay, see
    :func:`run_task`). A run that raises is reported in ``failed`` and the others go on; its directory
    stays without a summary, so a later call retries it. ``progress(done, total, note)`` follows the
    runs (``note``: the workers). ``task`` is the worker function (:func:`run_task`; benchmarks pass a
    stand-in). Raises ValueError, with nothing written, if the executor cannot be used.
    """
    t0 = time.perf_counter()
    out = Path(out)
    csv_path = out / CSV_NAME
    table = Table(csv_path)
    # the directory's table keeps the runs of other invocations (another grid subset) whose
    # directories are still there: a subset run on a campaign directory must not shrink its table
    planned = {r.run_dir.name for r in runs}
    try:
        for row in read_csv(csv_path):
            name = run_name(int(row["n"]), float(row["sigma"]), int(row["run"]))
            if name not in planned and (out / RUNS_DIR / name / "summary.json").is_file():
                table.put(name, row)
    except (OSError, ValueError):
        pass  # no table yet, or an unreadable one: rebuilt from the planned runs
    todo: list[PlannedRun] = []
    for r in runs:
        s = finished_summary(r)
        if s is None:
            todo.append(r)
        else:
            table.put(r.run_dir.name, row_of(r, s))
    reused = len(table.rows.keys() & planned)
    # run index first: an interrupted grid has (nearly) the same number of runs in every cell, so its
    # table and plots are those of a smaller grid, not of a few finished cells
    todo.sort(key=lambda r: r.k)
    failed: list[tuple[str, str]] = []
    done = 0
    note = ""
    segment = time.strftime("%Y-%m-%dT%H:%M:%S") + f"-{os.getpid()}"

    def show(text: str) -> None:
        nonlocal note
        note = text
        if progress is not None:
            progress(done, len(todo), note)

    def finish(r: PlannedRun, files_of: Callable[[], dict[str, bytes]]) -> None:
        nonlocal done
        try:
            files = files_of()
            summary = json.loads(files["summary.json"])
            # logged before the run's files land: a kill between the two leaves a logged run that is
            # redone (counted once, see logged_wall), never a finished run that no segment counted
            with (out / LOG_NAME).open("a", encoding="utf-8") as log:
                log.write(json.dumps({"segment": segment, "run": r.run_dir.name,
                                      "elapsed_s": round(time.perf_counter() - t0, 3)}) + "\n")
            unpack_dir(files, r.run_dir)
            table.put(r.run_dir.name, row_of(r, summary))
            table.write()
        except Exception as exc:  # noqa: BLE001  a failed run must not stop the campaign
            failed.append((r.run_dir.name, f"{type(exc).__name__}: {exc}"))
        done += 1
        show(note)

    with open_pool(executor, max(1, jobs or os.cpu_count() or 1), len(todo)) as pool:
        out.mkdir(parents=True, exist_ok=True)
        table.write()
        show("")
        sweep(pool, task, todo, lambda r: (r.scenario, keep_data), finish, show)
    result = CampaignResult(rows=sorted(table.rows.values(), key=lambda r: (r["n"], r["sigma"], r["run"])),
                            planned=len(runs), reused=reused, ran=done - len(failed), failed=failed,
                            wall_s=time.perf_counter() - t0)
    result.total_wall_s, result.total_ran, _ = logged_wall(out / LOG_NAME)
    if plots and result.rows:
        result.plots = plot_campaign(result.rows, out)
    return result


def parse_list(text: str, kind: type, what: str) -> list:
    """``"5,8,11"`` -> [5, 8, 11], with a clear error for a bad item."""
    items = [t.strip() for t in text.split(",") if t.strip()]
    if not items:
        raise ValueError(f"{what}: give a comma-separated list, e.g. {'5,8' if kind is int else '0.1,0.3'}")
    try:
        return [kind(t) for t in items]
    except ValueError:
        raise ValueError(f"{what}: {text!r} is not a comma-separated list of "
                         f"{'integers' if kind is int else 'numbers'}") from None


def cell_table(rows: Sequence[dict[str, Any]]) -> str:
    """Median [90th percentile] per (n, sigma) of the plotted errors the runs have (markdown)."""
    cols = [c for c, _ in FIG7_PANELS if any(r.get(c) is not None for r in rows)]
    cols += [c for lo, _, _ in FIG8_PANELS for c in (lo,) if any(r.get(c) is not None for r in rows)]
    cols += [c for c in ("dist_over_central_J", "dist_over_central_m", "dist_over_ci95_J", "dist_over_ci95_m")
             if any(r.get(c) is not None for r in rows)]
    head = "| n | sigma | runs | " + " | ".join(f"{c} median [p90]" for c in cols) + " |"
    lines = [head, "|" + "---|" * (3 + len(cols))]
    for n in sorted({r["n"] for r in rows}):
        for sigma in sorted({r["sigma"] for r in rows if r["n"] == n}):
            cell = [r for r in rows if r["n"] == n and r["sigma"] == sigma]
            vals = []
            for c in cols:
                v = cell_values(cell, c, n, sigma)
                vals.append(f"{np.median(v):.3g} [{np.percentile(v, 90):.3g}]" if v else "-")
            lines.append(f"| {n} | {sigma:g} | {len(cell)} | " + " | ".join(vals) + " |")
    return "\n".join(lines)


MATRIX_VIEWS = (
    ("J_rel", 50.0, 100.0, "RE of J (%), median"),
    ("J_rel", 90.0, 100.0, "RE of J (%), 90th percentile"),
    ("m_rel", 50.0, 100.0, "RE of m (%), median"),
    ("m_rel", 90.0, 100.0, "RE of m (%), 90th percentile"),
    ("finished_s", 50.0, 1.0, "finished (s of simulated time), median"),
)
"""The tables ``coload campaign --table`` prints: (column, percentile, scale, title)."""


def cell_matrix(rows: Sequence[dict[str, Any]], col: str, q: float = 50.0, scale: float = 1.0,
                digits: int = 2) -> str:
    """One statistic of one column as a sigma x n markdown table (the paper's grid layout).

    A cell where some runs lack the value (a run whose agents never got that far) says how many,
    "(k n/a)": the statistic is over the runs that have it, and hiding the rest would flatter it."""
    ns = sorted({int(r["n"]) for r in rows})
    sigmas = sorted({float(r["sigma"]) for r in rows})
    lines = ["| sigma \\ n | " + " | ".join(map(str, ns)) + " |", "|---|" + "---|" * len(ns)]
    for sigma in sigmas:
        vals = []
        for n in ns:
            have = [r for r in rows if r["n"] == n and r["sigma"] == sigma]
            v = cell_values(have, col, n, sigma)
            miss = len(have) - len(v)
            text = "-" if not v else f"{np.percentile(v, q) * scale:.{digits}f}"
            vals.append(text + (f" ({miss} n/a)" if miss and have else ""))
        lines.append(f"| {sigma:g} | " + " | ".join(vals) + " |")
    return "\n".join(lines)


def digest(rows: Sequence[dict[str, Any]], log: Path | None = None, worst: int = 5) -> str:
    """What a campaign directory holds now, for a person: how many runs per cell, the wall time over
    every invocation, the grid tables of :data:`MATRIX_VIEWS`, the runs without an estimate of J or m
    and the worst runs by J. Safe on a campaign still running (the CSV is replaced atomically)."""
    if not rows:
        return "no finished runs"
    cells: dict[tuple[int, float], int] = {}
    for r in rows:
        key = (int(r["n"]), float(r["sigma"]))
        cells[key] = cells.get(key, 0) + 1
    lo, hi = min(cells.values()), max(cells.values())
    out = [f"{len(rows)} finished runs in {len(cells)} cells ({lo if lo == hi else f'{lo} to {hi}'} per cell)"]
    if log is not None:
        wall, ran, segments = logged_wall(log)
        if ran:
            out.append(f"{ran} runs in {wall:.0f} s wall over {segments} invocation(s) "
                       f"({60.0 * ran / max(wall, 1e-9):.1f} runs/min; {log.name})")
    for col, q, scale, title in MATRIX_VIEWS:
        if any(r.get(col) is not None for r in rows):
            out += ["", f"{title}:", "", cell_matrix(rows, col, q, scale, 0 if scale == 1.0 else 2)]
    def name(r: dict[str, Any]) -> str:
        return run_name(int(r["n"]), float(r["sigma"]), int(r["run"]))

    missing = [name(r) for r in rows if r.get("J_rel") is None or r.get("m_rel") is None]
    if missing:
        out += ["", f"{len(missing)} run(s) without an estimate of J or m: " + ", ".join(missing)]
    ranked = sorted((r for r in rows if r.get("J_rel") is not None), key=lambda r: -r["J_rel"])[:worst]
    if ranked:
        out += ["", f"worst {len(ranked)} by RE of J: " + ", ".join(
            f"{name(r)} {100.0 * r['J_rel']:.2f} %" for r in ranked)]
    return "\n".join(out)
