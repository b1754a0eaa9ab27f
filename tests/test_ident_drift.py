"""A load whose mass drifts (ident/change.py): a change at one time is kept only where it leaves both sides'
residuals white; otherwise the model fitted per quarter of the recording says whether m drifts. The
recording comes from bench/foreign_recordings.py's plant (no code shared with ident/)."""

from __future__ import annotations

import pytest

from ident.diagnose import diagnose_dir
from tests.foreign_plant import plant


@pytest.mark.long
def test_a_mass_that_drifts_is_not_read_as_a_step_and_the_drift_is_named(tmp_path):
    """m and J fall linearly to 0.8 x over 20 s (50.7 -> 40.6 kg). The probe's mass_drain (its own generator,
    20 -> 16 kg) was read as a step between 7.5 and 12.5 s with the sides' whiteness p 5e-7 and 2e-31; here
    the search places the change in [10, 15] s, its earlier side stays structured (p 2e-44): unexplained, and m
    per quarter reads 49.5, 46.8, 44.5, 42.0 (the truth's means 49.4, 46.9, 44.4, 41.9); 27 s."""
    truth = plant.record(tmp_path, n=4, drift=0.8)
    d = diagnose_dir(tmp_path)
    assert d.unexplained and d.change is not None and not d.change["found"]
    parts = d.change["m_per_part"]
    m0, dur = truth["m"], 20.0
    for p in parts:  # the truth's mean over each part, within 2 % (the drift within a part is 5 %)
        mean = m0 * (1 - 0.2 * (p["from_s"] + p["to_s"]) / 2 / dur)
        assert abs(p["m"] / mean - 1) < 0.02, (p, mean)
    # m and J scale alike here: a mass that changes, not a payload that slides (J would move more than m)
    assert any(w.startswith(("m drifts: ", "m and J change: ")) and "mass (and inertia) changes gradually" in w
               for w in d.warnings), d.warnings
