"""The dynamical phase (agents/dynamic_phase.py): consensus, stage agreement, and the closed loop against truth.

The closed-loop checks run the whole of Algorithm 1 / 2 on the in-process engine against the plant's
truth; tolerances are the issue's targets with the spread measured over seeds (docs/dynamics.md).
"""

from __future__ import annotations

import json
import math
import random

import numpy as np
import pytest
from conftest import ROOT as REPO
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from agents.consensus import FlowAverage
from agents.rigid_filter import RigidEKF, fit_rotation
from agents.stage_agreement import StageBarrier
from coload.runs.engine import run_inproc
from config.agent_params import DynamicsSpec
from config.loader import load_scenario
from net import vocabulary as D
from simulator.plant import Plant

FIG4 = REPO / "config" / "scenarios" / "paper-fig4.toml"
FIG9 = REPO / "config" / "scenarios" / "paper-fig9.toml"


def _connected_graph(n: int, extra: list[tuple[int, int]], rng: random.Random) -> list[list[int]]:
    """A random spanning tree plus the given extra edges."""
    nbrs: list[set[int]] = [set() for _ in range(n)]
    for i in range(1, n):
        j = rng.randrange(i)
        nbrs[i].add(j)
        nbrs[j].add(i)
    for a, b in extra:
        a, b = a % n, b % n
        if a != b:
            nbrs[a].add(b)
            nbrs[b].add(a)
    return [sorted(s) for s in nbrs]


def _run_flow(nbrs, inputs, ticks, loss, rng, loss_until):
    """Synchronous rounds with a one-tick exchange; each directed message lost with prob ``loss``."""
    n = len(nbrs)
    avgs = [FlowAverage(nbrs[i], 1) for i in range(n)]
    msgs: list[tuple[list[float], dict[int, list[float]]] | None] = [None] * n
    means = []
    for k in range(ticks):
        for i in range(n):
            for j in nbrs[i]:
                if msgs[j] is not None and not (k < loss_until and rng.random() < loss):
                    xj, fl = msgs[j]
                    avgs[i].receive(j, xj, fl[i], len(nbrs[j]))
            avgs[i].u[0] = inputs(k, i)
            avgs[i].update()
        msgs = [(list(a.x), {j: list(a.flow[j]) for j in nbrs[i]}) for i, a in enumerate(avgs)]
        means.append((sum(a.x[0] for a in avgs) / n, sum(a.u[0] for a in avgs) / n))
    return avgs, means


@settings(max_examples=40, deadline=None)
@given(
    n=st.integers(2, 12),
    extra=st.lists(st.tuples(st.integers(0, 11), st.integers(0, 11)), max_size=10),
    seed=st.integers(0, 2**16),
)
def test_flow_average_keeps_the_mean_and_converges(n, extra, seed):
    rng = random.Random(seed)
    nbrs = _connected_graph(n, extra, rng)
    vals = [rng.uniform(-10, 10) for _ in range(n)]
    avgs, means = _run_flow(nbrs, lambda k, i: vals[i] + (3.0 if k >= 40 else 0.0), 40 * n + 400, 0.0, rng, 0)
    for mx, mu in means:  # lossless: the network mean is exact at every tick, also across the input step
        assert mx == pytest.approx(mu, abs=1e-9)
    target = sum(vals) / n + 3.0
    for a in avgs:
        assert a.x[0] == pytest.approx(target, abs=1e-6)


@settings(max_examples=25, deadline=None)
@given(n=st.integers(3, 10), seed=st.integers(0, 2**16), loss=st.floats(0.05, 0.5))
def test_flow_average_recovers_the_exact_mean_after_losses(n, seed, loss):
    """Lost messages disturb the mean only until the next exchange on that edge, never for good."""
    rng = random.Random(seed)
    nbrs = _connected_graph(n, [], rng)
    vals = [rng.uniform(-5, 5) for _ in range(n)]
    avgs, means = _run_flow(nbrs, lambda k, i: vals[i], 300 + 60 * n * n, loss, rng, 200)
    target = sum(vals) / n
    mx, mu = means[-1]
    assert mx == pytest.approx(mu, abs=1e-9)
    for a in avgs:
        assert a.x[0] == pytest.approx(target, abs=1e-6)


@settings(max_examples=40, deadline=None)
@given(
    n=st.integers(2, 70),
    seed=st.integers(0, 2**16),
    loss=st.floats(0.0, 0.6),
)
def test_stage_barrier_agrees_on_one_switch_tick(n, seed, loss):
    """Every agent computes the same switch tick = last ready tick + horizon (also n > 50: two mask
    floats); with lossy flooding some learn it late, none computes a different one."""
    rng = random.Random(seed)
    nbrs = _connected_graph(n, [(rng.randrange(n), rng.randrange(n)) for _ in range(n // 3)], rng)
    horizon = 100
    bars = [StageBarrier(i, n, horizon) for i in range(n)]
    ready = [rng.randrange(0, 50) for _ in range(n)]
    learnt = [-1] * n
    wire: list[dict[str, float]] = [{} for _ in range(n)]
    for k in range(60 + 40 * n):
        for i in range(n):
            for j in nbrs[i]:
                if wire[j] and rng.random() >= loss:
                    bars[i].merge(*bars[i].decode(wire[j]))
            if k >= ready[i]:
                bars[i].set_ready(k)
            if bars[i].switch >= 0 and learnt[i] < 0:
                learnt[i] = k
        for i in range(n):
            wire[i] = bars[i].encode()
    expect = max(ready) + horizon
    assert [b.switch for b in bars] == [expect] * n
    assert all(0 <= t for t in learnt)
    if loss == 0.0 and n <= 40:
        # diameter <= n - 1 ticks of flooding: everybody knows well before the switch
        assert max(learnt) <= max(ready) + n


def test_stage_barrier_rejects_a_malformed_mask():
    b = StageBarrier(0, 3, 10)
    for bad in ({"B0": -1.0, "Bt": 0.0, "Bs": -1.0}, {"B0": 0.5, "Bt": 0.0, "Bs": -1.0}, {"Bt": 0.0, "Bs": -1.0}):
        with pytest.raises((ValueError, KeyError)):
            b.decode(bad)


def test_rigid_ekf_recovers_mass_and_inertia_of_a_noise_free_body():
    """The filter's model is the plant's discrete step: on exact data it converges to the truth."""
    dt, m, J = 0.01, 50.0, 86.89
    q = complex(1.2, -0.7)
    vc = 0.3 + 0.1j
    om = 1.5
    kf = RigidEKF(0.01, DynamicsSpec(kf_angle_walk=0.0, kf_v_walk=0.0, omega_walk=0.0, u_bias_walk=0.0), False)
    kf.start(vc + om * 1j * q + 0.05, q + 0.2, om + 0.1)
    for k in range(6000):
        force = 20.0 * complex(math.cos(0.5), math.sin(0.5)) * (1 if (k // 300) % 2 == 0 else -1)
        torque = 10.0 * math.sin(2 * math.pi * k / 500)
        v = vc + om * 1j * q
        kf.update(v, om, 1e-4)
        kf.predict(force, torque, dt)
        q *= complex(math.cos(om * dt), math.sin(om * dt))
        vc += dt * force / m
        om += dt * torque / J
    assert 1.0 / kf.mu == pytest.approx(m, rel=1e-4)
    assert 1.0 / kf.iota == pytest.approx(J, rel=1e-4)
    assert abs(kf.q - q) < 1e-4


def _estimates(run_dir):
    import csv

    with open(run_dir / "estimates.csv") as f:
        rows = list(csv.DictReader(f))
    return [{k: v or "nan" for k, v in r.items()} for r in rows]  # an empty cell: no value


@pytest.mark.slow
def test_algorithm_1_on_the_reference_scenario(tmp_path):
    """paper-fig4 (n = 10 line, sigma 0.3): all six quantities, stages switched together, done < 200 s."""
    sc = load_scenario(FIG4, ["duration=95", "seed=2"])
    summary = run_inproc(sc, tmp_path)
    err = summary["errors"]
    # issue 3: median J <= 0.7 %, p90 <= 1.4 %, m <= 0.3 %; measured over 10 seeds J 0.07 % median,
    # 0.21 % max, m 0.08 % / 0.32 % (docs/dynamics.md); this seed J 0.02 %, m 0.03 %
    assert err["J_rel"] <= 0.005
    assert err["m_rel"] <= 0.005
    # every agent's own J before the averaging (filter sd ~0.5 %): a torque model that is off after the
    # J stage's sign flip put single agents 2-7 % off while the average still looked fine
    assert max(abs(e) for e in err["J_local_rel_per_agent"]) <= 0.015
    assert err["zC_rms"] <= 0.06
    assert err["vC_rms"] <= 0.1
    assert err["finished_s"] is not None and err["finished_s"] <= 95.0
    # every filter stayed consistent: the lock check must not restart any (docs/high-noise.md)
    assert err["filter_restarts"] == 0
    rows = _estimates(tmp_path)
    by_t: dict[str, set[str]] = {}
    for r in rows:
        by_t.setdefault(r["t"], set()).add(r["phase"])
    # lockstep, no faults: the agreed switch ticks are the same for everyone, so at every recorded
    # time every agent is in the same stage (the spin-up -> kinematic entry is local, excluded)
    mixed = [t for t, ph in by_t.items() if len(ph) > 1 and float(t) > 7.0]
    assert mixed == []
    last = [r for r in rows if r["t"] == rows[-1]["t"]]
    assert {r["phase"] for r in last} == {str(float(D.DONE))}
    for r in last:
        for key in ("J", "m", "zc_x", "zc_y", "vc_x", "vc_y", "zi_x", "omega"):
            assert math.isfinite(float(r[key])), key
    on_disk = json.loads((tmp_path / "summary.json").read_text())
    assert on_disk["errors"]["J_rel"] == err["J_rel"]


@pytest.mark.slow
def test_algorithm_1_agrees_on_stages_under_loss(tmp_path):
    """20 % Bernoulli loss on every link: the team still finishes, every agent holds J and m."""
    sc = load_scenario(FIG4, ["duration=100", "seed=2", 'link.loss.model="bernoulli"', "link.loss.p=0.2"])
    summary = run_inproc(sc, tmp_path)
    err = summary["errors"]
    assert err["finished_s"] is not None
    assert err["J_rel"] <= 0.03
    assert err["m_rel"] <= 0.01


@pytest.mark.long  # a minute: out of CI's budget (test_control_law drives Algorithm 2 in CI)
def test_algorithm_2_follows_a_load_change(tmp_path):
    """paper-fig9: m and J step down 20 % at t = 100 s; the background estimates follow within 5 %."""
    sc = load_scenario(FIG9, ["duration=170"])
    run_inproc(sc, tmp_path)
    rows = _estimates(tmp_path)
    t = np.array([float(r["t"]) for r in rows])
    J = np.array([float(r["J"]) for r in rows])
    m = np.array([float(r["m"]) for r in rows])
    before = (t > 85) & (t < 100)
    after = t > 155
    assert np.nanmedian(np.abs(m[before] / 50.0 - 1)) < 0.05
    assert np.nanmedian(np.abs(J[before] / 86.89 - 1)) < 0.05
    assert np.nanmedian(np.abs(m[after] / 40.0 - 1)) < 0.05
    assert np.nanmedian(np.abs(J[after] / 69.5 - 1)) < 0.05


def test_rigid_ekf_matches_the_plant_step_and_finds_J_under_the_j_stage_forces():
    """The filter on the pymunk plant's own noise-free contact velocity, under Result 5's forces
    f_i = k_z s(t) z_i^perp (tau_i = 0) after a common-force stage: the torque it is given is the exact
    sum_i q_i x f_i, so J, m and q come out to the integrator's precision. A model that rotates q by the
    new omega (pymunk moves the pose with the old one) fails here (m 0.4 % off, measured)."""
    sc = load_scenario(FIG4, ["noise.sigma_v=0.0", "initial.omega=1.5"])
    plant = Plant(sc)
    n, dt = sc.n, sc.dt
    kf = RigidEKF(0.01, DynamicsSpec(kf_angle_walk=0.0, kf_v_walk=0.0, omega_walk=0.0), False)
    tr = plant.truth()
    q0 = complex(*tr.zi[0]) + complex(*tr.zc)
    kf.start(complex(*plant.velocities()[0]) + 0.05, q0 + 0.3, tr.omega + 0.05)
    for k in range(6000):
        tr = plant.truth()
        q = [complex(*z) + complex(*tr.zc) for z in tr.zi]
        kf.update(complex(*plant.velocities()[0]), math.nan, 0.0)
        if k == 4000:
            kf.forget_iota()
        if k < 4000:  # m stage: a common force switched every 2 s
            f = [6.0 * complex(math.cos(0.5), math.sin(0.5)) * (1 if (k // 200) % 2 == 0 else -1)] * n
        else:  # J stage: omega ramps up for 10 s, then down
            s = 1.0 if k < 5000 else -1.0
            f = [s * 1j * complex(*z) for z in tr.zi]
        torque = sum(qi.real * fi.imag - qi.imag * fi.real for qi, fi in zip(q, f))
        kf.predict(sum(f), torque, dt)
        plant.apply_and_step([(fi.real, fi.imag, 0.0) for fi in f])
    tr = plant.truth()
    assert 1.0 / kf.mu == pytest.approx(sc.load.mass, rel=1e-4)
    assert 1.0 / kf.iota == pytest.approx(sc.load.inertia, rel=1e-4)
    assert abs(kf.q - (complex(*tr.zi[0]) + complex(*tr.zc))) < 1e-3
    assert kf.omega == pytest.approx(tr.omega, abs=1e-4)


def _j_stage_with_delayed_u(d: int, model_delay: bool, u_bias_walk: float | None = None) -> tuple[float, float]:
    """The filter on the noise-free pymunk plant as in the test above (m stage, then Result 5's J stage),
    given the own contact velocity of the tick and an eq. (9) sample (the exact omega) ``d`` ticks old,
    with (``model_delay``) or without the dt sum of its own predicted torques over those ticks. The
    filter's default process noise (as in a run: it keeps tracking, so a biased sample moves it; with
    no process noise it grows so confident that any omega sample stops mattering). u_var 1e-5 is the
    pooled rate's variance 2 sigma^2 / sum |z|^2 at sigma 0.01 m/s. Returns (J / J_true, m / m_true)."""
    sc = load_scenario(FIG4, ["noise.sigma_v=0.0", "initial.omega=1.5"])
    plant = Plant(sc)
    n, dt = sc.n, sc.dt
    spec = DynamicsSpec() if u_bias_walk is None else DynamicsSpec(u_bias_walk=u_bias_walk)
    kf = RigidEKF(0.01, spec, False)
    tr = plant.truth()
    kf.start(complex(*plant.velocities()[0]) + 0.05, complex(*tr.zi[0]) + complex(*tr.zc) + 0.3, tr.omega + 0.05)
    omegas: list[float] = []  # true omega of each tick
    cum = [0.0]  # dt sum of the torques the filter predicted with, up to each tick
    for k in range(6000):
        tr = plant.truth()
        omegas.append(tr.omega)
        q = [complex(*z) + complex(*tr.zc) for z in tr.zi]
        if k >= d:
            dc = cum[k] - cum[k - d] if model_delay else 0.0
            kf.update(complex(*plant.velocities()[0]), omegas[k - d], 1e-5, dc)
        else:
            kf.update(complex(*plant.velocities()[0]), math.nan, 0.0)
        if k == 4000:  # as DynamicPhase._enter(J_EXCITE)
            kf.forget_iota()
            kf.set_omega_walk(spec.j_omega_walk)
        if k < 4000:
            f = [6.0 * complex(math.cos(0.5), math.sin(0.5)) * (1 if (k // 200) % 2 == 0 else -1)] * n
        else:
            s = 1.0 if k < 5000 else -1.0
            f = [s * 1j * complex(*z) for z in tr.zi]
        torque = sum(qi.real * fi.imag - qi.imag * fi.real for qi, fi in zip(q, f))
        kf.predict(sum(f), torque, dt)
        cum.append(cum[-1] + dt * torque)
        plant.apply_and_step([(fi.real, fi.imag, 0.0) for fi in f])
    return 1.0 / kf.iota / sc.load.inertia, 1.0 / kf.mu / sc.load.mass


@pytest.mark.parametrize("d", [1, 10, 20])
def test_rigid_ekf_takes_a_delayed_rate_sample_without_biasing_J(d):
    """Issue 5: an eq. (9) sample d ticks old (100 ms delay + jitter: 10-15 ticks) is a measurement of
    omega d ticks ago; predicted back through the filter's own torques it gives the same J as a
    current one (measured: J within 3e-7 of the truth at d = 0, 1, 10, 20; m within 2e-4, the m stage's
    own precision here). Taken as current it does not: J off by 0.011 / 0.60 / 1.7 %, m by 0.13 / 1.7 /
    3.2 % at d = 1 / 10 / 20 (next test)."""
    j0, m0 = _j_stage_with_delayed_u(0, True)
    jd, md = _j_stage_with_delayed_u(d, True)
    assert j0 == pytest.approx(1.0, abs=1e-5)
    assert jd == pytest.approx(j0, abs=1e-5)
    assert md == pytest.approx(1.0, abs=5e-4)


def test_rigid_ekf_biases_J_when_a_delayed_rate_sample_is_taken_as_current():
    """The counterpart: the same 10-tick-old samples without their age move J far outside the tolerance
    above (so the delayed-measurement model is what the previous test checks). Shown with u taken as
    unbiased (u_bias_walk = 0): the default rate-error state b absorbs most of this slowly varying error
    too (J 5e-5 off, measured), which is its job at high noise."""
    jd, md = _j_stage_with_delayed_u(10, False, u_bias_walk=0.0)
    assert abs(jd - 1.0) > 1e-3
    assert abs(md - 1.0) > 5e-3


def _rigid_ekf_under_a_drifting_rate(u_bias_walk: float, seed: int) -> tuple[float, float]:
    """The filter on a body turning at 1.5 rad/s, own contact velocity with sigma 0.9 noise, and a pooled
    eq. (9) rate whose pair angle drifts from 0 to 60 deg over 30 s (u = omega cos theta: what a pair
    that no circle fit corrects gives at high noise, docs/dynamics.md "High noise"). Returns the mean
    |omega error| over the last 5 s and the final |q error| (m)."""
    rng = np.random.default_rng(seed)
    dt, om, sigma, T = 0.01, 1.5, 0.9, 3000
    q, vc = complex(0.8, -0.6), complex(0.2, 0.1)
    u_var = 2.0 * sigma**2 / 1.8  # 2 sigma^2 / sum_j |z_ij|^2 of a middle agent of the n = 5 grid runs
    kf = RigidEKF(sigma, DynamicsSpec(u_bias_walk=u_bias_walk), False)
    kf.start(vc + om * 1j * q, q, om)
    err = []
    for k in range(T):
        theta = math.radians(60.0) * k / T
        v = vc + om * 1j * q + complex(*rng.normal(0.0, sigma, 2))
        kf.update(v, om * math.cos(theta) + rng.normal(0.0, math.sqrt(u_var)), u_var)
        kf.predict(0j, 0.0, dt)
        q *= complex(math.cos(om * dt), math.sin(om * dt))
        err.append(abs(kf.omega - om))
    return float(np.mean(err[-500:])), abs(kf.q - q)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_rigid_ekf_holds_omega_when_the_rate_drifts(seed):
    """Issue: at sigma >= 0.9 the eq. (9) rate's pair angles drift and u falls below omega. With its
    error b as a state, the filter's omega rests on the rotation of the own contact velocity (measured:
    0.015-0.03 rad/s off at the end, q 2-4 cm); taking u as unbiased it follows u (0.15-0.2 rad/s, q
    28-38 cm off), which in a run then lost lock altogether."""
    om_err, q_err = _rigid_ekf_under_a_drifting_rate(DynamicsSpec().u_bias_walk, seed)
    assert om_err < 0.06
    assert q_err < 0.1
    om_err0, q_err0 = _rigid_ekf_under_a_drifting_rate(0.0, seed)
    assert om_err0 > 0.1  # the counterpart: the mechanism above is what holds omega
    assert q_err0 > 0.2


@pytest.mark.slow
def test_algorithm_1_at_high_noise_keeps_omega_locked(tmp_path):
    """A Monte Carlo grid cell that diverged (n = 5, sigma_v = 1.0, run 0 of `coload campaign`): short
    pairs lost their angle, omega_hat then lost lock in the m stage, and the J stage's forces on wrong
    q_i spun the load up to 14 rad/s (omega RMS 34 rad/s, J off by 1e6 %). With omega_hat measuring the
    filter's omega and the filter modelling the rate's error it finishes: measured J 0.64 %, m 0.44 %,
    omega RMS 0.021 rad/s over the last 20 s."""
    from coload.analysis.campaign import campaign_scenario

    sc = campaign_scenario(load_scenario(FIG4), 5, 1.0, 957995623)
    summary = run_inproc(sc.model_copy(update={"duration": 95.0}), tmp_path)
    err = summary["errors"]
    assert err["finished_s"] is not None
    assert err["omega_rms"] < 0.1
    assert err["J_rel"] < 0.03
    assert err["m_rel"] < 0.02
    rows = _estimates(tmp_path)
    import csv

    with open(tmp_path / "truth.csv") as f:
        om_true = {r["t"]: float(r["omega"]) for r in csv.DictReader(f)}
    worst = max(abs(float(r["omega"]) - om_true[r["t"]]) for r in rows if float(r["t"]) > 30.0)
    assert worst < 0.5  # never lost lock (it fell to ~0 and below while the load turned at 2 rad/s)



def _own_masses_at_the_end_of_the_m_stage(sc) -> tuple[list[float], list[int]]:
    """Runs ``sc`` like the in-process engine (one-tick links) until the m stage ends; every agent's own m
    error and its lock-check restarts."""
    from agents.factory import build_team
    from coload.runs.team import team_ticks

    plant = Plant(sc)
    team = build_team([sc.agent_view(i) for i in range(sc.n)])
    agents = [team.agent(i) for i in range(sc.n)]
    for _ in team_ticks(sc, plant, team):
        if agents[0]._dyn.stage == D.M_AVERAGE:
            break
    else:
        raise AssertionError("the m stage did not end")
    return [a._dyn.m_local / plant.mass - 1.0 for a in agents], [a._dyn.reseeds for a in agents]


@pytest.mark.slow
@pytest.mark.parametrize("sigma, seed, bad", [
    # n20-s0.9-r21: agent 6's filter restarted at kinematic readiness from an omega_hat 0.63 rad/s off and
    # locked onto a wrong (q_i, omega): its own m 651 % off, the team's averaged m 33 %
    pytest.param(0.9, 2454811040, 6.5, marks=pytest.mark.long),  # 1-2 min: out of CI's budget
    # n20-s0.8-r20: half the line (agents 0-7, 11, 12, 14) lost lock, their omega_hat -1.2..+0.8 rad/s
    # with the load at 2.5: own m up to 53 % off, the team's 6.6 %
    (0.8, 2244023880, 0.5),
])
def test_the_lock_check_restarts_a_filter_in_a_wrong_lock(sigma, seed, bad):
    """Two grid runs (n = 20) as the grid ran them (no omega boost), where filters locked onto a wrong
    (q_i, omega): their velocity NIS (~2 when the filter explains v_Ci) went to 10-300. The lock check
    restarts such a filter from a fit of its own last 2 s of contact velocities and keeps the restart
    only if clearly better: every agent's own m comes out as good as a healthy run's (per-agent sd at
    this noise ~1.5 %). ``bad``: the worst own-m error without the check (measured, lock_nis = 0)."""
    from coload.analysis.campaign import campaign_scenario

    sc = campaign_scenario(load_scenario(FIG4, ["control.omega_boost=0"]), 20, sigma, seed)
    own, restarts = _own_masses_at_the_end_of_the_m_stage(sc)
    assert sum(restarts) >= 1
    # measured with the check: every agent within 1.8 % (s0.9) and 3.1 % (s0.8), mean +0.1 %
    assert max(abs(e) for e in own) < 0.06 < bad
    assert abs(sum(own) / len(own)) < 0.01


@settings(max_examples=25, deadline=None)
@given(st.floats(1.5, 5.0), st.booleans(), st.floats(0.5, 4.0), st.floats(-math.pi, math.pi), st.floats(0.0, 1.0),
       st.integers(0, 2**31))
def test_fit_rotation_finds_omega_and_q_from_one_contact_velocity(speed, ccw, r, ang, sigma, seed):
    """The lock check's restart point: 2 s of one contact's velocity under a switched common force, noise
    up to sigma 1 m/s, give omega and q with errors of the order of 1/snr, snr = |omega| |q| / sigma (the
    contact's speed about the CoM over the noise): a global scan, no local minimum to lock onto (the
    grid's wrong locks started from an omega 0.6 rad/s off). Where it can: the load turns by >= 3 rad in
    the window and snr >= 3 (nearer the CoM, or slower, the restart is poorer and its trial decides).
    Measured over 284 random cases: |d omega| snr <= 3.8 (median 0.16), |dq| / |q| <= 1.4 / snr, omega
    within 0.05 rad/s in 95 % of them."""
    om = speed if ccw else -speed
    assume(speed * r >= 3.0 * sigma + 0.5)
    rng = np.random.default_rng(seed)
    dt, n, mu = 0.01, 200, 0.01
    q0 = r * complex(math.cos(ang), math.sin(ang))
    force = np.where((np.arange(n) // 150) % 2 == 0, 1.0, -1.0) * 200.0 * (0.8 + 0.6j)
    f = np.concatenate(([0.0], np.cumsum(dt * force)[:-1]))
    t = np.arange(n) * dt
    v = (0.3 - 0.2j) + mu * f + 1j * om * np.exp(1j * om * t) * q0
    v = v + sigma * (rng.standard_normal(n) + 1j * rng.standard_normal(n))
    om_fit, q_last, rms = fit_rotation(v, f, dt, 6.0)
    snr = speed * r / max(sigma, 1e-3)
    assert abs(om_fit - om) < 6.0 / snr + 0.02
    assert abs(q_last - q0 * np.exp(1j * om * t[-1])) < r * (3.0 / snr) + 0.02
    assert rms < 1.2 * sigma + 0.05
