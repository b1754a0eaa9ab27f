"""The plant against closed-form rigid-body truth (paper 000, Sec. II), its step against pymunk's bit for bit,
and its sensor model."""

from __future__ import annotations

import math

import numpy as np
import pymunk
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from config.loader import scenario_from_dict
from simulator import geometry
from simulator.arms import load_body
from simulator.plant import (
    Plant,
    contact_points_body,
    kinetic_energy,
    load_inertia,
    load_polygon_body,
    sensor_rng,
)


def make(n: int = 10, com_offset=(0.3, -0.2), initial=None, sigma=0.3, **extra):
    data = {
        "n": n,
        "load": {"width": 4.0, "height": 2.2, "mass": 50.0, "inertia": 86.89, "com_offset": list(com_offset)},
        "contacts": {"start": 0.05},
        "noise": {"sigma_v": sigma},
        "initial": initial or {},
    }
    for key, value in extra.items():
        data.setdefault(key, {}).update(value) if isinstance(value, dict) else data.__setitem__(key, value)
    return scenario_from_dict(data)


def cross(a, b) -> float:
    return a[0] * b[1] - a[1] * b[0]


def perp(q) -> np.ndarray:
    return np.array([-q[1], q[0]])


# --- dynamics ------------------------------------------------------------------------------------


def test_initial_state_matches_scenario():
    sc = make(initial={"position": [1.0, -2.0], "angle": 0.7, "v_c": [0.3, 0.1], "omega": -0.4})
    t = Plant(sc).truth()
    assert (t.tick, t.t, t.x, t.y, t.angle, t.omega) == (0, 0.0, 1.0, -2.0, 0.7, -0.4)
    assert t.vc == (0.3, 0.1)
    assert (t.mass, t.inertia) == (50.0, 86.89)


def test_pure_torque_spins_up_linearly():
    sc = make()
    plant = Plant(sc)
    tau, ticks = 0.5, 300
    for _ in range(ticks):
        plant.apply_and_step([(0.0, 0.0, tau)] * sc.n)
    t = plant.truth()
    assert t.omega == pytest.approx(sc.n * tau * ticks * sc.dt / 86.89, rel=1e-12)
    assert t.vc == (0.0, 0.0) and (t.x, t.y) == (0.0, 0.0)  # torque alone does not move the CoM
    # pymunk moves positions before velocities within a step: angle = sum_{k<K} omega_k dt, omega_k = k alpha dt
    alpha = sc.n * tau / 86.89
    assert t.angle == pytest.approx(alpha * sc.dt**2 * (ticks - 1) * ticks / 2, rel=1e-12)
    assert t.tick == ticks and t.t == pytest.approx(ticks * sc.dt)


def test_common_force_with_compensating_torques_translates_without_rotation():
    sc = make(initial={"angle": 0.3})
    plant = Plant(sc)
    f = np.array([1.5, -0.7])
    ticks = 200
    for _ in range(ticks):
        tr = plant.truth()
        # each contact's moment (p_Ci - p_C) x f is cancelled by the agent's own torque
        arms = np.array(tr.zi) + np.array(tr.zc)
        plant.apply_and_step([(f[0], f[1], -cross(a, f)) for a in arms])
    t = plant.truth()
    assert abs(t.omega) < 1e-12 and abs(t.angle - 0.3) < 1e-12
    np.testing.assert_allclose(t.vc, sc.n * f * ticks * sc.dt / 50.0, rtol=1e-12)
    np.testing.assert_allclose((t.x, t.y), sc.n * f / 50.0 * sc.dt**2 * (ticks - 1) * ticks / 2, rtol=1e-10)


def test_common_force_through_centred_contacts_does_not_rotate():
    sc = make(com_offset=(0.0, 0.0))  # 10 contacts on a centrally symmetric outline: p_G = p_C
    plant = Plant(sc)
    assert np.allclose(plant.truth().zc, 0.0, atol=1e-12)
    for _ in range(100):
        plant.apply_and_step([(2.0, 1.0, 0.0)] * sc.n)
    t = plant.truth()
    assert abs(t.omega) < 1e-12
    np.testing.assert_allclose(t.vc, np.array([2.0, 1.0]) * sc.n * 100 * sc.dt / 50.0, rtol=1e-12)


def test_common_force_with_offset_com_turns_by_zc_cross_f():
    """Paper eq. (3): a common force f gives omega_dot = n (z_C x f) / J (the z_i terms cancel)."""
    sc = make(initial={"angle": 0.9})
    plant = Plant(sc)
    f = (3.0, -1.0)
    zc = plant.truth().zc
    plant.apply_and_step([(f[0], f[1], 0.0)] * sc.n)
    assert plant.truth().omega == pytest.approx(sc.n * cross(zc, f) * sc.dt / 86.89, rel=1e-12)


def _reference_step(sc, plant: Plant, wrenches) -> pymunk.Body:
    """The same step done the pymunk way: apply_force_at_world_point per agent plus body.torque."""
    t = plant.truth()
    space = pymunk.Space()
    body = pymunk.Body(t.mass, t.inertia)
    body.position, body.angle, body.velocity, body.angular_velocity = (t.x, t.y), t.angle, t.vc, t.omega
    space.add(body)
    for (fx, fy, tau), zi in zip(wrenches, t.zi, strict=True):
        body.apply_force_at_world_point((fx, fy), (t.pg[0] + zi[0], t.pg[1] + zi[1]))
        body.torque += tau
    space.step(sc.dt)
    return body


@pytest.mark.parametrize("seed", range(5))
def test_resultant_matches_pymunk_apply_force_at_world_point(seed):
    rng = np.random.default_rng(seed)
    sc = make(initial={"angle": float(rng.uniform(-4, 4)), "omega": float(rng.normal()), "v_c": [0.2, -0.1]})
    plant = Plant(sc)
    for _ in range(3):
        wrenches = [tuple(w) for w in rng.normal(0.0, 5.0, size=(sc.n, 3)).tolist()]
        ref = _reference_step(sc, plant, wrenches)
        plant.apply_and_step(wrenches)
        t = plant.truth()
        assert t.omega == pytest.approx(ref.angular_velocity, rel=1e-12, abs=1e-12)
        np.testing.assert_allclose(t.vc, tuple(ref.velocity), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose((t.x, t.y, t.angle), (*ref.position, ref.angle), rtol=1e-12, atol=1e-12)


class PymunkBeside(Plant):
    """The plant with a pymunk body (simulator.arms.load_body: the body the arms step) beside it, given the
    same resultant and the same load changes each tick, for a bit-for-bit comparison of the states."""

    def __init__(self, scenario) -> None:
        self.space, self.body = load_body(scenario)
        super().__init__(scenario)

    def _integrate(self, fx: float, fy: float, torque: float) -> None:
        super()._integrate(fx, fy, torque)
        self.body.force = (fx, fy)
        self.body.torque = torque
        self.space.step(self.dt)

    def _place(self, x: float, y: float) -> None:
        super()._place(x, y)
        if getattr(self, "effects", None) is not None:  # a load change (construction placed the body itself)
            self.body.position = (x, y)

    def change_load(self, mass: float, inertia: float, com_shift: np.ndarray) -> None:
        super().change_load(mass, inertia, com_shift)
        self.body.velocity = self.com_velocity
        self.body.mass = mass
        self.body.moment = inertia

    def states(self) -> tuple[str, str]:
        """repr of (position, velocity, angle, omega): the plant's and pymunk's (repr shows a zero's sign)."""
        t, b = self.truth(), self.body
        return repr(((t.x, t.y), t.vc, t.angle, t.omega)), repr((tuple(b.position), tuple(b.velocity), b.angle,
                                                                  b.angular_velocity))


ALL_EFFECTS = {
    "actuator_gain": 0.9, "external_force": [0.3, -0.2],
    "friction": {"viscous": 2.0, "coulomb": 1.5, "coulomb_speed": 0.02, "rotational": 0.5},
    "periodic_force": {"amplitude": 2.0, "period_s": 3.0, "direction_deg": 120.0},
    "sensor": {"delay": 0.03, "velocity_bias": [0.02, -0.01]},
    "load_changes": [{"t": 0.0, "mass": 55.0}, {"t": 40.0, "mass": 70.0, "com_offset": [-0.2, 0.1]},
                     {"t": 80.0, "mass": 60.0, "inertia": 80.0, "com_offset": [0.0, 0.0]}],
}  # fmt: skip


@pytest.mark.parametrize("plant", [{}, ALL_EFFECTS], ids=["nominal", "all-effects"])
@pytest.mark.parametrize("initial", [{"angle": 2.5}, {"angle": -0.4, "v_c": [0.3, -0.1], "omega": -0.2},
                                     {"position": [-0.0, -0.0], "angle": -0.0, "v_c": [-0.0, -0.0], "omega": -0.0}],
                         ids=["at-rest", "moving", "signed-zeros"])
def test_the_step_equals_pymunks_bit_for_bit_over_12000_ticks(plant, initial):
    """Zero and -0.0 wrenches on a load at rest keep signed zeros alive (pymunk's zero bias velocity and zero
    gravity turn -0.0 into 0.0); a load change moves the body through its setters."""
    sc = make(initial=initial, plant=plant)
    p = PymunkBeside(sc)
    rng = np.random.default_rng(7)
    ticks = 12_000
    for k in range(ticks):
        if k % 1000 < 100:
            w = np.full((sc.n, 3), -0.0 if k % 2 else 0.0)  # quiet: a zero force, of either sign
        else:
            w = rng.normal(0.0, 2.0, (sc.n, 3))
        p.apply_and_step(w)
        ours, theirs = p.states()
        assert ours == theirs, f"tick {k + 1}"
    assert p.tick == ticks


def test_signed_zeros_follow_pymunk():
    """A -0.0 state under a -0.0 resultant (not reachable through the wrench reduction, whose sums give +0.0):
    pymunk's zero gravity and zero bias velocity turn -0.0 into 0.0, and the step does the same."""
    p = PymunkBeside(make(initial={"position": [-0.0, -0.0], "angle": -0.0, "v_c": [-0.0, -0.0], "omega": -0.0}))
    assert p.states()[0] == p.states()[1]
    for f in ((-0.0, -0.0, -0.0), (0.0, -0.0, 0.0), (-0.0, 0.0, -0.0)):
        p._integrate(*f)
        assert p.states()[0] == p.states()[1]


def test_contact_velocities_follow_rigid_body_kinematics():
    sc = make(initial={"angle": 1.1, "v_c": [0.4, -0.3], "omega": 0.8})
    plant = Plant(sc)
    plant.apply_and_step([(1.0, 2.0, 0.5)] * sc.n)
    t = plant.truth()
    v = np.array(plant.velocities())
    body = pymunk.Body(t.mass, t.inertia)  # pymunk's own rigid-body kinematics at the plant's state
    body.position, body.angle, body.velocity, body.angular_velocity = (t.x, t.y), t.angle, t.vc, t.omega
    for i, zi in enumerate(t.zi):
        arm = np.array(zi) + np.array(t.zc)  # p_Ci - p_C
        np.testing.assert_allclose(v[i], np.array(t.vc) + t.omega * perp(arm), rtol=0, atol=1e-12)
        world = (t.x + arm[0], t.y + arm[1])
        np.testing.assert_allclose(v[i], tuple(body.velocity_at_world_point(world)), atol=1e-12)


def test_contact_velocities_match_finite_differences_of_positions():
    """Checks the perp sign against pymunk's own angle convention, not against our formula."""
    sc = make(initial={"angle": 0.2, "v_c": [0.1, 0.0], "omega": 1.3})
    plant = Plant(sc)

    def positions():
        t = plant.truth()
        return np.array(t.zi) + np.array(t.pg)

    p0 = positions()
    plant.apply_and_step([(0.0, 0.0, 0.0)] * sc.n)
    v1 = np.array(plant.velocities())
    fd = (positions() - p0) / sc.dt
    # positions rotate along a chord: error ~ omega^2 |r| dt / 2
    np.testing.assert_allclose(fd, v1, atol=1.3**2 * 2.5 * sc.dt)


def test_free_spin_preserves_rigidity_energy_and_momentum():
    sc = make(initial={"position": [0.5, 0.5], "angle": 0.4, "v_c": [0.3, -0.2], "omega": 2.0})
    plant = Plant(sc)
    t0 = plant.truth()
    z0 = np.array(t0.zi)
    d0 = np.linalg.norm(z0[:, None] - z0[None], axis=2)
    ke0 = kinetic_energy(t0)
    l0 = t0.mass * cross((t0.x, t0.y), t0.vc) + t0.inertia * t0.omega
    for _ in range(2000):
        plant.apply_and_step([(0.0, 0.0, 0.0)] * sc.n)
    t = plant.truth()
    z = np.array(t.zi)
    np.testing.assert_allclose(np.linalg.norm(z[:, None] - z[None], axis=2), d0, atol=1e-12)  # |z_ij| constant
    np.testing.assert_allclose(z.sum(axis=0), 0.0, atol=1e-12)
    assert math.hypot(*t.zc) == pytest.approx(math.hypot(*t0.zc), rel=1e-12)
    assert kinetic_energy(t) == pytest.approx(ke0, rel=1e-12)
    assert t.mass * cross((t.x, t.y), t.vc) + t.inertia * t.omega == pytest.approx(l0, rel=1e-9)
    assert t.angle == pytest.approx(0.4 + 2.0 * 2000 * sc.dt, rel=1e-12)


def test_truth_geometry_is_consistent():
    sc = make(initial={"angle": 2.5, "position": [3.0, 1.0]})
    plant = Plant(sc)
    t = plant.truth()
    r = np.array(contact_points_body(sc))
    c, s = math.cos(2.5), math.sin(2.5)
    world = r @ np.array([[c, s], [-s, c]]) + (3.0, 1.0)
    np.testing.assert_allclose(t.pg, world.mean(axis=0), atol=1e-12)
    np.testing.assert_allclose(np.array(t.zi), world - world.mean(axis=0), atol=1e-12)
    np.testing.assert_allclose(np.array(t.pg) - (t.x, t.y), t.zc, atol=1e-12)


def test_default_inertia_is_uniform_lamina_about_offset_com():
    sc = scenario_from_dict({"load": {"width": 4.0, "height": 2.2, "mass": 50.0, "com_offset": [0.3, -0.2]}})
    expected = 50.0 * (4.0**2 + 2.2**2) / 12 + 50.0 * (0.3**2 + 0.2**2)
    assert load_inertia(sc) == pytest.approx(expected, rel=1e-12)
    assert Plant(sc).truth().inertia == pytest.approx(expected, rel=1e-12)


# --- sensor --------------------------------------------------------------------------------------


def test_measurement_noise_has_configured_std():
    sigma = 0.3
    sc = make(sigma=sigma, initial={"omega": 1.0})
    plant = Plant(sc)
    rng = sensor_rng(3)
    errs = []
    for _ in range(2000):
        errs.append(np.array(plant.measure(rng)) - np.array(plant.velocities()))
        plant.apply_and_step([(0.0, 0.0, 0.0)] * sc.n)
    e = np.concatenate(errs)  # 20000 x 2 samples
    count = e.size
    # std of the sample std is sigma / sqrt(2 N): 5 standard errors
    assert abs(e.std() - sigma) < 5 * sigma / math.sqrt(2 * count)
    assert abs(e.mean()) < 5 * sigma / math.sqrt(count)
    assert abs(np.corrcoef(e[:, 0], e[:, 1])[0, 1]) < 5 / math.sqrt(count / 2)


def test_same_seed_same_measurements_and_streams_are_isolated():
    def run(seed):
        sc = make(initial={"omega": 0.5})
        plant, rng = Plant(sc), sensor_rng(seed)
        out = []
        for _ in range(50):
            out.append(plant.measure(rng).tolist())
            plant.apply_and_step([(0.1, 0.0, 0.01)] * sc.n)
        return out

    a = run(11)
    saved = np.random.get_state()
    try:
        np.random.seed(0)  # the global RNG must play no part
        np.random.random(100)
        assert run(11) == a
    finally:
        np.random.set_state(saved)  # leave it as found (the autouse fixture checks)
    assert run(12) != a


def test_zero_noise_measures_truth():
    sc = make(sigma=0.0, initial={"omega": 0.5})
    plant = Plant(sc)
    assert plant.measure(sensor_rng(0)).tolist() == list(map(list, plant.velocities()))


@pytest.mark.parametrize(
    "wrenches",
    [
        [(0.0, 0.0, 0.0)] * 9,
        [(0.0, 0.0, 0.0)] * 11,
        [(0.0, 0.0)] * 10,
        [(0.0, 0.0, 0.0)] * 9 + [(0.0, 0.0)],
        [(0.0, 0.0, 0.0)] * 9 + [(math.nan, 0.0, 0.0)],
        [(0.0, 0.0, 0.0)] * 9 + [(0.0, 0.0, math.inf)],
        [(0.0, 0.0, 0.0)] * 9 + [("x", 0.0, 0.0)],
        [(0.0, 0.0, 0.0)] * 9 + [(None, 0.0, 0.0)],
        [(1e308, 0.0, 0.0)] * 10,
        [],
    ],
    ids=["short", "long", "pairs", "ragged", "nan", "inf", "string", "none", "overflow", "empty"],
)
def test_bad_wrenches_raise_and_leave_the_state_alone(wrenches):
    sc = make(initial={"omega": 0.5})
    plant = Plant(sc)
    before = plant.truth()
    with pytest.raises(ValueError):
        plant.apply_and_step(wrenches)
    assert plant.truth() == before


def test_numpy_wrenches_are_accepted():
    sc = make()
    plant = Plant(sc)
    plant.apply_and_step(np.zeros((sc.n, 3)))
    assert plant.tick == 1


# --- geometry ------------------------------------------------------------------------------------


def _polygon_scenario(vertices, n, start, offset, layout="perimeter", points=None):
    data = {
        "n": n,
        "load": {"shape": "polygon", "vertices": [list(v) for v in vertices], "com_offset": list(offset)},
        "contacts": {"layout": layout, "start": start},
    }
    if points is not None:
        data["contacts"]["points"] = points
    return scenario_from_dict(data)


@st.composite
def convex_polygons(draw):
    """Counter-clockwise convex polygons: points on an ellipse at sorted, well-separated angles."""
    k = draw(st.integers(3, 9))
    gaps = np.array(draw(st.lists(st.floats(0.2, 1.0), min_size=k, max_size=k)))
    angles = np.cumsum(gaps / gaps.sum() * 2 * math.pi)
    a, b = draw(st.floats(0.5, 5.0)), draw(st.floats(0.5, 5.0))
    cx, cy = draw(st.floats(-3, 3)), draw(st.floats(-3, 3))
    return [(cx + a * math.cos(t), cy + b * math.sin(t)) for t in angles]


# The CoM offset as fractions of the load's size: a rigid load's CoM lies inside its outline (the
# scenario refuses one outside), so the offset scales with the load.
fractions = st.tuples(st.floats(-0.45, 0.45), st.floats(-0.45, 0.45))


@settings(max_examples=150, deadline=None)
@given(
    w=st.floats(0.1, 20.0), h=st.floats(0.1, 20.0), n=st.integers(2, 60), start=st.floats(0.0, 0.999), frac=fractions
)
def test_rectangle_contacts_lie_on_outline_evenly_spaced(w, h, n, start, frac):
    off = (frac[0] * w, frac[1] * h)
    sc = scenario_from_dict(
        {"n": n, "load": {"width": w, "height": h, "com_offset": list(off)}, "contacts": {"start": start}}
    )
    outline = np.array(load_polygon_body(sc))
    pts = np.array(contact_points_body(sc))
    assert pts.shape == (n, 2)
    assert geometry.distance_to_outline(pts, outline).max() < 1e-9 * (w + h)
    np.testing.assert_allclose(geometry.centroid(outline), -np.array(off), atol=1e-9 * (w + h))
    # the first contact sits at fraction `start` of the outline from the bottom-left corner
    s0 = start * 2 * (w + h)
    first = np.array([-w / 2 + min(s0, w), -h / 2 + min(max(s0 - w, 0.0), h)]) if s0 <= w + h else None
    if first is not None:
        np.testing.assert_allclose(pts[0], first - off, atol=1e-9 * (w + h))


@settings(max_examples=150, deadline=None)
@given(poly=convex_polygons(), n=st.integers(2, 40), start=st.floats(0.0, 0.999), vertex=st.integers(0, 8),
       towards=st.floats(0.0, 0.9))
def test_polygon_contacts_and_centroid(poly, n, start, vertex, towards):
    # a point between the area centroid and a vertex: inside the convex outline
    off = tuple(towards * (np.array(poly[vertex % len(poly)]) - geometry.centroid(np.array(poly))))
    sc = _polygon_scenario(poly, n, start, off)
    outline = np.array(load_polygon_body(sc))
    pts = np.array(contact_points_body(sc))
    scale = np.abs(outline).max()
    assert geometry.distance_to_outline(pts, outline).max() < 1e-9 * scale
    # the body frame is re-centred on the area centroid; the CoM sits at com_offset from it
    np.testing.assert_allclose(geometry.centroid(outline), -np.array(off), atol=1e-9 * scale)
    np.testing.assert_allclose(outline + off, np.array(poly) - geometry.centroid(poly), atol=1e-9 * scale)
    # evenly spaced in arc length: every contact advances P/n along the outline
    arc = _arc_positions(pts + off, outline + off)
    gaps = np.diff(np.concatenate((arc, arc[:1] + _perimeter(outline))))
    gaps = np.mod(gaps, _perimeter(outline))
    np.testing.assert_allclose(gaps, _perimeter(outline) / n, atol=1e-8 * scale)
    # default inertia: uniform lamina about the centroid (cf. pymunk) moved to the CoM
    j = pymunk.moment_for_poly(1.0, [tuple(v) for v in outline + off]) + (off[0] ** 2 + off[1] ** 2)
    assert load_inertia(sc) == pytest.approx(sc.load.mass * j, rel=1e-9)


def _perimeter(outline: np.ndarray) -> float:
    return float(np.sum(np.linalg.norm(np.roll(outline, -1, axis=0) - outline, axis=1)))


def _arc_positions(points: np.ndarray, outline: np.ndarray) -> np.ndarray:
    """Arc length from vertex 0 of each point's projection on its nearest edge."""
    seg = np.roll(outline, -1, axis=0) - outline
    lengths = np.linalg.norm(seg, axis=1)
    cum = np.concatenate(([0.0], np.cumsum(lengths)))
    out = []
    for p in points:
        t = np.clip(np.sum((p - outline) * seg, axis=1) / lengths**2, 0, 1)
        d = np.linalg.norm(outline + t[:, None] * seg - p, axis=1)
        k = int(np.argmin(d))
        out.append(cum[k] + t[k] * lengths[k])
    return np.array(out)


def test_explicit_points_are_relative_to_the_centroid():
    pts = [[-1.0, -1.1], [1.0, -1.1], [2.0, 0.0], [0.0, 1.1]]
    sc = scenario_from_dict(
        {"n": 4, "load": {"com_offset": [0.3, -0.2]}, "contacts": {"layout": "explicit", "points": pts}}
    )
    np.testing.assert_allclose(contact_points_body(sc), np.array(pts) - (0.3, -0.2))


def test_paper_fig4_geometry(scenarios_dir):
    from config.loader import load_scenario

    sc = load_scenario(scenarios_dir / "paper-fig4.toml")
    pts = np.array(contact_points_body(sc)) + sc.load.com_offset  # about the centroid
    corners = geometry.rectangle(4.0, 2.2)
    assert np.min(np.linalg.norm(pts[:, None] - corners[None], axis=2)) > 0.3
    assert np.allclose(Plant(sc).truth().zc, (-0.3, 0.2))
    d = [np.linalg.norm(pts[i] - pts[j]) for i, j in sc.edges()]
    assert min(d) > 0.8
