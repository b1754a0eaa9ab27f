"""EMPS: a real prismatic axis (../shared/data/emps, Janot, Gautier & Brunot 2019), imported and
diagnosed from the identification file alone; the published values are the truth. Skipped when the
data are not next to the repository."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from ident.diagnose import diagnose_dir
from tests.conftest import coload_cmd

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "emps"
pytestmark = pytest.mark.skipif(not (DATA / "DATA_EMPS.mat").exists(), reason="EMPS data not in ../shared/data/emps")

PUBLISHED = {"viscous_friction": 203.5, "coulomb_friction": 20.39, "force_bias": 3.16}  # N s/m, N, N (= -OF)


@pytest.fixture(scope="module")
def emps(tmp_path_factory):
    base = tmp_path_factory.mktemp("emps")
    for name, out in (("DATA_EMPS.mat", "id"), ("DATA_EMPS_PULSES.mat", "val")):
        proc = subprocess.run(coload_cmd("import", "emps", str(DATA / name), "--out", str(base / out)),
                              capture_output=True, text=True, timeout=300)  # fmt: skip
        assert proc.returncode == 0, proc.stderr
    return base


def test_import_writes_a_one_agent_position_recording(emps):
    head = (emps / "id" / "samples.csv").read_text().splitlines()[:2]
    assert head[0] == "t,agent,x,y,fx,fy,tau"
    t, agent, x, y, fx, fy, tau = head[1].split(",")
    assert agent == "0" and float(y) == 0.0 and float(fy) == 0.0 and float(tau) == 0.0
    assert abs(float(fx) - 35.15065188248547 * 2.53862809) < 1e-3  # gtau * vir at t = 0
    toml = (emps / "id" / "run.toml").read_text()
    assert "n = 1" in toml and "edges = []" in toml and "dt = 0.001" in toml


@pytest.mark.long  # 1-2 min: out of CI's budget; python -m pytest -m long tests/test_ident_emps.py
@pytest.mark.timeout(1200)  # ~70 s of CPU: 25 000 stamps, three effects, a held-out fit and a prediction
def test_diagnosis_names_the_published_effects_and_predicts_the_pulses_file(emps):
    r = diagnose_dir(emps / "id", validate=emps / "val")
    assert sorted(e["name"] for e in r.effects) == sorted(PUBLISHED) and not r.unexplained
    for e in r.effects:
        value = e["value"][0] if isinstance(e["value"], list) else e["value"]
        assert abs(value / PUBLISHED[e["name"]] - 1) < 0.05, e
    assert abs(r.augmented.m / 95.1 - 1) < 0.02
    assert r.augmented.J != r.augmented.J  # NaN: one axis, J not identifiable (and said so)
    assert any("J, the contact geometry" in w for w in r.warnings)
    # the coloured residual is searched for a change of the load, and none explains it (a split at the best
    # boundary removes 16 % of the excess): the machine's load does not change
    assert r.change is not None and not r.change["found"] and r.change["split_share"] < 0.5
    v = r.validation
    assert v["augmented"]["rms"] < v["nominal"]["rms"] / 5  # the augmented model predicts the other file
