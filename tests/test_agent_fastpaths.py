"""The agent core's and the in-process engine's fast paths change no result.

* ``StepResult.estimate`` is built lazily from a snapshot: it must equal what an eager build gives,
  whenever it is read;
* the engine's ring buffer for fault-free lockstep links must hand every agent the inbox that
  ``DelayLine`` would.
"""

from __future__ import annotations

import hashlib
import math

import numpy as np
import pytest

from agents.agent import AgentCore, StepResult
from coload.runs.engine import run_inproc
from config.agent_params import ControlSpec, EstimatorSpec
from config.loader import load_scenario
from net.link import LinkModel
from net.messages import Estimate, StateMsg
from tests.conftest import SCENARIOS


def _inputs(seed: int, ticks: int):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(seed)
    for k in range(ticks):
        inbox = [
            StateMsg(k - 1, j, float(rng.normal()), float(rng.normal()), 1,
                     {"om": 0.5, "oi": 1.0, "ph": 0.1 * k, "yx": 0.2, "yy": -0.1}, {1: (0.3, 0.4, 0.01, -0.02)})
            for j in (0, 2)
        ]
        yield k, float(rng.normal()), float(rng.normal()), inbox


def test_lazy_estimate_equals_eager_whenever_read() -> None:
    a = AgentCore(1, [0, 2], 3, 0.01, 0.3, EstimatorSpec(), ControlSpec())
    b = AgentCore(1, [0, 2], 3, 0.01, 0.3, EstimatorSpec(), ControlSpec())
    kept = []
    for k, vx, vy, inbox in _inputs(5, 200):
        ra = a.step(k, vx, vy, inbox)
        rb = b.step(k, vx, vy, inbox)
        eager = rb.estimate  # read at once
        assert isinstance(eager, Estimate)
        assert eager.values["zi_x"] == b.x.real and eager.values["zi_y"] == b.x.imag
        assert eager.pairs == {j: p[:2] for j, p in rb.state.pair.items()}
        kept.append((ra, eager))
    for ra, eager in kept:  # read late: the snapshot, not the agent's current state
        assert ra.estimate == eager
        assert ra.estimate is ra.estimate  # built once


def test_step_result_behaves_like_the_dataclass() -> None:
    a = AgentCore(1, [0, 2], 3, 0.01, 0.3, EstimatorSpec(), ControlSpec())
    r = a.step(0, 0.1, 0.2, [])
    again = StepResult(r.state, r.wrench, r.estimate)
    assert again == r
    assert (again != r) is False
    assert repr(again) == repr(r)
    assert repr(r).startswith("StepResult(state=StateMsg(") and "estimate=Estimate(" in repr(r)
    assert r != StepResult(r.state, r.wrench, Estimate(0, 1, {}, {}))
    with pytest.raises(TypeError):
        hash(r)
    nan_u = r.estimate.values["omega_local"]
    assert math.isnan(nan_u)


def _hashes(run_dir) -> dict[str, str]:  # type: ignore[no-untyped-def]
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(run_dir.glob("*.csv"))}


@pytest.mark.parametrize("delay", [0, 2])
def test_engine_ring_buffer_equals_delay_line(tmp_path, monkeypatch, delay: int) -> None:
    sc = load_scenario(SCENARIOS / "paper-fig4.toml", ["duration=6", "initial.omega=0", "record.every_ticks=1",
                                                       f"link.delay_ticks={delay}"])
    fast = run_inproc(sc, tmp_path / "fast")
    monkeypatch.setattr(LinkModel, "fixed_delays", property(lambda self: None))  # force the DelayLine path
    slow = run_inproc(sc, tmp_path / "slow")
    assert _hashes(tmp_path / "fast") == _hashes(tmp_path / "slow")
    assert fast["links"] == slow["links"]
    assert all(v["delivered"] == v["sent"] == 600 for v in fast["links"].values())
