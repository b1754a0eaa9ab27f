"""Plant effects (simulator/effects.py) against closed-form truth, and the load change in truth.csv."""

from __future__ import annotations

import math

import numpy as np
import pytest

from config.loader import ScenarioError, load_scenario, scenario_from_dict
from simulator.plant import Plant, contact_points_body, sensor_rng

M, J = 50.0, 86.89


def make(plant: dict | None = None, sigma=0.0, initial=None, n=4):
    return scenario_from_dict({
        "n": n,
        "load": {"width": 4.0, "height": 2.2, "mass": M, "inertia": J, "com_offset": [0.3, -0.2]},
        "contacts": {"start": 0.05},
        "noise": {"sigma_v": sigma},
        "initial": initial or {},
        "plant": plant or {},
    })  # fmt: skip


def idle(plant: Plant, ticks: int) -> None:
    for _ in range(ticks):
        plant.apply_and_step([(0.0, 0.0, 0.0)] * plant.n)


def test_no_effects_takes_the_nominal_path():
    assert make().plant.active is False
    assert Plant(make()).effects is None
    assert Plant(make({"actuator_gain": 1.2})).effects is not None


def test_viscous_friction_decays_velocity_geometrically():
    c, ticks = 5.0, 400
    p = Plant(make({"friction": {"viscous": c}}, initial={"v_c": [0.4, -0.2]}))
    idle(p, ticks)
    factor = (1 - 0.01 * c / M) ** ticks  # semi-implicit Euler: v_{k+1} = v_k (1 - dt c / m)
    np.testing.assert_allclose(p.truth().vc, (0.4 * factor, -0.2 * factor), rtol=1e-12)


def test_coulomb_friction_decelerates_at_fc_over_m():
    fc, ticks = 2.0, 300
    p = Plant(make({"friction": {"coulomb": fc, "coulomb_speed": 1e-3}}, initial={"v_c": [0.6, 0.8]}))
    idle(p, ticks)
    speed = math.hypot(*p.truth().vc)
    assert speed == pytest.approx(1.0 - fc / M * ticks * 0.01, rel=1e-9)  # tanh(>= 200) = 1
    assert p.truth().vc[1] / p.truth().vc[0] == pytest.approx(0.8 / 0.6)  # opposes the motion


def test_rotational_damping_decays_omega():
    c, ticks = 8.0, 500
    p = Plant(make({"friction": {"rotational": c}}, initial={"omega": 1.5}))
    idle(p, ticks)
    assert p.truth().omega == pytest.approx(1.5 * (1 - 0.01 * c / J) ** ticks, rel=1e-12)


def test_external_force_and_actuator_gain():
    p = Plant(make({"external_force": [0.5, -1.0], "actuator_gain": 0.8}))
    ticks, tau = 200, 0.25
    for _ in range(ticks):
        p.apply_and_step([(0.0, 0.0, tau)] * p.n)
    t = p.truth()
    np.testing.assert_allclose(t.vc, (0.5 * ticks * 0.01 / M, -1.0 * ticks * 0.01 / M), rtol=1e-12)
    assert t.omega == pytest.approx(0.8 * p.n * tau * ticks * 0.01 / J, rel=1e-12)


def test_measurement_delay_returns_the_true_velocity_of_d_ticks_ago():
    p = Plant(make({"sensor": {"delay": 0.05}}))  # 5 ticks
    rng = sensor_rng(1)
    true = []
    for k in range(30):
        true.append(np.array(p.velocities()))
        meas = np.array(p.measure(rng))
        np.testing.assert_array_equal(meas, true[max(k - 5, 0)])
        p.apply_and_step([(1.0, 0.5, 0.3)] * p.n)
    assert p.effects.delay_ticks == 5
    assert np.abs(true[-1] - true[-6]).max() > 1e-3  # the delay is visible, not a constant signal


def test_velocity_bias_uses_the_same_noise_draw_as_nominal():
    nominal = Plant(make(sigma=0.3))
    biased = Plant(make({"sensor": {"velocity_bias": [0.1, -0.05]}}, sigma=0.3))
    ra, rb = sensor_rng(3), sensor_rng(3)
    for _ in range(20):
        a, b = np.array(nominal.measure(ra)), np.array(biased.measure(rb))
        np.testing.assert_allclose(b - a, np.tile([0.1, -0.05], (4, 1)), atol=1e-12)
        for p in (nominal, biased):
            p.apply_and_step([(0.5, 0.0, 0.2)] * p.n)
    assert biased.truth() == nominal.truth()  # truth is the true state


def test_load_change_steps_parameters_keeps_contacts_and_velocity_field():
    change = {"t": 0.5, "mass": 40.0, "inertia": 70.0, "com_offset": [-0.4, 0.1]}
    ini = {"v_c": [0.2, 0.1], "omega": 0.7, "angle": 0.4}
    changed, same = Plant(make({"load_changes": [change]}, initial=ini)), Plant(make(initial=ini))
    for p in (changed, same):
        idle(p, 50)  # the change is due at tick 50
    t_post, t_pre = changed.truth(), same.truth()
    assert (t_pre.mass, t_pre.inertia) == (M, J) and (t_post.mass, t_post.inertia) == (40.0, 70.0)
    # the same instant with and without the change: contact velocities and positions are continuous
    np.testing.assert_allclose(changed.velocities(), same.velocities(), atol=1e-12)
    np.testing.assert_allclose(np.array(t_post.zi) + t_post.pg, np.array(t_pre.zi) + t_pre.pg, atol=1e-12)
    assert t_post.omega == t_pre.omega
    # the CoM moved by R(angle) (new - old offset), so z_C = p_G - p_C moved the other way
    c, s = math.cos(t_post.angle), math.sin(t_post.angle)
    d = np.array([-0.7, 0.3])
    np.testing.assert_allclose(np.array(t_post.zc) - t_pre.zc, -np.array([c * d[0] - s * d[1], s * d[0] + c * d[1]]),
                               atol=1e-12)
    # afterwards a pure torque spins the new load at the new J
    w0 = changed.truth().omega
    for _ in range(10):
        changed.apply_and_step([(0.0, 0.0, 1.0)] * changed.n)
    assert changed.truth().omega - w0 == pytest.approx(changed.n * 1.0 * 0.1 / 70.0, rel=1e-12)


def test_load_change_shows_in_truth_csv(tmp_path, scenarios_dir):
    from coload.rundir.format import read_run
    from coload.runs.engine import run_inproc

    sc = load_scenario(scenarios_dir / "quick.toml", [
        "duration=4.0", "record.every_ticks=1",
        'plant.load_changes=[{t = 2.0, mass = 40.0, inertia = 70.0, com_offset = [-0.5, 0.4]}]',
    ])  # fmt: skip
    run_inproc(sc, tmp_path / "run")
    tr = read_run(tmp_path / "run").truth
    before, after = tr.t < 2.0 - 1e-9, tr.t >= 2.0 - 1e-9
    assert np.all(tr.columns["mass"][before] == 50.0) and np.all(tr.columns["mass"][after] == 40.0)
    assert np.all(tr.columns["inertia"][before] == 86.89) and np.all(tr.columns["inertia"][after] == 70.0)
    # |z_C| is rotation invariant: |mean of the contact points about the old, then the new CoM|
    expect = [np.hypot(*np.mean(contact_points_body(sc.model_copy(update={"load": sc.load.model_copy(
        update={"com_offset": off})})), axis=0)) for off in ((0.3, -0.2), (-0.5, 0.4))]  # fmt: skip
    zc = np.hypot(tr.columns["zc_x"], tr.columns["zc_y"])
    np.testing.assert_allclose(zc[before], expect[0], atol=1e-9)
    np.testing.assert_allclose(zc[after], expect[1], atol=1e-9)
    k = int(np.argmax(after))
    assert abs(tr.columns["zc_x"][k] - tr.columns["zc_x"][k - 1]) > 0.1  # a step, not a drift


def test_default_inertia_after_change_is_uniform_lamina():
    p = Plant(make({"load_changes": [{"t": 0.0, "mass": 20.0}]}))
    # uniform 4.0 x 2.2 rectangle: (w^2 + h^2)/12 per kg, moved to the unchanged offset (0.3, -0.2)
    assert p.inertia == pytest.approx(20.0 * ((16 + 4.84) / 12 + 0.09 + 0.04))


@pytest.mark.parametrize("plant, match", [
    ({"load_changes": [{"t": 3.0, "mass": 1.0}, {"t": 2.0, "mass": 2.0}]}, "strictly increasing"),
    ({"friction": {"viscus": 1.0}}, "viscus"),
    ({"friction": {"viscous": -1.0}}, "greater than or equal"),
    ({"actuator_gain": 0.0}, "greater than 0"),
])  # fmt: skip
def test_bad_plant_section_is_a_clear_error(plant, match):
    with pytest.raises(ScenarioError, match=match):
        make(plant)
