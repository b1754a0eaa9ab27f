"""The fit's windows on long recordings and on robots that log on their own clocks: the initial guess's
per-window least squares solved block by block (memory linear in the length), and windows and gaps sized on
each robot's own sample period, not on the interval between the interleaved stamps of all robots."""

from __future__ import annotations

import numpy as np
import pytest

from ident.fit import FitOptions, _lstsq_blocks, make_problem
from ident.recording import agent_period, read_recording
from tests.foreign_plant import plant


@pytest.mark.parametrize("nl", [1, 2])
def test_block_least_squares_equals_the_dense_one(nl):
    """Rows in 7 groups (one with no row, one whose local columns lack rank: a single row of [1, 0]), each
    with nl local columns of its own, and 3 shared columns: the same coefficients as the dense design's
    minimum-norm least squares, to 1e-10."""
    rng = np.random.default_rng(5)
    G, R, p = 7, 400, 3
    group = rng.choice([0, 1, 2, 4, 5, 6], R)  # group 3: no row
    group[-1] = 6
    group[group == 6] = 5
    group[-1] = 6  # group 6: one row only
    local = np.ones((R, nl))
    if nl == 2:
        local[:, 1] = rng.uniform(0, 2.5, R)
        local[-1, 1] = 0.0
    shared = rng.normal(size=(R, p))
    y = shared @ [1.5, -2.0, 0.3] + rng.normal(size=R)
    dense = np.zeros((R, G * nl + p))
    for j in range(nl):
        dense[np.arange(R), group * nl + j] = local[:, j]
    dense[:, G * nl :] = shared
    ref = np.linalg.lstsq(dense, y, rcond=None)[0]
    c, x = _lstsq_blocks(group, local, shared, y, G)
    assert np.allclose(c, ref[G * nl :], rtol=0, atol=1e-10)
    if nl == 1:  # with a rank-deficient group the dense minimum norm spreads over the shared columns too
        assert np.allclose(x.ravel(), ref[: G * nl], rtol=0, atol=1e-10)
    else:
        full = [g for g in range(G) if g not in (3, 6)]
        assert np.allclose(x[full], ref[: G * nl].reshape(G, nl)[full], rtol=0, atol=1e-10)
    assert np.all(x[3] == 0)


@pytest.mark.parametrize("clock", [(0.0013, 0.0), (0.0, 0.002)])
def test_robots_on_their_own_clocks_get_the_windows_of_synchronised_ones(tmp_path, clock):
    """Four robots at 200 Hz, each sampling on its own clock (stamps 1.3 ms apart, or each instant jittered
    +-2 ms): the period is each robot's 5 ms, not the union's; the windows are those of the synchronised twin
    (2.5 s, all linked: no interleaved or jittered interval is a gap)."""
    kw = {"n": 4, "rate": 200.0, "dur": 10.0, "b": 5.0, "seed": 12}
    plant.record(tmp_path / "sync", **kw)
    plant.record(tmp_path / "own", own_clock=clock, **kw)
    sync, own = read_recording(tmp_path / "sync"), read_recording(tmp_path / "own")
    assert own.T > 3.99 * sync.T  # (almost) no stamp shared
    assert agent_period(own) == pytest.approx(0.005, rel=1e-3) and agent_period(sync) == pytest.approx(0.005, rel=1e-6)
    pa, pb = make_problem(sync, 0.01, 0.01, FitOptions()), make_problem(own, 0.01, 0.01, FitOptions())
    assert pb.win.S == pa.win.S == 4 and pb.link.all() and pa.link.all()
    assert np.allclose(pb.t0, pa.t0, atol=0.005)
