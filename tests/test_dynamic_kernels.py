"""The dynamical phase's row kernels (agents/kernels/dynamic.py): on inputs recorded from the Python
DynamicPhase they replaced (tests/dynamic_reference.py, frozen) in quick-dynamics runs (the phase's state
copied into a bank row before and after each call of the method a kernel replaces), the kernel gives the
Python's state bit for bit, compiled equals the same source interpreted (``py_func``), and a row's result
does not depend on the batch it is in."""

from __future__ import annotations

import dynamic_reference as DP
import numpy as np
import pytest

from agents.effect_decision import SLOPE
from agents.kernels import dynamic as K
from agents.rigid_filter import RigidEKF
from config.loader import load_scenario

AGENTS = (1, 2)  # degree 2 on the line: their rows stack into one batch


def _banks_of(dp: DP.DynamicPhase) -> tuple:
    banks = K.new_banks(1, dp.avg.deg, dp.avg.nch, dp.kf.d, dp.hist, dp.win_n, 1)
    K.load_row(dp, banks, 0)
    return banks


def _copy(banks: tuple) -> tuple:
    return tuple(a.copy() for a in banks)


def _record(overrides: list[str], age: int) -> dict[str, list]:
    """Runs quick-dynamics with ``overrides`` on fault-free links of ``age`` ticks and records (before, args,
    after[, result]) of the replaced methods for agents 1 and 2 on every 3rd tick, and on every tick while a
    shadow or twin filter runs."""
    from agents.factory import member
    from coload.runs.team import team_ticks
    from simulator.plant import Plant

    recs: dict[str, list] = {"predict": [], "body": [], "update": [], "late": [], "inputs": [], "converged": [],
                             "advance": [], "receive": [], "estimates": []}
    cls = DP.DynamicPhase
    orig = {m: getattr(cls, m) for m in ("_predict", "_body_frame", "_filter_update", "_note_late",
                                         "_consensus_inputs", "_converged", "_advance_stage", "_receive",
                                         "_estimates")}

    def take(dp: DP.DynamicPhase, tick: int) -> bool:
        return dp.id in AGENTS and (tick % 3 == 0 or dp.shadow is not None or dp.twin is not None)

    def predict(self, tick, rot, j_sign):  # noqa: ANN001, ANN202
        before = _banks_of(self) if take(self, tick) else None
        orig["_predict"](self, tick, rot, j_sign)
        if before is not None:
            args = (tick, rot, j_sign is not None, 0.0 if j_sign is None else j_sign)
            recs["predict"].append((before, args, _banks_of(self)))

    def body(self, tick, phi):  # noqa: ANN001, ANN202
        before = _banks_of(self) if take(self, tick) else None
        rot = orig["_body_frame"](self, tick, phi)
        if before is not None:
            recs["body"].append((before, (tick, phi), _banks_of(self), rot))
        return rot

    def update(self, tick, v, u, u_den, omega_hat, zi, rot):  # noqa: ANN001, ANN202
        before = None
        if take(self, tick):
            before = _banks_of(self)
            plain = self.shadow is None and self.q_held is None  # no lock-check restart, judgement or hold
        starts.clear()
        out = orig["_filter_update"](self, tick, v, u, u_den, omega_hat, zi, rot)
        if before is not None:
            plain = plain and self.shadow is None and self.q_held is None
            reseed = starts[-1] if self.trial_tick == tick else None  # the restart point P2 fitted
            recs["update"].append((before, (tick, v, u, u_den), _banks_of(self), plain, (zi, rot, reseed, out)))
        return out

    starts: list[tuple] = []
    orig_start = RigidEKF.start

    def start(self, v, q0, omega):  # noqa: ANN001, ANN202
        starts.append((complex(v), complex(q0), float(omega)))
        orig_start(self, v, q0, omega)

    def late(self, t, zz):  # noqa: ANN001, ANN202
        before = _banks_of(self) if self.id in AGENTS else None
        orig["_note_late"](self, t, zz)
        if before is not None:
            recs["late"].append((before, (t, zz), _banks_of(self)))

    calls = [0]

    def inputs(self, stage, q, zc, held, rot, fx, fy, tau, jstage):  # noqa: ANN001, ANN202
        calls[0] += 1
        before = _banks_of(self) if take(self, calls[0]) else None
        orig["_consensus_inputs"](self, stage, q, zc, held, rot, fx, fy, tau, jstage)
        if before is not None:
            args = (stage, q, zc, held is not None, 0j if held is None else held, rot, fx, fy, tau, jstage,
                    self._on())
            recs["inputs"].append((before, args, _banks_of(self)))

    def conv(self, num, wch, tick):  # noqa: ANN001, ANN202
        before = _banks_of(self) if take(self, tick) else None
        out = orig["_converged"](self, num, wch, tick)
        if before is not None:
            recs["converged"].append((before, (num, wch, tick), _banks_of(self), out))
        return out

    def advance(self, tick, v, omega_hat, phi, zi, trusted, om_init):  # noqa: ANN001, ANN202
        stage, restarted = self.stage, self.restarted
        before = _banks_of(self) if self.id in AGENTS else None
        slope = self.detect is not None and self.detect.undecided(SLOPE)
        orig["_advance_stage"](self, tick, v, omega_hat, phi, zi, trusted, om_init)
        # every 3rd tick, and every stage change and restart
        if before is not None and (take(self, tick) or self.stage != stage or self.restarted != restarted):
            recs["advance"].append((before, (tick, v, omega_hat, phi, zi, trusted, om_init, slope), _banks_of(self)))

    rows: dict[int, tuple] = {}
    orig_msg = DP._dynamic_msg

    def dynamic_msg(v, lay):  # noqa: ANN001, ANN202
        m = orig_msg(v, lay)
        rows[id(m)] = (m, np.array(v, float), lay.lay)  # m kept: its id stays its own while recorded
        return m

    def receive(self, m):  # noqa: ANN001, ANN202
        before = _banks_of(self) if take(self, m.tick) else None
        orig["_receive"](self, m)
        if before is not None:
            _, v, lay = rows[id(m)]
            args = (self.avg.ids.index(m.sender), v, lay)
            recs["receive"].append((before, args, _banks_of(self)))

    def estimates(self):  # noqa: ANN202
        out = orig["_estimates"](self)
        if self.id in AGENTS and len(recs["estimates"]) < 400 and calls[0] % 3 == 0:
            # the OUT row's dynamical part too: _shared and the flows are read at the same point of the tick
            flows = {j: tuple(f) for j, f in self.avg.flow.items()}
            recs["estimates"].append((_banks_of(self), self._on(), out, self._shared(), flows, self.avg.ids,
                                      len(self.barrier.mask_keys)))
        return out

    sc = load_scenario("quick-dynamics", overrides)
    try:
        cls._predict, cls._body_frame, cls._filter_update, cls._note_late = predict, body, update, late
        cls._consensus_inputs, cls._converged, cls._advance_stage, cls._receive = inputs, conv, advance, receive
        DP._dynamic_msg = dynamic_msg
        cls._estimates = estimates
        RigidEKF.start = start
        team = DP.ReferenceTeam([member(sc.agent_view(i)) for i in range(sc.n)], age + 1)
        for _ in team_ticks(sc, Plant(sc), team, age):
            pass
    finally:
        for m, f in orig.items():
            setattr(cls, m, f)
        RigidEKF.start = orig_start
        DP._dynamic_msg = orig_msg
    return recs


SCENARIOS = {
    "quick-dynamics": ([], 1),
    # samples 2 ticks old (the late sums, the delayed rate); the augmented filter, the detection's force
    # error and the slope's twin
    "online": (["duration=16", "plant.friction.viscous=5", "dynamics.online_detection=true"], 2),
    # restarts on trial (a low lock threshold: each goes back to the old filter) and the shape hold of done
    "lock": (["dynamics.lock_nis=1.8", "dynamics.lock_hold_s=0.5", "dynamics.brake=0.5"], 1),
    # Algorithm 2 with the augmented model: the background stage's offers, dither and releases
    "background": (["duration=20", 'dynamics.algorithm="background"',
                    'dynamics.estimate_effects=["viscous_friction", "rotational_damping"]'], 1),
}


@pytest.fixture(scope="module", params=list(SCENARIOS))
def recs(request) -> dict[str, list]:  # noqa: ANN001
    return {"scenario": request.param, **_record(*SCENARIOS[request.param])}


def _value(out):  # noqa: ANN001, ANN202
    """A kernel's result as Python numbers (interpreted, record fields give numpy scalars)."""
    if isinstance(out, tuple):
        return tuple(float(x) for x in out)
    if isinstance(out, bool | np.bool_):
        return bool(out)
    return None if out is None else complex(out)


def _same(a: tuple, b: tuple) -> bool:
    return all(x.tobytes() == y.tobytes() for x, y in zip(a, b, strict=True))


def _call(kernel, name: str, banks: tuple, args: tuple, b: int = 0):  # noqa: ANN001, ANN202
    dyn, dnb, nbr_mask, rx_order, psi_order, cum, cum_t, _, S, Fa, Ia, fs, s, P, sens, Qd, aug, innov, sens_h = banks
    if name == "predict":
        return kernel(b, *args, dyn, cum, cum_t, Fa, fs, s, P, sens, Qd, aug)
    if name == "body":
        return kernel(b, *args, dyn, dnb, psi_order, Ia, fs, s)
    if name == "update":
        return kernel(b, *args, dyn, cum, cum_t, fs, s, P, sens, innov, sens_h)
    if name == "inputs":
        return kernel(b, *args, dyn, Fa, fs, s, P)
    if name == "converged":
        return kernel(b, *args, dyn, Fa, Ia)
    if name == "receive":
        return kernel(b, *args, dyn, dnb, nbr_mask, rx_order, psi_order, Fa, Ia)
    if name == "advance":
        return kernel(b, *args, dyn, dnb, nbr_mask, rx_order, S, fs, s, P, sens, Qd, aug, innov, sens_h)
    return kernel(b, *args, dyn, cum, cum_t)


KERNELS = {"predict": K.dyn_predict, "body": K.body_frame, "update": K.dyn_filter_update, "late": K.note_late,
           "inputs": K.consensus_inputs, "converged": K.converged, "advance": K.dyn_advance_stage,
           "receive": K.dyn_receive}


def test_the_recording_covers_the_branches(recs):
    assert all(len(recs[k]) > 100 for k in ("predict", "body", "update", "inputs"))
    dyn = [r[0][0][0] for r in recs["predict"]]
    if recs["scenario"] == "background":
        assert any(r[1][0] == K.BACKGROUND and r[2][0][0]["b_offered"] for r in recs["inputs"])
        return
    assert K.M_EXCITE in {int(r["stage"]) for r in dyn}
    if recs["scenario"] == "quick-dynamics":
        assert any(r[1][2] for r in recs["predict"])  # the J stage's torque
        assert len(recs["converged"]) > 10 and any(r[3] for r in recs["converged"])
        assert any(r[1][0] == K.M_AVERAGE and r[2][0][0]["frozen_m"] and not r[0][0][0]["frozen_m"]
                   for r in recs["inputs"])
        assert any(r[0][11][0, 0]["ready"] and not r[0][11][0, 0]["has_aug"] for r in recs["predict"])
    elif recs["scenario"] == "online":
        assert len(recs["late"]) > 100
        assert any(r["twin_slot"] >= 0 for r in dyn) and any(r["has_detect"] for r in dyn)
        assert any(r[0][11][0, 0]["has_aug"] for r in recs["predict"])


@pytest.mark.parametrize("name", ["predict", "body", "late", "inputs", "converged"])
def test_kernel_equals_the_python_phase(recs, name):
    """The whole banks after the kernel == the phase's state after the method it replaces."""
    for before, args, after, *rest in recs[name]:
        got = _copy(before)
        out = _call(KERNELS[name], name, got, args)
        assert _same(got, after), (name, args)
        if rest:
            assert repr(_value(out)) == repr(rest[0])


def test_filter_update_equals_the_python_phase(recs):
    """The cum ring always; the kf and twin slots where the lock check did not restart, judge or hold."""
    n_plain = 0
    for before, args, after, plain, _ in recs["update"]:
        got = _copy(before)
        _call(K.dyn_filter_update, "update", got, args)
        assert got[5].tobytes() == after[5].tobytes() and got[6].tobytes() == after[6].tobytes()
        if plain:
            n_plain += 1
            slots = [K.KF] + ([K.TWIN] if before[0]["twin_slot"][0] >= 0 else [])
            for x, y in zip(got[11:], after[11:], strict=True):
                assert x[0, slots].tobytes() == y[0, slots].tobytes(), args
    assert n_plain > 100


def _filter_update(banks: tuple, args: tuple, extra: tuple, interpreted: bool = False) -> tuple:
    """DynamicPhase._filter_update as the kernels' chain: update, lock check, P2's restart at the recorded
    point, the shape hold. Returns (q, zc, held or None, events)."""
    dyn, _, _, _, _, cum, cum_t, win, _, Fa, _, fs, s, P, sens, Qd, aug, innov, sens_h = banks
    k = {n: getattr(K, n).py_func if interpreted else getattr(K, n)
         for n in ("dyn_filter_update", "lock_check", "dyn_reseed", "hold_shape_check")}
    tick, v, u, u_den = args
    zi, rot, reseed, _ = extra
    u_var, u_dc, u_dw = k["dyn_filter_update"](0, *args, dyn, cum, cum_t, fs, s, P, sens, innov, sens_h)
    ev = k["lock_check"](0, tick, v, u, u_var, u_dc, u_dw, dyn, win, fs, s, P, sens, innov, sens_h)
    if ev & K.E_RESEED:
        v0, q0, om0 = reseed
        k["dyn_reseed"](0, tick, v0, q0, om0, dyn, fs, s, P, sens, Qd, aug, innov, sens_h)
    q, zc, ev2 = k["hold_shape_check"](0, tick, zi, rot, dyn, Fa, fs, s, P, Qd)
    held = complex(dyn[0]["q_held"]) if dyn[0]["has_q_held"] else None
    return complex(q), complex(zc), held, int(ev | ev2)


def _same_by_role(got: tuple, after: tuple) -> None:
    """The banks are the same, the filter slots compared by role (kf, shadow, twin: the kernels swap indices
    where Python swaps objects)."""
    g, a = got[0].copy(), after[0].copy()
    for role in ("kf_slot", "shadow_slot", "twin_slot"):
        gs, as_ = int(g[0][role]), int(a[0][role])
        assert (gs < 0) == (as_ < 0), role
        if gs >= 0:
            for x, y in zip(got[11:], after[11:], strict=True):
                assert x[0, gs].tobytes() == y[0, as_].tobytes(), role
        g[role] = a[role] = 0
    assert g.tobytes() == a.tobytes()
    assert all(x.tobytes() == y.tobytes() for x, y in zip(got[1:11], after[1:11], strict=True))


def test_advance_stage_equals_the_python_phase(recs):
    """A6 bit for bit: starts, the restart at kinematic readiness, every stage entered, the barrier, the twin."""
    entered = set()
    for before, args, after in recs["advance"]:
        got = _copy(before)
        ev = _call(K.dyn_advance_stage, "advance", got, args)
        _same_by_role(got, after)
        st0, st1 = int(before[0][0]["stage"]), int(after[0][0]["stage"])
        if st1 != st0:
            entered.add(st1)
            assert bool(ev & K.E_REGIME) == bool(before[0][0]["has_detect"])
    want = {K.KINEMATIC, K.BACKGROUND} if recs["scenario"] == "background" else {K.KINEMATIC, K.M_EXCITE}
    if recs["scenario"] in ("quick-dynamics", "lock"):
        want |= {K.M_AVERAGE, K.J_EXCITE, K.J_AVERAGE, K.DONE}
    assert want <= entered, entered
    if recs["scenario"] == "online":
        assert any(r[2][0][0]["twin_slot"] >= 0 and r[0][0][0]["twin_slot"] < 0 for r in recs["advance"])


def test_receive_equals_the_python_phase(recs):
    """dyn_receive from the IN row == DynamicPhase._receive of its decoded message (but the decision's flood)."""
    assert len(recs["receive"]) > 100
    for before, args, after in recs["receive"]:
        got = _copy(before)
        _call(K.dyn_receive, "receive", got, args)
        _same_by_role(got, after)


def test_estimates_equal_the_python_phase(recs):
    assert len(recs["estimates"]) > 100
    for banks, on, want, *_ in recs["estimates"]:
        assert tuple(want) == K.ESTIMATES
        dyn, Fa, s = banks[0], banks[9], banks[12]
        for fn in (K.dyn_estimates, K.dyn_estimates.py_func):
            out = np.zeros(len(K.ESTIMATES))
            fn(0, on, dyn, Fa, s, out)
            assert repr(out.tolist()) == repr(list(want.values()))


def test_out_row_equals_the_python_shared_states(recs):
    from net.rows import Layout, state_from_row

    for banks, _, _, shared, flows, ids, nbk in recs["estimates"]:
        dyn, S, Fa, Ia = banks[0], banks[8], banks[9], banks[10]
        lay = Layout(True, Fa.shape[2], nbk, bool(dyn[0]["has_detect"]), len(ids))
        for fn in (K.dyn_write_out, K.dyn_write_out.py_func):
            row = np.zeros(lay.size_out)
            fn(0, row, lay.lay, dyn, S, Fa, Ia)
            msg = state_from_row(row, lay, ids)
            got = {key: msg.shared[key] for key in shared if key[0] != "D"}  # D*: the flood's, not the kernel's
            assert repr(got) == repr({key: v for key, v in shared.items() if key[0] != "D"})
            assert repr({j: p[4:] for j, p in msg.pair.items()}) == repr(flows)


def test_the_slope_index_is_the_detections():
    assert K.SLOPE == SLOPE


def test_filter_update_chain_equals_the_python_phase(recs):
    """The whole of _filter_update (lock check, restarts on trial, judgements, the shape hold) bit for bit."""
    events = 0
    for before, args, after, _, extra in recs["update"]:
        got = _copy(before)
        q, zc, held, ev = _filter_update(got, args, extra)
        _same_by_role(got, after)
        assert repr((q, zc, held)) == repr(extra[3]), args
        events |= ev
        interp = _copy(before)
        assert repr(_filter_update(interp, args, extra, True)) == repr((q, zc, held, ev))
        assert _same(interp, got)
    if recs["scenario"] == "lock":
        assert events == K.E_RESEED | K.E_BACK
        assert any(r[2][0][0]["has_q_held"] and not r[0][0][0]["has_q_held"] for r in recs["update"])


@pytest.mark.parametrize("name", list(KERNELS))
def test_compiled_equals_py_func(recs, name):
    for before, args, *_ in recs[name]:
        a, b = _copy(before), _copy(before)
        out_a = _call(KERNELS[name], name, a, args)
        out_b = _call(KERNELS[name].py_func, name, b, args)
        assert _same(a, b), (name, args)
        assert repr(_value(out_a)) == repr(_value(out_b))


@pytest.mark.parametrize("name", list(KERNELS))
def test_batch_of_one_equals_batch_of_n(recs, name):
    if not recs[name]:
        pytest.skip("no such call in this run")
    sel = recs[name][::max(1, len(recs[name]) // 16)][:16]
    batch = tuple(np.concatenate([r[0][i] for r in sel]) for i in range(len(sel[0][0])))
    outs = [_call(KERNELS[name], name, batch, r[1], b) for b, r in enumerate(sel)]
    for b, r in enumerate(sel):
        one = _copy(r[0])
        out = _call(KERNELS[name], name, one, r[1])
        assert all(x[b:b + 1].tobytes() == y.tobytes() for x, y in zip(batch, one, strict=True))
        assert repr(_value(out)) == repr(_value(outs[b]))


SPECS = {
    "nominal": {},
    "ccw2": {"omega_sign": -1, "j_cycles": 2, "brake": 0.5, "m_force_angle": -1.3},
    "background": {"algorithm": "background", "dither_torque": 1.5, "dither_period_s": 2.3},
}


@pytest.mark.parametrize("spec", list(SPECS))
def test_stage_wrench_and_dither_equal_the_python(spec):
    from config.agent_params import DynamicsSpec

    excitation = DP  # the Python stage_wrench, j_sign and dither

    sp = DynamicsSpec(**SPECS[spec])
    dyn = np.zeros(1, K.DYN)
    K.init_dyn_row(dyn, 0, 5, 0.01, 0.1, sp)
    r = dyn[0]
    rng = np.random.default_rng(3)
    for stage in range(8):
        for k in range(0, 3000, 7):
            v, q, zc = (complex(*rng.normal(0, 1, 2)) for _ in range(3))
            wr = tuple(float(x) for x in rng.normal(0, 1, 3))
            want = excitation.stage_wrench(stage, k, sp, int(r["m_switch"]), int(r["j_ticks"]), v, q, zc, wr)
            for fn in (K.stage_wrench, K.stage_wrench.py_func):
                got = fn(0, stage, k, v, q, zc, *wr, dyn)
                assert repr(tuple(float(x) for x in got)) == repr(want), (stage, k)
            want = excitation.dither(k, sp, int(r["dither_ticks"]))
            assert repr(float(K.dither(0, k, dyn))) == repr(float(K.dither.py_func(0, k, dyn))) == repr(want)


def _phase(spec_kw: dict | None = None) -> DP.DynamicPhase:
    """Agent 1 of a line of 3, its filter started, in the kinematic stage with both neighbours heard."""
    from config.agent_params import DynamicsSpec

    DynamicMsg = DP.DynamicMsg

    dp = DP.DynamicPhase(1, [0, 2], 3, 0.01, 0.1, DynamicsSpec(**(spec_kw or {})))
    dp._advance_stage(0, 0.3 + 0.1j, 0.5, 0.2, 1.0 + 0.5j, False, True)
    for j, stage in ((0, K.J_EXCITE), (2, K.KINEMATIC)):
        nch = dp.avg.nch
        dp._receive(DynamicMsg(j, 0, stage, 0.1, 1, [0.0] * nch, [0.0] * nch, (0, -1, -1), 57, 0.5))
    return dp


def test_advance_jumps_to_a_neighbour_two_stages_ahead():
    dp = _phase()
    before = _banks_of(dp)
    args = (1, 0.3 + 0.1j, 0.5, 0.2, 1.0 + 0.5j, True, True, False)
    dp._advance_stage(*args[:7])
    assert dp.stage == K.J_EXCITE and dp.late_switches == 1
    got = _copy(before)
    _call(K.dyn_advance_stage, "advance", got, args)
    _same_by_role(got, _banks_of(dp))


@pytest.mark.parametrize("better", [True, False])
def test_a_trial_is_kept_or_dropped_as_the_python_judges(better):
    import copy

    dp = _phase()
    dp.restarted = True
    dp.shadow = copy.copy(dp.kf)
    dp.kf.start(0.3 + 0.1j, 1.1 + 0.4j, 0.45)
    dp.nis_avg, dp.shadow_nis, dp.trial_tick, dp.lock_from = (0.5, 5.0, 3, 5) if better else (3.0, 4.0, 3, 5)
    before = _banks_of(dp)
    args, extra = (6, 0.31 + 0.12j, 0.47, 40.0), (1.0 + 0.5j, complex(0.8, 0.6), None)
    out = dp._filter_update(*args, 0.5, extra[0], extra[1])
    assert dp.shadow is None and dp.reseeds == int(better)
    got = _copy(before)
    q, zc, held, ev = _filter_update(got, args, (*extra, out))
    _same_by_role(got, _banks_of(dp))
    assert repr((q, zc, held)) == repr(out) and ev == (0 if better else K.E_BACK)


@pytest.mark.parametrize("dec, undecided", [(SLOPE, False), (SLOPE, True), (-1, True), (-1, False), (0, False)])
def test_twin_decision_equals_the_python(dec, undecided, monkeypatch):
    """The twin handed over (its sensitivities from zero) or dropped, as _twin_decision does."""
    import copy

    dp = _phase({"online_detection": True})
    dp.twin = copy.copy(dp.kf)
    dp.twin.release_effect(SLOPE)
    dp.twin.sens = None
    dp.kf.sens = np.full_like(dp.kf.sens, 0.25)
    twin = dp.twin
    monkeypatch.setattr(type(dp.detect), "undecided", lambda self, k: undecided)  # the team's, after the decision
    before = _banks_of(dp)
    dp._twin_decision(dec)
    assert (dp.kf is twin) == (dec == SLOPE) and (dp.twin is None) == (not undecided)
    got = _copy(before)
    dyn, fs, sens = got[0], got[11], got[14]
    ev = K.dyn_twin_decision(0, dec, undecided, dyn, fs, sens)
    assert ev == (K.E_REPLACED if dec == SLOPE else 0)
    _same_by_role(got, _banks_of(dp))
