"""The in-process engine: plant, agents and link models in one loop, no transport.

Used for fast runs, Monte Carlo campaigns and as the reference that a lockstep Zenoh run must
reproduce bit for bit: both feed each agent the inbox that ``net.link.DelayLine`` releases for the
tick, after the same per-link fault draws in the same (tick) order.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from agents.factory import build_team
from agents.team import empty_inbox, handle_inbox, lockstep_inboxes
from coload.analysis.summary import complete_summary
from coload.rundir.recorder import Recorder
from config.scenario import Scenario
from net.link import (
    DelayLine,
    LinkStats,
    build_in_links,
    deliver_tick,
    partition_events,
)
from net.vocabulary import ESTIMATE_NAMES
from simulator.plant import Plant, sensor_rng
from simulator.stop import done_stop

Progress = Callable[[int, int], None]


class LinkNetwork:
    """Every directed link of a scenario with its receiver's ``DelayLine`` and its counters.

    Shared by the in-process engines (paper 000's and the arm agents'), so that a message crosses a
    link the same way in each: ``send`` draws the link's fate and buffers the copies, ``inbox`` releases
    what is due, ``close`` settles the counters and gives the summary's ``links`` block.
    """

    def __init__(self, scenario: Scenario, mode: str) -> None:
        n = scenario.n
        self.dt = scenario.dt
        self.mode = mode
        neighbours = scenario.neighbours()
        # links[sender][receiver]: the model at the receiving end of sender -> receiver
        self.links: list[dict[int, Any]] = [{} for _ in range(n)]
        for receiver in range(n):
            for sender, model in build_in_links(scenario.agent_view(receiver), mode).items():
                self.links[sender][receiver] = model
        self.stats = {(s, r): LinkStats() for s in range(n) for r in self.links[s]}
        self.lines = [DelayLine() for _ in range(n)]
        # Hot-loop tables, built once (a tick's loop is ~1/3 slower without them):
        # out[i] = [(receiver, link model, its line's push, its stats)] in neighbour order, so a tick
        # does no dict lookups; counters that only move on faults are updated on the rare branches.
        self.out = [
            [(j, self.links[i][j], self.lines[j].push, self.stats[(i, j)]) for j in neighbours[i]]
            for i in range(n)
        ]
        self.pops = [line.pop_due for line in self.lines]

    def send(self, sender: int, k: int, state: Any) -> None:
        """``sender``'s message of tick ``k`` through each of its out-links."""
        dt, mode = self.dt, self.mode
        lockstep = mode == "lockstep"
        k1 = k + 1
        for _j, link, push, st in self.out[sender]:
            delays = link.deliveries(k)
            if len(delays) == 1:
                # deliver_tick(k, d, dt, mode), inlined
                push(k1 + int(delays[0]) if lockstep else k1 + int(delays[0] // dt), sender, k, 0, state)
                continue
            if not delays:
                st.count_lost(link, k)
                continue
            st.duplicated += len(delays) - 1
            for copy, d in enumerate(delays):
                push(deliver_tick(k, d, dt, mode), sender, k, copy, state)

    @property
    def reach(self) -> int:
        """The most ticks from a message's send tick to its delivery (1 + the longest delay a link draws)."""
        return max((deliver_tick(0, link.longest_delay, self.dt, self.mode) for row in self.links
                    for link in row.values()), default=1)

    def close(self, ticks: int) -> dict[str, dict[str, int]]:
        """Settles the counters of a run of ``ticks`` ticks; the summary's ``links`` block."""
        for st in self.stats.values():
            # one message per link per tick; each one delivered once unless dropped, partitioned, stale or duplicated
            st.sent += ticks
            st.delivered += ticks - st.dropped - st.partitioned - st.stale_age + st.duplicated
        return {f"{s}->{r}": st.as_dict() for (s, r), st in sorted(self.stats.items())}


def base_summary(engine: str, scenario: Scenario, mode: str, ticks: int, wall: float,
                 links: dict[str, dict[str, int]]) -> dict[str, Any]:
    """summary.json's head for an in-process engine (no daemons: nothing dropped at an edge, no timeouts)."""
    return {
        "engine": engine,
        "mode": mode,
        "sim_s": ticks * scenario.dt,
        "wall_s": wall,
        "seed": scenario.seed,
        "n": scenario.n,
        "scenario": scenario.name,
        "links": links,
        "drops": {},
        "timeouts": {"wrench": 0, "neighbour": 0},
        "events": partition_events(scenario),
    }


def run_inproc(
    scenario: Scenario,
    run_dir: Path | None,
    progress: Progress | None = None,
    pace: bool | None = None,
    tables: bool = True,
) -> dict[str, Any]:
    """Runs the scenario in this process; writes ``run_dir`` when given; returns the summary.

    ``pace`` holds each tick to wall-clock time (default: only in real-time mode). ``tables=False`` writes
    run.toml and summary.json only: the summary is computed from the recorder's tables in memory.
    """
    n, dt, ticks, mode = scenario.n, scenario.dt, scenario.ticks, scenario.mode
    pace = (mode == "realtime") if pace is None else pace
    plant = Plant(scenario)
    rng = sensor_rng(scenario.seed)
    neighbours = scenario.neighbours()
    net = LinkNetwork(scenario, mode)
    team = build_team([scenario.agent_view(i) for i in range(n)], ring=1 + net.reach)
    rec = Recorder(run_dir, scenario, ESTIMATE_NAMES, tables=tables) if run_dir is not None else None
    pops = net.pops
    send = net.send
    keeps = rec.keeps if rec is not None else None
    # Fault-free lockstep links (the common case): every message is due the same whole number of ticks
    # after it is sent, so each tick's inboxes are known in advance (DelayLine's order: by sender).
    # Otherwise the link models decide each message's fate, and its handle (send tick, sender) goes
    # through the receivers' DelayLines.
    fates = {m.fixed_delays for row in net.links for m in row.values()}
    fixed = None
    if mode == "lockstep" and len(fates) == 1 and None not in fates:
        (fate,) = fates
        (delay,) = fate  # type: ignore[misc]
        age = 1 + int(delay)
        fixed = lockstep_inboxes(team, [[i for i in range(n) if r in neighbours[i]] for r in range(n)], age)
        nothing = empty_inbox(team)

    stop = done_stop(scenario)
    every = scenario.record.every_ticks
    step_s = 0.0  # time inside TeamCore.step, for the per-agent cost in the summary
    clock = time.perf_counter
    wall0 = clock()
    report_every = max(1, ticks // 100)
    try:
        for k in range(ticks):
            if stop is not None and k >= stop.end:
                break
            if pace:
                lag = wall0 + k * dt - time.perf_counter()
                if lag > 0:
                    time.sleep(lag)
            meas = plant.measure(rng)  # (n, 2)
            # only recorded ticks need the truth and the estimates
            keep = keeps is not None and keeps(k)
            watch = stop is not None and k % every == 0  # the agents' stages, on the recording grid
            if keep:
                rec.truth(plant.truth())  # type: ignore[union-attr]
            if fixed is not None:
                inbox = fixed[k % team.ring] if k >= age else nothing
            else:
                inbox = handle_inbox(team, k, [pop(k) for pop in pops])
            c0 = clock()
            wrenches = team.step(k, meas, inbox)
            step_s += clock() - c0
            if fixed is None:
                for i in range(n):
                    send(i, k, (k, i))
            if keep:
                rec.estimate_rows(k, team.ids, *team.estimate_rows())  # type: ignore[union-attr]
            if watch:
                for i, stage in enumerate(team.stages):
                    stop.see(k, i, float(stage))  # type: ignore[union-attr]
            if rec is not None:
                rec.samples(k, meas, wrenches)
            plant.apply_and_step(wrenches)
            if progress is not None and (k % report_every == 0 or k == ticks - 1):
                progress(k + 1, ticks)
    except BaseException as exc:  # Ctrl-C, SIGTERM, an error: keep what was recorded, say where it stopped
        if rec is not None:
            rec.abort(type(exc).__name__)
        raise
    wall = time.perf_counter() - wall0
    if stop is not None:
        ticks = stop.end  # ticks run (fewer than the scenario's if it stopped after done)

    summary = base_summary("inproc", scenario, mode, ticks, wall, net.close(ticks))
    summary["agent_step_us"] = 1e6 * step_s / max(1, ticks * n)
    if rec is not None:
        summary = rec.close(summary)
        summary = complete_summary(run_dir, scenario, summary, None if tables else rec.held())
    return summary
