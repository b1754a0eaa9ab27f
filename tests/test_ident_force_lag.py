"""A force sensor that lags (docs/diagnose.md, "Measured: a fifth generator"): every robot's logged force is
its applied force low-passed (first order, 30 ms), so the motion leads the logged force. The recording comes
from bench/foreign_recordings.py's plant (no code shared with ident/)."""

from __future__ import annotations

import pytest

from ident.diagnose import diagnose_dir
from tests.foreign_plant import plant


@pytest.mark.long  # ~35 s CPU: the nominal fit is 2x the floor, so every candidate is fitted in each round
def test_a_force_sensor_low_pass_is_named_with_the_friction_and_nothing_else(tmp_path):
    """Viscous friction 8 N s/m behind force sensors that low-pass at 30 ms: the lag was a negative delay, held
    at measurement_delay's bound 0 in silence, and the recording `unexplained` with the friction lost; now the
    lag is named on the force side (a low-pass or late rows: at these frequencies about the same), its value
    within 20 %, the friction within 5 %, m and J within 2 % (the bench's tolerance for this noise)."""
    truth = plant.record(tmp_path, n=4, dur=10.0, b=8.0, flp=0.03)
    d = diagnose_dir(tmp_path)
    named = {e["name"]: e for e in d.effects}
    lag = [c for c in ("force_sensor_lowpass", "force_sensor_lag") if c in named]
    assert not d.unexplained and len(lag) == 1 and set(named) == {"viscous_friction", *lag}, named
    assert abs(named[lag[0]]["value"] / 0.03 - 1) < 0.2
    assert abs(named["viscous_friction"]["value"] / 8.0 - 1) < 0.05
    assert abs(d.augmented.m / truth["m"] - 1) < 0.02 and abs(d.augmented.J / truth["J"] - 1) < 0.02
    assert any(w.startswith(f"{lag[0]}: the ") and " ms" in w for w in d.warnings), d.warnings
    # the lag's two shapes were fitted side by side: the text says how they compare
    assert any(w.startswith(f"{lag[0]}: the ") and ("fits worse (BIC" in w or "do not tell it from" in w)
               for w in d.warnings), d.warnings
