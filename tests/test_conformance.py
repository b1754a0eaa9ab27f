"""Every estimator core of the project passes the shipped conformance checks (net/conformance.py):
deterministic for a seed, no global RNG, no clock, ticks increase, a malformed inbox entry is counted."""

from __future__ import annotations

import json
import warnings
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from agents.agent import AgentCore
from agents.arm import ArmModel, make_observer
from config.agent_params import ControlSpec, DynamicsSpec, EstimatorSpec
from net import conformance
from net.hinf_messages import HinfState
from net.messages import StateMsg

ROOT = Path(__file__).resolve().parents[1]
warnings.filterwarnings("ignore", message="Solution may be inaccurate")
_DYN = DynamicsSpec(algorithm="sequential")


class AgentCase:
    """AgentCore (both phases) as agent 1 of a line of three, fed its neighbours' real messages."""

    name = "AgentCore"
    has_inbox = True
    checks_ticks = True

    def make(self, seed: int) -> AgentCore:
        return AgentCore(1, [0, 2], 3, 0.01, 0.3, EstimatorSpec(), ControlSpec(), _DYN)

    def inputs(self, seed: int, ticks: int) -> list[tuple[int, Any, list[Any]]]:
        rng = np.random.default_rng(seed)
        team = [AgentCore(i, [j for j in (i - 1, i + 1) if 0 <= j < 3], 3, 0.01, 0.3, EstimatorSpec(),
                          ControlSpec(), _DYN) for i in range(3)]
        sent: list[StateMsg] = []
        out = []
        for k in range(ticks):
            v = rng.normal(0.0, 0.5, (3, 2))
            inbox = [m for m in sent if m.sender != 1]
            out.append((k, (float(v[1, 0]), float(v[1, 1])), inbox))
            sent = [a.step(k, float(v[i, 0]), float(v[i, 1]), [m for m in sent if m.sender != i]).state
                    for i, a in enumerate(team)]
        return out

    def step(self, core: AgentCore, tick: int, measurement: Any, inbox: Any) -> Any:
        r = core.step(tick, measurement[0], measurement[1], inbox)
        values = {k: v for k, v in r.estimate.values.items() if not k.startswith("dropped")}  # counters differ
        return r.state, r.wrench, values

    def malformed(self, entry: StateMsg) -> StateMsg:
        return replace(entry, shared={k: v for k, v in entry.shared.items() if k != "om"})

    def dropped(self, core: AgentCore) -> int:
        return core.dropped_stale


class HinfCase:
    """Paper 003's estimator k = 0 of the Sec. 5 example, fed random measurements and neighbour states."""

    name = "hinf EstimatorCore"
    has_inbox = True
    checks_ticks = True

    def __init__(self) -> None:
        from hinf import load_spec, run_design
        from hinf import runtime as R

        spec = load_spec(ROOT / "config" / "hinf" / "sec5-cyclic.toml")
        self.setup = R.build_setup(spec, json.loads(json.dumps(run_design(spec))))
        self.R = R

    def make(self, seed: int) -> Any:
        return self.R.EstimatorCore(self.setup, 0)

    def inputs(self, seed: int, ticks: int) -> list[tuple[int, Any, list[Any]]]:
        rng = np.random.default_rng(seed)
        core = self.make(seed)
        nz = core.Tz.shape[1]
        out = []
        for t in range(ticks):
            inbox = [HinfState(t - 1, j, tuple(rng.normal(size=x.shape).tolist()), tuple(rng.normal(size=u.shape).tolist()),
                               tuple(rng.normal(size=z.shape).tolist())) for j, (_, x, u, z) in core.nb.items()]
            out.append((t, tuple(rng.normal(size=nz).tolist()), inbox if t > 0 else []))
        return out

    def step(self, core: Any, tick: int, measurement: Any, inbox: Any) -> Any:
        return core.step(tick, measurement, inbox)

    def malformed(self, entry: HinfState) -> HinfState:
        return replace(entry, xhat=entry.xhat + (1.0,))

    def dropped(self, core: Any) -> int:
        return core.dropped


class _ArmObserverCore:
    """Paper 004's speed observer on one arm, stepped on sampled encoders every 1 ms (its state held here)."""

    def __init__(self) -> None:
        self.ob = make_observer(ArmModel(0.8, 0.8, 4.0, 2.0), 20.0, 8.0, 25.0, 1e-3, 8, seed=0)
        q0 = np.array([0.3, 1.4])
        self.state = self.ob.start(q0, np.zeros(2), q0, np.zeros(2), 0.01)

    def step(self, tick: int, y: Any, u: Any) -> list[float]:
        """The joint-speed estimate after the encoder sample ``y`` under the held input ``u``."""
        self.state = self.ob.step(self.state, y, u, 1e-3)
        return self.ob.estimate(self.state.vector(), y).tolist()


class ArmCase:
    """The arm speed observer: no inbox, and time enters as dt, not as a tick."""

    name = "arm speed observer"
    has_inbox = False
    checks_ticks = False

    def make(self, seed: int) -> _ArmObserverCore:
        return _ArmObserverCore()

    def inputs(self, seed: int, ticks: int) -> list[tuple[int, Any, list[Any]]]:
        rng = np.random.default_rng(seed)
        q = np.array([0.3, 1.4]) + np.cumsum(rng.normal(0.0, 1e-3, (ticks, 2)), axis=0)
        u = rng.normal(0.0, 1.0, (ticks, 2))
        return [(k, (q[k], u[k]), []) for k in range(ticks)]

    def step(self, core: _ArmObserverCore, tick: int, measurement: Any, inbox: Any) -> Any:
        return core.step(tick, measurement[0], measurement[1])

    def malformed(self, entry: Any) -> Any:  # pragma: no cover - no inbox
        raise NotImplementedError

    def dropped(self, core: Any) -> int:  # pragma: no cover - no inbox
        return 0


@pytest.fixture(scope="module", params=[AgentCase, HinfCase, ArmCase], ids=lambda c: c.name)
def case(request: pytest.FixtureRequest) -> Any:
    return request.param()


@pytest.mark.parametrize("check", conformance.CHECKS, ids=lambda c: c.__name__)
def test_core_conforms(case: Any, check: Any) -> None:
    check(case)


def test_checks_catch_a_core_that_breaks_the_contract() -> None:
    """The checks can fail: a core that reads the clock, one that uses the global RNG, one that accepts
    any tick and one that raises on a malformed entry are each caught."""
    import time

    class Bad(AgentCase):
        def __init__(self, flaw: str) -> None:
            self.flaw = flaw

        def step(self, core: AgentCore, tick: int, measurement: Any, inbox: Any) -> Any:
            if self.flaw == "clock":
                time.perf_counter()
            elif self.flaw == "rng":
                np.random.random()
            elif self.flaw == "malformed" and any("om" not in m.shared for m in inbox):
                raise KeyError("om")
            out = super().step(core, tick, measurement, inbox)
            if self.flaw == "ticks":
                core.kin["last_tick"] = -1  # forgets the tick: accepts a replay
            return out

    for flaw, check in (("clock", conformance.check_no_clock), ("rng", conformance.check_no_global_rng),
                        ("ticks", conformance.check_ticks_increase), ("malformed", conformance.check_malformed_counted)):
        state = np.random.get_state()
        with pytest.raises((AssertionError, KeyError)):
            check(Bad(flaw))
        np.random.set_state(state)
