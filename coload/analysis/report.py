"""``coload report RUN_DIR``: a Fig. 4-style figure and a per-agent error table for one run.

The figure stacks panels sharing the time axis, as paper 000's Fig. 4 does: EERD, omega, EEC, the
z_i errors, then J, z_C, v_C and m when the run's estimates carry them. It is drawn with the Agg
backend so that it works headless (CI, docker). Numbers in the table come from
:func:`coload.analysis.metrics.final_errors`, the same block summary.json holds, so the two never disagree.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402  (backend must be chosen first)
import numpy as np  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402

from coload.analysis import metrics  # noqa: E402
from coload.analysis.summary import effects_block, monitor_block, trust_block  # noqa: E402
from coload.rundir import format as rundir_format  # noqa: E402
from coload.rundir.format import REPORT_PNG, RunData, read_run  # noqa: E402

WINDOW_S = 20.0
"""Window (s) of the windowed RMS errors in the table: the last 20 s, as in the task's metrics."""

MAX_PLOT_POINTS = 20_000
"""Longer series are strided before plotting; the eye cannot tell and Agg stays fast."""

_TRUE_STYLE = {"color": "black", "linestyle": "--", "linewidth": 1.6, "zorder": 5}
_TRUE_STYLE_Y = {"color": "dimgray", "linestyle": ":", "linewidth": 1.8, "zorder": 5}
_TOTAL_COLOR = "0.2"  # sums over agents: dark grey, distinct from every agent colour
# online detection's events (summary.json ``effect_*``): a switch solid magenta, a withdrawal dotted black, a
# candidate ruled out dashed black, any other kind dashed magenta; colours no agent line has (tab10), and stage
# changes stay thin grey dash-dot
_EFFECT_STYLE = {"switch": {"color": "magenta", "linestyle": "-"},
                 "withdrawn": {"color": "black", "linestyle": ":"},
                 "ruled_out": {"color": "black", "linestyle": "--"}}
_EFFECT_OTHER = {"color": "magenta", "linestyle": "--"}
_UNEXPLAINED_COLOR = "crimson"


# --- panels -------------------------------------------------------------------------------------
def panel_names(run: RunData) -> list[str]:
    """Panels the report draws for this run, top to bottom (a panel appears when its columns exist)."""
    est = run.estimates
    names: list[str] = []
    if run.pairs is not None:
        names.append("eerd")
    if est is None:
        return names
    if est.has("omega"):
        names.append("omega")
    if est.has("zi_x", "zi_y"):
        names += ["eec", "zi_err"]
    if est.has("J"):
        names.append("J")
    if est.has("zc_x", "zc_y"):
        names.append("zc")
    if est.has("vc_x", "vc_y"):
        names.append("vc")
    if est.has("m"):
        names.append("m")
    return names


def _agent_colors(n: int) -> list[Any]:
    cmap = plt.get_cmap("tab10") if n <= 10 else plt.get_cmap("viridis")
    return [cmap(i) if n <= 10 else cmap(i / max(n - 1, 1)) for i in range(n)]


def _stride(length: int) -> slice:
    return slice(None, None, max(1, int(np.ceil(length / MAX_PLOT_POINTS))))


def _log_or_linear(ax: Axes, data: np.ndarray, also: Sequence[float] = ()) -> None:
    """Log scale when the data has something positive to show (exact-zero errors would leave it blank).

    ``also`` are reference levels (e.g. the 1 % line) kept inside the limits of a log axis.
    """
    values = np.ravel(np.asarray(data, dtype=float))
    positive = values[np.isfinite(values) & (values > 0)]
    if positive.size:
        ax.set_yscale("log")
        hi = max(positive.max(), *also) if also else positive.max()
        lo = max(positive.min(), hi * 1e-9)
        if also:
            lo = min(lo, *also)
        ax.set_ylim(lo / 2, hi * 2)
    else:
        ax.text(0.5, 0.75, "all zero", transform=ax.transAxes, ha="center", va="center", color="gray")


class _Ctx:
    """What every panel drawer needs: the run, its error series, the table numbers and colours."""

    def __init__(self, run: RunData, series: metrics.ErrorSeries, errors: dict[str, Any]) -> None:
        self.run = run
        self.s = series
        self.errors = errors
        self.colors = _agent_colors(run.n)
        assert run.estimates is not None and run.truth is not None
        self.est = run.estimates
        self.truth = run.truth
        self.es = _stride(len(series.est_t))

    def agents(self, ax: Axes, values: np.ndarray, **kw: Any) -> None:
        """One line per agent from a (K, n) array on the estimates grid."""
        t = self.s.est_t[self.es]
        for i in range(self.run.n):
            ax.plot(t, values[self.es, i], color=self.colors[i], linewidth=1.0, **kw)

    def truth_at_est(self, name: str) -> np.ndarray:
        return self.truth.columns[name][self.s.truth_est_idx]


def _draw_eerd(ax: Axes, c: _Ctx) -> None:
    s = c.s
    assert s.pair_t is not None and s.eerd is not None and s.eerd_ref is not None
    st = _stride(len(s.pair_t))
    ax.plot(s.pair_t[st], s.eerd[st], color=_TOTAL_COLOR, linewidth=1.4, label="EERD")
    initial = c.errors.get("eerd_initial")
    if initial:
        ax.axhline(metrics.CONVERGED_FRACTION * initial, color="tab:red", linestyle=":", linewidth=1.2,
                   label="1 % of initial")
    t_conv = c.errors.get("eerd_converge_s")
    if t_conv is not None:
        ax.axvline(t_conv, color="tab:red", linewidth=0.8, alpha=0.6)
        ax.annotate(f"below 1 % from {t_conv:.1f} s", xy=(t_conv, 1), xycoords=("data", "axes fraction"),
                    xytext=(4, -4), textcoords="offset points", va="top", color="tab:red", fontsize=8)
    _log_or_linear(ax, s.eerd, [metrics.CONVERGED_FRACTION * initial] if initial else [])
    ax.set_ylabel("EERD [m²]")
    ax.set_title("relative-position error  EERD(t) = Σ_edges |z_ij − ẑ_ij|²", loc="left", fontsize=9)


def _draw_omega(ax: Axes, c: _Ctx) -> None:
    assert c.s.omega_hat is not None
    c.agents(ax, c.s.omega_hat)
    if c.s.omega_true is not None:
        ax.plot(c.s.est_t[c.es], c.s.omega_true[c.es], **_TRUE_STYLE)
    # frame the truth and the settled estimates; transients (estimates start far off) may clip
    vals = np.concatenate([np.ravel(c.s.omega_true if c.s.omega_true is not None else []),
                           np.ravel(c.s.omega_hat[c.s.est_t >= c.s.est_t[-1] / 2])])
    vals = vals[np.isfinite(vals)]
    if vals.size:
        lo, hi = float(vals.min()), float(vals.max())
        pad = max(0.25 * (hi - lo), 0.1 * max(abs(lo), abs(hi)), 1e-3)
        ax.set_ylim(lo - pad, hi + pad)
    ax.set_ylabel("ω [rad/s]")
    ax.set_title("angular rate: true (dashed) and each agent's estimate ω̂", loc="left", fontsize=9)


def _draw_eec(ax: Axes, c: _Ctx) -> None:
    assert c.s.eec is not None
    ax.plot(c.s.est_t[c.es], c.s.eec[c.es], color=_TOTAL_COLOR, linewidth=1.4)
    _log_or_linear(ax, c.s.eec)
    ax.set_ylabel("EEC [m²]")
    ax.set_title("contact-to-centre error  EEC(t) = Σ_i |z_i − ẑ_i|²", loc="left", fontsize=9)


def _draw_zi_err(ax: Axes, c: _Ctx) -> None:
    assert c.s.zi_err is not None
    c.agents(ax, c.s.zi_err)
    _log_or_linear(ax, c.s.zi_err)
    ax.set_ylabel("|ẑ_i − z_i| [m]")
    ax.set_title("z_i error per agent", loc="left", fontsize=9)


def _scalar_panel(col: str, truth_col: str, ylabel: str, title: str) -> Callable[[Axes, _Ctx], None]:
    def draw(ax: Axes, c: _Ctx) -> None:
        c.agents(ax, c.est.columns[col])
        if truth_col in c.truth.columns:
            ax.plot(c.s.est_t[c.es], c.truth_at_est(truth_col)[c.es], **_TRUE_STYLE)
            true = c.truth_at_est(truth_col)
            finite = true[np.isfinite(true)]
            if finite.size:
                # estimates start at 0 and may overshoot wildly: keep the true value readable
                lo, hi = float(finite.min()), float(finite.max())
                pad = max(0.5 * (hi - lo), 0.5 * max(abs(lo), abs(hi)), 1e-6)
                ax.set_ylim(min(0.0, lo - pad), hi + pad)
        ax.set_ylabel(ylabel)
        ax.set_title(title, loc="left", fontsize=9)
        block = trust_block(c.run).get(col)
        if block and block["untrusted_agents"]:
            ax.set_title(f"UNTRUSTED at agents {block['untrusted_agents']} (fresh neighbour states "
                         f"{block['fresh_min']:.0%})", loc="right", fontsize=9, color="crimson")

    return draw


def _vector_panel(prefix: str, ylabel: str, title: str) -> Callable[[Axes, _Ctx], None]:
    def draw(ax: Axes, c: _Ctx) -> None:
        for comp in ("x", "y"):
            c.agents(ax, c.est.columns[f"{prefix}_{comp}"], alpha=1.0 if comp == "x" else 0.55)
        for comp, style in (("x", _TRUE_STYLE), ("y", _TRUE_STYLE_Y)):
            name = f"{prefix}_{comp}"
            if name in c.truth.columns:
                ax.plot(c.s.est_t[c.es], c.truth_at_est(name)[c.es], **style)
        ax.set_ylabel(ylabel)
        ax.set_title(title, loc="left", fontsize=9)

    return draw


_DRAWERS: dict[str, Callable[[Axes, _Ctx], None]] = {
    "eerd": _draw_eerd,
    "omega": _draw_omega,
    "eec": _draw_eec,
    "zi_err": _draw_zi_err,
    "J": _scalar_panel("J", "inertia", "J [kg m²]", "moment of inertia: true (dashed) and estimates Ĵ"),
    "zc": _vector_panel("zc", "z_C [m]", "z_C = p_G − p_C: x (solid, true dashed), y (faint, true dotted)"),
    "vc": _vector_panel("vc", "v_C [m/s]", "CoM velocity v_C: x (solid, true dashed), y (faint, true dotted)"),
    "m": _scalar_panel("m", "mass", "m [kg]", "mass: true (dashed) and estimates m̂"),
}


def _team_series(run: RunData, column: str, reduce: Callable[..., np.ndarray]) -> tuple[np.ndarray, np.ndarray] | None:
    """An estimates.csv column held forward per agent and reduced over the agents (``reduce(x, axis=1)``;
    NaN where no agent has reported yet); None if the run has no such column."""
    est = run.estimates
    if est is None or not est.has(column) or len(est.t) == 0:
        return None
    held = metrics.hold_last(est.columns[column])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN rows before any agent reported
        return est.t, reduce(held, axis=1)


def _phase_changes(run: RunData) -> list[tuple[float, int]]:
    """Times at which the agents' median phase changes, for the thin vertical markers."""
    got = _team_series(run, "phase", np.nanmedian)
    if got is None:
        return []
    t, median = got
    t = t[np.isfinite(median)]
    median = median[np.isfinite(median)]
    change = np.flatnonzero(median[1:] != median[:-1]) + 1
    out = [(float(t[k]), int(round(median[k]))) for k in change]
    return out[:20]  # a flapping phase would otherwise draw a barcode


def effect_events(run: RunData) -> list[dict[str, Any]]:
    """The online detection's events, in time order: each ``effect_*`` entry of summary.json's ``events``
    (``kind`` the name after ``effect_``: ``switch``, ``withdrawn``, ...; ``t`` in s). A run whose summary has
    no ``effects`` block (not completed) gets its switches from the estimates' ``eff_*`` columns. Empty for
    a run without online detection."""
    summary = run.summary or {}
    if "effects" in summary:
        raw = [e for e in summary.get("events", []) if str(e.get("event", "")).startswith("effect_")]
    else:
        raw = [{"event": "effect_switch", **e} for e in effects_block(run).get("events", []) if e["tick"] >= 0]
    out = []
    for e in raw:
        tick = e.get("tick")
        t = e.get("t", None if tick is None else tick * run.dt)
        if t is None:
            continue
        out.append({"kind": e["event"][len("effect_"):], "t": float(t), "tick": tick, "effect": e.get("effect", "?"),
                    "statistic": e.get("statistic"), "agents": e.get("agents")})
    return sorted(out, key=lambda e: e["t"])


def unexplained_times(run: RunData) -> list[float]:
    """Times at which the team's count of ``unexplained`` windows grows (the largest ``eff_unexplained``
    over the agents): the ticks the windows were judged."""
    got = _team_series(run, "eff_unexplained", np.nanmax)
    if got is None:
        return []
    t, team = got
    team = np.where(np.isfinite(team), team, 0.0)
    grew = np.flatnonzero(np.diff(team, prepend=0.0) > 0)
    return [float(t[k]) for k in grew]


def _effect_style(kind: str) -> dict[str, Any]:
    return _EFFECT_STYLE.get(kind, _EFFECT_OTHER)


def _draw_effects(axes: Sequence[Axes], events: list[dict[str, Any]], unexplained: list[float]) -> None:
    """A vertical line per effect event on every panel, labelled once on the top panel (effect, z); the
    unexplained windows as small triangles along the top panel's upper edge (a line each would crowd it)."""
    for ax in axes:
        for e in events:
            ax.axvline(e["t"], linewidth=1.5, alpha=0.85, zorder=1, gid=f"effect_{e['kind']}",
                       **_effect_style(e["kind"]))
    top = axes[0]
    for e in events:
        z = "" if e["statistic"] is None else f", z {e['statistic']:.1f}"
        what = "on" if e["kind"] == "switch" else e["kind"].replace("_", " ")
        top.annotate(f"{e['effect']} {what}{z}", xy=(e["t"], 0.97), xycoords=("data", "axes fraction"),
                     xytext=(-3, 0), textcoords="offset points", rotation=90, ha="right", va="top", fontsize=7,
                     color=_effect_style(e["kind"])["color"], gid=f"effect_{e['kind']}_label",
                     bbox={"boxstyle": "square,pad=0.1", "facecolor": "white", "edgecolor": "none", "alpha": 0.7})
    if unexplained:
        top.plot(unexplained, [1.0] * len(unexplained), linestyle="none", marker="v", markersize=6,
                 color=_UNEXPLAINED_COLOR, transform=top.get_xaxis_transform(), clip_on=False, zorder=6,
                 gid="effect_unexplained")


def build_figure(run: RunData, errors: dict[str, Any] | None = None) -> Figure:
    """Draw the report figure for a run (needs truth and estimates); returns it unsaved.

    Each data panel's axes carries its panel name as its label (``ax.get_label()``), so callers and
    tests can find the panels among the legend/colour-bar axes.
    """
    series = metrics.error_series(run)
    if errors is None:
        errors = metrics.final_errors(run, WINDOW_S)
    names = panel_names(run)
    if not names:
        raise ValueError(f"{run.path}: nothing to plot (no pairs and no known estimate columns)")
    ctx = _Ctx(run, series, errors)
    fig, axes = plt.subplots(
        len(names), 1, sharex=True, figsize=(11, 1.2 + 2.0 * len(names)), layout="constrained", squeeze=False
    )
    phases = _phase_changes(run)
    for ax, name in zip(axes[:, 0], names):
        ax.set_label(name)
        _DRAWERS[name](ax, ctx)
        ax.grid(True, which="major", alpha=0.3)
        for t, _ in phases:
            ax.axvline(t, color="gray", linewidth=0.7, linestyle="-.", alpha=0.5, zorder=0)
    if phases:
        # phase changes as ticks of a top axis: labelled once, never on top of data or titles
        top = axes[0, 0].secondary_xaxis("top")
        top.set_xticks([t for t, _ in phases], labels=[f"phase {p}" for _, p in phases], fontsize=7,
                       color="dimgray")
        top.tick_params(length=3, color="gray")
    effects, unexplained = effect_events(run), unexplained_times(run)
    _draw_effects(list(axes[:, 0]), effects, unexplained)
    axes[-1, 0].set_xlabel("time [s]")
    t_all = series.est_t if series.pair_t is None else np.concatenate([series.est_t, series.pair_t])
    if len(t_all):
        axes[-1, 0].set_xlim(float(np.min(t_all)), float(np.max(t_all)))
    marks = [Line2D([], [], linewidth=1.5, label=f"effect {kind}", **_effect_style(kind))
             for kind in dict.fromkeys(e["kind"] for e in effects)]
    if unexplained:
        marks.append(Line2D([], [], linestyle="none", marker="v", color=_UNEXPLAINED_COLOR,
                            label="window unexplained"))
    _agent_legend(fig, run.n, ctx.colors, with_eerd="eerd" in names, extra=marks)
    cfg = run.config
    fig.suptitle(
        f"coload run '{run.name}'  ({cfg.get('mode', '?')}, n = {run.n}, seed = {cfg.get('seed', '?')}, "
        f"dt = {run.dt:g} s)",
        fontsize=11,
    )
    return fig


def _agent_legend(fig: Figure, n: int, colors: Sequence[Any], *, with_eerd: bool,
                  extra: Sequence[Line2D] = ()) -> None:
    """One legend outside the panels so no data is covered; beyond 12 agents a colour bar names them."""
    common = [Line2D([], [], **{k: v for k, v in _TRUE_STYLE.items() if k != "zorder"}, label="true value"),
              *extra]
    if with_eerd:
        common = [
            Line2D([], [], color=_TOTAL_COLOR, linewidth=1.4, label="EERD, EEC (sums)"),
            Line2D([], [], color="tab:red", linestyle=":", linewidth=1.2, label="1 % of initial EERD"),
        ] + common
    if n <= 12:
        handles = [Line2D([], [], color=colors[i], linewidth=1.5, label=f"agent {i}") for i in range(n)]
        fig.legend(handles=handles + common, loc="outside right upper", fontsize=8, frameon=False)
    else:
        data_axes = list(fig.axes)
        sm = plt.cm.ScalarMappable(cmap="viridis", norm=plt.Normalize(0, n - 1))
        fig.colorbar(sm, ax=data_axes, location="right", shrink=0.4, label="agent", pad=0.01)
        fig.legend(handles=common, loc="outside right upper", fontsize=8, frameon=False)


# --- table --------------------------------------------------------------------------------------
def _fmt(x: Any, spec: str = ".4f") -> str:
    return "-" if x is None else format(x, spec)


def summary_table(run: RunData, errors: dict[str, Any]) -> str:
    """Plain-text per-agent error table plus a totals line, from the ``errors`` block."""
    n = run.n
    cfg = run.config

    def per(key: str) -> list[Any]:
        return list(errors.get(key) or [None] * n)

    zi, om, share = per("zi_err_per_agent"), per("omega_rms_per_agent"), per("eerd_ratio_per_agent")
    win = errors.get("window_s", WINDOW_S)
    cols = ("agent", "|z_i err| final [m]", f"omega RMS last {win:g} s [rad/s]", "EERD share [final/initial]")
    widths = [max(9, len(c)) for c in cols]
    lines = [
        f"run '{run.name}' ({cfg.get('mode', '?')}, n = {n}, seed = {cfg.get('seed', '?')}, "
        f"t_final = {_fmt(errors.get('t_final'), '.2f')} s)  {run.path}",
        "  ".join(c.rjust(w) for c, w in zip(cols, widths)),
    ]
    for i in range(n):
        cells = (str(i), _fmt(zi[i], ".3e"), _fmt(om[i], ".3e"), _fmt(share[i], ".3e"))
        lines.append("  ".join(c.rjust(w) for c, w in zip(cells, widths)))
    lines.append("-" * (sum(widths) + 2 * (len(widths) - 1)))
    total = ("all (RMS)", _fmt(errors.get("zi_rms"), ".3e"), _fmt(errors.get("omega_rms"), ".3e"),
             "ratio " + _fmt(errors.get("eerd_ratio"), ".3e"))
    lines.append("  ".join(c.rjust(w) for c, w in zip(total, widths)))
    conv = errors.get("eerd_converge_s")
    lines.append(
        f"EERD {_fmt(errors.get('eerd_initial'), '.4g')} -> {_fmt(errors.get('eerd_final'), '.4g')} m^2; "
        f"below 1 % of initial {'from t = ' + format(conv, '.2f') + ' s' if conv is not None else 'never'}; "
        f"EEC final {_fmt(errors.get('eec_final'), '.4g')} m^2; "
        f"z_i RMS last {win:g} s {_fmt(errors.get('zi_rms_window'), '.4g')} m"
    )
    extra = [
        f"{label} {_fmt(errors[key], spec)}{unit}"
        for key, label, spec, unit in (
            ("J_rel", "J rel err", ".2%", ""), ("m_rel", "m rel err", ".2%", ""),
            ("zC_rms", "z_C err", ".4g", " m"), ("vC_rms", "v_C RMS", ".4g", " m/s"),
        )
        if key in errors
    ]
    if extra:
        lines.append("; ".join(extra))
    for name, block in trust_block(run).items():
        sd = block["sd_max"]
        verdict = "trusted" if block["trusted"] else f"UNTRUSTED at agents {block['untrusted_agents']}"
        lines.append(f"{name}: {verdict} (fresh neighbour states >= {_fmt(block['fresh_min'], '.0%')} in its "
                     f"stages; sd <= {_fmt(sd, '.3g')})")
    mon = monitor_block(run)
    if mon:
        firsts = [t for t in mon["per_agent"]["first_alarm_t"] if t is not None]
        lines.append(f"innovation monitor: {mon['alarms']} of {mon['windows']} windows alarmed"
                     + (f", first at t = {min(firsts):.1f} s" if firsts else "") + " (report-only)")
    lines += effect_lines(run)
    lines += centralized_lines(run.summary)
    return "\n".join(lines)


def effect_lines(run: RunData) -> list[str]:
    """The online detection's events as a small table (event, effect, tick, t, z, the agents that applied
    it) and the count of ``unexplained`` windows; nothing for a run without online detection."""
    events, unexplained = effect_events(run), unexplained_times(run)
    if not events and not unexplained and not effects_block(run):
        return []
    lines = [f"online detection: {len(events)} effect event(s), {len(unexplained)} window(s) unexplained"
             + (" (judged at t = " + ", ".join(f"{t:.1f}" for t in unexplained) + " s)" if unexplained else "")]
    if events:
        cols = ("event", "effect", "tick", "t [s]", "z", "agents")
        rows = []
        for e in events:
            agents = e["agents"]
            who = "-" if agents is None else ("all " + str(run.n) if sorted(agents) == list(range(run.n))
                                              else ",".join(str(a) for a in agents))  # fmt: skip
            rows.append((e["kind"], str(e["effect"]), "-" if e["tick"] is None else str(e["tick"]),
                         f"{e['t']:.2f}", _fmt(e["statistic"], ".2f"), who))
        widths = [max(len(c), *(len(r[k]) for r in rows)) for k, c in enumerate(cols)]
        lines.append("  " + "  ".join(c.ljust(w) for c, w in zip(cols, widths)).rstrip())
        lines += ["  " + "  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows]
    return lines


def centralized_lines(summary: dict[str, Any] | None) -> list[str]:
    """The batch-fit yardstick of summary.json (``centralized``, ``distributed_over_centralized``) as text;
    nothing when the run was made without it (``--no-batch-fit``)."""
    c = (summary or {}).get("centralized")
    r = (summary or {}).get("distributed_over_centralized") or {}
    if not isinstance(c, dict):
        return []

    def est(name: str, unit: str) -> str:
        if c.get(name) is None:
            return f"{name} -"
        rel = c.get(f"{name}_rel")
        return (f"{name} {c[name]:.5g} +- {_fmt(c.get(f'{name}_ci95'), '.2g')} {unit}"
                + ("" if rel is None else f" ({rel:+.3%})"))  # fmt: skip

    span = "" if c.get("t0") is None else f", {c['t0']:g}-{c['t1']:g} s, fit {_fmt(c.get('fit_s'), '.1f')} s"
    lines = [f"centralized (batch fit of all samples{span}): {est('m', 'kg')}, {est('J', 'kg m^2')}"]
    parts = []
    for name in ("J", "m"):
        dist, cen = r.get(f"{name}_dist_rel"), c.get(f"{name}_rel")
        if dist is not None and cen is not None:
            parts.append(f"{name} {dist:.3%} / {abs(cen):.3%} = {_fmt(r.get(name), '.3g')} "
                         f"({_fmt(r.get(f'{name}_over_ci95'), '.3g')} x its 95 % half-width)")
        else:
            parts.append(f"{name} -")
    lines.append("distributed / centralized error (median over agents): " + ", ".join(parts))
    reason = r.get("reason") or c.get("reason")
    if reason:
        lines.append(f"  ({reason})")
    return lines


DIAGNOSIS_JSON = rundir_format.DIAGNOSIS_JSON
RESIDUAL_PNG = rundir_format.RESIDUAL_PNG


def write_diagnosis(run_dir: str | Path, progress: Callable[[str], None] | None = None) -> Path:
    """Diagnoses the run's recording (ident.diagnose) and writes ``RUN_DIR/diagnosis.json``."""
    import json

    from ident.diagnose import diagnose_dir

    result = diagnose_dir(run_dir, progress=progress)
    path = Path(run_dir) / DIAGNOSIS_JSON
    path.write_text(json.dumps(result.as_dict(), indent=1) + "\n", encoding="utf-8")
    return path


def residual_panels_of(run_dir: str | Path) -> dict[str, Any] | None:
    """The ``residual`` data of ``RUN_DIR/diagnosis.json`` (ident.diagnose.residual_panels); None when the
    run carries no diagnosis; ValueError when its diagnosis.json lacks the residual data."""
    import json

    src = Path(run_dir) / DIAGNOSIS_JSON
    if not src.exists():
        return None
    try:
        panels = json.loads(src.read_text(encoding="utf-8"))["residual"]
        if not isinstance(panels, dict):
            raise TypeError("'residual' is not an object")
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{src}: no residual data ({type(exc).__name__}: {exc}); re-run coload diagnose "
                         f"--json or coload report --diagnose") from None  # fmt: skip
    return panels


def build_residual_figure(panels: dict[str, Any]) -> Figure:
    """The residual figure (ident.diagnose.draw_residuals) of :func:`residual_panels_of`, unsaved."""
    from ident.diagnose import draw_residuals

    fig = plt.figure(figsize=(12, 8), layout="constrained")
    draw_residuals(fig, panels)
    return fig


def residual_figure(run_dir: str | Path, out_png: str | Path | None = None) -> Path | None:
    """``RUN_DIR/residual.png`` from ``RUN_DIR/diagnosis.json``: the residual before (nominal model) and
    after (with the accepted effects), time series and autocorrelation with the +-1.96/sqrt(N) bounds.
    None when the run carries no diagnosis."""
    panels = residual_panels_of(run_dir)
    if panels is None:
        return None
    out = Path(out_png) if out_png is not None else Path(run_dir) / RESIDUAL_PNG
    fig = build_residual_figure(panels)
    try:
        fig.savefig(out, dpi=90)
    finally:
        plt.close(fig)
    return out


def make_report(run_dir: str | Path, out_png: str | Path | None = None) -> tuple[Path, str]:
    """Read a run, write its figure (default ``RUN_DIR/report.png``), return the PNG path and the table."""
    run = read_run(run_dir)
    errors = metrics.final_errors(run, WINDOW_S)
    out = Path(out_png) if out_png is not None else run.path / REPORT_PNG
    fig = build_figure(run, errors)
    try:
        fig.savefig(out, dpi=110)
    finally:
        plt.close(fig)
    return out, summary_table(run, errors)
