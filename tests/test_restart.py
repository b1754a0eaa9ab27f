"""An agent daemon crashes mid-run and a fresh one takes its place (the daemons themselves, over the
in-memory transport): the simulator and the neighbours go on without it (liveliness), the new daemon
joins at the current tick, re-estimates, and the run completes with every agent's estimates."""

from __future__ import annotations

import asyncio

from agents.daemon import AgentDaemon
from coload.analysis.summary import complete_summary
from coload.rundir.recorder import Recorder
from config.loader import load_scenario
from net import keys
from net.memory import MemoryBus, MemoryTransport
from net.messages import Control
from net.schema import decode
from net.vocabulary import ESTIMATE_NAMES
from simulator.daemon import SimDaemon
from tests.conftest import SCENARIOS

CRASHED = 2


async def _run(tmp_path):
    sc = load_scenario(SCENARIOS / "quick.toml", ["timing.wrench_timeout_s=0.5", "timing.neighbour_timeout_s=0.5"])
    loop = asyncio.get_running_loop()
    bus, run = MemoryBus(), "restart"
    transports = {i: MemoryTransport(bus, loop) for i in range(sc.n)}
    tasks = {i: asyncio.ensure_future(AgentDaemon(sc.agent_view(i), transports[i], run).run()) for i in range(sc.n)}
    observer = MemoryTransport(bus, loop)
    reached: dict[int, asyncio.Future] = {300: loop.create_future(), 600: loop.create_future()}

    def on_control(_key: str, payload: bytes) -> None:
        msg = decode(payload, Control)
        for tick, fut in reached.items():
            if msg.tick >= tick and not fut.done():
                fut.set_result(msg.tick)

    observer.subscribe(keys.sim_control(run), on_control)
    sim_t = MemoryTransport(bus, loop)
    sim = asyncio.ensure_future(SimDaemon(sc, sim_t, run, Recorder(tmp_path / "run", sc, ESTIMATE_NAMES), engine="memory").run())
    try:
        await asyncio.wait_for(reached[300], 60)
        tasks[CRASHED].cancel()  # the process dies: its subscriptions and token go with it
        transports[CRASHED].close()
        await asyncio.wait_for(reached[600], 60)  # the run goes on without it
        transports[CRASHED] = MemoryTransport(bus, loop)
        tasks[CRASHED] = asyncio.ensure_future(AgentDaemon(sc.agent_view(CRASHED), transports[CRASHED], run).run())
        summary = await asyncio.wait_for(sim, 120)
        reports = await asyncio.wait_for(asyncio.gather(*tasks.values()), 30)
    finally:
        for t in [*tasks.values(), sim]:
            t.cancel()
        for t in [*transports.values(), observer, sim_t]:
            t.close()
    return sc, complete_summary(tmp_path / "run", sc, summary), reports


def test_crashed_agent_is_replaced_and_the_run_completes(tmp_path):
    sc, summary, reports = asyncio.run(_run(tmp_path))
    events = [(e["event"], e.get("agent")) for e in summary["events"]]
    assert ("agent_down", CRASHED) in events and ("agent_up", CRASHED) in events
    assert summary["agents_reported"] == list(range(sc.n))
    restarted = next(r for r in reports if r.agent == CRASHED)
    assert 0 < restarted.ticks < sc.ticks - 600  # joined late, stepped to the end
    samples = (tmp_path / "run" / "samples.csv").read_text().splitlines()
    assert len(samples) == 1 + sc.n * sc.ticks  # every tick recorded, the dead agent's with zero wrench
    errors = summary["errors"]
    # the replacement re-estimated from scratch within the ~14 s it had left (quick converges in ~11 s)
    assert errors["zi_err_per_agent"][CRASHED] is not None
    assert errors["eerd_ratio_per_agent"][CRASHED] < 0.05
    assert max(errors["zi_err_per_agent"]) < 0.2


async def _sim_dies(tmp_path):
    sc = load_scenario(SCENARIOS / "quick.toml", ["timing.sim_lost_timeout_s=1.0"])
    loop = asyncio.get_running_loop()
    bus, run = MemoryBus(), "simdies"
    transports = {i: MemoryTransport(bus, loop) for i in range(sc.n)}
    daemons = {i: AgentDaemon(sc.agent_view(i), transports[i], run) for i in range(sc.n)}
    tasks = {i: asyncio.ensure_future(d.run()) for i, d in daemons.items()}
    observer = MemoryTransport(bus, loop)
    reached = loop.create_future()
    reports: list[int] = []
    observer.subscribe(keys.sim_control(run), lambda _k, p: (decode(p, Control).tick >= 100 and not reached.done()
                                                             and reached.set_result(True)))
    observer.subscribe(keys.agent_all(run, "report"), lambda key, _p: reports.append(keys.parse_agent_key(key).agent))
    sim_t = MemoryTransport(bus, loop)
    sim = asyncio.ensure_future(SimDaemon(sc, sim_t, run, Recorder(tmp_path / "run", sc, ESTIMATE_NAMES), engine="memory").run())
    try:
        await asyncio.wait_for(reached, 60)
        sim.cancel()  # the simulator's process dies and nobody restarts it
        sim_t.close()
        t0 = loop.time()
        done = await asyncio.wait_for(asyncio.gather(*tasks.values()), 30)
        waited = loop.time() - t0
    finally:
        for t in [*tasks.values(), sim]:
            t.cancel()
        for t in [*transports.values(), observer]:
            t.close()
    return sc, daemons, done, reports, waited


def test_agents_give_up_on_a_simulator_that_never_comes_back(tmp_path):
    """Without a simulator the agents wait timing.sim_lost_timeout_s (a restart would resume the
    run), then each sends its report and ends, marked as having given up; none hangs."""
    sc, daemons, done, reports, waited = asyncio.run(_sim_dies(tmp_path))
    assert all(d.gave_up for d in daemons.values())
    assert sorted(r.agent for r in done) == sorted(reports) == list(range(sc.n))
    assert all(r.ticks >= 100 for r in done)
    assert 1.0 <= waited < 10.0
    assert (tmp_path / "run" / "interrupted.json").exists()  # the cancelled simulator kept its tables


async def _core_fails(tmp_path):
    sc = load_scenario(SCENARIOS / "quick.toml", ["duration=5", "timing.wrench_timeout_s=0.5",
                                                    "timing.neighbour_timeout_s=0.5"])
    loop = asyncio.get_running_loop()
    bus, run = MemoryBus(), "fails"
    transports = {i: MemoryTransport(bus, loop) for i in range(sc.n)}
    daemons = {i: AgentDaemon(sc.agent_view(i), transports[i], run) for i in range(sc.n)}
    class Failing:  # the agent's core, with a bug at tick 200
        def __init__(self, core):
            self.core = core

        def step(self, k, *args):
            if k == 200:
                raise RuntimeError("a bug")
            return self.core.step(k, *args)

        def __getattr__(self, name):
            return getattr(self.core, name)

    daemons[CRASHED].core = Failing(daemons[CRASHED].core)
    tasks = {i: asyncio.ensure_future(d.run()) for i, d in daemons.items()}
    sim_t = MemoryTransport(bus, loop)
    try:
        summary = await asyncio.wait_for(SimDaemon(sc, sim_t, run, Recorder(tmp_path / "run", sc, ESTIMATE_NAMES), engine="memory").run(), 120)
        reports = await asyncio.wait_for(asyncio.gather(*tasks.values()), 30)
    finally:
        for t in tasks.values():
            t.cancel()
        for t in [*transports.values(), sim_t]:
            t.close()
    return sc, daemons, summary, reports


def test_an_agent_whose_step_fails_leaves_the_run_like_a_crashed_one(tmp_path):
    """An exception in an agent's core (a bug, or a user's control law) ends that daemon with its one-line
    cause (its process exits 1), instead of leaving it half alive inside a transport callback, where a
    lockstep run crawled at one neighbour timeout per tick; the others and the simulator finish."""
    sc, daemons, summary, reports = asyncio.run(_core_fails(tmp_path))
    assert daemons[CRASHED].failed == f"agent {CRASHED} failed at tick 200: RuntimeError: a bug"
    assert all(d.failed is None for i, d in daemons.items() if i != CRASHED)
    assert summary["sim_s"] == sc.duration - sc.dt or summary["sim_s"] == sc.duration
    assert reports[CRASHED].ticks == 200
    assert all(r.ticks == sc.ticks for i, r in enumerate(reports) if i != CRASHED)
