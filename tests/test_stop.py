"""simulator.stop.DoneStop: the early-end rule both engines share."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from net.vocabulary import DONE, J_AVERAGE
from simulator.stop import DoneStop


def test_ends_after_the_last_agent_is_done():
    s = DoneStop(3, ticks=1000, after_ticks=50)
    s.see(100, 0, DONE)
    s.see(100, 1, J_AVERAGE)
    s.see(110, 2, DONE)
    assert not s.triggered and s.end == 1000
    s.see(120, 1, DONE)
    assert s.triggered and s.end == 120 + 1 + 50
    s.see(130, 1, DONE)  # seen again: nothing moves
    assert s.end == 171


def test_never_past_the_duration():
    s = DoneStop(1, ticks=100, after_ticks=50)
    s.see(90, 0, DONE)
    assert s.end == 100


@given(st.lists(st.tuples(st.integers(0, 4), st.sampled_from([DONE, J_AVERAGE, float("nan")])), max_size=40))
def test_end_is_the_tick_that_completed_the_set(events):
    """Whatever the order of estimates: the end is set exactly when the last agent is first seen done."""
    s = DoneStop(5, ticks=10_000, after_ticks=7)
    seen: set[int] = set()
    end = 10_000
    for t, (agent, phase) in enumerate(events):
        s.see(t, agent, phase)
        if phase == DONE and agent not in seen:
            seen.add(agent)
            if len(seen) == 5:
                end = t + 8
    assert s.triggered == (len(seen) == 5)
    assert s.end == end
