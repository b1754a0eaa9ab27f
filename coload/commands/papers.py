"""Papers 003 and 004: hinf design/run/sim/agent, the speed observer, arm agents."""

from __future__ import annotations

import argparse
import json
import sys

from coload.commands.common import (
    refuse_unwritable,
    run_daemon,
    scenario_of,
)
from coload.extras import require


def cmd_observer(args: argparse.Namespace) -> int:
    from coload.runs.observer_run import ObserverScenarioError, run_observer_cli

    try:
        summary = run_observer_cli(args.scenario, args.out, list(args.overrides))
    except ObserverScenarioError as exc:
        print(f"coload observer run: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(summary, indent=2, default=str))
    print(f"plot: {args.out / 'observer.png'}")
    return 0


def cmd_arms(args: argparse.Namespace) -> int:
    from coload.runs.arm_run import run_arms_cli
    from simulator.arms import ArmSetupError

    scenario = scenario_of(args)
    try:
        _, table = run_arms_cli(scenario, args.out, batch_fit=not args.no_batch_fit, quiet=args.quiet)
    except (ArmSetupError, ValueError) as exc:
        print(f"coload arms run: {args.scenario}: {exc}", file=sys.stderr)
        return 2
    print(table)
    print(f"runs: {args.out / 'observer'}, {args.out / 'velocity'}; comparison: {args.out / 'comparison.png'}")
    return 0


def cmd_hinf(args: argparse.Namespace) -> int:
    from hinf import SpecError, design_cli
    from hinf.design import HinfDesignError

    if args.hinf_command != "design":
        return cmd_hinf_runtime(args)
    require("hinf", "cvxpy")
    if refuse_unwritable("hinf design", ("--out", args.out)):
        return 2
    try:
        result = design_cli(args.spec, args.out)
    except (SpecError, HinfDesignError) as exc:
        print(f"coload hinf design: {exc}", file=sys.stderr)
        return 2
    keys = ("gamma", "gamma_centralized", "gamma_centralized_alpha", "realised_norm", "error_decay_rate")
    shown = {k: result[k] for k in keys if k in result}
    sync = result.get("sync") or {}
    shown.update({k: sync[k] for k in ("kappa", "theta") if k in sync})
    print(json.dumps(shown, indent=2, default=str))
    if args.out:
        print(f"gains and results: {args.out}")
    return 0


def cmd_hinf_runtime(args: argparse.Namespace) -> int:
    """`coload hinf run|sim|agent`: the paper-003 runtime (hinf.daemon)."""
    from coload.runs.hinf_run import run_cli
    from hinf import SpecError
    from hinf.design import HinfDesignError

    if args.hinf_command == "run":
        require("hinf", "cvxpy")
        try:
            if args.secure and args.engine != "zenoh":
                raise SpecError("--secure is for --engine zenoh (the in-process engine has no network)")
            s = run_cli(args.spec, args.out, args.engine, args.mode, args.overrides, args.quiet, args.verbose,
                        args.secure)
        except (SpecError, HinfDesignError) as exc:
            print(f"coload hinf run: {exc}", file=sys.stderr)
            return 2
        if s is None:
            return 1
        en, de = s["energy"], s["decay"]
        print(json.dumps({"gamma": en["gamma"], "empirical_gain": en["empirical_gain"],
                          "sampled_norm": en["sampled_norm"], "continuous_norm": en["continuous_norm"],
                          "alpha": de["alpha"], "V_rate_fit": de["V_rate_fit"],
                          "alpha_bound_holds": de["alpha_bound_holds"],
                          "own_error_final": {k: v["own_final"] for k, v in s["errors"].items()},
                          "y_spread": [s["sync"]["y_spread_initial"], s["sync"]["y_spread_final"]]}, indent=2))
        print(f"run directory: {args.out} (summary.json, hinf.png)")
        return 0
    from coload.runs.hinf_run import finish_run
    from hinf.daemon import HinfAgentDaemon, HinfSimDaemon
    from hinf.report import load_run_dir

    try:
        setup = load_run_dir(args.run_dir)
    except SpecError as exc:
        print(f"coload hinf {args.hinf_command}: {exc}", file=sys.stderr)
        return 2
    if args.hinf_command == "agent":
        rep = run_daemon("hinf agent", args, lambda t: HinfAgentDaemon(setup, args.id, t, args.run).run(),
                          f"agent-{args.id}")
        return 0 if rep is not None else 130
    res = run_daemon("hinf sim", args, lambda t: HinfSimDaemon(setup, t, args.run).run(), "sim")
    if res is None:
        return 130
    trace, info = res
    finish_run(args.run_dir, setup, trace, {**info, "engine": "zenoh"})
    print(f"run directory: {args.run_dir}")
    return 0
