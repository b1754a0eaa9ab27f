"""A load that hardly moves under the applied force (docs/diagnose.md, "Limits"): m is reported as not
resolved (``identifiable.m`` false, a warning with the fitted 1/m and its interval), not as a number. The
recording comes from bench/foreign_recordings.py's plant (no code shared with ident/)."""

from __future__ import annotations

from ident.diagnose import diagnose_dir
from tests.foreign_plant import plant


def test_a_load_friction_holds_leaves_m_unresolved_and_says_so(tmp_path):
    """Coulomb friction of 200 N against pushes of a few tens of N: the load creeps; 1/m is not above its own
    95 % half-width, so m is flagged, while J (the rotation answers the torques) stays resolved."""
    plant.record(tmp_path, n=4, dur=10.0, fc=200.0, vs=0.01)
    d = diagnose_dir(tmp_path)
    assert d.identifiable["m"] is False and d.identifiable["J"] is True
    assert any(w.startswith("m not resolved: the fit's 1/m") for w in d.warnings), d.warnings
