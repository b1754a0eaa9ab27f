"""``coload report RUN_DIR`` draws the residual before and after when the run carries a diagnosis (issue 4).

The recording has a known effect the agents' model lacks (viscous floor friction, 5 N s/m, in the
scenario's [plant] section), as in tests/test_diagnose.py: the nominal residual is a slow drift
(autocorrelation far outside the white-noise bounds), the augmented one is white.
"""

from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path

import matplotlib.pyplot as plt
import pytest

from coload.analysis import report
from coload.runs.engine import run_inproc
from config.loader import load_scenario
from ident.diagnose import Z95
from tests.conftest import coload_cmd

ROOT = Path(__file__).resolve().parents[1]
SETS = ["duration=30", "control.force=3", "seed=2", "plant.friction.viscous=5.0"]


@pytest.fixture(scope="module")
def diagnosed(tmp_path_factory):
    """A run dir with viscous friction, diagnosed through the CLI (`coload report RUN_DIR --diagnose`)."""
    out = tmp_path_factory.mktemp("residual") / "run"
    run_inproc(load_scenario(ROOT / "config/scenarios/quick.toml", SETS), out)
    assert report.residual_figure(out) is None  # no diagnosis yet: no residual figure
    proc = subprocess.run(coload_cmd("report", str(out), "--diagnose"), capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert f"residual: {out / report.RESIDUAL_PNG}" in proc.stdout
    return out


def test_report_draws_residual_before_and_after_with_bounds(diagnosed):
    assert (diagnosed / report.RESIDUAL_PNG).stat().st_size > 10_000
    d = json.loads((diagnosed / report.DIAGNOSIS_JSON).read_text())
    assert [e["name"] for e in d["effects"]] == ["viscous_friction"]
    panels = report.residual_panels_of(diagnosed)
    fig = report.build_residual_figure(panels)
    try:
        axes = {ax.get_label(): ax for ax in fig.axes}
        n_blocks = round(30.0 / panels["block_s"])
        for j in range(3):  # mean x, mean y, rotation
            ts, acf = axes[f"residual:{j}"], axes[f"acf:{j}"]
            assert [len(line.get_xdata()) for line in ts.get_lines()] == [n_blocks, n_blocks]  # before, after
            curves = [line for line in acf.get_lines() if len(line.get_xdata()) == panels["lags"]]
            bounds = sorted(line.get_ydata()[0] for line in acf.get_lines() if len(line.get_xdata()) == 2)
            assert len(curves) == 2
            assert bounds == pytest.approx([-Z95 / math.sqrt(n_blocks), Z95 / math.sqrt(n_blocks)])
        # the known effect shows: the nominal mean-x residual is a drift far outside the bounds at lag 1,
        # the augmented one (with viscous friction) is inside them at most lags (white: Ljung-Box p > 0.01)
        before, after = (line.get_ydata() for line in axes["acf:0"].get_lines()[:2])
        bound = Z95 / math.sqrt(n_blocks)
        assert before[0] > 5 * bound
        assert sum(abs(a) <= bound for a in after) >= 0.8 * len(after)
        assert panels["augmented"]["whiteness_p"] > 0.01 > panels["nominal"]["whiteness_p"]
        assert panels["augmented"]["effects"] == ["viscous_friction"] and panels["nominal"]["effects"] == []
    finally:
        plt.close(fig)


def test_a_diagnosis_without_residual_data_is_a_clear_error(tmp_path):
    (tmp_path / report.DIAGNOSIS_JSON).write_text(json.dumps({"nominal": {}}))
    with pytest.raises(ValueError, match="no residual data"):
        report.residual_figure(tmp_path)


def test_a_recording_without_truth_is_diagnosed_not_a_traceback(diagnosed, tmp_path):
    """A measured recording (run.toml + samples.csv, nothing the simulator knows): no report.png to
    draw, said in one line; with --diagnose the diagnosis and the residual figure still come."""
    rec = tmp_path / "rec"
    rec.mkdir()
    for name in ("run.toml", "samples.csv"):
        (rec / name).write_bytes((diagnosed / name).read_bytes())
    plain = subprocess.run(coload_cmd("report", str(rec)), capture_output=True, text=True, timeout=600)
    assert plain.returncode == 2 and "Traceback" not in plain.stderr
    assert "truth.csv" in plain.stderr
    proc = subprocess.run(coload_cmd("report", str(rec), "--diagnose"), capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert "no report.png" in proc.stderr and not (rec / report.REPORT_PNG).exists()
    assert json.loads((rec / report.DIAGNOSIS_JSON).read_text())["effects"][0]["name"] == "viscous_friction"
    assert (rec / report.RESIDUAL_PNG).stat().st_size > 10_000
