"""Cooperative H-infinity estimation from relative measurements (paper 003): design tool and runtime.

``design_cli`` is the thin IO shell behind ``coload hinf design SPEC`` and ``run_cli`` the one behind
``coload hinf run SPEC``; the maths lives in ``hinf.design`` and ``hinf.runtime`` (pure), the daemons
in ``hinf.daemon``, the run directory and its checks in ``hinf.report``, the spec in ``hinf.spec``.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from .spec import HinfSpec, SpecError, load_spec, parse_spec

__all__ = ["HinfSpec", "SpecError", "design_cli", "load_spec", "parse_spec", "run_cli", "run_design"]


def run_design(spec: HinfSpec, sync: bool = True, verify: bool = True, clock=None) -> dict:
    """Whole design as a JSON-ready dict: Prop. 2 check, LMIs (6)-(7), centralized yardstick,
    realised norm of the designed error network, and Theorem 3 if the spec has [sync]."""
    from . import design as D

    net = D.network_from_spec(spec)
    checks = D.check_detectability(net)
    D.require_detectable(net)
    est = D.design_estimators(net, check_detect=False, clock=clock)  # clock: times the solve (the CLI's)
    out: dict = {
        "name": spec.name,
        "detectability": [{"component": c.agents, "detectable": c.detectable} for c in checks],
        "gamma": est.gamma,
        "solver": est.solver,
        "status": est.status,
        "solve_time_s": est.solve_time_s,
        "gamma_centralized": D.centralized_bound(net, 0.0),
        "gamma_centralized_alpha": D.centralized_bound(net, net.alpha),
        "gains": [{"agent": g.agent, "tracks": g.tracks, "L": g.L.tolist(), "K": g.K.tolist(),
                   "P": g.P.tolist()} for g in est.gains],
    }
    if verify:
        es = D.error_system(net, est)
        norm, w = D.hinf_norm(es.A, es.B, es.C)
        out["realised_norm"] = norm
        out["realised_norm_freq"] = w
        out["error_decay_rate"] = float(-np.linalg.eigvals(es.A).real.max())
    if sync and spec.sync is not None:
        sd = D.design_sync(net, spec)
        out["sync"] = {
            "gamma": sd.gamma, "kappa": sd.kappa, "theta": sd.theta,
            "francis_residual": sd.francis_residual,
            "H": [h.tolist() for h in sd.H], "X": [x.tolist() for x in sd.X],
            "gains": [{"agent": g.agent, "tracks": g.tracks, "L": g.L.tolist(), "K": g.K.tolist(),
                       "P": g.P.tolist()} for g in sd.estimator.gains],
        }
    return out


def design_cli(spec_path: Path, out: Path | None) -> dict:
    """Load SPEC, design, write the result as JSON to ``out`` (if given) and return it.

    Raises SpecError (bad file/field) or hinf.design.HinfDesignError (undetectable component,
    infeasible LMIs, failed Francis/Riccati); both carry a one-paragraph user message.
    """
    result = run_design(load_spec(spec_path), clock=time.perf_counter)
    if out is not None:
        out = Path(out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(result, indent=1) + "\n")
    return result
