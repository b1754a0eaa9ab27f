"""The report: a readable PNG with the right panels, and a table that matches the metrics."""

from __future__ import annotations

import matplotlib.image as mpimg
import matplotlib.pyplot as plt
import numpy as np
import pytest

from coload.analysis import metrics, report
from coload.rundir.format import PAIRS_CSV, REPORT_PNG, read_run
from tests.synthetic_run import SyntheticSpec, write_run

BASE_PANELS = ["eerd", "omega", "eec", "zi_err"]
ALL_PANELS = BASE_PANELS + ["J", "zc", "vc", "m"]


def _converging(n):
    """Errors that decay like a working estimator's, so the log panels have something to show."""
    rng = np.random.default_rng(3)

    def zi_err(t):
        return rng.normal(0, 0.5, (1, n, 2)) * np.exp(-t / 4)[:, None, None] + rng.normal(0, 1e-3, (len(t), n, 2))

    def omega_err(t):
        return -0.3 * np.exp(-t / 3)[:, None] + rng.normal(0, 0.01, (len(t), n))

    return {"zi_err": zi_err, "omega_err": omega_err, "pair_scale": lambda t: 1 - np.exp(-t / 3)}


def _panels(fig):
    return [ax.get_label() for ax in fig.axes if ax.get_label() in ALL_PANELS]


def test_make_report_writes_a_real_png(tmp_path):
    write_run(tmp_path, SyntheticSpec(n=4, duration=40.0, dt=0.05), **_converging(4))
    path, table = report.make_report(tmp_path)
    assert path == tmp_path / REPORT_PNG
    assert path.stat().st_size > 10_000
    img = mpimg.imread(path)
    assert img.ndim == 3 and img.shape[0] > 500 and img.shape[1] > 800
    assert img[..., :3].std() > 0.05  # not a blank canvas
    lines = table.splitlines()
    for i in range(4):
        assert any(line.split()[:1] == [str(i)] for line in lines), i
    assert any(line.startswith("all (RMS)") for line in lines)
    assert "EERD" in table and "below 1 % of initial from t =" in table


def test_table_numbers_are_the_metrics(tmp_path):
    offsets = np.array([0.0, 0.01, -0.02])
    write_run(tmp_path, SyntheticSpec(n=3), omega_err=lambda t: np.tile(offsets, (len(t), 1)),
              zi_err=lambda t: np.full((len(t), 3, 2), 0.06))
    run = read_run(tmp_path)
    errors = metrics.final_errors(run, report.WINDOW_S)
    table = report.summary_table(run, errors)
    row1 = next(line for line in table.splitlines() if line.split()[:1] == ["1"])
    assert [float(x) for x in row1.split()[1:3]] == pytest.approx([0.06 * np.sqrt(2), 0.01], rel=1e-3)


def test_panels_follow_the_columns(tmp_path):
    base, full = tmp_path / "base", tmp_path / "full"
    write_run(base, SyntheticSpec(n=3), **_converging(3))
    write_run(full, SyntheticSpec(n=3, extra_estimates=True), **_converging(3))
    for d, expected in ((base, BASE_PANELS), (full, ALL_PANELS)):
        run = read_run(d)
        assert report.panel_names(run) == expected
        fig = report.build_figure(run)
        try:
            assert _panels(fig) == expected
            axes = [ax for ax in fig.axes if ax.get_label() in expected]
            assert all(ax.get_xlim() == axes[-1].get_xlim() for ax in axes)  # shared time axis
            assert axes[-1].get_xlabel() == "time [s]"
            assert all(ax.get_ylabel() for ax in axes)
        finally:
            plt.close(fig)


def test_no_pairs_means_no_eerd_panel(tmp_path):
    write_run(tmp_path, SyntheticSpec(n=3))
    (tmp_path / PAIRS_CSV).unlink()
    run = read_run(tmp_path)
    assert report.panel_names(run) == BASE_PANELS[1:]
    out, table = report.make_report(tmp_path, tmp_path / "elsewhere.png")
    assert out == tmp_path / "elsewhere.png" and out.exists()
    assert not (tmp_path / REPORT_PNG).exists()
    assert "EERD - -> - m^2" in table


def test_many_agents_and_exact_estimates(tmp_path):
    # 14 agents (colour bar instead of a legend) and all-zero errors (no log axis possible)
    write_run(tmp_path, SyntheticSpec(n=14, duration=10.0, edges=tuple((0, j) for j in range(1, 14))))
    path, table = report.make_report(tmp_path)
    assert path.stat().st_size > 10_000
    assert len([line for line in table.splitlines() if line.split()[:1] and line.split()[0].isdigit()]) == 14


def test_report_needs_truth(tmp_path):
    write_run(tmp_path, SyntheticSpec(n=3))
    (tmp_path / "truth.csv").unlink()
    with pytest.raises(ValueError, match="truth"):
        report.make_report(tmp_path)
