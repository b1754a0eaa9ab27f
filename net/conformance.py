"""Conformance checks for estimator cores (the contract in :mod:`net.estimator_core`).

Each check takes a :class:`net.estimator_core.CoreCase` and raises ``AssertionError`` naming the core
and the tick where it breaks the contract; :func:`check_all` runs them all. ``tests/test_conformance.py``
runs them over every core of the project; a new core gets a case there. See docs/agent-step.md.
"""

from __future__ import annotations

import contextlib
import random
import time
from collections.abc import Iterator
from typing import Any
from unittest import mock

import numpy as np

from net.estimator_core import CoreCase, EstimatorCore

_CLOCKS = ("time", "time_ns", "monotonic", "monotonic_ns", "perf_counter", "perf_counter_ns",
           "process_time", "process_time_ns", "sleep")


@contextlib.contextmanager
def no_clock() -> Iterator[None]:
    """Every clock of the ``time`` module raises while inside."""
    def refuse(*_: Any, **__: Any) -> Any:
        raise AssertionError("a core read a clock")

    with contextlib.ExitStack() as stack:
        for name in _CLOCKS:
            stack.enter_context(mock.patch.object(time, name, refuse))
        yield


def _run(case: CoreCase, seed: int, ticks: int) -> list[str]:
    core = case.make(seed)
    assert isinstance(core, EstimatorCore), f"{case.name}: the core has no step"
    return [repr(case.step(core, t, m, inbox)) for t, m, inbox in case.inputs(seed, ticks)]


def check_deterministic(case: CoreCase, seed: int = 7, ticks: int = 60) -> None:
    """Two cores built from the same seed, fed the same inputs, give the same outputs at every tick."""
    a = _run(case, seed, ticks)
    b = _run(case, seed, ticks)
    assert len(a) == len(b) == ticks, f"{case.name}: {len(a)} and {len(b)} outputs for {ticks} ticks"
    for k, (x, y) in enumerate(zip(a, b, strict=True)):
        assert x == y, f"{case.name}: two runs of seed {seed} differ at step {k}"


def check_no_global_rng(case: CoreCase, seed: int = 7, ticks: int = 30) -> None:
    """Building and stepping a core leaves numpy's and Python's global RNG states untouched."""
    np_before = np.random.get_state(legacy=False)
    py_before = random.getstate()
    _run(case, seed, ticks)
    np_after = np.random.get_state(legacy=False)
    assert np_before["bit_generator"] == np_after["bit_generator"], f"{case.name}: global numpy RNG used"
    assert np.array_equal(np_before["state"]["key"], np_after["state"]["key"]) and \
        np_before["state"]["pos"] == np_after["state"]["pos"], f"{case.name}: global numpy RNG used"
    assert random.getstate() == py_before, f"{case.name}: Python's global random used"


def check_no_clock(case: CoreCase, seed: int = 7, ticks: int = 30) -> None:
    """Stepping a core reads no clock: ``time.*`` raises during every step, and the outputs are the same."""
    want = _run(case, seed, ticks)
    core = case.make(seed)
    for k, (t, m, inbox) in enumerate(case.inputs(seed, ticks)):
        with no_clock():
            got = repr(case.step(core, t, m, inbox))
        assert got == want[k], f"{case.name}: outputs differ with the clocks off at step {k}"


def check_ticks_increase(case: CoreCase, seed: int = 7, ticks: int = 10) -> None:
    """A tick not after the last one is refused with ValueError (a replay would corrupt the state)."""
    if not case.checks_ticks:
        return
    core = case.make(seed)
    steps = case.inputs(seed, ticks)
    for t, m, inbox in steps:
        case.step(core, t, m, inbox)
    t, m, inbox = steps[-1]
    for again in (t, t - 1):
        try:
            case.step(core, again, m, inbox)
        except ValueError:
            continue
        raise AssertionError(f"{case.name}: tick {again} after tick {t} was accepted")


def check_malformed_counted(case: CoreCase, seed: int = 7, ticks: int = 40) -> None:
    """A malformed copy of an inbox entry, added at every tick, is counted and changes no output."""
    if not case.has_inbox:
        return
    steps = case.inputs(seed, ticks)
    want = _run(case, seed, ticks)
    core = case.make(seed)
    bad = 0
    for k, (t, m, inbox) in enumerate(steps):
        extra = [case.malformed(e) for e in inbox[:1]]
        bad += len(extra)
        before = case.dropped(core)
        got = repr(case.step(core, t, m, extra + list(inbox)))
        assert case.dropped(core) - before >= len(extra), f"{case.name}: a malformed entry at step {k} was not counted"
        assert got == want[k], f"{case.name}: a malformed entry at step {k} changed the outputs"
    assert bad > 0, f"{case.name}: the inputs have no inbox entries to break"


CHECKS = (check_deterministic, check_no_global_rng, check_no_clock, check_ticks_increase, check_malformed_counted)


def check_all(case: CoreCase) -> None:
    for check in CHECKS:
        check(case)
