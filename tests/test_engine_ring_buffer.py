"""The in-process engine's fixed inboxes for fault-free lockstep links (agents.team.lockstep_inboxes) hand every
agent the inbox that ``DelayLine`` would."""

from __future__ import annotations

import hashlib

import pytest

from coload.runs.engine import run_inproc
from config.loader import load_scenario
from net.link import LinkModel
from tests.conftest import SCENARIOS


def _hashes(run_dir) -> dict[str, str]:  # type: ignore[no-untyped-def]
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(run_dir.glob("*.csv"))}


@pytest.mark.parametrize("delay", [0, 2])
def test_fixed_lockstep_inboxes_equal_the_delay_line(tmp_path, monkeypatch, delay: int) -> None:
    sc = load_scenario(SCENARIOS / "paper-fig4.toml", ["duration=6", "initial.omega=0", "record.every_ticks=1",
                                                       f"link.delay_ticks={delay}"])
    fast = run_inproc(sc, tmp_path / "fast")
    monkeypatch.setattr(LinkModel, "fixed_delays", property(lambda self: None))  # force the DelayLine path
    slow = run_inproc(sc, tmp_path / "slow")
    assert _hashes(tmp_path / "fast") == _hashes(tmp_path / "slow")
    assert fast["links"] == slow["links"]
    assert all(v["delivered"] == v["sent"] == 600 for v in fast["links"].values())
