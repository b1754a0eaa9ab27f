"""The team's kernels between its phases (agents/kernels/team_dynamic.py): on their calls recorded from a
quick-dynamics run over faulty links (held, late, reordered and duplicated states; the monitor's windows),
compiled equals the same source interpreted (``py_func``) bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from agents.kernels import team_dynamic as TD
from tests.test_team_core import FAULTY

KERNELS = ("dyn_inputs", "dyn_outputs", "trust_observe_rows", "monitor_observe_rows", "trust_entries_rows")


def _copy(args: tuple) -> tuple:
    return tuple(a.copy() if isinstance(a, np.ndarray) else a for a in args)


@pytest.fixture(scope="module")
def recs() -> dict[str, list]:
    """(arguments before, arguments after, result) of each kernel on every 7th tick and every tick a monitor's
    window completes."""
    from agents import team as team_mod
    from agents.factory import build_team
    from agents.team import handle_inbox
    from coload.runs.engine import LinkNetwork
    from config.loader import load_scenario
    from simulator.plant import Plant, sensor_rng

    out: dict[str, list] = {k: [] for k in KERNELS}
    orig = {k: getattr(team_mod, k) for k in KERNELS}
    tick = [0]

    def recorder(name: str):  # noqa: ANN202
        def rec(*args):  # noqa: ANN002, ANN202
            before = _copy(args)
            got = orig[name](*args)
            if tick[0] % 7 == 0 or (name == "monitor_observe_rows" and got):
                out[name].append((before, _copy(args), got))
            return got
        return rec

    sc = load_scenario("quick-dynamics", ["duration=16", "dynamics.monitor_window_s=1", *FAULTY])
    try:
        for k in KERNELS:
            setattr(team_mod, k, recorder(k))
        plant = Plant(sc)
        rng = sensor_rng(sc.seed)
        net = LinkNetwork(sc, sc.mode)
        team = build_team([sc.agent_view(i) for i in range(sc.n)], ring=1 + net.reach)
        for k in range(sc.ticks):
            tick[0] = k
            due = [pop(k) for pop in net.pops]
            wr = team.step(k, plant.measure(rng).tolist(), handle_inbox(team, k, due))
            for i in range(sc.n):
                net.send(i, k, (k, i))
            if k % 7 == 0:
                team.estimates()
            plant.apply_and_step(wr)
    finally:
        for k, f in orig.items():
            setattr(team_mod, k, f)
    return out


def test_the_recording_covers_the_cases(recs):
    ins = recs["dyn_inputs"]
    assert len(ins) > 200
    assert any(int(x[1][8][-1]) > 0 for x in ins)  # IN rows taken
    assert any((x[0][2][:, TD.KN.R_NLATE] > 0).any() for x in ins)  # late samples
    assert any(n > 0 for _, _, n in recs["monitor_observe_rows"])  # complete windows
    assert any((x[1][4][:, 0] == x[1][4][:, 0]).any() for x in recs["trust_entries_rows"])  # m judged


@pytest.mark.parametrize("name", KERNELS)
def test_compiled_equals_py_func(recs, name):
    fn = getattr(TD, name)
    for before, after, got in recs[name]:
        args = _copy(before)
        assert fn.py_func(*args) == got
        assert all(np.asarray(a).tobytes() == np.asarray(b).tobytes() for a, b in zip(args, after, strict=True))
