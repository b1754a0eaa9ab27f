"""Velocity noise correlated in time (docs/diagnose.md, "Velocities whose noise is correlated in time"): a
filtered velocity estimate's noise, a low-pass of white noise (first order, or a second-order Butterworth), is
measured on the rigid-body kinematics and the residual whitened for it. The recording comes from bench/foreign_recordings.py's plant
(scipy, no code shared with ident/), loaded by its path.
"""

from __future__ import annotations

import math

from ident.diagnose import diagnose_dir
from tests.foreign_plant import plant


def _within(a, truth) -> None:
    """m and J each within its own 95 % interval (white-noise intervals were ~4x too narrow for this noise)."""
    assert abs(a.m - truth["m"]) < a.m_ci95, (a.m, a.m_ci95, truth["m"])
    assert abs(a.J - truth["J"]) < a.J_ci95, (a.J, a.J_ci95, truth["J"])


def test_low_passed_velocity_noise_alone_is_not_missing_dynamics(tmp_path):
    # the nominal plant, 0.1 s correlation time (lag-1 correlation 0.905 at 100 Hz): before, `unexplained`
    # (Ljung-Box p 2e-11 at 0.95x the floor) with J outside its interval
    truth = plant.record(tmp_path / "clean", n=4, dur=10.0, seed=2, vcolor=0.1)
    d = diagnose_dir(tmp_path / "clean")
    assert not d.effects and not d.unexplained and d.random_force is None, (d.effects, d.warnings)
    _within(d.augmented, truth)
    assert d.noise_floor["velocity_correlation"]["ar1"]


def test_low_passed_velocity_noise_is_measured_and_the_intervals_hold(tmp_path):
    # viscous friction 8 N s/m: before, m and J outside their intervals and the residual not white (p 6e-17)
    truth = plant.record(tmp_path / "viscous", n=4, dur=10.0, b=8.0, vcolor=0.1)
    d = diagnose_dir(tmp_path / "viscous")
    corr = d.noise_floor["velocity_correlation"]
    assert corr["ar1"] and abs(corr["tau_s"] / 0.1 - 1) < 0.2, corr
    assert any("correlated in time" in w for w in d.warnings)
    named = {e["name"]: e for e in d.effects}
    # the effect present and nothing else; white once whitened for the sensor (no random force)
    assert set(named) == {"viscous_friction"} and not d.unexplained, named
    assert d.random_force is None
    b = named["viscous_friction"]
    a = d.augmented
    assert abs(b["value"] - 8.0) < b["ci95"], b
    _within(a, truth)
    assert 0.9 < a.residual_over_floor < 1.1 and math.isfinite(a.whiteness_p)


def test_second_order_filtered_velocity_noise_is_modelled(tmp_path):
    # a digital second-order Butterworth low-pass of the noise (0.1 s, lag-1 correlation 0.996) is no AR(1):
    # before, treated as white: viscous friction outside its interval, m and J outside theirs (probe6 bw_visc)
    truth = plant.record(tmp_path / "bw", n=4, dur=10.0, b=8.0, vfilter=("butter2", 0.1))
    d = diagnose_dir(tmp_path / "bw")
    corr = d.noise_floor["velocity_correlation"]
    assert corr["modelled"] and corr["order"] > 1 and len(corr["coefficients"]) == corr["order"], corr
    named = {e["name"]: e for e in d.effects}
    assert set(named) == {"viscous_friction"} and not d.unexplained, (named, d.warnings)
    b = named["viscous_friction"]
    assert abs(b["value"] - 8.0) < b["ci95"], b
    _within(d.augmented, truth)
    assert not any("held at its bound" in w for w in d.warnings), d.warnings
