"""A load spinning at about a turn per second is fitted (ident/fit.py's kinematic start: the window over which
it sums h^2, which turns at twice the rate, shrinks with the spin). The recording comes from
bench/foreign_recordings.py's plant (no code shared with ident/)."""

from __future__ import annotations

from ident.diagnose import diagnose_dir
from tests.foreign_plant import plant


def test_a_load_spinning_over_a_turn_a_second_is_fitted_to_the_floor(tmp_path):
    """Initial rate 10 rad/s, viscous friction 8 N s/m, 10 s: before, the kinematic start's 0.5 s windows summed
    h^2 over ~10 rad and the fit never reached the basin (residual 501x the floor, m -37 %, `unexplained`);
    now m and J within 1 %, the residual at the floor, viscous friction named."""
    truth = plant.record(tmp_path, n=4, dur=10.0, b=8.0, spin=10.0)
    d = diagnose_dir(tmp_path)
    a = d.augmented
    assert a.residual_over_floor < 1.1 and not d.unexplained, (a.residual_over_floor, d.warnings)
    assert abs(a.m / truth["m"] - 1) < 0.01 and abs(a.J / truth["J"] - 1) < 0.01, (a.m, truth["m"], a.J, truth["J"])
    assert [e["name"] for e in d.effects] == ["viscous_friction"]
