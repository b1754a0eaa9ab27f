"""Force spikes (docs/diagnose.md, "Input"): single samples of one agent's logged force far off its
neighbours. Spikes of the log (a dropped byte) that the motion does not follow are left out as the velocity
glitches are; one-sample knocks the load feels are kept (ident/diagnose.py). The recordings come from
bench/foreign_recordings.py's plant (no code shared with ident/)."""

from __future__ import annotations

import pytest

from ident.diagnose import diagnose_dir
from tests.foreign_plant import plant


def _spike_warning(d) -> str:
    (w,) = [w for w in d.warnings if w.split(" ", 1)[1].startswith("force samples")]
    return w


def test_spikes_of_the_force_log_are_left_out(tmp_path):
    """0.5 % of the force samples off by 3x the force's RMS per axis, in the log only, nothing else (12 s): the
    spikes were read as a random force of 3.9 N, J +35 % with an interval of +-49 %; now they are left out
    (the velocities across them jump 0.1 +- 0.34 x what a real force would give: 1 rejected at p 1e-7), nothing is named and m, J
    are the plant's within 1 % and 3 % (J's interval +-6.5 %)."""
    truth = plant.record(tmp_path, n=4, dur=12.0, fspikes=(0.005, 3.0))
    d = diagnose_dir(tmp_path)
    assert "left out" in _spike_warning(d)
    assert not d.effects and d.random_force is None and not d.unexplained
    assert abs(d.augmented.m / truth["m"] - 1) < 0.01 and abs(d.augmented.J / truth["J"] - 1) < 0.03
    assert d.augmented.J_ci95 < 0.08 * truth["J"]


@pytest.mark.long
def test_knocks_the_load_feels_are_kept(tmp_path):
    """Spikes of 4x the force's RMS applied to the load too (one-sample knocks), viscous friction 8: the
    velocities jump 0.76 +- 0.24 x what the model predicts (0 rejected at p 5e-10, 1 not at p 0.03): kept as
    logged, viscous friction named, m and J the plant's."""
    truth = plant.record(tmp_path, n=4, dur=20.0, b=8.0, fspikes=(0.005, 4.0), fspikes_applied=True)
    d = diagnose_dir(tmp_path)
    assert "kept as logged" in _spike_warning(d)
    assert [e["name"] for e in d.effects] == ["viscous_friction"], d.effects
    assert abs(d.augmented.m / truth["m"] - 1) < 0.01 and abs(d.augmented.J / truth["J"] - 1) < 0.03
