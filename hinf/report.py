"""A `coload hinf run`'s inputs (spec.json, design.json: what every daemon reads), its summary (final
errors, decay, energy gain vs gamma, synchronization) and its figure (hinf.png). The application
writes the run directory (coload/runs/hinf_run.py; layout in docs/run-directory.md)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from .runtime import (
    Disturbance,
    Setup,
    Trace,
    build_setup,
    continuous_norm,
    discrete_error_network,
    discrete_norm,
    errors,
)
from .spec import HinfSpec, SpecError, parse_spec

COLOURS = ["black", "red", "blue", "green"]  # agents 1-4 as in the paper's Fig. 2


def prepare_run_dir(run_dir: Path, spec: HinfSpec, design: dict) -> None:
    """Write the two inputs every daemon reads."""
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "spec.json").write_text(json.dumps(spec.model_dump(mode="json"), indent=1) + "\n")
    (run_dir / "design.json").write_text(json.dumps(design, indent=1) + "\n")


def load_run_dir(run_dir: Path) -> Setup:
    """The Setup of a prepared run directory (what `coload hinf sim|agent RUN_DIR` start from)."""
    run_dir = Path(run_dir)

    def read(name: str) -> dict:
        path = run_dir / name
        try:
            return json.loads(path.read_text(encoding="utf-8"))
        except OSError as exc:
            raise SpecError(f"{path}: cannot read it ({exc.strerror}); RUN_DIR must be a directory "
                            f"prepared by `coload hinf run`") from None
        except json.JSONDecodeError as exc:
            raise SpecError(f"{path}, line {exc.lineno}, column {exc.colno}: not JSON ({exc.msg})") from None

    spec = parse_spec(read("spec.json"), str(run_dir / "spec.json"))
    design = read("design.json")
    try:
        return build_setup(spec, design)
    except (KeyError, TypeError, ValueError) as exc:
        raise SpecError(f"{run_dir / 'design.json'}: not a design of this spec ({exc!r})") from None


def _own_cols(setup: Setup) -> list[np.ndarray]:
    soff = np.concatenate([[0], np.cumsum([lc.sigma for lc in setup.locs])]).astype(int)
    return [np.arange(soff[k], soff[k] + setup.net.n[k]) for k in range(setup.N)]


def lyapunov(setup: Setup, e: np.ndarray) -> np.ndarray:
    """V(t) = sum_k e^(k)' P^(k) e^(k) of Theorem 1, per tick."""
    soff = np.concatenate([[0], np.cumsum([lc.sigma for lc in setup.locs])]).astype(int)
    V = np.zeros(e.shape[0])
    for k in range(setup.N):
        ek = e[:, soff[k]:soff[k + 1]]
        V += np.einsum("ti,ij,tj->t", ek, setup.P[k], ek)
    return V


def _rate(t: np.ndarray, v: np.ndarray, floor: float) -> float | None:
    """Least-squares decay rate of v (exp(-rate t)) over the ticks where v is above ``floor`` * v[0]."""
    ok = (v > floor * v[0]) & (v > 0)
    if ok.sum() < 3:
        return None
    return float(-np.polyfit(t[ok], np.log(v[ok]), 1)[0])


def summarize(setup: Setup, trace: Trace, info: dict[str, Any]) -> dict[str, Any]:
    """The numbers a user checks: errors, decay vs alpha, energy gain vs gamma, synchronization."""
    net, dt, T = setup.net, setup.dt, setup.ticks
    t = np.arange(T) * dt
    run = setup.spec.run
    e = errors(setup, trace)
    own = _own_cols(setup)
    soff = np.concatenate([[0], np.cumsum([lc.sigma for lc in setup.locs])]).astype(int)
    per_agent = {}
    for k in range(setup.N):
        eo = np.linalg.norm(e[:, own[k]], axis=1)
        ef = np.linalg.norm(e[:, soff[k]:soff[k + 1]], axis=1)
        per_agent[net.names[k]] = {"own_initial": float(eo[0]), "own_final": float(eo[-1]),
                                   "own_max": float(np.nanmax(eo)), "local_final": float(ef[-1])}
    V = lyapunov(setup, e)
    alpha = net.alpha
    ok = np.isfinite(V)
    bound_ratio = float(np.nanmax(V[ok] * np.exp(alpha * t[ok]) / V[0])) if V[0] > 0 else None
    en = np.linalg.norm(e, axis=1)
    half = t >= t[-1] / 2
    # the alpha guarantee is about disturbance-free runs that start with an error
    undisturbed = bool(run.disturbance.kind == "none" and V[0] > 0)
    decay = {
        "alpha": alpha,
        "applies": undisturbed,
        "V0": float(V[0]),
        "V_final": float(V[-1]),
        "V_rate_overall": float(-math.log(V[-1] / V[0]) / t[-1]) if V[0] > 0 and V[-1] > 0 else None,
        "V_rate_fit": _rate(t, V, 1e-24),
        "max_V_exp_alpha_t_over_V0": bound_ratio,
        "alpha_bound_holds": bool(bound_ratio <= 1.0 + 1e-9) if undisturbed and bound_ratio is not None else None,
        "error_rate_second_half": _rate(t[half], en[half], 1e-12),
        "continuous_error_rate": float(-np.linalg.eigvals(_cont_A(setup)).real.max()),
    }
    dist = Disturbance(setup)
    Ew_tick = np.array([dist.charged_energy(trace.xi[i], trace.eta[i]) for i in range(T)])
    Ee_tick = np.zeros(T)
    for k in range(setup.N):
        ek = e[:, own[k]]
        Ee_tick += np.einsum("ti,ij,tj->t", ek, net.W[k], ek)
    Ee, Ew = float(Ee_tick.sum() * dt), float(Ew_tick.sum() * dt)
    cnorm, cw = continuous_norm(setup)
    Ad, Bd, Cz = discrete_error_network(setup)
    dnorm, dth = discrete_norm(Ad, Bd, Cz)
    energy = {
        "gamma": setup.gamma,
        "continuous_norm": cnorm, "continuous_norm_freq_rad_s": cw,
        "sampled_norm": dnorm, "sampled_norm_freq_rad_s": dth / dt,
        "E_error": Ee, "E_disturbance": Ew,
        "empirical_gain": math.sqrt(Ee / Ew) if Ew > 0 else None,
        "I0": float(V[0]),
        "bound_5_holds": bool(Ee <= setup.gamma**2 * Ew + V[0] + 1e-12),
        "note": "E_error = sum_t dt sum_k e_k' W_k e_k; E_disturbance = sum_t dt (sum_j (1+q_j)|xi_j|^2 + |eta|^2) "
                "as charged by (5); (5) reads E_error <= gamma^2 E_disturbance + I0",
    }
    out: dict[str, Any] = {
        "name": setup.spec.name, "control": setup.control, "mode": run.mode, "dt": dt, "ticks": T,
        "duration_s": T * dt, "seed": run.seed, "disturbance": run.disturbance.kind,
        "errors": per_agent, "decay": decay, "energy": energy,
    }
    y = _outputs(setup, trace)
    spread = y.max(axis=1) - y.min(axis=1)
    sync: dict[str, Any] = {"y_spread_initial": float(spread[0]), "y_spread_final": float(spread[-1]),
                            "y_final": y[-1].tolist()}
    if setup.control:
        nu = setup.nu
        G = np.asarray(setup.spec.sync.Gamma, float)
        gz = np.stack([trace.zeta[:, k * nu:(k + 1) * nu] @ G.T for k in range(setup.N)], axis=1)[..., 0]
        xoff = np.concatenate([[0], np.cumsum(net.n)]).astype(int)
        eps = [np.linalg.norm(trace.x[-1, xoff[k]:xoff[k + 1]] - setup.Pi[k] @ trace.zeta[-1, k * nu:(k + 1) * nu])
               for k in range(setup.N)]
        zs = trace.zeta[-1].reshape(setup.N, nu)
        sync.update({"max_y_minus_Gamma_zeta_final": float(np.abs(y[-1] - gz[-1]).max()),
                     "zeta_spread_final": float(np.abs(zs - zs.mean(axis=0)).max()),
                     "regulation_error_final": {net.names[k]: float(eps[k]) for k in range(setup.N)},
                     "kappa": (setup.design.get("sync") or {}).get("kappa"),
                     "theta": (setup.design.get("sync") or {}).get("theta")})
    out["sync"] = sync
    out["messages"] = {k: info[k] for k in ("links", "drops", "timeouts", "held", "stale_u", "late_inputs") if k in info}
    out["inputs_missing"] = int((~trace.got).sum())
    for k in ("engine", "wall_s", "events", "agents_reported"):
        if k in info:
            out[k] = info[k]
    return out


def _cont_A(setup: Setup) -> np.ndarray:
    from . import design as D
    from .runtime import _design_of

    return D.error_system(setup.net, _design_of(setup)).A


def _outputs(setup: Setup, trace: Trace) -> np.ndarray:
    net = setup.net
    xoff = np.concatenate([[0], np.cumsum(net.n)]).astype(int)
    return np.stack([trace.x[:, xoff[k]:xoff[k + 1]] @ net.C[k][0] for k in range(setup.N)], axis=1)


def plot(setup: Setup, trace: Trace, png: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    net, dt = setup.net, setup.dt
    t = np.arange(setup.ticks) * dt
    e = errors(setup, trace)
    own = _own_cols(setup)
    col = [COLOURS[k] if setup.N <= 4 else plt.cm.viridis(k / max(1, setup.N - 1)) for k in range(setup.N)]
    fig, ax = plt.subplots(2, 2, figsize=(12, 8.5))
    a = ax[0, 0]
    for k in range(setup.N):
        for c, ls in zip(own[k], ("-", "--", ":", "-.")):
            a.plot(t, e[:, c], color=col[k], ls=ls, lw=0.9,
                   label=f"agent {net.names[k]}" if c == own[k][0] else None)
    a.set(xlabel="t [s]", ylabel="x_k - x^_k^(k)", title="Fig. 2: local estimation errors (own state; - 1st, -- 2nd)")
    a.legend(fontsize=8)
    a = ax[0, 1]
    soff = np.concatenate([[0], np.cumsum([lc.sigma for lc in setup.locs])]).astype(int)
    for k in range(setup.N):
        a.semilogy(t, np.maximum(np.linalg.norm(e[:, soff[k]:soff[k + 1]], axis=1), 1e-300), color=col[k], lw=0.9,
                   label=f"|e^({net.names[k]})|")
    V = lyapunov(setup, e)
    if V[0] > 0:
        a.semilogy(t, V / V[0], "m-", lw=1.5, label="V(t)/V(0)")
        a.semilogy(t, np.exp(-net.alpha * t), "m--", lw=1.0, label=f"exp(-alpha t), alpha={net.alpha:g}")
    a.set(xlabel="t [s]", title="decay: errors and V against the guaranteed rate")
    a.legend(fontsize=8)
    y = _outputs(setup, trace)
    a = ax[1, 0]
    for k in range(setup.N):
        a.plot(t, y[:, k], color=col[k], lw=1.0, label=f"y_{net.names[k]}")
    if setup.control:
        G = np.asarray(setup.spec.sync.Gamma, float)[0]
        nu = setup.nu
        for k in range(setup.N):
            a.plot(t, trace.zeta[:, k * nu:(k + 1) * nu] @ G, color=col[k], ls=":", lw=0.8)
        a.set_title("outputs y_k (solid) and exosystem outputs Gamma zeta_k (dotted)")
    else:
        a.set_title("outputs y_k (no control)")
    a.set(xlabel="t [s]")
    a.legend(fontsize=8)
    a = ax[1, 1]
    a.semilogy(t, np.maximum(y.max(axis=1) - y.min(axis=1), 1e-300), "k-", label="max_k y_k - min_k y_k")
    dist = Disturbance(setup)
    Ew = np.cumsum([dist.charged_energy(trace.xi[i], trace.eta[i]) for i in range(setup.ticks)]) * dt
    if Ew[-1] > 0:
        Ee = np.zeros(setup.ticks)
        for k in range(setup.N):
            ek = e[:, own[k]]
            Ee += np.einsum("ti,ij,tj->t", ek, net.W[k], ek)
        Ee = np.cumsum(Ee) * dt
        with np.errstate(divide="ignore", invalid="ignore"):
            a.semilogy(t, np.sqrt(Ee / Ew), "b-", label="running energy gain")
        a.axhline(setup.gamma, color="b", ls="--", lw=0.8, label=f"gamma = {setup.gamma:.3g}")
    a.set(xlabel="t [s]", title="output spread; energy gain vs gamma")
    a.legend(fontsize=8)
    fig.suptitle(f"{setup.spec.name}: cooperative H-infinity estimators (paper 003), "
                 f"{'with' if setup.control else 'without'} synchronization control")
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=90)
    plt.close(fig)


def json_default(o: Any) -> Any:
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)
