"""Self-tests of the independent continuous-time plant (tests/ctplant.py): closed forms, conservation,
energy balance, rigid-body kinematics of what it writes, integrator convergence, effect signs."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest

import ctplant


def _free(tmp_path=None, **kw):
    """Free motion (no applied wrench) of a 4-agent load from a given state."""
    args = dict(n=4, rate_hz=50.0, duration_s=4.0, sigma_v=0.0, seed=11, inputs=False,
                x0=[0.3, -0.2, 0.5, 0.8, -0.4, 0.6])  # fmt: skip
    args.update(kw)
    return ctplant.make_recording(tmp_path, **args)


def _com(tr, t):
    return tr["trajectory"].state(np.asarray(t))


def test_free_motion_keeps_momentum_and_angular_momentum():
    tr = _free()
    t = tr["t"]
    s = _com(tr, t)
    np.testing.assert_allclose(s[:, 3:5], np.tile([0.8, -0.4], (t.size, 1)), atol=1e-12)
    np.testing.assert_allclose(s[:, 5], 0.6, atol=1e-12)
    np.testing.assert_allclose(s[:, 2], 0.5 + 0.6 * t, atol=1e-9)
    L = tr["J"] * s[:, 5] + tr["m"] * (s[:, 0] * s[:, 4] - s[:, 1] * s[:, 3])  # about the world origin
    assert np.ptp(L) < 1e-9 * abs(L[0])


def _power_balance(tr, t0, t1, viscous=0.0, rotational=0.0, m=None, J=None):
    """(KE(t1) - KE(t0), integral of the power of the applied wrench minus the dissipation), the power
    computed from each agent's force at its contact point (not the plant's aggregated right-hand side)."""
    traj, inp = tr["trajectory"], tr["inputs"]
    m = m or tr["m"]
    J = J or tr["J"]
    t = np.linspace(t0, t1, 20001)
    s = traj.state(t)
    pos, vel = traj.contacts(t)
    w = inp.wrench(t)  # (T, n, 3)
    power = np.einsum("tij,tij->t", w[..., :2], vel) + w[..., 2].sum(axis=1) * s[:, 5]
    power -= viscous * (s[:, 3] ** 2 + s[:, 4] ** 2) + rotational * s[:, 5] ** 2
    h = t[1] - t[0]
    work = h / 3 * (power[0] + power[-1] + 4 * power[1:-1:2].sum() + 2 * power[2:-1:2].sum())  # Simpson
    ke = 0.5 * m * (s[:, 3] ** 2 + s[:, 4] ** 2) + 0.5 * J * s[:, 5] ** 2
    return ke[-1] - ke[0], work, float(np.max(ke))


def test_power_balance_with_viscous_friction_and_rotational_damping():
    tr = ctplant.make_recording(None, n=5, rate_hz=50.0, duration_s=10.0, sigma_v=0.0, seed=4,
                                effects=["viscous_friction", "rotational_damping"])  # fmt: skip
    e = tr["effects"]
    dke, work, ke_max = _power_balance(tr, 0.0, 10.0, e["viscous_friction"], e["rotational_damping"])
    assert abs(dke - work) < 1e-7 * ke_max
    # the dissipation is a real share of the energy budget (the check would not see a sign error otherwise)
    dke0, work0, _ = _power_balance(tr, 0.0, 10.0)
    assert abs(dke0 - work0) > 0.05 * ke_max


def test_translation_matches_closed_form():
    """Axis geometry, sinusoids only: v(t) = v0 + sum a (cos phi - cos(w t + phi)) / (m w), no rotation."""
    tr = ctplant.make_recording(None, n=2, rate_hz=100.0, duration_s=6.0, sigma_v=0.0, seed=5, geometry="axis",
                                pulses=False)  # fmt: skip
    inp = tr["inputs"]
    w = 2 * np.pi * inp.freq
    a = inp.coef[:, 0, :].sum(axis=0)  # total fx per basis function
    t = tr["t"]
    v = tr["v0"][0] + (a / (tr["m"] * w) * (np.cos(inp.phase) - np.cos(np.outer(t, w) + inp.phase))).sum(axis=1)
    s = _com(tr, t)
    np.testing.assert_allclose(s[:, 3], v, atol=1e-9)
    np.testing.assert_allclose(s[:, [4, 5]], 0.0, atol=1e-12)
    assert np.all(inp.wrench(t)[..., 1:] == 0.0)


def test_written_samples_are_rigid_body_contact_motion(tmp_path):
    tr = ctplant.make_recording(tmp_path, n=4, rate_hz=200.0, duration_s=3.0, sigma_v=0.0, seed=6, positions=True)
    with open(tmp_path / "samples.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == ["t", "agent", "vx", "vy", "x", "y", "fx", "fy", "tau"]
    T, n = tr["t"].size, 4
    arr = np.array([[float(r[k]) for k in ("vx", "vy", "x", "y", "fx", "fy", "tau")] for r in rows]).reshape(T, n, 7)
    v, p = arr[..., 0:2], arr[..., 2:4]
    np.testing.assert_array_equal(v, tr["vel_true"])  # repr round trip: bit-identical
    np.testing.assert_array_equal(arr[..., 4:], tr["wrench"])
    for i in range(n):
        for j in range(i + 1, n):
            dp, dv = p[:, i] - p[:, j], v[:, i] - v[:, j]
            assert np.max(np.abs((dp * dv).sum(axis=1))) < 1e-9  # relative velocity is a rotation of dp
            dist = np.hypot(dp[:, 0], dp[:, 1])
            assert np.ptp(dist) < 1e-9
    # velocities are the time derivative of the positions (central differences, O(dt^2))
    dt = 1 / 200.0
    fd = (p[2:] - p[:-2]) / (2 * dt)
    assert np.max(np.abs(fd - v[1:-1])) < 1e-3
    run = (tmp_path / "run.toml").read_text()
    assert "n = 4" in run and "dt = 0.005" in run and "edges = [[0, 1], [1, 2], [2, 3]]" in run
    truth = json.loads((tmp_path / "truth.json").read_text())
    assert truth["m"] == tr["m"] and len(truth["r0"]) == 4


def test_integrator_converged_far_below_the_noise():
    kw = dict(n=6, rate_hz=50.0, duration_s=2.0, sigma_v=0.0, seed=7,
              effects=["coulomb_friction", "viscous_friction", "rotational_damping"])  # fmt: skip
    a = ctplant.make_recording(None, **kw)
    b = ctplant.make_recording(None, max_step=0.1 / 50.0, **kw)  # a tenth of the sample period
    c = ctplant.make_recording(None, max_step=0.05 / 50.0, **kw)
    assert np.max(np.abs(a["vel_true"] - b["vel_true"])) < 1e-7  # the lowest noise level is 1e-3 m/s
    assert np.max(np.abs(b["vel_true"] - c["vel_true"])) < 1e-7


V0, W0 = np.array([0.8, -0.4]), 0.6
F_PER, A_PER, ANG_PER = 0.7, 5.0, 0.3


def _closed_form(name, t, m, J):
    """CoM velocity (T, 2) and omega (T,) of the free motion from (V0, W0) with one effect."""
    one = np.ones_like(t)
    if name == "viscous_friction":  # 20 N s/m
        return V0 * np.exp(-20.0 * t / m)[:, None], W0 * one
    if name == "force_bias":  # (3, -2) N
        return V0 + np.outer(t, [3.0, -2.0]) / m, W0 * one
    if name == "rotational_damping":  # 15 N m s
        return V0 * one[:, None], W0 * np.exp(-15.0 * t / J)
    w = 2 * np.pi * F_PER  # periodic force A sin(w t) along ANG_PER
    return V0 + np.outer(A_PER * (1 - np.cos(w * t)) / (m * w), [math.cos(ANG_PER), math.sin(ANG_PER)]), W0 * one


@pytest.mark.parametrize(
    ("name", "value"),
    [("viscous_friction", 20.0), ("force_bias", [3.0, -2.0]), ("rotational_damping", 15.0),
     ("periodic_force", {"amplitude": A_PER, "freq": F_PER, "angle": ANG_PER})],
)  # fmt: skip
def test_effect_closed_forms_in_free_motion(name, value):
    tr = _free(effects={name: value})
    t = tr["t"]
    s = _com(tr, t)
    v, w = _closed_form(name, t, tr["m"], tr["J"])
    np.testing.assert_allclose(s[:, 3:5], v, atol=1e-9)
    np.testing.assert_allclose(s[:, 5], w, atol=1e-9)


def test_coulomb_friction_opposes_the_velocity_at_constant_magnitude():
    fc = 8.0
    tr = _free(effects={"coulomb_friction": fc}, duration_s=3.0, x0=[0, 0, 0, 1.0, 0.0, 0.0])
    t = tr["t"]
    s = _com(tr, t)
    speed = 1.0 - fc * t / tr["m"]
    fast = speed > 0.1  # tanh(|v| / 0.01) = 1 to 1e-8 there
    assert fast.sum() > 10
    np.testing.assert_allclose(s[fast, 3], speed[fast], atol=1e-7)
    np.testing.assert_allclose(s[:, 4], 0.0, atol=1e-12)
    assert np.all(s[:, 3] > -1e-6)  # it stops, it does not reverse


def test_measurement_delay_and_velocity_bias():
    d, b = 0.033, [0.03, -0.02]
    tr = _free(effects={"measurement_delay": d, "velocity_bias": b}, sigma_v=0.0)
    traj = tr["trajectory"]
    t = tr["t"]
    # the heading at t = 0 is theta0; the measurement at t shows the body at t - d
    th = tr["theta0"] + 0.6 * (t - d)
    r = np.asarray(tr["r_body"])
    c, s = np.cos(th)[:, None], np.sin(th)[:, None]
    vx = 0.8 - 0.6 * (s * r[:, 0] + c * r[:, 1])
    vy = -0.4 + 0.6 * (c * r[:, 0] - s * r[:, 1])
    # make_recording returns the noise-free delayed contact velocities without the bias
    np.testing.assert_allclose(tr["vel_true"][..., 0], vx, atol=1e-9)
    np.testing.assert_allclose(tr["vel_true"][..., 1], vy, atol=1e-9)
    assert traj.breaks[0] == pytest.approx(-d)


def test_velocity_bias_is_in_the_written_measurements(tmp_path):
    tr = _free(tmp_path, effects={"velocity_bias": [0.03, -0.02]})
    with open(tmp_path / "samples.csv", newline="") as fh:
        v = np.array([[float(r["vx"]), float(r["vy"])] for r in csv.DictReader(fh)]).reshape(tr["vel_true"].shape)
    np.testing.assert_allclose(v - tr["vel_true"], np.broadcast_to([0.03, -0.02], v.shape), atol=1e-12)


def test_load_change_keeps_body_points_and_changes_mass():
    change = {"t": 2.0, "m": 70.0, "J": 90.0, "shift": [0.2, -0.1]}
    tr = ctplant.make_recording(None, n=3, rate_hz=50.0, duration_s=4.0, sigma_v=0.0, seed=8, m=50.0,
                                effects={"load_change": change})  # fmt: skip
    traj = tr["trajectory"]
    assert traj.m == [50.0, 70.0] and traj.J[1] == 90.0
    eps = 1e-9
    pa, va = traj.contacts(np.array([2.0 - eps]))
    pb, vb = traj.contacts(np.array([2.0 + eps]))
    np.testing.assert_allclose(pa, pb, atol=1e-7)
    np.testing.assert_allclose(va, vb, atol=1e-7)
    sa, sb = traj.state(np.array([2.0 - eps]))[0], traj.state(np.array([2.0 + eps]))[0]
    assert np.hypot(*(sb[:2] - sa[:2])) == pytest.approx(math.hypot(0.2, 0.1), rel=1e-6)
    # after the change the energy balance holds with the new mass and inertia, not the old ones
    dke, work, ke_max = _power_balance(tr, 2.0 + 1e-6, 4.0, m=70.0, J=90.0)
    assert abs(dke - work) < 1e-6 * ke_max
    dke_old, work_old, _ = _power_balance(tr, 2.0 + 1e-6, 4.0, m=50.0, J=tr["J"])
    assert abs(dke_old - work_old) > 1e-3 * ke_max


def test_deterministic_and_noise_level_leaves_the_motion_unchanged(tmp_path):
    kw = dict(n=3, rate_hz=20.0, duration_s=3.0, seed=9, effects=["viscous_friction"])
    a = ctplant.make_recording(tmp_path / "a", sigma_v=0.02, **kw)
    b = ctplant.make_recording(tmp_path / "b", sigma_v=0.02, **kw)
    c = ctplant.make_recording(tmp_path / "c", sigma_v=0.3, **kw)
    assert (tmp_path / "a" / "samples.csv").read_bytes() == (tmp_path / "b" / "samples.csv").read_bytes()
    np.testing.assert_array_equal(a["vel_true"], c["vel_true"])
    assert a["m"] == c["m"]


def test_noise_level_and_stamps_gaps_missing_cells(tmp_path):
    tr = ctplant.make_recording(tmp_path, n=4, rate_hz=100.0, duration_s=10.0, sigma_v=0.05, seed=10,
                                jitter=0.4, gaps=[(3.0, 4.5)], missing=0.05)  # fmt: skip
    t = tr["t"]
    assert np.all(np.diff(t) > 0.6 / 100.0 - 1e-12)
    assert not np.any((t >= 3.0) & (t < 4.5))
    k = np.round(t * 100.0)
    assert np.max(np.abs(t - k / 100.0)) <= 0.2 / 100.0 + 1e-12
    assert np.max(np.abs(t - k / 100.0)) > 0.1 / 100.0  # jitter is present
    with open(tmp_path / "samples.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    empty = sum(r["vx"] == "" for r in rows)
    assert 0.03 * len(rows) < empty < 0.07 * len(rows)
    assert all((r["vx"] == "") == (r["vy"] == "") for r in rows)
    v = np.array([[float(r["vx"] or "nan"), float(r["vy"] or "nan")] for r in rows]).reshape(tr["vel_true"].shape)
    e = (v - tr["vel_true"])[~np.isnan(v)]
    assert np.std(e) == pytest.approx(0.05, rel=0.05)
    assert abs(np.mean(e)) < 4 * 0.05 / math.sqrt(e.size)


def test_rotation_excited_and_velocities_cross_zero():
    """The default inputs make a rich recording: rotation for n >= 2, CoM velocity components changing sign."""
    tr = ctplant.make_recording(None, n=4, rate_hz=20.0, duration_s=30.0, sigma_v=0.0, seed=12)
    s = _com(tr, tr["t"])
    assert np.std(s[:, 5]) > 0.1
    for j in (3, 4):
        assert np.count_nonzero(np.diff(np.sign(s[:, j]))) >= 4
    assert np.max(np.hypot(s[:, 3], s[:, 4])) < 3.0  # a load pushed by hand, not a projectile


def test_axis_geometry_has_one_degree_of_freedom():
    tr = ctplant.make_recording(None, n=1, rate_hz=50.0, duration_s=5.0, sigma_v=0.0, seed=13, geometry="axis")
    s = _com(tr, tr["t"])
    assert np.max(np.abs(s[:, [1, 2, 4, 5]])) < 1e-12
    assert tr["identifiable"] == {"m": True, "J": False, "geometry": False}


def test_bad_arguments():
    with pytest.raises(ValueError, match="1..12"):
        ctplant.make_recording(None, n=13, rate_hz=50.0, duration_s=1.0, sigma_v=0.0, seed=0)
    with pytest.raises(ValueError, match="unknown effect"):
        ctplant.make_recording(None, n=2, rate_hz=50.0, duration_s=1.0, sigma_v=0.0, seed=0, effects=["slope"])


def test_shares_no_code_with_the_project():
    """The generator judges the diagnosis only if it is independent of it: numpy, scipy and the standard
    library only."""
    import ast
    from pathlib import Path

    tree = ast.parse(Path(ctplant.__file__).read_text())
    roots = {a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    roots |= {n.module.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
    assert roots <= {"__future__", "csv", "json", "math", "collections", "dataclasses", "pathlib", "typing", "numpy",
                     "scipy"}, roots  # fmt: skip
