"""A load that hardly moves under the applied force (docs/diagnose.md, "Limits"): m is reported as not
resolved (``identifiable.m`` false, a warning with the fitted 1/m and its interval), not as a number. The
recording comes from bench/foreign_recordings.py's plant (no code shared with ident/)."""

from __future__ import annotations

import numpy as np

from ident.diagnose import diagnose_dir
from ident.fit import Fit
from ident.model import Layout
from ident.select import _unresolved_effects
from ident.stats import Z95
from tests.foreign_plant import plant


def test_a_load_friction_holds_leaves_m_unresolved_and_says_so(tmp_path):
    """Coulomb friction of 200 N against pushes of a few tens of N: the load creeps; 1/m is not above its own
    95 % half-width, so m is flagged, while J (the rotation answers the torques) stays resolved."""
    plant.record(tmp_path, n=4, dur=10.0, fc=200.0, vs=0.01)
    d = diagnose_dir(tmp_path)
    assert d.identifiable["m"] is False and d.identifiable["J"] is True
    assert any(w.startswith("m not resolved: the fit's 1/m") for w in d.warnings), d.warnings


def test_an_effect_acting_through_an_unresolved_inverse_is_not_named():
    """The rule (ident/select.py ``_unresolved_effects``): a force on the translation whose 1/m is not above its
    own 95 % half-width, or a torque whose 1/J is not, has no determined value (the data see it times 1/m):
    it is not named. The probe's creeping stick-slip load named force_bias (3.19, -0.99) +- (2.8, 1.4) N beside
    1/m -0.000314 +- 0.00029 and its own 'not excited enough' warning; now nothing is named there."""
    lay = Layout(3, True, (True, True), False, ("force_bias", "rotational_damping"))
    g = np.zeros(lay.G)
    g[lay.ia], g[lay.ib] = -3e-4, 0.4
    cov = np.zeros((lay.G, lay.G))
    cov[lay.ia, lay.ia], cov[lay.ib, lay.ib] = (2.9e-4 / Z95) ** 2, (0.01 / Z95) ** 2
    fit = Fit(lay, g, np.zeros((1, lay.K)), cov, 0.0, 1, np.zeros((1, 1)), 0)
    assert _unresolved_effects(fit, ["force_bias", "rotational_damping"]) == ["force_bias"]
    cov[lay.ia, lay.ia] = (1e-4 / Z95) ** 2
    g[lay.ia] = 3e-4
    assert _unresolved_effects(Fit(lay, g, fit.x, cov, 0.0, 1, fit.res, 0), ["force_bias"]) == []
