"""I&I speed observer (paper 004): exact constant-inertia case, convergence, property checks, scenario."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from agents.speed_observer import (
    ClosedForm,
    ELModel,
    Gains,
    PropertyViolation,
    SpeedObserver,
    check_properties,
    plant_rhs,
    two_link,
)

ROOT = Path(__file__).resolve().parent.parent
PAPER = dict(c1=0.9698, c2=0.1575, c3=0.264, c4=1.74, c5=0.44)
M0 = np.array([[2.0, 0.5], [0.5, 1.0]])


def _const_model(Mc: np.ndarray = M0) -> ELModel:
    lam = np.linalg.eigvalsh(Mc)
    return ELModel(
        2,
        M=lambda q: np.broadcast_to(Mc, np.shape(q)[:-1] + (2, 2)),
        C=lambda q, x: np.zeros(np.broadcast_shapes(np.shape(q), np.shape(x))[:-1] + (2, 2)),
        G=lambda q: np.zeros(np.shape(q)),
        k_m=float(lam[0]), k_M=float(lam[1]), k_c=0.0, q_low=(-5.0, -5.0), q_high=(5.0, 5.0),
    )


def _closed_form(k1: float) -> ClosedForm:
    H = k1 * np.linalg.inv(M0)  # C = 0: H constant, beta = H y exactly
    zero = lambda y, sy, sx: np.zeros((2, 2))  # noqa: E731
    return ClosedForm(beta=lambda y, sy, sx: H @ y, dbeta_dy=lambda y, sy, sx: H, dbeta_dsy=zero, dbeta_dsx=zero)


def _integrate(ob: SpeedObserver, y0, x0, obs0, t_end, u=(0.0, 0.0), rtol=1e-10, atol=1e-12, t_eval=None):
    u = np.asarray(u, float)

    def f(_t, z):
        y, x = z[:2], z[2:4]
        dy, dx = plant_rhs(ob.model, y, x, u)
        return np.concatenate([dy, dx, ob.rhs(z[4:], y, u)])

    z0 = np.concatenate([y0, x0, obs0])
    sol = solve_ivp(f, (0, t_end), z0, method="DOP853", rtol=rtol, atol=atol, t_eval=t_eval)
    assert sol.success, sol.message
    return sol


@pytest.mark.parametrize("closed", [False, True], ids=["quadrature", "closed-form"])
def test_constant_inertia_matches_exact_solution(closed):
    """M const, C = 0: z' = -k1 M^-1 z, so z(t) = expm(-k1 M^-1 t) z0, and (Delta = 0) r(t) = c_r + (r0 - c_r) exp(-k1 t / (4 k_M))."""
    g = Gains(k1=10.0, k2=3.0, k3=5.0, c_r=1e-3)
    ob = SpeedObserver(_const_model(), g, nodes=4, closed_form=_closed_form(g.k1) if closed else None)
    y0, x0 = np.array([0.3, -0.2]), np.array([1.0, 2.0])
    obs0 = ob.initial([5.0, -7.0], [1.0, 1.0], [0.0, 3.0], 0.5)
    ts = np.linspace(0, 0.5, 11)
    sol = _integrate(ob, y0, x0, obs0, 0.5, u=(0.4, -0.1), t_eval=ts)
    z0 = ob.estimate(obs0, y0) - x0
    for k, t in enumerate(ts):
        z = ob.estimate(sol.y[4:, k], sol.y[:2, k]) - sol.y[2:4, k]
        assert np.allclose(z, expm(-g.k1 * np.linalg.inv(M0) * t) @ z0, atol=1e-8), (t, z)
        r_exact = g.c_r + (0.5 - g.c_r) * math.exp(-g.k1 * t / (4 * ob.model.k_M))
        assert sol.y[-1, k] == pytest.approx(r_exact, rel=1e-8)
    # the quadrature beta is exact for this linear beta
    b = ob.beta_terms(np.array([2.0, -3.0]), np.array([0.1, 0.4]), np.array([1.0, 1.0]))
    assert np.allclose(b[0], g.k1 * np.linalg.solve(M0, [2.0, -3.0]))
    assert np.allclose(b[1], g.k1 * np.linalg.inv(M0)) and np.allclose(b[2], 0) and np.allclose(b[3], 0)


def test_partials_match_finite_differences_of_beta():
    """(13)-(15) from the quadrature agree with finite differences of the quadrature beta (12)."""
    ob = SpeedObserver(two_link(**PAPER), nodes=16)
    y, sy, sx = np.array([0.7, -9.1]), np.array([1.2, 0.3]), np.array([3.0, -8.0])
    beta, dy, dsy, dsx = ob.beta_terms(y, sy, sx)
    h = 1e-6
    for arg, ana in ((0, dy), (1, dsy), (2, dsx)):
        for k in range(2):
            p, m = [y.copy(), sy.copy(), sx.copy()], [y.copy(), sy.copy(), sx.copy()]
            p[arg][k] += h
            m[arg][k] -= h
            fd = (ob.beta_terms(*p)[0] - ob.beta_terms(*m)[0]) / (2 * h)
            assert np.allclose(fd, ana[:, k], atol=1e-6), (arg, k, fd, ana[:, k])


def test_periodic_split_equals_plain_quadrature():
    """Splitting whole periods off (trapezoid) gives the same beta as a fine composite rule."""
    m = two_link(**PAPER)
    ob = SpeedObserver(m, nodes=16)
    aper = SpeedObserver(ELModel(2, m.M, m.C, m.G, m.k_m, m.k_M, m.k_c, m.q_low, m.q_high), nodes=200, check=False)
    y, sy, sx = np.array([13.0, -21.0]), np.array([0.2, 1.1]), np.array([2.0, 5.0])
    assert np.allclose(ob.beta_terms(y, sy, sx)[0], aper.beta_terms(y, sy, sx)[0], rtol=1e-9, atol=1e-9)


def test_two_link_paper_scenario_short_run():
    """Table I/II start: |x_hat - x| and |s_x - x| shrink by > 100x within 0.3 s, r stays bounded."""
    ob = SpeedObserver(two_link(**PAPER), Gains(40, 8, 25, 1e-3), nodes=8)
    y0, x0 = np.zeros(2), np.array([-0.29, 6.66])
    obs0 = ob.initial([-8.45, 68.33], [1, 2], [10, 20], 0.1)
    sol = _integrate(ob, y0, x0, obs0, 0.3, rtol=1e-6, atol=1e-8, t_eval=[0.0, 0.3])
    e0 = np.linalg.norm(ob.estimate(obs0, y0) - x0)
    e1 = np.linalg.norm(ob.estimate(sol.y[4:, -1], sol.y[:2, -1]) - sol.y[2:4, -1])
    assert e1 < e0 / 100
    assert np.linalg.norm(sol.y[8:10, -1] - sol.y[2:4, -1]) < np.linalg.norm([10.29, 13.34]) / 100
    assert 1e-3 <= sol.y[-1, -1] < 0.2


def _far_start(seed: int):
    rng = np.random.default_rng(seed)
    y0 = rng.uniform(-math.pi, math.pi, 2)
    x0 = rng.uniform(-8, 8, 2)
    return y0, x0, rng.uniform(-100, 100, 2), y0 + rng.uniform(-5, 5, 2), rng.uniform(-100, 100, 2), rng.uniform(0.01, 0.5)


def _converges(seed: int, t_end: float) -> None:
    ob = SpeedObserver(two_link(**PAPER), Gains(40, 8, 25, 1e-3), nodes=8)
    y0, x0, xi, sy, sx, r0 = _far_start(seed)
    obs0 = ob.initial(xi, sy, sx, r0)
    sol = _integrate(ob, y0, x0, obs0, t_end, rtol=1e-7, atol=1e-9)
    r = sol.y[-1]
    obs1, y1, x1 = sol.y[4:, -1], sol.y[:2, -1], sol.y[2:4, -1]
    e0 = np.linalg.norm(ob.estimate(obs0, y0) - x0)
    assert np.linalg.norm(ob.estimate(obs1, y1) - x1) < 1e-3 * max(e0, 1.0)
    assert np.linalg.norm(obs1[4:6] - x1) < 1e-3 * np.linalg.norm(sx - x0)
    assert np.isfinite(r).all() and r.min() >= 1e-3 * (1 - 1e-9) and r.max() < 50


@pytest.mark.parametrize("seed", [1, 2])
def test_global_convergence_from_far_initial_conditions(seed):
    _converges(seed, 0.6)


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(3, 11))
def test_global_convergence_grid_slow(seed):
    _converges(seed, 1.5)


def test_sampled_step_tracks_continuous_observer():
    """The sampled RK4 step (agents with encoders only) converges like the continuous-time observer."""
    ob = SpeedObserver(two_link(**PAPER), nodes=8)
    ts = np.linspace(0, 0.4, 401)  # 1 kHz encoder
    y0, x0 = np.zeros(2), np.array([-0.29, 6.66])
    obs0 = ob.initial([-8.45, 68.33], [1, 2], [10, 20], 0.1)
    plant = _integrate(ob, y0, x0, obs0, 0.4, rtol=1e-9, atol=1e-11, t_eval=ts)
    st = ob.start(y0, [-8.45, 68.33], [1, 2], [10, 20], 0.1)
    for k in range(1, ts.size):
        st = ob.step(st, plant.y[:2, k], np.zeros(2), ts[k] - ts[k - 1])
    x_true = plant.y[2:4, -1]
    assert np.linalg.norm(ob.estimate(st.vector(), st.y) - x_true) < 1e-3
    assert np.allclose(st.vector(), plant.y[4:, -1], atol=1e-3)


# -- property violations ---------------------------------------------------------------------------


def _variant(**kw) -> ELModel:
    m = two_link(**PAPER)
    fields = dict(n=2, M=m.M, C=m.C, G=m.G, k_m=m.k_m, k_M=m.k_M, k_c=m.k_c, q_low=m.q_low, q_high=m.q_high, periods=m.periods)
    fields.update(kw)
    return ELModel(**fields)


def _paper_printed_C(q, x):
    """eq. (56b) as extracted (-s x2 upper right, +s x1 lower left, s = sin(y1 - y2)): -C of the Christoffel C."""
    return -two_link(**PAPER).C(q, x)


@pytest.mark.parametrize(
    "kw, prop",
    [
        (dict(C=_paper_printed_C), "P5"),
        (dict(k_m=0.3), "P1 (k_m I <= M(q))"),
        (dict(k_M=0.9), "P1 (M(q) <= k_I"),
        (dict(k_c=0.1), "P4"),
        (dict(C=lambda q, x: np.einsum("...i,ij->...ij", np.asarray(x)[..., :1] * np.ones(2), [[0, 1], [-1, 0]])), "P2"),
        (dict(C=lambda q, x: two_link(**PAPER).C(q, x) * np.linalg.norm(x, axis=-1)[..., None, None]), "P"),
        (dict(M=lambda q: two_link(**PAPER).M(q) + np.array([[0, 0.01], [0, 0]])), "P1 (M symmetric)"),
    ],
    ids=["coriolis-sign", "k_m", "k_M", "k_c", "P2", "nonlinear-C", "asymmetric-M"],
)
def test_property_violations_refused(kw, prop):
    with pytest.raises(PropertyViolation) as exc:
        SpeedObserver(_variant(**kw))
    msg = str(exc.value)
    assert msg.startswith(prop.replace("k_I", "k_M I")) and "violated at q=" in msg, msg


def test_coriolis_sign_message_names_property_and_point():
    with pytest.raises(PropertyViolation, match=r"P5 \(M_dot = C \+ C\^T\) violated at q=\[.*\]: along q_dot="):
        check_properties(_variant(C=_paper_printed_C), np.random.default_rng(0))


def test_property_residuals_of_the_two_link_model():
    res = check_properties(two_link(**PAPER), np.random.default_rng(3), samples=64)
    assert res["P2"] < 1e-12 and res["P3"] < 1e-12 and res["P5"] < 1e-8 and res["skew_Mdot_minus_2C"] < 1e-8
    assert res["P4_ratio"] <= PAPER["c2"]


# -- scenario --------------------------------------------------------------------------------------


def test_bundled_scenario_loads_with_tables_i_ii_and_rejects_unknown_keys():
    from coload.runs.observer_run import ObserverScenarioError, load_observer_scenario

    sc = load_observer_scenario(ROOT / "config/observers/ii-two-link.toml")
    assert sc.observer.k1 == 40 and sc.observer.k2 == 8 and sc.observer.k3 == 25 and sc.observer.c_r == 0.001
    assert sc.initial.xi == [-8.45, 68.33] and sc.initial.x == [-0.29, 6.66] and sc.initial.r == 0.1
    sc2 = load_observer_scenario(ROOT / "config/observers/ii-two-link.toml", ["observer.k1=50", "run.t_end=0.5"])
    assert sc2.observer.k1 == 50 and sc2.run.t_end == 0.5
    with pytest.raises(ObserverScenarioError, match="observer.kk1"):
        load_observer_scenario(ROOT / "config/observers/ii-two-link.toml", ["observer.kk1=5"])
    with pytest.raises(ObserverScenarioError, match="observer.k1"):
        load_observer_scenario(ROOT / "config/observers/ii-two-link.toml", ["observer.k1=3"])


def test_run_observer_cli_writes_png_and_summary(tmp_path):
    from coload.runs.observer_run import run_observer_cli

    s = run_observer_cli(ROOT / "config/observers/ii-two-link.toml", tmp_path,
                         ["run.t_end=0.3", "run.samples=61", "run.rtol=1e-6", "observer.nodes=8"])
    assert (tmp_path / "observer.png").stat().st_size > 10_000 and (tmp_path / "summary.json").exists()
    assert s["metrics"]["s_x-x"]["t_5pct"] is not None and s["metrics"]["r"]["max"] < 1
    # the run directory's layout: the resolved scenario reloads as itself, the series as recorded
    from coload.rundir.series import read_series
    from coload.runs.observer_run import load_observer_scenario, simulate

    sc = load_observer_scenario(tmp_path / "run.toml")
    assert sc.run.t_end == 0.3 and sc.run.samples == 61 and sc.observer.nodes == 8
    t, cols = read_series(tmp_path / "series.csv")
    res = simulate(sc)
    np.testing.assert_array_equal(t, res["t"])
    np.testing.assert_array_equal(cols["x_hat"], res["x_hat"])
    assert s["final"]["x_hat"] == cols["x_hat"][-1].tolist()


def test_cli_names_a_bad_file_or_field(tmp_path, capsys):
    from coload.cli import main

    scenario = str(ROOT / "config/observers/ii-two-link.toml")
    assert main(["observer", "run", str(tmp_path / "nope.toml"), "--out", str(tmp_path / "o")]) == 2
    assert "nope.toml" in capsys.readouterr().err
    assert main(["observer", "run", scenario, "--out", str(tmp_path / "o"), "--set", "observer.k1=3"]) == 2
    assert "observer.k1" in capsys.readouterr().err
    bad = tmp_path / "bad.toml"
    bad.write_text("[observer]\nk1 = \n")
    assert main(["observer", "run", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "bad.toml" in err and "line 2" in err
    assert not (tmp_path / "o").exists()
