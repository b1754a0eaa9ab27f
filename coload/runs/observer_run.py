"""``coload observer run SCENARIO``: the two-link arm of paper 004 Sec. III with its I&I speed observer.

Integrates plant (eq. 2) and observer (agents/speed_observer.py) as one ODE with scipy's
error-controlled DOP853: the observer's stiffness grows with r (paper Fig. 5) and an adaptive
explicit method shrinks its step when it has to (and fails loudly) where a fixed-step RK4 would
silently lose accuracy; y is then exact inside the observer (no sample-and-hold). Draws Figs. 2, 3
and 5 equivalents (plus errors and r) into one PNG and writes summary.json.

The scenario model lives here (not in config/scenario.py, which describes load-pushing runs).
"""

from __future__ import annotations

import json
import time
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator
from scipy.integrate import solve_ivp

from agents.speed_observer import Gains, SpeedObserver, plant_rhs, two_link
from coload.rundir.series import write_series
from config.loader import deep_merge, parse_overrides


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


Vec2 = list[float]


def _two(v: list[float]) -> list[float]:
    if len(v) != 2:
        raise ValueError(f"expected 2 values, got {len(v)}")
    return v


class RobotSpec(_Strict):
    c1: float = Field(0.9698, gt=0, description="kg m^2, M11")
    c2: float = Field(0.1575, ge=0, description="kg m^2, coupling: M12 = c2 cos(q1-q2)")
    c3: float = Field(0.264, gt=0, description="kg m^2, M22")
    c4: float = Field(1.74, description="N m, gravity torque amplitude of joint 1")
    c5: float = Field(0.44, description="N m, gravity torque amplitude of joint 2")
    u: Vec2 = Field([0.0, 0.0], description="N m, constant joint torques")
    _v = field_validator("u")(_two)


class ObserverSpec(_Strict):
    k1: float = Field(40.0, gt=4, description="rate of the ideal error dynamics; > 4 (eq. 55)")
    k2: float = Field(8.0, gt=0, description="extra damping of e_y (eq. 53)")
    k3: float = Field(25.0, gt=0, description="extra damping of e_x (eq. 54)")
    c_r: float = Field(1e-3, gt=0, description="lower bound of r (eq. 38)")
    k_c: float | None = Field(None, gt=0, description="P4 bound; default c2")
    nodes: int = Field(16, ge=2, le=128, description="Gauss-Legendre order per integral")
    seed: int = Field(0, description="seed of the Generator for property checks and Lemma-2 suprema")


class InitialSpec(_Strict):
    y: Vec2 = [0.0, 0.0]
    x: Vec2 = [-0.29, 6.66]
    xi: Vec2 = [-8.45, 68.33]
    s_y: Vec2 = [1.0, 2.0]
    s_x: Vec2 = [10.0, 20.0]
    r: float = Field(0.1, gt=0)
    _v = field_validator("y", "x", "xi", "s_y", "s_x")(_two)


class RunSpec(_Strict):
    t_end: float = Field(6.0, gt=0, description="s")
    samples: int = Field(3001, ge=11, description="output grid points")
    rtol: float = Field(1e-8, gt=0)
    atol: float = Field(1e-9, gt=0)
    t_angles: float = Field(0.2, gt=0, description="s, span of the angle plot (Fig. 2)")


class ObserverScenario(_Strict):
    name: str = "ii-two-link"
    robot: RobotSpec = RobotSpec()
    observer: ObserverSpec = ObserverSpec()
    initial: InitialSpec = InitialSpec()
    run: RunSpec = RunSpec()


class ObserverScenarioError(Exception):
    """A scenario that cannot be used; the message names the source and the dotted field."""


def load_observer_scenario(path: Path, overrides: list[str] = ()) -> ObserverScenario:
    """Read the TOML, apply ``key=value`` overrides (TOML values), validate; errors name the field."""
    try:
        data = tomllib.loads(Path(path).read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ObserverScenarioError(f"{path}: {exc}") from exc
    data = deep_merge(data, parse_overrides(overrides))
    try:
        return ObserverScenario.model_validate(data)
    except ValidationError as exc:
        msgs = [f"{path}: {'.'.join(str(p) for p in e['loc'])}: {e['msg']} (got {e.get('input')!r})" for e in exc.errors()]
        raise ObserverScenarioError("\n".join(msgs)) from exc


def build(sc: ObserverScenario) -> SpeedObserver:
    rb, ob = sc.robot, sc.observer
    model = two_link(rb.c1, rb.c2, rb.c3, rb.c4, rb.c5, k_c=ob.k_c)
    return SpeedObserver(model, Gains(ob.k1, ob.k2, ob.k3, ob.c_r), nodes=ob.nodes, seed=ob.seed)


def simulate(sc: ObserverScenario, observer: SpeedObserver | None = None) -> dict[str, Any]:
    """Integrate robot + observer; return time series (t, y, x, s_y, s_x, x_hat, r) and run stats."""
    obs_model = observer or build(sc)
    n = 2
    u = np.asarray(sc.robot.u, float)
    ini = sc.initial
    obs0 = obs_model.initial(ini.xi, ini.s_y, ini.s_x, ini.r)
    z0 = np.concatenate([ini.y, ini.x, obs0])

    def f(_t: float, z: np.ndarray) -> np.ndarray:
        y, x = z[:n], z[n: 2 * n]
        dy, dx = plant_rhs(obs_model.model, y, x, u)
        return np.concatenate([dy, dx, obs_model.rhs(z[2 * n:], y, u)])

    t_eval = np.linspace(0.0, sc.run.t_end, sc.run.samples)
    wall = time.perf_counter()
    sol = solve_ivp(f, (0.0, sc.run.t_end), z0, method="DOP853", t_eval=t_eval, rtol=sc.run.rtol, atol=sc.run.atol)
    wall = time.perf_counter() - wall
    if not sol.success:
        raise RuntimeError(f"integration failed: {sol.message}")
    Z = sol.y.T
    y, x, obs = Z[:, :n], Z[:, n: 2 * n], Z[:, 2 * n:]
    x_hat = np.array([obs_model.estimate(o, yy) for o, yy in zip(obs, y)])
    return {"t": sol.t, "y": y, "x": x, "xi": obs[:, :n], "s_y": obs[:, n: 2 * n], "s_x": obs[:, 2 * n: 3 * n],
            "r": obs[:, 3 * n], "x_hat": x_hat, "nfev": int(sol.nfev), "wall_s": wall, "observer": obs_model}


def settle_time(t: np.ndarray, err: np.ndarray, frac: float) -> float | None:
    """First time after which err stays below frac * err[0] (None if it never settles)."""
    above = np.nonzero(err > frac * err[0])[0]
    if above.size == 0:
        return 0.0
    last = above[-1]
    return None if last + 1 >= t.size else float(t[last + 1])


def metrics(res: dict[str, Any]) -> dict[str, Any]:
    t = res["t"]
    out: dict[str, Any] = {}
    for name, a, b in (("s_y-y", res["s_y"], res["y"]), ("s_x-x", res["s_x"], res["x"]), ("x_hat-x", res["x_hat"], res["x"])):
        e = np.linalg.norm(a - b, axis=1)
        out[name] = {"initial": float(e[0]), "final": float(e[-1]), "max": float(e.max()),
                     "t_5pct": settle_time(t, e, 0.05), "t_1pct": settle_time(t, e, 0.01)}
    out["r"] = {"initial": float(res["r"][0]), "max": float(res["r"].max()), "t_max": float(t[np.argmax(res["r"])]),
                "final": float(res["r"][-1])}
    return out


def stiffness_curve(sc: ObserverScenario, observer: SpeedObserver, rs: np.ndarray) -> np.ndarray:
    """||[xi', s_y', s_x', r']|| at the initial state for each r (paper Fig. 5)."""
    ini = sc.initial
    out = []
    for r in rs:
        obs = observer.initial(ini.xi, ini.s_y, ini.s_x, max(r, observer.gains.c_r * (1 + 1e-9)))
        out.append(np.linalg.norm(observer.rhs(obs, np.asarray(ini.y), np.asarray(sc.robot.u))))
    return np.asarray(out)


def plot(sc: ObserverScenario, res: dict[str, Any], png: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = res["t"]
    fig, axes = plt.subplots(4, 2, figsize=(12, 13))
    near = t <= sc.run.t_angles + 1e-12
    for j in range(2):
        ax = axes[0, j]
        ax.plot(t[near], res["y"][near, j], "b-", label=f"y{j + 1}")
        ax.plot(t[near], res["s_y"][near, j], "g--", label=f"s_y{j + 1}")
        ax.set(xlabel="t [s]", ylabel=f"y{j + 1} [rad]", title=f"Fig. 2: joint angle {j + 1} (0-{sc.run.t_angles:g} s)")
        ax.legend()
        ax = axes[1, j]
        ax.plot(t, res["x"][:, j], "b-", label=f"x{j + 1}")
        ax.plot(t, res["s_x"][:, j], "g--", label=f"s_x{j + 1}")
        ax.plot(t, res["x_hat"][:, j], "r:", label=f"x_hat{j + 1} = xi + beta")
        lo, hi = np.percentile(res["x"][:, j], [0, 100])
        pad = max(5.0, hi - lo)
        ax.set_ylim(lo - pad, hi + pad)
        ax.set(xlabel="t [s]", ylabel=f"x{j + 1} [rad/s]", title=f"Fig. 3: joint speed {j + 1} (clipped view)")
        ax.legend(fontsize=8)
    ax = axes[2, 0]
    for name, a, b in (("|s_y - y|", res["s_y"], res["y"]), ("|s_x - x|", res["s_x"], res["x"]), ("|x_hat - x|", res["x_hat"], res["x"])):
        ax.semilogy(t, np.maximum(np.linalg.norm(a - b, axis=1), 1e-16), label=name)
    ax.set(xlabel="t [s]", ylabel="error norm", title="estimation errors")
    ax.legend()
    ax = axes[2, 1]
    ax.semilogy(t, res["r"])
    ax.set(xlabel="t [s]", ylabel="r", title="dynamic scaling r (bounded)")
    ax = axes[3, 0]
    rs = np.logspace(-3, 2, 41)
    ax.loglog(rs, stiffness_curve(sc, res["observer"], rs), "k.-")
    ax.set(xlabel="r", ylabel="||[xi', s_y', s_x', r']||", title="Fig. 5: observer derivative at the initial state vs r")
    ax = axes[3, 1]
    ax.axis("off")
    m = metrics(res)
    def fmt(v: float | None) -> str:
        return "never" if v is None else f"{v:.3g} s"

    lines = [f"{k}: e0={v['initial']:.3g} final={v['final']:.2e} t5%={fmt(v['t_5pct'])} t1%={fmt(v['t_1pct'])}"
             for k, v in m.items() if k != "r"]
    lines.append(f"r: r0={m['r']['initial']:g} max={m['r']['max']:.4g} at t={m['r']['t_max']:.3g} s, final={m['r']['final']:.3g}")
    ax.text(0, 0.9, "\n".join(lines), va="top", family="monospace", fontsize=8)
    fig.suptitle(f"{sc.name}: I&I speed observer (paper 004 Sec. III)")
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=90)
    plt.close(fig)


SERIES_CSV = "series.csv"


def _without_none(d: Any) -> Any:
    """TOML has no null: an unset optional field is left out, as a scenario file would."""
    if isinstance(d, dict):
        return {k: _without_none(v) for k, v in d.items() if v is not None}
    if isinstance(d, (list, tuple)):
        return [_without_none(v) for v in d]
    return d


def run_observer_cli(scenario_path: Path, out_dir: Path, overrides: list[str]) -> dict:
    """Load, integrate, measure, plot: writes out_dir/observer.png and out_dir/summary.json, returns the summary."""
    sc = load_observer_scenario(Path(scenario_path), list(overrides))
    res = simulate(sc)
    ob: SpeedObserver = res["observer"]
    summary = {
        "scenario": sc.name,
        "t_end": sc.run.t_end,
        "nfev": res["nfev"],
        "wall_s": round(res["wall_s"], 3),
        "bounds": {"k_m": ob.model.k_m, "k_M": ob.model.k_M, "k_c": ob.model.k_c},
        "property_residuals": ob.property_residuals,
        "metrics": metrics(res),
        "final": {"y": res["y"][-1].tolist(), "x": res["x"][-1].tolist(), "s_x": res["s_x"][-1].tolist(),
                  "x_hat": res["x_hat"][-1].tolist()},
    }
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    plot(sc, res, out_dir / "observer.png")
    write_series(out_dir / SERIES_CSV, res["t"], {k: v for k, v in res.items() if isinstance(v, np.ndarray) and k != "t"})
    (out_dir / "run.toml").write_text(tomli_w.dumps(_without_none(sc.model_dump())))
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2))
    summary["png"] = str(out_dir / "observer.png")
    return summary
