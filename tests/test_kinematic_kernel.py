"""agents/kernels/kinematic.py: the kinematic phase's kernel, replayed on a recorded team's inboxes.

A 4-agent line runs 8 s in closed loop behind faulty links (loss, jitter that reorders and overtakes,
duplicates, an intruder, malformed messages); every agent's velocities and inboxes are recorded as rows.
The replay runs the kernel on them with two agents given a dynamical phase's feedback (feed-forward
alpha, a filter omega): the whole team as one batch equals each agent alone and a mixed batch, bit for
bit at every tick, and the compiled kernel equals the same source interpreted (``NUMBA_DISABLE_JIT=1``).
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rigid_truth import line_neighbours, reference_load, run_closed_loop
from test_agent_core import Links

from agents.agent import AgentCore
from agents.kernels.kinematic import HOLD_MAX, I_ALPHA, I_OM_MEAS, R_PAIRS, kin_bank, kin_step, set_kin_params
from agents.kernels.message_rows import in_rows
from agents.kernels.pair import pair_bank, pair_checkpoints
from config.agent_params import ControlSpec, EstimatorSpec
from net.messages import StateMsg
from net.rows import Layout

N = 4
NBRS = line_neighbours(N)
LAY = Layout(False, 0, 0, False, 2)
SECONDS = 8.0
NBRS_MASK = np.array([[k < len(NBRS[i]) for k in range(2)] for i in range(N)])  # the used neighbour slots


class _Spoilt(Links):
    """The link faults, plus an intruder's message and a malformed copy of every 7th message."""

    def __call__(self, tick: int, i: int, msgs: list[StateMsg]) -> list[StateMsg]:
        out = super().__call__(tick, i, msgs)
        if tick % 5 == 0:
            out.append(StateMsg(max(tick - 1, 0), 9, 1.0, 1.0, 1, {"om": 1.0, "oi": 1.0, "ph": 0.0, "yx": 0.0,
                                                                   "yy": 0.0}, {i: (1.0, 0.0)}))
        if tick % 7 == 0 and out:
            m = out[0]
            out.append(StateMsg(m.tick, m.sender, m.vx, m.vy, m.phase, {**m.shared, "ph": "x"}, m.pair))
        return out


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Every agent's (tick, velocity, inbox rows) of the closed-loop run, saved as an .npz."""
    calls: list[tuple[int, int, float, float, list[StateMsg]]] = []
    step = AgentCore.step

    def recording(self: AgentCore, tick: int, vx: float, vy: float, inbox: list[StateMsg]):  # noqa: ANN202
        calls.append((self.id, tick, vx, vy, list(inbox)))
        return step(self, tick, vx, vy, inbox)

    mp = pytest.MonkeyPatch()
    mp.setattr(AgentCore, "step", recording)
    try:
        run_closed_loop(reference_load(N), NBRS, sigma=0.3, seconds=SECONDS, seed=2, record_every=100,
                        deliver=_Spoilt(3, loss=0.1, delay=1, jitter=4, dup=0.1))
    finally:
        mp.undo()
    ticks = int(round(SECONDS / 0.01))
    assert len(calls) == ticks * N
    meas = np.zeros((ticks, N, 2))
    ptr = np.zeros((ticks, N + 1), np.int64)
    rows = []
    for c, (i, tick, vx, vy, inbox) in enumerate(calls):
        assert (tick, i) == divmod(c, N)
        meas[tick, i] = vx, vy
        rows.extend(in_rows(inbox, i, LAY))
        ptr[tick, i + 1] = len(rows)
    path = tmp_path_factory.mktemp("kin") / "inboxes.npz"
    np.savez(path, meas=meas, ptr=ptr, rows=np.array(rows))
    return path


def replay(path: Path, groups: list[list[int]]) -> np.ndarray:
    """The recorded run through the kernel, the agents batched as ``groups``; returns every agent's KIN
    record, NBR rows and pair records after every tick, as bytes (ticks, N, ...) to compare bit for bit."""
    with np.load(path) as data:
        meas, ptr, rows = data["meas"], data["ptr"], data["rows"]
    est = EstimatorSpec()
    H = est.history_ticks
    C = pair_checkpoints(est.fit_min_ticks, est.fit_max_ticks, est.fit_check_ticks)
    banks = []
    for g in groups:
        bank = kin_bank(len(g), 2, H)
        P, cps, prm = pair_bank(len(g), 2, C)
        for b, i in enumerate(g):
            # agents 1 and 2 as if a dynamical phase ran on top (its feed-forward and late samples)
            set_kin_params(bank[0], bank[1], P, prm, b, i, NBRS[i], 0.01, 0.3, est, ControlSpec(), i in (1, 2))
        banks.append((bank, P, cps, prm))
    ticks = len(meas)
    out = []
    for tick in range(ticks):
        snap: list[bytes] = [b""] * N
        for g, (bank, P, cps, prm) in zip(groups, banks, strict=True):
            kin = bank[0]
            inp = np.zeros((len(g), 6))
            inp[:, :2] = meas[tick, g]
            inp[:, I_OM_MEAS] = math.nan
            for b, i in enumerate(g):
                if kin[b]["dynamic"]:
                    inp[b, I_ALPHA] = 0.05 * math.sin(0.01 * tick * i)
                    inp[b, I_OM_MEAS] = 1.5 if i == 2 and tick > ticks // 2 else math.nan
            sel = np.concatenate([np.arange(ptr[tick, i], ptr[tick, i + 1]) for i in g]).astype(np.int64)
            in_ptr = np.concatenate([[0], np.cumsum([ptr[tick, i + 1] - ptr[tick, i] for i in g])]).astype(np.int64)
            E = len(sel)
            res = np.zeros((len(g), R_PAIRS + 8))
            late_t = np.zeros((len(g), E + 2 * (H + HOLD_MAX)), np.int64)
            err = kin_step(*bank, P, cps, prm, tick, inp, rows[sel].reshape(E, LAY.size_in), in_ptr,
                           np.zeros(E, np.int64), LAY.lay, np.zeros(E, np.int64), late_t, np.zeros(late_t.shape), res)
            assert err == -1
            for b, i in enumerate(g):
                snap[i] = kin[b].tobytes() + bank[1][b].tobytes() + P[b].tobytes() + res[b].tobytes()
        out.append(np.frombuffer(b"".join(snap), np.uint8))
    return np.array(out)


def test_a_batch_of_n_equals_n_batches_of_one(recorded: Path) -> None:
    alone = replay(recorded, [[i] for i in range(N)])
    assert np.array_equal(replay(recorded, [list(range(N))]), alone)
    assert np.array_equal(replay(recorded, [[2, 0], [3, 1]]), alone)


def test_the_replay_exercises_the_kernel(recorded: Path) -> None:
    """The recorded faults reach every path: pairs ready, held samples, unknown and stale messages."""
    data = dict(np.load(recorded))
    est = EstimatorSpec()
    bank = kin_bank(N, 2, est.history_ticks)
    P, cps, prm = pair_bank(N, 2, pair_checkpoints(est.fit_min_ticks, est.fit_max_ticks, est.fit_check_ticks))
    for i in range(N):
        set_kin_params(bank[0], bank[1], P, prm, i, i, NBRS[i], 0.01, 0.3, est, ControlSpec(), False)
    held = 0
    for tick in range(len(data["meas"])):
        sel = slice(data["ptr"][tick, 0], data["ptr"][tick, N])
        E = sel.stop - sel.start
        late_t = np.zeros((N, E + 2 * (est.history_ticks + HOLD_MAX)), np.int64)
        inp = np.zeros((N, 6))
        inp[:, :2] = data["meas"][tick]
        inp[:, I_OM_MEAS] = math.nan
        kin_step(*bank, P, cps, prm, tick, inp, data["rows"][sel], data["ptr"][tick] - sel.start,
                 np.zeros(E, np.int64), LAY.lay, np.zeros(E, np.int64), late_t, np.zeros(late_t.shape),
                 np.zeros((N, R_PAIRS + 8)))
        held += int(bank[1]["npend"].sum())
    kin = bank[0]
    assert P["ready"][NBRS_MASK].all() and kin["om_init"].all()
    assert held > 0 and (kin["dropped_unknown"] > 0).all() and (kin["dropped_stale"] > 0).all()


def test_compiled_equals_interpreted(recorded: Path, tmp_path: Path) -> None:
    """Agents 1 and 2 (two neighbours each, a dynamical phase's feedback) through the interpreted source."""
    out = tmp_path / "interpreted.npy"
    code = (f"import sys; sys.path.insert(0, {str(Path(__file__).parent)!r}); import numpy as np; "
            f"from test_kinematic_kernel import replay; "
            f"np.save({str(out)!r}, replay({str(recorded)!r}, [[1, 2]]))")
    env = {**os.environ, "NUMBA_DISABLE_JIT": "1"}
    subprocess.run([sys.executable, "-c", code], check=True, env=env, cwd=Path(__file__).parents[1], timeout=900)
    assert np.array_equal(np.load(out), replay(recorded, [[1, 2]]))
