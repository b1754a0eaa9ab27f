"""Presentation of a diagnosis: the result types, text, JSON and the residual figure (docs/diagnose.md)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ident.stats import Z95, autocorrelation, block_average


@dataclass
class ModelReport:
    effects: tuple[str, ...]
    m: float
    m_ci95: float
    J: float  # NaN when not identifiable (n = 1)
    J_ci95: float
    zc: tuple[float, float]
    residual_rms: float  # per measured component, of the first channel (velocity m/s, else position m)
    whiteness_p: float
    heldout_rms: float
    bic: float
    m_rel_err: float | None = None
    J_rel_err: float | None = None
    residual_rms_pos: float | None = None
    residual_over_floor: float = math.nan
    modes: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)), repr=False)

    def as_dict(self) -> dict[str, Any]:
        out = {
            "m": _f(self.m), "J": _f(self.J), "residual_rms": _f(self.residual_rms),
            "whiteness_p": _f(self.whiteness_p),
            "m_ci95": _f(self.m_ci95), "J_ci95": _f(self.J_ci95), "zc": [_f(v) for v in self.zc],
            "heldout_rms": _f(self.heldout_rms), "bic": _f(self.bic), "effects": list(self.effects),
            "residual_over_floor": _f(self.residual_over_floor),
        }  # fmt: skip
        if self.residual_rms_pos is not None:
            out["residual_rms_position"] = _f(self.residual_rms_pos)
        if self.m_rel_err is not None:
            out["m_rel_err"] = _f(self.m_rel_err)
            out["J_rel_err"] = _f(self.J_rel_err) if self.J_rel_err is not None else None
        return out


def _f(x: Any) -> float | None:
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


@dataclass
class Diagnosis:
    """What :func:`ident.select.diagnose` found. ``as_dict`` is the JSON of ``coload diagnose --json``."""

    nominal: ModelReport
    augmented: ModelReport
    effects: list[dict[str, Any]]
    unexplained: bool
    warnings: list[str]
    candidates: list[dict[str, Any]]
    signatures: list[dict[str, Any]]
    ambiguous: list[list[str]]
    noise_sigma: float
    wall_s: float
    truth: dict[str, float] | None = None
    block_s: float = 0.1
    lags: int = 20
    noise_floor: dict[str, float] = field(default_factory=dict)
    identifiable: dict[str, bool] = field(default_factory=dict)
    model: dict[str, Any] = field(default_factory=dict)
    validation: dict[str, Any] | None = None
    frames: dict[str, Any] | None = None  # ident/frames.py: the robot-frame check
    velocity_frames: dict[str, Any] | None = None  # ident/frames.py: the velocities' robot-frame check
    change: dict[str, Any] | None = None  # ident/change.py: a change of the load, and each side's diagnosis
    random_force: dict[str, Any] | None = None  # ident/random_force.py: the residual's walk, in N and N m
    saturation: list[dict[str, Any]] = field(default_factory=list)  # ident/saturation.py: forces at a limit
    offset_drift: dict[str, Any] | None = None  # ident/offsets.py: which robot's force offset drifts
    fits: dict[str, Any] = field(default_factory=dict, repr=False)
    problem: Any = field(default=None, repr=False)

    @property
    def modes_nominal(self) -> np.ndarray:
        return block_average(self.nominal.modes, max(1, self._block))

    @property
    def modes_augmented(self) -> np.ndarray:
        return block_average(self.augmented.modes, max(1, self._block))

    @property
    def _block(self) -> int:
        pb = self.problem
        if pb is None:
            return 1
        return max(1, round(self.block_s / float(np.median(np.diff(pb.win.u_t)))))

    def as_dict(self) -> dict[str, Any]:
        out = {
            "nominal": self.nominal.as_dict(), "augmented": self.augmented.as_dict(), "effects": self.effects,
            "unexplained": self.unexplained, "warnings": self.warnings, "candidates": self.candidates,
            "signatures": self.signatures, "ambiguous": self.ambiguous, "noise_sigma": _f(self.noise_sigma),
            "noise_floor": _jsonable(self.noise_floor), "identifiable": self.identifiable,
            "model": self.model, "truth": self.truth, "wall_s": self.wall_s, "residual": residual_panels(self),
            "random_force": None if self.random_force is None else _jsonable(self.random_force),
        }  # fmt: skip
        if self.validation is not None:
            out["validation"] = self.validation
        out["change"] = _jsonable(self.change)
        out["saturation"] = _jsonable(self.saturation)
        out["frames"] = _jsonable(self.frames)
        out["velocity_frames"] = _jsonable(self.velocity_frames)
        if self.offset_drift is not None:
            out["offset_drift"] = _jsonable(self.offset_drift)
        return out


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (float, np.floating)):
        return _f(x)
    if isinstance(x, np.integer):
        return int(x)
    return x


def format_diagnosis(r: Diagnosis) -> str:
    """A short human-readable summary (the JSON has everything)."""
    lines = []
    for label, m in (("nominal", r.nominal), ("augmented", r.augmented)):
        err = ""
        if m.m_rel_err is not None:
            err = f"  [vs truth: m {100 * m.m_rel_err:+.2f} %" + (
                f", J {100 * m.J_rel_err:+.2f} %]" if m.J_rel_err is not None else "]")
        J = f"J {m.J:.4g} +- {m.J_ci95:.2g} kg m^2" if math.isfinite(m.J) else "J not identifiable"
        M = f"m {m.m:.4g} +- {m.m_ci95:.2g} kg" if math.isfinite(m.m) else "m not resolved"
        lines.append(f"{label:9s} effects {list(m.effects) or '-'}: {M}, {J}, "
                     f"residual {m.residual_rms:.4g} ({m.residual_over_floor:.3g} x noise floor), "
                     f"whiteness p {m.whiteness_p:.3g}, held-out {m.heldout_rms:.4g}{err}")  # fmt: skip
    if r.effects:
        for e in r.effects:
            lines.append(f"effect    {e['name']}: {_fmt(e['value'])} +- {_fmt(e['ci95'])} {e['unit']}{_agents(e)}"
                         + _principal(e) + _moment(e))
    else:
        lines.append("effect    none named")
    lines.append(f"unexplained: {str(r.unexplained).lower()}")
    ch = r.change
    if ch is not None and ch.get("found"):
        lines.append(f"change    the load changes between {ch['window'][0]:.4g} and {ch['window'][1]:.4g} s "
                     f"(F {ch['F']:.3g}, p {ch['p']:.2g}); each side diagnosed as a recording of its own:")
        for key in ("before", "after"):
            d = ch[key]
            if "error" in d:
                lines.append(f"  {key:6s} {d['from_s']:.4g}-{d['to_s']:.4g} s: {d['error']}")
                continue
            J = f"J {d['J']:.4g} +- {d['J_ci95']:.2g}" if math.isfinite(d["J"]) else "J not identifiable"
            eff = ", ".join(f"{e['name']} {_fmt(e['value'])} +- {_fmt(e['ci95'])} {e['unit']}" for e in d["effects"])
            lines.append(f"  {key:6s} {d['from_s']:.4g}-{d['to_s']:.4g} s: m {d['m']:.4g} +- {d['m_ci95']:.2g}, {J}, "
                         f"effects {eff or '-'}, residual {d['residual_over_floor']:.3g} x floor, whiteness p "
                         f"{d['whiteness_p']:.3g}{', unexplained' if d['unexplained'] else ''}")  # fmt: skip
    elif ch is not None and "p" in ch:
        lines.append(f"change    none that explains the residual (the best split, at {ch['t']:.4g} s: F-test p "
                     f"{ch['p']:.2g} at level {ch['level']:.2g}, "
                     + (("the residual has no excess over the noise floor" if not math.isfinite(ch["split_share"])
                         else f"removes {100 * ch['split_share']:.0f} % of the excess" if ch["split_share"] <= 1.0
                         else f"its sides fit below the noise floor: {100 * ch['split_share']:.0f} % of the excess"))
                     + (f"; its sides leave {100 * (1 - ch['share']):.0f} %)" if "share" in ch else ")"))
    elif ch is not None:
        lines.append(f"change    not searched: {ch.get('why')}")
    if r.validation is not None:
        v = r.validation
        for key in ("nominal", "augmented"):
            m = v[key]
            lines.append(f"validation {key:9s}: rms {m['rms']:.4g} ({m['channel']}), "
                         f"{m['ratio_to_identification']:.3g} x the identification residual, "
                         f"whiteness p {m['whiteness_p']:.3g}")  # fmt: skip
        lines.append(f"validation flagged: {str(v['flagged']).lower()}"
                     + (" (the other recording holds a force or effect the models lack)" if v["flagged"] else ""))
    lines += [f"warning   {w}" for w in r.warnings]
    return "\n".join(lines)


def _agents(e: dict[str, Any]) -> str:
    """A per-agent effect's reading: which agents are off the reference agent, and by how much."""
    if e.get("agents") is None:
        return ""
    off = ", ".join(f"agent {i} {e['value'][i]:.4g} +- {e['ci95'][i]:.2g}" for i in e["agents"]
                    if e["ci95"][i] is not None) or "none"  # fmt: skip
    if e.get("reference") is None and e.get("unit") != "deg":  # a scale relative to the team's median agent
        return f" (per agent, {e.get('frame', 'relative to the team')}; off: {off})"
    if e.get("reference") is None:
        return f" (per agent: each robot's mounting angle, {e.get('frame', 'body frame at the first stamp')})"
    why = "the team's median" if len(e["value"]) > 2 else "two agents: which of them is off is not identifiable"
    return f" (per agent, relative to agent {e['reference']}, {why}; outside its 95 % interval: {off})"


def _principal(e: dict[str, Any]) -> str:
    """An anisotropic friction's reading: the viscous friction along and across its axis."""
    p = e.get("principal")
    if p is None:
        return ""
    return (f" (viscous friction {p['along']:.4g} N s/m along the load's axis at {p['axis_deg']:.3g} deg, "
            f"{p['across']:.4g} across it)")


def _moment(e: dict[str, Any]) -> str:
    """Per-robot force offsets' reading: their sum is the value, their moment is said beside it."""
    if "moment_Nm" not in e:
        return ""
    return (f" (the robots' force offsets summed, and their moment {e['moment_Nm']:.3g} +- {e['moment_ci95']:.2g} N m "
            "turning with the load; each robot's own offset is not identifiable)")


def _fmt(v: Any) -> str:
    if isinstance(v, list):
        return "[" + ", ".join("-" if x is None else f"{x:.4g}" for x in v) + "]"
    return f"{v:.4g}"


def _jlist(x: np.ndarray) -> list:
    return [_jlist(v) for v in x] if np.ndim(x) > 1 else [float(v) if math.isfinite(v) else None for v in x]


def mode_names(r: Diagnosis) -> list[str]:
    pb = r.problem
    if pb is None:
        return ["mean x", "mean y", "rotation"]
    names = []
    for ch, y in (("velocity", pb.win.vel), ("position", pb.win.pos)):
        if y is None:
            continue
        names += [f"{ch} mean {a} (x noise floor)" for a, on in zip("xy", pb.base.axes) if on]
        if pb.base.rotation:
            names.append(f"{ch} rotation (x noise floor)")
    return names


def residual_panels(r: Diagnosis) -> dict[str, Any]:
    """The residual figure's data, JSON-ready (the ``residual`` key): per model the block-averaged
    rigid-body modes of the residual (in units of the noise floor), their autocorrelations r_1..r_lags, and
    per mode the 95 % bound +-1.96/sqrt(N) of a white residual's autocorrelation."""
    out: dict[str, Any] = {"block_s": r.block_s, "lags": r.lags, "modes": mode_names(r)}
    for key, modes, rep in (("nominal", r.modes_nominal, r.nominal), ("augmented", r.modes_augmented, r.augmented)):
        out[key] = {
            "effects": list(rep.effects), "whiteness_p": _f(rep.whiteness_p), "series": _jlist(modes),
            "acf": [_jlist(autocorrelation(modes[:, j], r.lags)) for j in range(modes.shape[1])],
        }  # fmt: skip
    mn = r.modes_nominal
    counts = [int(np.count_nonzero(~np.isnan(mn[:, j]))) for j in range(mn.shape[1])]
    out["bound"] = [Z95 / math.sqrt(max(nb, 1)) for nb in counts]
    out["unexplained"] = r.unexplained
    return out


def draw_residuals(fig: Any, panels: dict[str, Any], title: str = "") -> None:
    """Draws :func:`residual_panels` into ``fig``: one row per mode, block means before and after on the
    left, their autocorrelation with the white-noise bounds on the right (axes ``residual:<j>``, ``acf:<j>``)."""
    names = panels["modes"]
    axes = fig.subplots(len(names), 2, gridspec_kw={"width_ratios": [3, 1]}, squeeze=False)
    block_s, lags = float(panels["block_s"]), int(panels["lags"])
    lag_t = np.arange(1, lags + 1) * block_s
    for j, name in enumerate(names):
        ax, axc = axes[j]
        ax.set_label(f"residual:{j}")
        axc.set_label(f"acf:{j}")
        for key, color in (("nominal", "tab:red"), ("augmented", "tab:blue")):
            m = panels[key]
            series = np.array([np.nan if v is None else v for v in (row[j] for row in m["series"])], dtype=float)
            label = f"{'before' if key == 'nominal' else 'after'}: {', '.join(m['effects']) or 'nominal'}"
            ax.plot(np.arange(len(series)) * block_s, series, color=color, lw=0.8, label=label)
            acf = np.array([np.nan if v is None else v for v in m["acf"][j]], dtype=float)
            axc.plot(lag_t, acf, "o-", color=color, ms=3, lw=0.8)
        b = panels["bound"][j]
        axc.axhline(b, color="k", ls="--", lw=0.8)
        axc.axhline(-b, color="k", ls="--", lw=0.8)
        ax.set_ylabel(f"residual, {name}", fontsize=8)
        axc.set_ylabel("autocorrelation", fontsize=8)
    axes[0, 0].legend(loc="upper right", fontsize=8)
    axes[-1, 0].set_xlabel(f"t (s), {block_s:g} s block means")
    axes[-1, 1].set_xlabel("lag (s); dashed: +-1.96/sqrt(N)")
    nom, aug = panels["nominal"], panels["augmented"]
    fig.suptitle(title or (
        f"residual before (nominal, Ljung-Box p = {nom['whiteness_p'] or 0:.2g}) and after "
        f"({', '.join(aug['effects']) or 'none'}, p = {aug['whiteness_p'] or 0:.2g})"
        f"{'  UNEXPLAINED' if panels.get('unexplained') else ''}"))  # fmt: skip


def plot_diagnosis(r: Diagnosis, path: str | Path) -> Path:
    """diagnose.png: :func:`draw_residuals` of this diagnosis."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(12, 8), layout="constrained")
    draw_residuals(fig, residual_panels(r))
    path = Path(path)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
