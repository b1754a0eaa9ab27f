"""Viscous friction stronger along one axis of the load than across it (a cart on wheels, casters):
``anisotropic_friction`` beside ``viscous_friction`` (docs/diagnose.md, "A cart: friction fixed to the load's axes").

The model's term is checked against a fine ODE solution written here with the friction as a matrix in the
load's frame; the diagnosis runs on bench/foreign_recordings.py's plant (no code shared with ident/)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from ident.diagnose import diagnose_dir
from ident.model import simulate
from tests.foreign_plant import plant
from tests.test_ident_model import ARMS, _problem, smooth_wrench

B_X, B_Y = 2.0, 20.0  # N s/m along the load's own x and y axes


def test_the_term_gives_back_the_true_motion():
    """tests/test_ident_model.py's 3-contact load turning under its smooth forces with friction R(theta) diag(b_x, b_y) R(theta)^T v: the
    model with viscous_friction (b_x + b_y) / 2 and D = ((b_x - b_y) / 2, 0) predicts the contact velocities
    to the interpolation's error (cubic, 100 Hz: 3e-7 m/s in tests/test_ident_model.py)."""
    r = ARMS
    m, J = 20.0, 15.0

    def f(t, s):
        vx, vy, om, th = s
        w = smooth_wrench(t)
        R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
        fr = R @ np.diag((B_X, B_Y)) @ R.T @ np.array((vx, vy))
        Rr = r @ R.T
        tq = w[:, 2].sum() + np.sum(Rr[:, 0] * w[:, 1] - Rr[:, 1] * w[:, 0])
        return [(w[:, 0].sum() - fr[0]) / m, (w[:, 1].sum() - fr[1]) / m, tq / J, om]

    t = np.arange(0, 6.0, 0.01)
    sol = solve_ivp(f, (0, 6.0), [0.3, -0.1, 0.6, 0.0], t_eval=t, rtol=1e-11, atol=1e-12, method="DOP853")
    vx, vy, om, th = sol.y
    assert np.ptp(th) > 2.0  # the load turns: the friction's axes turn with it
    Rr = np.stack([r @ np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]).T for a in th])
    vel = np.stack((vx[:, None] - om[:, None] * Rr[..., 1], vy[:, None] + om[:, None] * Rr[..., 0]), -1)
    pb = _problem(t, np.stack([smooth_wrench(x) for x in t]), vel=vel, hold="cubic")
    lay = pb.base.with_effects(("viscous_friction", "anisotropic_friction"))
    g = np.concatenate((r.ravel(), [1 / m, 1 / J, (B_X + B_Y) / 2, (B_X - B_Y) / 2, 0.0]))
    pred, _, _ = simulate(pb.win, lay, g[None], sol.y[:, 0][None, None], coulomb_speed=0.0, max_step=0.01)
    assert np.abs(pred[0, 0, : t.size] - vel).max() < 3e-7


@pytest.mark.long
def test_a_cart_is_named_with_its_axes(tmp_path):
    """The bench's `cart_2_20` (b 2 along the load's x, 20 along its y, nothing else): the nominal fit is
    rejected (m +3 %, residual 1.3x the floor); the diagnosis names viscous and anisotropic friction, reads
    the friction along and across the axis to within 1 N s/m (their intervals are +-0.2-0.4), m and J within
    their intervals, and the residual white."""
    truth = plant.record(tmp_path / "cart", **plant.CASES["cart_2_20"])
    d = diagnose_dir(tmp_path / "cart").as_dict()
    named = {e["name"]: e for e in d["effects"]}
    assert set(named) == {"viscous_friction", "anisotropic_friction"} and not d["unexplained"]
    p = named["anisotropic_friction"]["principal"]
    assert abs(p["along"] - B_Y) < 1.0 and abs(p["across"] - B_X) < 1.0
    aug = d["augmented"]
    assert abs(aug["m"] - truth["m"]) < aug["m_ci95"] and abs(aug["J"] - truth["J"]) < aug["J_ci95"]
    assert aug["whiteness_p"] > 0.01
