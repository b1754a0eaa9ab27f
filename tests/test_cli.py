"""The command line a user meets: help everywhere, every scenario field documented, clear errors."""

from __future__ import annotations

import argparse
import typing

import pytest
from pydantic import BaseModel, Field

from coload.cli import COMMANDS, build_parser, main
from config.scenario import Scenario


def _command_paths(parser: argparse.ArgumentParser, prefix: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    """Every command and sub-command of the parser tree (``("hinf", "design")``, ...)."""
    paths = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                paths.append((*prefix, name))
                paths += _command_paths(sub, (*prefix, name))
    return paths


COMMAND_PATHS = _command_paths(build_parser())


def test_the_command_tree_is_walked():
    assert set(COMMANDS) <= {p[0] for p in COMMAND_PATHS}
    assert {("hinf", "design"), ("hinf", "agent"), ("observer", "run")} <= set(COMMAND_PATHS)


@pytest.mark.parametrize("argv", [["--help"], *([*p, "--help"] for p in COMMAND_PATHS)], ids=" ".join)
def test_every_command_has_help(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "usage: coload" in out and len(out) > 200
    for line in out.split("options:")[-1].splitlines():  # every option says what it does
        if line.startswith("  -") and "  " not in line.strip():
            nxt = out.split(line, 1)[1].splitlines()[1:2]
            assert nxt and nxt[0].startswith("        "), f"{' '.join(argv)}: {line.strip()} has no help"


def _models_in(ann: object) -> list[type[BaseModel]]:
    """The pydantic models an annotation holds: ``Model``, ``Model | None``, ``list[Model]``, ..."""
    if isinstance(ann, type) and issubclass(ann, BaseModel):
        return [ann]
    return [m for arg in typing.get_args(ann) for m in _models_in(arg)]


def _undocumented(model: type[BaseModel], prefix: str = "") -> list[str]:
    missing = []
    for name, field in model.model_fields.items():
        models = _models_in(field.annotation)
        if not (field.description or any(m.__doc__ for m in models)):
            missing.append(prefix + name)
        for sub in models:
            missing += _undocumented(sub, f"{prefix}{name}.")
    return missing


def test_the_field_walk_reaches_optional_and_list_models():
    class Inner(BaseModel):
        x: int = 0

    class Outer(BaseModel):
        maybe: Inner | None = Field(None, description="an optional model")
        many: list[Inner] = Field(default_factory=list, description="a list of models")

    assert _undocumented(Outer) == ["maybe.x", "many.x"]


def test_every_scenario_field_is_documented():
    assert _undocumented(Scenario) == []


def test_bad_scenario_is_reported_with_file_line_and_field(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "bad"\nn = 5\n\n[load]\nmass = -3\n')
    assert main(["run", str(bad), "--engine", "inproc"]) == 2
    err = capsys.readouterr().err
    assert f"{bad}:5: load.mass:" in err and "greater than 0" in err


def test_report_on_missing_directory_is_an_error(tmp_path, capsys):
    assert main(["report", str(tmp_path / "nope")]) == 2
    assert "not a directory" in capsys.readouterr().err


def test_run_output_directory_problems_are_said(tmp_path, capsys):
    afile = tmp_path / "file"
    afile.write_text("x")
    assert main(["run", "quick", "--engine", "inproc", "--out", str(afile)]) == 2
    assert "exists and is not a directory" in capsys.readouterr().err
    out = tmp_path / "run"
    args = ["run", "quick", "--engine", "inproc", "--out", str(out), "--no-report", "--no-batch-fit",
            "--set", "duration=0.5", "--quiet"]
    assert main(args) == 0
    assert "held a previous run" not in capsys.readouterr().err
    assert main(args) == 0
    assert f"{out} held a previous run (summary.json, samples.csv): replaced" in capsys.readouterr().err
    (out / "report.png").write_bytes(b"old")
    assert main([*args, "--set", "duration=abc"]) == 2  # fails before running
    assert main(["run", str(tmp_path / "nope.toml"), "--engine", "inproc", "--out", str(out)]) == 2
    assert (out / "summary.json").exists()  # a run that never started replaced nothing
