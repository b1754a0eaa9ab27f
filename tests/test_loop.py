"""``coload loop`` (docs/loop.md): run, diagnose offline, re-run with the named effects online, one table.

* A plant with viscous friction the scenario does not estimate (quick-dynamics, 5 N s/m): the diagnosis
  names viscous_friction, the after run estimates it online, and the team's m error falls by far more
  than the margin (measured 14.9 % -> 1.33 %).
* A clean plant given as a finished run directory: nothing named, no re-run, the table written, the
  input run untouched.
* Bad input: one line on stderr, exit status 2, nothing in --out (also when the diagnosis fails after
  the before run).
* The plan (which effects go online) on diagnoses built by hand, and the online set against config.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from coload.analysis import loop as L
from coload.cli import main
from coload.commands.loop import _install
from config.loader import load_scenario
from ident.model import EFFECTS

VISCOUS = ["--set", "plant.friction.viscous=5.0"]


def _loop(capsys, *args: str) -> tuple[int, str, str]:
    code = main(["loop", *args, "--engine", "inproc", "--quiet"])
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def _leftovers(parent: Path, name: str) -> list[str]:
    return [p.name for p in parent.iterdir() if p.name.startswith(f".{name}.")]


@pytest.mark.slow  # two 34 s runs and a diagnosis: 21 s CPU, ~30 s wall on an idle machine
def test_loop_names_viscous_friction_and_reruns_with_it_online(tmp_path, capsys):
    out = tmp_path / "loop"
    code, stdout, err = _loop(capsys, "quick-dynamics", *VISCOUS, "--out", str(out))
    assert code == 0, err
    loop = json.loads((out / "loop.json").read_text())
    assert loop["diagnosis"]["named"] == ["viscous_friction"]
    assert loop["online"] == ["viscous_friction"] and loop["offline_only"] == []
    assert loop["rerun"] and loop["after"]["estimate_effects"] == ["viscous_friction"]
    assert loop["before"]["estimate_effects"] == []
    after_toml = (out / "after" / "run.toml").read_text()
    assert 'estimate_effects = ["viscous_friction"]' in after_toml
    assert load_scenario(out / "before").seed == load_scenario(out / "after").seed == 7
    # measured (seed 7): m 14.9 % -> 1.33 %, b 4.955 (0.9 %); the nominal agents read the friction as mass
    before, after = loop["before"], loop["after"]
    assert before["m_rel"] > 0.05
    assert after["m_rel"] < before["m_rel"] / 3, (before["m_rel"], after["m_rel"])
    assert abs(after["effects"]["viscous_friction"]["value"] / 5.0 - 1) < 0.1
    # the offline residual: coloured with the nominal model, white with the named effect
    assert loop["residual_offline"]["before"]["whiteness_p"] < 1e-6
    assert loop["residual_offline"]["after"]["whiteness_p"] > 0.01
    assert [e["name"] for e in loop["effects"]] == ["viscous_friction"] and loop["effects"][0]["truth"] == 5.0
    md = (out / "loop.md").read_text()
    assert "| viscous_friction (N s/m) | 5 |" in md and md in stdout
    assert (out / "loop.png").stat().st_size > 10_000 and (out / "diagnosis.json").is_file()
    assert _leftovers(tmp_path, "loop") == []


def test_clean_run_dir_names_nothing_and_is_not_rerun(tmp_path, capsys):
    run = tmp_path / "run"
    assert main(["run", "quick-dynamics", "--engine", "inproc", "--out", str(run), "--quiet", "--no-report",
                 "--no-batch-fit"]) == 0
    files = sorted((p.name, p.stat().st_mtime_ns) for p in run.iterdir())
    out = tmp_path / "loop"
    code, stdout, err = _loop(capsys, str(run), "--out", str(out))
    assert code == 0, err
    loop = json.loads((out / "loop.json").read_text())
    assert loop["input"]["kind"] == "run_dir" and loop["diagnosis"]["named"] == []
    assert not loop["rerun"] and loop["after"] is None and "no re-run" in loop["reason"]
    assert not (out / "after").exists() and not (out / "before").exists()  # the given run is not copied
    assert "(no re-run)" in (out / "loop.md").read_text()
    assert (out / "loop.png").is_file()
    assert sorted((p.name, p.stat().st_mtime_ns) for p in run.iterdir()) == files  # input untouched
    # a run directory fixes scenario and seed; an --out that would replace the input run is refused
    for args in ([str(run), "--seed", "3", "--out", str(tmp_path / "x")], [str(run), "--out", str(run)]):
        code, _, err = _loop(capsys, *args)
        assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "x").exists()
    assert sorted((p.name, p.stat().st_mtime_ns) for p in run.iterdir()) == files


@pytest.mark.parametrize("args, says", [
    (["nosuch-scenario"], "no such file or bundled scenario"),
    (["quick-dynamics", "--set", "noise.sigma_v=-1"], "sigma_v"),
    (["quick-dynamics", "--set", "dynamics.estimate_effects=['slope']"], "estimate_effects"),
])
def test_bad_input_is_one_line_and_leaves_nothing(tmp_path, capsys, args, says):
    out = tmp_path / "loop"
    code, stdout, err = _loop(capsys, *args, "--out", str(out))
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and says in err, err
    assert not out.exists() and _leftovers(tmp_path, "loop") == []


def test_unfinished_run_dir_and_occupied_out_are_refused(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    (run / "run.toml").write_text("n = 2\ndt = 0.01\nedges = [[0, 1]]\n")
    code, _, err = _loop(capsys, str(run), "--out", str(tmp_path / "loop"))
    assert code == 2 and "not a finished coload run" in err and len(err.strip().splitlines()) == 1
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "notes.txt").write_text("mine")
    code, _, err = _loop(capsys, "quick-dynamics", "--out", str(busy))
    assert code == 2 and "holds no finished loop" in err
    assert [p.name for p in busy.iterdir()] == ["notes.txt"]


def test_a_failed_diagnosis_after_the_run_leaves_nothing(tmp_path, capsys):
    out = tmp_path / "loop"
    code, _, err = _loop(capsys, "quick-dynamics", "--set", "duration=0.3", "--out", str(out))
    assert code == 2 and "before/samples.csv: too short" in err and len(err.strip().splitlines()) == 1, err
    assert not out.exists() and _leftovers(tmp_path, "loop") == []


def test_install_replaces_a_finished_loop_only(tmp_path):
    out, work = tmp_path / "loop", tmp_path / ".loop.tmp-1"
    out.mkdir()
    (out / "loop.json").write_text("{}")
    (out / "old.txt").write_text("old")
    work.mkdir()
    (work / "loop.json").write_text('{"new": 1}')
    _install(work, out, replace=True)
    assert sorted(p.name for p in out.iterdir()) == ["loop.json"] and "new" in (out / "loop.json").read_text()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["loop"]


# --- the plan, on diagnoses built by hand ----------------------------------------------------------------
def _diag(*names: str, unexplained: bool = False) -> dict:
    return {"effects": [{"name": n, "value": 1.0, "unit": EFFECTS[n][0], "ci95": 0.1} for n in names],
            "unexplained": unexplained}


def test_online_set_is_what_the_agents_accept_and_in_the_diagnosis_vocabulary():
    assert set(L.ONLINE_EFFECTS) <= set(EFFECTS)
    assert set(L.ESTIMATE_COLUMN) <= set(L.ONLINE_EFFECTS)
    for name in L.ONLINE_EFFECTS:  # each is a valid dynamics.estimate_effects entry
        assert load_scenario("quick-dynamics", [f"dynamics.estimate_effects=['{name}']"]).dynamics.estimate_effects == (name,)


def test_plan_splits_online_and_offline_and_decides_the_rerun():
    p = L.plan(_diag("viscous_friction", "measurement_delay"), ())
    assert p.rerun and p.online == ("viscous_friction",) and [e["name"] for e in p.offline] == ["measurement_delay"]
    p = L.plan(_diag("measurement_delay"), ())
    assert not p.rerun and "offline only" in p.reason
    p = L.plan(_diag(), ())
    assert not p.rerun and "named no effect" in p.reason
    p = L.plan(_diag(unexplained=True), ())
    assert not p.rerun and "unexplained" in p.reason
    p = L.plan(_diag("rotational_damping", "viscous_friction"), ("viscous_friction", "rotational_damping"))
    assert not p.rerun and "already estimates" in p.reason
    p = L.plan(_diag("viscous_friction"), ("viscous_friction", "rotational_damping"))
    assert p.rerun and p.online == ("viscous_friction",)


@pytest.mark.long
@pytest.mark.zenoh
def test_loop_over_zenoh_processes(tmp_path):
    """The same loop as the first test with the simulator and every agent as separate processes over a
    Zenoh router: lockstep Zenoh equals in-process bit for bit, so the same numbers come out."""
    out = tmp_path / "loop"
    assert main(["loop", "quick-dynamics", *VISCOUS, "--engine", "zenoh", "--out", str(out), "--quiet"]) == 0
    loop = json.loads((out / "loop.json").read_text())
    assert loop["input"]["engine"] == "zenoh" and loop["rerun"]
    assert json.loads((out / "after" / "summary.json").read_text())["engine"] == "zenoh"
    assert (out / "after" / "logs").is_dir()
    # the in-process loop of test_loop_names_viscous_friction_and_reruns_with_it_online gave these
    assert loop["before"]["m_rel"] == pytest.approx(0.14937850457530344, rel=1e-12)
    assert loop["after"]["m_rel"] < loop["before"]["m_rel"] / 3
