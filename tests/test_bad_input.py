"""Bad input: one clear line on stderr, exit status 2, and nothing written half-way."""

from __future__ import annotations

import gzip
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import coload_cmd
from ident.diagnose import read_recording
from coload.rundir import format as rf

ROOT = Path(__file__).resolve().parents[1]


def coload(*args: str, timeout: float = 240) -> subprocess.CompletedProcess:
    return subprocess.run(coload_cmd(*args), capture_output=True, text=True, timeout=timeout)


def one_line(proc: subprocess.CompletedProcess) -> str:
    """The error line, checked to be the whole of stderr and to come with exit status 2."""
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.count("\n") == 1, proc.stderr
    return proc.stderr.rstrip("\n")


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A short quick.toml run: enough for report and diagnose to get as far as their output."""
    from coload.runs.engine import run_inproc
    from config.loader import load_scenario

    path = tmp_path_factory.mktemp("bad") / "run"
    run_inproc(load_scenario("quick", ["duration=8"]), path)
    return path


def test_a_duration_shorter_than_one_tick(tmp_path):
    out = tmp_path / "d"
    line = one_line(coload("run", "quick", "--engine", "inproc", "--set", "duration=0.004", "--out", str(out)))
    assert line == ("coload run: --set duration=0.004: duration: 0.004 s is less than one tick (dt = 0.01 s): "
                    "the run would record nothing")
    assert not out.exists()


def test_a_centre_of_mass_outside_the_outline(tmp_path):
    out = tmp_path / "d"
    line = one_line(coload("run", "quick", "--engine", "inproc", "--set", "load.com_offset=[2.5, 0.0]",
                           "--out", str(out)))
    assert line == ("coload run: --set load.com_offset=[2.5, 0.0]: load.com_offset: (2.5, 0) lies outside the "
                    "load's outline (the CoM of a rigid load is inside its convex hull)")
    assert not out.exists()


@pytest.mark.parametrize("command", [
    ("diagnose", "{run}", "--quiet", "--json", "{bad}"),
    ("report", "{run}", "--out", "{bad}"),
    ("export", "{run}", "--mcap", "{bad}"),
])  # fmt: skip
def test_an_output_path_that_cannot_be_written_is_refused_before_the_work(run_dir, tmp_path, command):
    bad = tmp_path / "missing" / "out.file"
    before = sorted(p.name for p in run_dir.iterdir())
    args = [a.format(run=run_dir, bad=bad) for a in command]
    line = one_line(coload(*args))
    flag = command[-2]
    assert line == f"coload {command[0]}: {flag} {bad}: cannot write there: no directory {bad.parent}"
    assert sorted(p.name for p in run_dir.iterdir()) == before  # nothing written, not even the default outputs


def test_an_output_path_that_is_a_directory_is_refused(run_dir, tmp_path):
    line = one_line(coload("report", str(run_dir), "--out", str(tmp_path)))
    assert line == f"coload report: --out {tmp_path}: cannot write there: it is a directory"


def test_a_negative_sigma_in_a_campaign(tmp_path):
    out = tmp_path / "camp"
    line = one_line(coload("campaign", "paper-fig4", "--out", str(out), "--n", "5", "--sigma=0.1,-0.2", "--runs-per-cell", "1"))
    assert line == "coload campaign: --sigma: a noise level must be >= 0 m/s (got -0.2)"
    assert not out.exists()


def _recording(src, dst, samples: bytes):
    dst.mkdir()
    (dst / rf.RUN_TOML).write_bytes((src / rf.RUN_TOML).read_bytes())
    (dst / rf.SAMPLES_CSV).write_bytes(samples)
    return dst


def test_a_compressed_samples_csv(run_dir, tmp_path):
    rec = _recording(run_dir, tmp_path / "gz", gzip.compress((run_dir / rf.SAMPLES_CSV).read_bytes()))
    line = one_line(coload("diagnose", str(rec), "--quiet", "--json", str(rec / "d.json")))
    assert line == (f"coload diagnose: {rec / rf.SAMPLES_CSV}: gzip-compressed data, not CSV text: "
                    f"decompress it first (gunzip -c FILE > samples.csv)")
    assert not (rec / "d.json").exists()


@pytest.mark.parametrize("cut", [1, 3, 9])
def test_a_samples_csv_without_its_final_newline_loses_its_last_line_and_says_so(run_dir, tmp_path, cut):
    """A write cut mid-line (a killed recorder): the last line may be cut mid-number, so it is dropped
    with a warning, whether or not it still has all its fields."""
    whole = (run_dir / rf.SAMPLES_CSV).read_bytes()
    rec = _recording(run_dir, tmp_path / "cut", whole[:-cut])
    lines = whole.decode().splitlines()
    fields = whole[:-cut].decode().splitlines()[-1].count(",") + 1
    want = f"{rec / rf.SAMPLES_CSV}:{len(lines)}: last line cut off ({fields} of 7 fields, no newline): ignored"
    recording = read_recording(rec)
    assert recording.warnings[0] == want  # (then: the cut agent-stamp has no wrench, interpolated)
    table = rf.read_agent_csv(rec / rf.SAMPLES_CSV, rf.SAMPLES_HEADER, recording.n)
    assert table.warnings == (want,)
    last_t, last_agent = float(lines[-1].split(",")[0]), int(lines[-1].split(",")[1])
    k = list(table.t).index(last_t)
    assert math.isnan(table.columns["vx"][k, last_agent])  # the cut row is not read, not even in part
    assert table.columns["vx"][k, last_agent - 1] == float(lines[-2].split(",")[2])


def test_the_cut_line_warning_reaches_the_diagnosis_json(run_dir, tmp_path):
    whole = (run_dir / rf.SAMPLES_CSV).read_bytes()
    rec = _recording(run_dir, tmp_path / "cut", whole[:-4])
    proc = coload("diagnose", str(rec), "--quiet", "--json", str(rec / "d.json"))
    assert proc.returncode == 0, proc.stderr
    n_lines = whole.decode().count("\n")
    want = f"{rec / rf.SAMPLES_CSV}:{n_lines}: last line cut off (7 of 7 fields, no newline): ignored"
    assert want in json.loads((rec / "d.json").read_text())["warnings"]
    assert f"warning   {want}" in proc.stdout


def test_a_mistyped_bundled_scenario_name_gets_a_suggestion(tmp_path):
    line = one_line(coload("run", "papr-fig4", "--engine", "inproc", "--out", str(tmp_path / "r")))
    assert line.startswith("coload run: papr-fig4: no such file or bundled scenario (did you mean paper-fig4?); "
                           "bundled scenarios: ")
    assert not (tmp_path / "r").exists()


def test_hinf_design_without_its_extra_names_it(tmp_path):
    code = ("import sys; sys.modules['cvxpy'] = None; from coload.cli import main; "
            f"sys.exit(main(['hinf', 'design', {str(ROOT / 'config/hinf/sec5-cyclic.toml')!r}, '--out', "
            f"{str(tmp_path / 'g.json')!r}]))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert one_line(proc) == "coload hinf: needs the Python package(s) cvxpy: pip install 'coload[hinf]'"
    assert not (tmp_path / "g.json").exists()


def test_version_and_verbose_after_the_command():
    from coload.cli import build_parser
    from coload.provenance import version

    proc = coload("--version", timeout=60)
    assert proc.returncode == 0 and proc.stdout.startswith(f"coload {version('coload')}")
    args = build_parser().parse_args(["-v", "report", "r", "-vv"])
    assert args.verbose + args.verbose_after == 3
    args = build_parser().parse_args(["hinf", "run", "spec.toml", "--out", "o", "-v"])
    assert args.verbose + args.verbose_after == 1
