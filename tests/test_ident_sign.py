"""Forces logged with the opposite sign on every robot (docs/diagnose.md, "Method"): the load accelerates
against the logged force, the nominal fit's 1/m is negative far beyond its interval, and the diagnosis turns
the wrench round and says so. The recording comes from bench/foreign_recordings.py's plant (no code shared
with ident/); only the logged sign is changed."""

from __future__ import annotations

import csv

from ident.diagnose import diagnose_dir
from tests.foreign_plant import plant


def _negate_wrench(path):
    rows = list(csv.reader(open(path, newline="")))
    head = rows[0]
    cols = [head.index(c) for c in ("fx", "fy", "tau")]
    for r in rows[1:]:
        for c in cols:
            r[c] = repr(-float(r[c]))
    with open(path, "w", newline="") as f:
        csv.writer(f).writerows(rows)


def test_forces_logged_with_the_opposite_sign_are_turned_round_and_named(tmp_path):
    """Viscous friction 8 N s/m, every agent's force logged negated: as logged, 1/m ~ -1/m (m and J were not
    reported, "friction holding the load"); now `force_sign_reversed` is named as a logger quirk and m, J and
    the friction are the plant's (within 2 %, the bench's tolerance for this noise)."""
    truth = plant.record(tmp_path, n=4, dur=10.0, b=8.0)
    _negate_wrench(tmp_path / "samples.csv")
    d = diagnose_dir(tmp_path)
    assert d.effects[0]["name"] == "force_sign_reversed", d.effects
    assert any(w.startswith("force_sign_reversed:") for w in d.warnings)
    assert abs(d.augmented.m / truth["m"] - 1) < 0.02 and abs(d.augmented.J / truth["J"] - 1) < 0.02
    (visc,) = [e for e in d.effects if e["name"] == "viscous_friction"]
    assert abs(visc["value"] / 8.0 - 1) < 0.05


def test_a_creeping_load_held_by_friction_is_not_taken_for_a_reversed_sign(tmp_path):
    """Coulomb friction 200 N against pushes of a few tens of N: 1/m is near zero (slightly negative within
    its interval): not a reversed sign."""
    plant.record(tmp_path, n=4, dur=10.0, fc=200.0, vs=0.01)
    d = diagnose_dir(tmp_path)
    assert not any(e["name"] == "force_sign_reversed" for e in d.effects)
