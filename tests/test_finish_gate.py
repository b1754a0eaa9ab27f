"""The end-of-run gate: a daemon reports once the neighbours' last states are in, whatever the order
in which their states, their liveliness changes and the simulator's ``done`` arrive."""

from __future__ import annotations

import asyncio

from net.finish import FinishGate

END = 200


async def _gate(events, grace_s=30.0):
    """Plays ``events`` (("done",) / ("state", j, tick) / ("gone", j)) into a gate the way a daemon
    does, for neighbours 0 and 1; returns the event index at which it reported (None: not yet)."""
    fired: list[int] = []
    at = [0]
    gate = FinishGate(lambda: fired.append(at[0]), grace_s=grace_s)
    last_from = {0: END - 2, 1: END - 2}
    expect = {0, 1}
    for at[0], ev in enumerate(events):
        if ev[0] == "done":
            gate.begin(END, last_from, expect)
        elif ev[0] == "state":
            last_from[ev[1]] = ev[2]
            expect.add(ev[1])
            gate.check(last_from, expect)
        else:
            expect.discard(ev[1])
            gate.check(last_from, expect)
    gate.cancel()
    return fired[0] if fired else None


def test_reports_when_the_last_states_are_in():
    events = [("state", 0, END - 1), ("done",), ("state", 1, END - 1)]
    assert asyncio.run(_gate(events)) == 2


def test_a_neighbour_that_finished_first_is_waited_for_even_when_its_token_goes_first():
    # neighbour 0 finished, reported and closed its session: its token's withdrawal reaches this
    # daemon (on another subscription's thread) before its last state does
    events = [("done",), ("state", 1, END - 1), ("gone", 0), ("state", 0, END - 1)]
    assert asyncio.run(_gate(events)) == 3
    events = [("gone", 0), ("done",), ("state", 1, END - 1), ("state", 0, END - 1)]
    assert asyncio.run(_gate(events)) == 3


def test_a_neighbour_that_fell_behind_and_left_is_not_waited_for():
    async def go():
        fired = []
        gate = FinishGate(lambda: fired.append(True), grace_s=30.0)
        last_from, expect = {0: END - 1, 1: 50}, {0, 1}  # 1 stopped sending at tick 50
        expect.discard(1)  # and its token went
        gate.begin(END, last_from, expect)
        gate.cancel()
        return fired

    assert asyncio.run(go()) == [True]


def test_the_grace_time_bounds_the_wait():
    async def go():
        done = asyncio.get_running_loop().create_future()
        gate = FinishGate(lambda: done.set_result(True), grace_s=0.01)
        gate.begin(END, {0: END - 2}, {0})  # its last state never comes
        return await asyncio.wait_for(done, timeout=10)

    assert asyncio.run(go()) is True
