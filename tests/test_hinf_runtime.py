"""Paper 003 at runtime: pure cores against closed forms, the H-infinity and decay guarantees measured
in runs, daemons equal to the in-process engine (memory transport and real Zenoh processes)."""
from __future__ import annotations

import asyncio
import json
import warnings
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg as sla
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.signal import cont2discrete

from coload.runs.hinf_run import finish_run, load_trace, run_processes
from config.scenario import LinkSpec, LossSpec, PartitionSpec
from hinf import SpecError, load_spec, run_design
from hinf import design as D
from hinf import runtime as R
from hinf.daemon import (
    HinfAgentDaemon,
    HinfSimDaemon,
    run_daemons_in_memory,
)
from hinf.report import load_run_dir, prepare_run_dir, summarize
from net import keys
from net.hinf_messages import HinfInput, HinfMeas, HinfState
from net.schema import DecodeError, decode, encode

EXAMPLE = Path(__file__).resolve().parents[1] / "config" / "hinf" / "sec5-cyclic.toml"
warnings.filterwarnings("ignore", message="Solution may be inaccurate")
pytestmark = pytest.mark.filterwarnings("ignore:Solution may be inaccurate")


@pytest.fixture(scope="module")
def design():
    """One design of the Sec. 5 example (estimation gains and the Theorem 3 sync gains), JSON round-tripped
    as the daemons read it."""
    return json.loads(json.dumps(run_design(load_spec(EXAMPLE))))


def _setup(design, *sets: str, **run) -> R.Setup:
    spec = load_spec(EXAMPLE, list(sets))
    if run:
        spec = spec.model_copy(update={"run": spec.run.model_copy(update=run)})
    return R.build_setup(spec, design)


def _equal(a: R.Trace, b: R.Trace) -> None:
    for k, v in a.arrays().items():
        assert np.array_equal(v, b.arrays()[k], equal_nan=True), f"{k} differs"


# ----------------------------------------------------------------------------- pure cores


def test_zoh_is_the_exact_discretisation():
    rng = np.random.default_rng(0)
    A, B = rng.normal(size=(3, 3)), rng.normal(size=(3, 2))
    Ad, Bd = R.zoh(A, B, 0.05)
    Ad2, Bd2, *_ = cont2discrete((A, B, np.eye(3), np.zeros((3, 2))), 0.05, method="zoh")
    np.testing.assert_allclose(Ad, Ad2, atol=1e-13)
    np.testing.assert_allclose(Bd, Bd2, atol=1e-13)


def test_plant_core_matches_the_closed_form(design):
    """Constant u held for 5 s: x(T) = e^{AT} x0 + int_0^T e^{As} ds B u, agent by agent."""
    su = _setup(design, "run.control=false")
    plant = R.PlantCore(su)
    u = [np.array([0.3 * (k + 1)]) for k in range(su.N)]
    T = 500
    for t in range(T):
        plant.measure(t)
        plant.step(u)
    for k in range(su.N):
        Ad, G = R.zoh(su.net.A[k], su.B[k], T * su.dt)
        np.testing.assert_allclose(plant.x[k], Ad @ su.x0[k] + G @ u[k], rtol=1e-10, atol=1e-10)


def test_measurements_are_relative_outputs_plus_noise(design):
    su = _setup(design, "run.control=false", "run.disturbance.kind=white")
    plant = R.PlantCore(su)
    z = plant.measure(0)
    y = [su.net.C[k] @ su.x0[k] for k in range(su.N)]
    o = 0
    for k in range(su.N):
        for i, j in enumerate(su.nbrs(k)):
            assert z[k][i] == pytest.approx(float((y[j] - y[k])[0] + su.net.omega * plant.eta[o]), abs=1e-14)
            o += 1


def test_estimator_cores_implement_the_sampled_error_network(design):
    """With white xi, eta and fault-free links, the recorded errors follow e(t+1) = Ad e + Bd w exactly
    (Remark 2: u drops out of the error), with the controllers on."""
    su = _setup(design, "run.disturbance.kind=white", "run.duration=5")
    trace, _ = R.run_inproc(su)
    e = R.errors(su, trace)
    Ad, Bd, _ = R.discrete_error_network(su)
    q = su.net.q
    scale = np.concatenate([np.full(b.shape[1], np.sqrt(1 + q[j])) for j, b in enumerate(su.net.Bt)])
    w = np.hstack([trace.xi * scale, trace.eta])
    pred = e[:-1] @ Ad.T + w[:-1] @ Bd.T
    err = np.abs(pred - e[1:]).max() / np.abs(e).max()
    assert err < 1e-9


def test_sampled_network_converges_to_the_continuous_one(design):
    """The implementation is a consistent discretisation of (4): one step of the sampled error network is
    e^{A_e dt} up to O(dt^2), and its decay rate and H-infinity norm tend to the continuous ones."""
    devs, rates, norms = [], [], []
    for dt in (0.02, 0.01, 0.005):
        su = _setup(design, "run.control=false", f"run.dt={dt}")
        Ad, Bd, Cz = R.discrete_error_network(su)
        es = D.error_system(su.net, R._design_of(su))
        devs.append(np.abs(Ad - sla.expm(es.A * dt)).max())
        rates.append(-np.log(np.abs(np.linalg.eigvals(Ad)).max()) / dt)
        norms.append(R.discrete_norm(Ad, Bd, Cz)[0])
    cont_rate = -np.linalg.eigvals(es.A).real.max()
    cont_norm = D.hinf_norm(es.A, es.B, es.C)[0]
    assert devs[1] < devs[0] and devs[2] < devs[1]
    assert abs(rates[2] - cont_rate) < abs(rates[0] - cont_rate) + 1e-12 and abs(rates[2] - cont_rate) < 0.01
    assert abs(norms[2] - cont_norm) < abs(norms[0] - cont_norm) and abs(norms[2] - cont_norm) / cont_norm < 0.02


# ----------------------------------------------------------------------------- guarantees, measured


def test_energy_gain_of_a_run_is_below_gamma(design):
    """Theorem 1 (5) with zero initial error: sum e'We <= gamma^2 sum |w|^2. Driven by the worst-case
    input (DC here) the run's gain comes within 3 % of the network's norm, so the check is not vacuous;
    a white-noise run stays well below."""
    su = _setup(design, "run.control=false", "run.disturbance.kind=worst", "run.x0_std=0", "run.duration=60")
    s = summarize(su, *R.run_inproc(su))
    en = s["energy"]
    assert en["I0"] == 0.0
    assert en["empirical_gain"] < en["sampled_norm"] < en["gamma"]
    assert en["empirical_gain"] > 0.97 * en["continuous_norm"]
    su = _setup(design, "run.control=false", "run.disturbance.kind=white", "run.x0_std=0", "run.duration=20")
    white = summarize(su, *R.run_inproc(su))["energy"]
    assert white["empirical_gain"] < 0.5 * white["gamma"] and white["bound_5_holds"]


@pytest.mark.parametrize("control", [False, True])
def test_errors_decay_at_least_at_rate_alpha(design, control):
    """Without disturbances V(t) = sum e^(k)'P^(k)e^(k) <= e^{-alpha t} V(0) at every tick of a run (the
    sampled implementation keeps Theorem 1's guarantee), for the estimation gains and the Theorem 3 ones."""
    su = _setup(design, f"run.control={str(control).lower()}", "run.duration=20")
    s = summarize(su, *R.run_inproc(su))
    d = s["decay"]
    assert d["applies"] and d["alpha_bound_holds"]
    assert d["V_rate_fit"] > d["alpha"] and d["V_rate_overall"] > d["alpha"]
    assert d["error_rate_second_half"] == pytest.approx(d["continuous_error_rate"], rel=0.05)


def test_sync_example_synchronizes_in_process(design):
    su = _setup(design, "run.duration=20")
    s = summarize(su, *R.run_inproc(su))
    sy = s["sync"]
    assert sy["y_spread_final"] < 0.01 * sy["y_spread_initial"]
    assert sy["zeta_spread_final"] < 1e-6
    assert max(sy["regulation_error_final"].values()) < 0.02


# ----------------------------------------------------------------------------- daemons


def _faulty(su: R.Setup) -> R.Setup:
    link = LinkSpec(loss=LossSpec(model="bernoulli", p=0.2), jitter_ticks=2, duplicate=0.1,
                    partitions=[PartitionSpec(start=1.0, end=1.5, cut=[(0, 1)])])
    su.spec.run.link = link
    return su


def test_memory_daemons_equal_the_in_process_engine_under_faults(design):
    """Codec, link model with loss, jitter, duplicates and a partition, lockstep waits: bit for bit."""
    su = _faulty(_setup(design, "run.duration=3"))
    a, ia = R.run_inproc(su)
    b, ib = asyncio.run(run_daemons_in_memory(su))
    _equal(a, b)
    assert ia["links"] == ib["links"] and ia["held"] == ib["held"]
    assert ib["links"]["1->0"]["partitioned"] == 50 and ib["links"]["0->3"]["dropped"] > 0
    assert ib["timeouts"] == {"input": 0, "neighbour": 0} and ib["drops"] == {}


def test_daemons_drop_and_count_bad_messages(design, caplog):
    """Garbage, wrong shapes, spoofed senders and unknown keys are counted by reason; the run is unchanged.
    A malformed payload is also said once in the receiver's log."""
    su = _setup(design, "run.duration=1")
    ref, _ = R.run_inproc(su)

    async def main():
        from net.memory import MemoryBus, MemoryTransport

        loop = asyncio.get_running_loop()
        bus = MemoryBus()
        ts = [MemoryTransport(bus, loop) for _ in range(su.N + 2)]
        run = "hostile"
        agents = [HinfAgentDaemon(su, k, ts[k], run) for k in range(su.N)]
        tasks = [asyncio.ensure_future(a.run()) for a in agents]
        evil = ts[-1]
        while not all(a._subs for a in agents):  # until every daemon has subscribed
            await asyncio.sleep(0)
        evil.publish(keys.hinf(run, 1, "state"), b"\xc1garbage")
        evil.publish(keys.hinf(run, 1, "state"), encode(HinfState(0, 1, (1.0,), (0.0,), (0.0, 0.0))))
        evil.publish(keys.hinf(run, 1, "state"), encode(HinfState(0, 2, (1.0, 2.0), (0.0,), (0.0, 0.0))))
        evil.publish(keys.hinf(run, 0, "meas"), encode(HinfMeas(0, 1, (0.0,))))
        sim = HinfSimDaemon(su, ts[-2], run)
        sim_task = asyncio.ensure_future(sim.run())
        while not sim._subs:
            await asyncio.sleep(0)
        evil.publish(keys.hinf(run, 0, "input"), encode(HinfInput(0, 0, (0.0,), (0.0,), ())))
        evil.publish("coload/hostile/hinf/9/input", encode(HinfInput(0, 9, (0.0,), (0.0,), ())))
        trace, info = await sim_task
        await asyncio.wait_for(asyncio.gather(*tasks), 10.0)
        for t in ts:
            t.close()
        return trace, info

    trace, info = asyncio.run(main())
    _equal(ref, trace)
    d = info["drops"]
    assert d["0:not_msgpack"] == 1 and d["0:bad_shape"] == 1 and d["0:spoofed_sender"] == 1
    assert d["0:wrong_agent"] == 1 and d["sim:bad_shape"] == 1 and d["sim:unknown_sender"] == 1
    assert "hinf estimator 0: dropped a hinf_state on coload/hostile/hinf/1/state: not_msgpack" in caplog.text


def test_realtime_mode_runs_on_wall_clock(design):
    """Real time (memory transport, 1.5 s): the plant steps on the clock and applies the latest u."""
    su = _setup(design, "run.duration=1.5", "run.mode=realtime", "run.dt=0.02")
    trace, info = asyncio.run(run_daemons_in_memory(su))
    assert info["wall_s"] >= 1.5 * 0.95
    assert trace.got.mean() > 0.9 and np.all(np.isfinite(trace.x))
    zeta = trace.zeta.reshape(len(trace.zeta), su.N, su.nu)
    spread = np.abs(zeta - np.nanmean(zeta, axis=1, keepdims=True)).max(axis=(1, 2))
    assert spread[-1] < 0.5 * spread[0]  # the internal models (10) synchronize on the wall clock


def test_sync_over_zenoh_processes_equals_in_process(design, tmp_path):
    """Router, simulator and four estimator daemons as OS processes on loopback: the Sec. 5 example
    synchronizes, and the lockstep run equals the in-process engine bit for bit."""
    spec = load_spec(EXAMPLE, ["run.duration=12"])  # ~2 s of lockstep run, ~5 s of process start-up
    prepare_run_dir(tmp_path / "z", spec, design)
    su = load_run_dir(tmp_path / "z")
    assert run_processes(su, tmp_path / "z", quiet=True)
    s = json.loads((tmp_path / "z" / "summary.json").read_text())
    assert s["engine"] == "zenoh" and s["inputs_missing"] == 0
    assert s["sync"]["y_spread_final"] < 0.1 * s["sync"]["y_spread_initial"]
    assert s["sync"]["zeta_spread_final"] < 1e-4
    assert s["messages"]["timeouts"] == {"input": 0, "neighbour": 0} and s["messages"]["drops"] == {}
    assert (tmp_path / "z" / "hinf.png").stat().st_size > 10_000
    ref, _ = R.run_inproc(su)
    _equal(ref, load_trace(tmp_path / "z"))


# ----------------------------------------------------------------------------- spec, wire, CLI


def test_run_section_errors_name_the_field(tmp_path):
    with pytest.raises(SpecError, match=r"run.x0: agent '2' has n_k=2 states, got 1"):
        load_spec(EXAMPLE, ["run.x0=[[0.0, 0.0], [1.0], [0.0, 0.0], [0.0, 0.0]]"])
    with pytest.raises(SpecError, match=r"run.dt: Input should be greater than 0"):
        load_spec(EXAMPLE, ["run.dt=0"])
    with pytest.raises(SpecError, match=r"partition 0 cuts \[0, 2\], not an edge"):
        load_spec(EXAMPLE, ["run.link.partitions=[{start = 1.0, end = 2.0, cut = [[0, 2]]}]"])
    with pytest.raises(SpecError, match="t_off"):
        load_spec(EXAMPLE, ["run.disturbance.t_on=2.0", "run.disturbance.t_off=1.0"])
    nosync = tmp_path / "nosync.toml"
    text = EXAMPLE.read_text()
    nosync.write_text(text[:text.index("[sync]")] + text[text.index("[[agents]]"):])
    with pytest.raises(SpecError, match="run.control: the controllers need a \\[sync\\] section"):
        load_spec(nosync, ["run.control=true"])


def test_every_run_field_is_documented():
    from hinf.spec import RunSection

    def missing(model, prefix=""):
        out = []
        for name, f in model.model_fields.items():
            if not f.description:
                out.append(prefix + name)
            ann = f.annotation
            if isinstance(ann, type) and hasattr(ann, "model_fields") and ann.__module__.startswith("hinf"):
                out += missing(ann, f"{prefix}{name}.")
        return out

    assert missing(RunSection) == []


vec = st.lists(st.floats(allow_nan=False, allow_infinity=False), max_size=8).map(tuple)


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 2**40), st.integers(0, 1000), vec, vec, vec)
def test_hinf_messages_round_trip(tick, who, a, b, c):
    for m in (HinfMeas(tick, who, a), HinfState(tick, who, a, b, c), HinfInput(tick, who, a, b, c)):
        assert decode(encode(m), type(m)) == m
    with pytest.raises(DecodeError) as exc:
        decode(encode(HinfMeas(tick, who, a)), HinfState)
    assert exc.value.reason == "wrong_kind"


def test_hinf_keys_parse_back():
    k = keys.hinf("r1", 3, "state")
    assert k == "coload/r1/hinf/3/state" and keys.parse_hinf_key(k) == ("r1", 3, "state")
    assert keys.key_matches(keys.hinf_all("r1", "input"), keys.hinf("r1", 7, "input"))
    assert keys.parse_hinf_key("coload/r1/hinf/03/state") is None
    assert keys.parse_hinf_key(keys.hinf_control("r1")) is None
    with pytest.raises(ValueError):
        keys.hinf("r1", 0, "wrench")


def test_cli_inproc_run_writes_the_run_directory(tmp_path, capsys):
    from coload.cli import main

    out = tmp_path / "run"
    assert main(["hinf", "run", str(EXAMPLE), "--engine", "inproc", "--out", str(out), "--set", "run.duration=2"]) == 0
    assert "empirical_gain" in capsys.readouterr().out
    for f in ("spec.json", "design.json", "trace.csv", "summary.json", "hinf.png"):
        assert (out / f).is_file()
    assert main(["hinf", "run", str(EXAMPLE), "--engine", "inproc", "--mode", "realtime", "--out", str(out)]) == 2
    assert "lockstep only" in capsys.readouterr().err


def test_finish_run_round_trips_the_trace(design, tmp_path):
    su = _setup(design, "run.duration=0.5")
    tr, info = R.run_inproc(su)
    s = finish_run(tmp_path, su, tr, info, draw=False)
    _equal(tr, load_trace(tmp_path))
    assert json.loads((tmp_path / "summary.json").read_text())["ticks"] == s["ticks"] == 50


def test_cli_bad_set_and_bad_run_dir_are_one_line(tmp_path, capsys):
    from coload.cli import main

    assert main(["hinf", "run", str(EXAMPLE), "--out", str(tmp_path / "o"), "--set", "run.duration"]) == 2
    assert "--set run.duration: expected key=value" in capsys.readouterr().err
    assert main(["hinf", "agent", "--id", "0", str(tmp_path / "nope"), "--run", "x"]) == 2
    err = capsys.readouterr().err
    assert "spec.json: cannot read it" in err and "prepared by `coload hinf run`" in err
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "spec.json").write_text("{\n  oops\n}")
    assert main(["hinf", "sim", str(tmp_path / "d"), "--run", "x"]) == 2
    assert "spec.json, line 2, column 3: not JSON" in capsys.readouterr().err


def test_an_estimator_that_misses_measurements_rejoins_the_lockstep_run(design):
    """Estimator 2 loses ten measurements mid-run (ticks 30-39: a cut connection). The simulator goes
    on after its input timeouts; when the measurements come back the estimator rejoins at the
    current tick (two consecutive ones confirm the gap), steps the missed ticks with its last data,
    and from then on its inputs reach the simulator again every tick."""
    from net.memory import MemoryBus, MemoryTransport

    su = _setup(design, "run.duration=1.2", "run.timing.input_timeout_s=0.05", "run.timing.neighbour_timeout_s=0.05")
    lost = range(30, 40)

    class CutOff(HinfAgentDaemon):
        def _on_meas(self, key, payload):
            if self.id == 2 and decode(payload, HinfMeas).tick in lost:
                return  # the fault: these never arrive
            super()._on_meas(key, payload)

    async def main():
        loop = asyncio.get_running_loop()
        bus = MemoryBus()
        ts = [MemoryTransport(bus, loop) for _ in range(su.N + 1)]
        agents = [CutOff(su, k, ts[k], "gap") for k in range(su.N)]
        tasks = [asyncio.ensure_future(a.run()) for a in agents]
        try:
            trace, info = await HinfSimDaemon(su, ts[-1], "gap").run()
            reports = await asyncio.wait_for(asyncio.gather(*tasks), 10.0)
        finally:
            for t in ts:
                t.close()
        return trace, info, reports

    trace, info, reports = asyncio.run(main())
    assert reports[2].drops.get("_rejoined") == 1
    got = trace.got[:, 2]
    assert not got[lost.start + 1:lost.stop].any()  # (the input for tick t is sent while stepping t - 1)
    assert got[lost.stop + 2:].all()  # back every tick once rejoined (one tick to confirm the gap)
    assert trace.got[:, [0, 1, 3]].all()  # the others never missed a tick
