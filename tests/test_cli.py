"""The command line a user meets: help everywhere, every scenario field documented, clear errors."""

from __future__ import annotations

import pytest
from pydantic import BaseModel

from coload.cli import COMMANDS, main
from config.scenario import Scenario


@pytest.mark.parametrize("argv", [["--help"], *([c, "--help"] for c in COMMANDS)])
def test_every_command_has_help(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "usage: coload" in out and len(out) > 200


def _undocumented(model: type[BaseModel], prefix: str = "") -> list[str]:
    missing = []
    for name, field in model.model_fields.items():
        ann = field.annotation
        if isinstance(ann, type) and issubclass(ann, BaseModel):
            if not (field.description or ann.__doc__):
                missing.append(prefix + name)
            missing += _undocumented(ann, f"{prefix}{name}.")
        elif not field.description:
            missing.append(prefix + name)
    return missing


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
