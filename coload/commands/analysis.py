"""Commands on a finished run or a recording: report, diagnose, export, import."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from coload.commands.common import (
    refuse_unwritable,
)
from coload.extras import require


def cmd_report(args: argparse.Namespace) -> int:
    from coload.analysis.report import make_report
    from coload.rundir.format import INTERRUPTED_JSON

    if not args.run_dir.is_dir():
        print(f"coload report: {args.run_dir}: not a directory", file=sys.stderr)
        return 2
    if refuse_unwritable("report", ("--out", args.out)):
        return 2
    try:
        path, table = make_report(args.run_dir, args.out)
    except ValueError as exc:  # RunFormatError; a recording without truth.csv/estimates.csv
        print(f"coload report: {exc}", file=sys.stderr)
        if not args.diagnose:
            return 2
        print("coload report: no report.png; diagnosing the recording", file=sys.stderr)
    else:
        print(table)
        print(f"report: {path}")
    stopped = args.run_dir / INTERRUPTED_JSON
    if stopped.exists():
        try:
            info = json.loads(stopped.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            info = {}
        print(f"coload report: this run was stopped at t = {info.get('t', '?')} s of {info.get('duration', '?')} s "
              f"({info.get('reason', '?')}); its tables end there", file=sys.stderr)
    from coload.analysis.report import residual_figure, write_diagnosis
    from ident.diagnose import DiagnoseError, stderr_progress

    try:
        if args.diagnose:
            print(f"diagnosis: {write_diagnosis(args.run_dir, stderr_progress('coload report --diagnose'))}")
        residual = residual_figure(args.run_dir)
    except (DiagnoseError, ValueError) as exc:
        print(f"coload report: {exc}", file=sys.stderr)
        return 2
    if residual is not None:
        print(f"residual: {residual}")
    return 0


def cmd_diagnose(args: argparse.Namespace) -> int:
    from ident.diagnose import (
        DiagnoseError,
        DiagnoseOptions,
        diagnose_dir,
        format_diagnosis,
        plot_diagnosis,
        stderr_progress,
    )

    if refuse_unwritable("diagnose", ("--json", args.json)):
        return 2
    try:
        if args.max_samples < 0:
            raise DiagnoseError(f"--max-samples: expected 0 (all) or a positive number, got {args.max_samples}")
        result = diagnose_dir(args.recording, progress=None if args.quiet else stderr_progress(),
                              validate=args.validate, options=DiagnoseOptions(max_samples=args.max_samples))
    except DiagnoseError as exc:
        print(f"coload diagnose: {exc}", file=sys.stderr)
        return 2
    print(format_diagnosis(result))
    if args.json:
        args.json.write_text(json.dumps(result.as_dict(), indent=2) + "\n", encoding="utf-8")
        print(f"json: {args.json}")
    if args.plot:
        print(f"plot: {plot_diagnosis(result, args.recording / 'diagnose.png')}")
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from coload.rundir.format import RunFormatError
    from coload.viz.mcap_export import default_path, export_mcap

    if args.mcap is None:
        print("coload export: choose a format: --mcap [FILE]", file=sys.stderr)
        return 2
    if not args.run_dir.is_dir():
        print(f"coload export: {args.run_dir}: not a directory", file=sys.stderr)
        return 2
    out = Path(args.mcap) if args.mcap else default_path(args.run_dir)
    if refuse_unwritable("export", ("--mcap", out)):
        return 2
    require("viz", "mcap")
    try:
        counts = export_mcap(args.run_dir, out)
    except RunFormatError as exc:
        print(f"coload export: {exc}", file=sys.stderr)
        return 2
    print(f"{sum(counts.values())} messages on {len(counts)} channels")
    print(f"mcap: {out}")
    return 0


def cmd_import(args: argparse.Namespace) -> int:
    from ident.emps import import_emps
    from ident.recording import RecordingError

    try:
        out = import_emps(args.file, args.out)
    except RecordingError as exc:
        print(f"coload import: {exc}", file=sys.stderr)
        return 2
    print(f"recording: {out}")
    return 0
