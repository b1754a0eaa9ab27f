"""The agents that one process steps, behind one call per tick: the team core.

:meth:`TeamCore.step` (tick, measured velocities (B, 2), :class:`Inbox`) -> wrenches (B, 3): every agent's
tick. The agents' messages are float rows (net/rows.py): each tick's OUT rows stay in the team's OUT ring
``out`` (ring, B, size_out), slot ``tick % ring``; an inbox names each agent's due messages as a CSR over
that ring, in the order the agent takes them: ``ref[ptr[b]:ptr[b + 1]]`` = rows (ring slot, sender row,
the receiver's pair block in the sender's OUT row, -1: none). Estimates are built on demand
(:meth:`TeamCore.estimates`), on the ticks that are recorded. docs/fast-core-plan.md, sections 2 and 4 (S7).

A tick: one compiled gather of every IN row from the ring (agents/kernels/message_rows.py), one
kinematic kernel call for all B agents (agents/kernels/kinematic.py), one write of every OUT row's
kinematic part; with a dynamical phase, the kinematic results into its tick values
(agents/kernels/team_dynamic.py), one dyn_tick for all B rows (agents/kernels/dynamic_step.py), the Python
handlers of only the rows it stopped (:class:`agents.dynamic_phase.DynamicPhase`, row b of the team's
banks), the feedback into the next tick's kinematic inputs and the estimate trust's tick, compiled.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from statistics import NormalDist
from typing import NamedTuple

import numpy as np

import agents.kernels.window_stats as ws
from agents import dynamic_phase
from agents.estimate_trust import TRUST_NAMES, EstimateTrust
from agents.kernels import dynamic as DK
from agents.kernels import dynamic_step as DT
from agents.kernels.kinematic import (
    HOLD_MAX,
    I_OM_MEAS,
    R_DROPPED_STALE,
    R_DROPPED_UNKNOWN,
    R_FX,
    R_OM_INIT,
    R_OMEGA,
    R_PAIRS,
    R_READY,
    R_TAU,
    R_U,
    R_ZI,
    kin_bank,
    kin_step,
    set_kin_params,
)
from agents.kernels.message_rows import gather_inbox, write_kin_out
from agents.kernels.pair import pair_bank, pair_checkpoints
from agents.kernels.team_dynamic import (
    dyn_inputs,
    dyn_outputs,
    monitor_observe_rows,
    trust_entries_rows,
    trust_observe_rows,
)
from agents.laws import LawInput
from agents.pair_estimator import PairEstimator
from config.agent_params import ControlSpec, DynamicsSpec, EstimatorSpec
from net.messages import Estimate, StateMsg
from net.rows import Layout, state_from_row
from net.vocabulary import ESTIMATE_NAMES, KINEMATIC, SPINUP

# where each estimate entry comes from: the kinematic results, the dynamical kernel's, the trust's
_COL = {name: c for c, name in enumerate(ESTIMATE_NAMES)}
_KIN_COLS = [_COL[n] for n in ("omega", "omega_local", "zi_x", "zi_y")]
_KIN_RES = [R_OMEGA, R_U, R_ZI, R_ZI + 1]
_COUNT_COLS = [_COL[n] for n in ("pairs_ready", "dropped_unknown", "dropped_stale")]
_COUNT_RES = [R_READY, R_DROPPED_UNKNOWN, R_DROPPED_STALE]
_DEST_COLS = [_COL[n] for n in DK.ESTIMATES]
_TRUST_COLS = [_COL[n] for n in TRUST_NAMES]


class Member(NamedTuple):
    """One agent of a team: what :class:`agents.agent.AgentCore` is built from."""

    agent_id: int
    neighbours: Sequence[int]
    n: int
    dt: float
    sigma_v: float
    estimator: EstimatorSpec
    control: ControlSpec
    dynamics: DynamicsSpec | None = None
    law: Callable[[LawInput], Sequence[float]] | None = None  # a control law of the user's (agents/laws.py)


def assumed_sigma_v(m: Member) -> float:
    """The velocity noise the agent assumes: its estimator's, else the scenario's."""
    return float(m.estimator.sigma_v if m.estimator.sigma_v is not None else m.sigma_v)


@dataclass(frozen=True, slots=True)
class Inbox:
    """The due messages of every agent of a tick: ``ref[ptr[b]:ptr[b + 1]]`` are agent b's, in taking order."""

    ptr: np.ndarray  # (B + 1,) int64
    ref: np.ndarray  # (E, 3) int64: ring slot, sender row, the receiver's block in the sender's OUT row


class AgentView:
    """Row ``_row`` of a team: one agent's kinematic state, dynamical phase and stage, read by tests and tools."""

    _team: TeamCore
    _row: int

    @property
    def id(self) -> int:
        return self._team.ids[self._row]

    @property
    def stage(self) -> int:
        """The stage of the last tick stepped."""
        return self._team.stages[self._row]

    @property
    def _dyn(self) -> dynamic_phase.DynamicPhase | None:
        return self._team.dyns[self._row]

    @property
    def omega(self) -> float:
        """omega_hat (rad/s)."""
        return self._team.kin["omega"].item(self._row)

    @property
    def phi(self) -> float:
        """Body-frame angle (rad)."""
        return self._team.kin["phi"].item(self._row)

    @property
    def y(self) -> complex:
        """z_i in the body frame."""
        return self._team.kin["y"].item(self._row)

    @property
    def x(self) -> complex:
        """z_i estimate (world frame)."""
        ph = self.phi
        return self.y * complex(math.cos(ph), math.sin(ph))

    @property
    def trusted(self) -> bool:
        """Every pair is estimated."""
        return self._team.kin["trusted"].item(self._row)

    @property
    def dropped_unknown(self) -> int:
        return self._team.kin["dropped_unknown"].item(self._row)

    @property
    def dropped_stale(self) -> int:
        return self._team.kin["dropped_stale"].item(self._row)

    @property
    def pairs(self) -> dict[int, PairEstimator]:
        """Each neighbour's pair estimator (z_ij)."""
        t, b = self._team, self._row
        return {j: PairEstimator.of(t._P, t._cps, t._prm, b, k) for k, j in enumerate(t.nbr_ids[b])}


def _row_view(team: TeamCore, b: int) -> AgentView:
    v = AgentView()
    v._team, v._row = team, b
    return v


class TeamCore:
    """B agents' estimators and controllers, stepped together (module docstring)."""

    def __init__(self, members: Sequence[Member], ring: int = 2) -> None:
        """``ring``: slots of the OUT ring; an inbox may reach back ``ring - 1`` ticks (a message sent at
        tick k - ring + 1 is the oldest one due at tick k)."""
        if ring < 2:
            raise ValueError("the OUT ring needs 2 slots at least (messages are due a tick after they are sent)")
        self.B = B = len(members)
        self.ring = ring
        self.ids: list[int] = []
        self.nbr_ids: list[list[int]] = []  # each agent's neighbours, ascending (its pair blocks' order)
        self.dyns: list[dynamic_phase.DynamicPhase | None] = []
        dyn_members = []
        for m in members:
            if m.agent_id in m.neighbours:
                raise ValueError("an agent cannot be its own neighbour")
            self.ids.append(int(m.agent_id))
            self.nbr_ids.append(sorted(set(int(j) for j in m.neighbours)))
            if m.dynamics is not None and m.dynamics.algorithm != "none":
                dyn_members.append(m)
            elif m.law is not None:
                raise ValueError("a control law needs the dynamical phase "
                                 "(dynamics.algorithm sequential or background)")
        if dyn_members and len(dyn_members) < B:
            raise ValueError("a team's agents share one message layout (all with or all without a dynamical phase)")
        D = max(map(len, self.nbr_ids), default=0)
        self._dynamic = bool(dyn_members)
        if self._dynamic:
            self._init_dynamic(members, D)
        else:
            self.dyns = [None] * B
        self._lay = Layout(*(self._dyn_lay if self._dynamic else (False, 0, 0, False)), D)
        # the kinematic phase: one bank for the team (agents/kernels/kinematic.py) and its pair estimators
        H = max((m.estimator.history_ticks for m in members), default=1)
        self._bank = kin_bank(B, D, H)
        self.kin, self.nbr = self._bank[0], self._bank[1]
        self.vbuf = self._bank[4]
        self._P, self._cps, self._prm = pair_bank(B, D, max((pair_checkpoints(
            m.estimator.fit_min_ticks, m.estimator.fit_max_ticks, m.estimator.fit_check_ticks) for m in members),
            default=1))
        for b, m in enumerate(members):
            set_kin_params(self.kin, self.nbr, self._P, self._prm, b, self.ids[b], self.nbr_ids[b], float(m.dt),
                           assumed_sigma_v(m), m.estimator, m.control, self.dyns[b] is not None)
        self._id_arr = np.array(self.ids, np.int64)
        self._deg = np.array([len(ids) for ids in self.nbr_ids], np.int64)
        # blocks[s][r]: receiver row r's pair block in sender row s's OUT row
        row_of = {j: b for b, j in enumerate(self.ids)}
        self.blocks = [{row_of[j]: k for k, j in enumerate(ids) if j in row_of} for ids in self.nbr_ids]
        self.out = np.zeros((ring, B, self._lay.size_out))  # out[slot, row]: the OUT row of that tick's agent
        self.stages = [SPINUP] * B  # each agent's stage at the last tick
        self._inp = np.zeros((B, 6))  # the kinematic kernel's inputs (agents/kernels/kinematic.py I_*)
        self._inp[:, I_OM_MEAS] = math.nan  # (none before the dynamical phase runs)
        self._late_cap = D * (H + HOLD_MAX)  # held samples a tick can release
        self._res = np.zeros((B, R_PAIRS + 4 * D))
        self._tick_no = -1
        self._grow(0)

    def _init_dynamic(self, members: Sequence[Member], D: int) -> None:
        """The team's dynamical phase: one set of banks (agents/kernels/dynamic.py) and trust rows
        (agents/kernels/window_stats.py) for its B rows, the tick's arrays of dyn_tick
        (agents/kernels/dynamic_step.py), a :class:`agents.dynamic_phase.DynamicPhase` per row (its handlers
        and a view)."""
        B = self.B
        DP = dynamic_phase.DynamicPhase
        shapes = [DP.shape(int(m.n), float(m.dt), m.dynamics) for m in members]
        lays = {(s[0], s[3], m.dynamics.online_detection) for s, m in zip(shapes, members, strict=True)}
        if len(lays) > 1 or len({s[1] for s in shapes}) > 1:
            raise ValueError("a team's agents share one message layout (all with or all without a dynamical phase)")
        nch, nbk, det = lays.pop()
        self._dyn_lay = (True, nch, nbk, det)
        hist = max(m.estimator.history_ticks for m in members)
        banks = DK.new_banks(B, D, nch, shapes[0][1], hist, max(s[2] for s in shapes), nbk)
        self._dbanks = banks
        self._dkin = np.zeros((B, DT.NK))  # the tick's values
        self._dres = np.zeros((B, DT.NR))  # its results
        self._dres[:, DT.R_M_SD] = self._dres[:, DT.R_J_SD] = math.nan
        self._dest = np.zeros((B, len(DK.ESTIMATES)))  # the estimates' dynamical entries
        self._dids = np.full((B, D), -1, np.int64)  # the neighbour ids of the slots
        self._at = np.zeros(B, np.int64)
        self._all = np.arange(B, dtype=np.int64)
        self._in_ptr = np.zeros(B + 1, np.int64)
        self._stage = np.zeros(B, np.int64)
        # the estimate trust: a row per agent (its degree, the age of a fresh state, its level, the tails)
        tails = [round((m.dynamics.avg_window_s + m.dynamics.horizon_s) / float(m.dt)) for m in members]
        self._tr = tr = list(ws.trust_rows(B, D, 0, 0.0, 0.0, max(tails)))
        self.trust: list[EstimateTrust] = []
        # the innovation monitors: a row per agent (one window length for the team)
        windows = {d.monitor_window_s for d in (m.dynamics for m in members) if d.monitor_window_s > 0.0}
        if len(windows) > 1:
            raise ValueError("a team's innovation monitors share one window (dynamics.monitor_window_s)")
        mon = None
        if windows:
            mon = ws.monitor_rows(B, max(1, int(round(windows.pop() / float(members[0].dt)))), 0.0)
        self._mon = mon
        for b, m in enumerate(members):
            spec = m.dynamics
            one = ws.trust_rows(1, len(self.nbr_ids[b]), m.estimator.max_age_ticks, spec.trust_min_fresh,
                                NormalDist().inv_cdf(1.0 - spec.trust_alpha), tails[b])
            tr[0][b], tr[1][b], tr[3][b] = one[0][0], one[1][0], one[3][0]
            self.trust.append(EstimateTrust(0, 0, 0.0, spec.trust_alpha, rows=tuple(tr), b=b))
            self._dids[b, :len(self.nbr_ids[b])] = self.nbr_ids[b]
            if mon is not None:
                mon[1][b] = ws.monitor_rows(1, 1, spec.monitor_alpha)[1][0]  # its level
            self.dyns.append(DP(self.ids[b], self.nbr_ids[b], int(m.n), float(m.dt), assumed_sigma_v(m), spec,
                                m.estimator.history_ticks, law=m.law, law_ref=m.control.law,
                                team=(banks, self._dkin, self._dres, self._dest, mon), b=b))
        self._py_rows = [d for d in self.dyns if d.detect is not None]  # Python of their own every tick
        # the monitors the team's kernel feeds (the detection's rows feed theirs in Python)
        self._mon_on = np.array([d.monitor is not None and d.detect is None for d in self.dyns], np.bool_)
        self._auto = self._mon_on.copy()  # this tick's: those of rows no handler ran for
        self._full = np.zeros(B, np.int64)
        self._trust_out = np.zeros((B, len(TRUST_NAMES)))

    def _grow(self, n: int) -> None:
        """Scratch for a tick of n IN rows."""
        self._rows = np.zeros((n, self._lay.size_in))
        self._order = np.zeros(n, np.int64)
        self._acc = np.zeros(n, np.int64)
        self._late_t = np.zeros((self.B, n + self._late_cap), np.int64)
        self._late_z = np.zeros((self.B, n + self._late_cap))
        self._taken = np.zeros((n, self._lay.size_in))  # the accepted IN rows, in taking order
        self._pairs = np.zeros(2 * n, np.int64)

    def agent(self, i: int) -> AgentView:
        """Row i's view (read by tests and tools)."""
        return _row_view(self, i)

    def step(self, tick: int, meas: Sequence[Sequence[float]], inbox: Inbox) -> np.ndarray:
        """Every agent's tick: ``meas[b]`` its measured (vx, vy), ``inbox`` its due messages; the wrenches
        (B, 3). The OUT rows land in the ring's slot ``tick % ring`` after every agent has read its inbox."""
        E = len(inbox.ref)
        if E > len(self._order):
            self._grow(E)
        rows = self._rows[:E]
        gather_inbox(self.out, inbox.ref, self._lay.lay, rows)
        self._inp[:, :2] = meas
        return self._tick(tick, rows, inbox.ptr)

    def _tick(self, tick: int, rows: np.ndarray, ptr: np.ndarray) -> np.ndarray:
        """Every agent's tick on its IN rows ``rows[ptr[b]:ptr[b + 1]]`` (the measured velocities already in
        the kernel's inputs); the wrenches (B, 3)."""
        E = len(rows)
        if E > len(self._order):
            self._grow(E)
        inp = self._inp
        lay = self._lay
        res = self._res
        b = kin_step(*self._bank, self._P, self._cps, self._prm, tick, inp, rows, ptr, self._order, lay.lay,
                     self._acc, self._late_t, self._late_z, res)
        if b >= 0:
            raise ValueError(f"ticks must increase: got {tick} after {self.kin['last_tick'].item(b)}")
        self._tick_no = tick
        out = self.out[tick % self.ring]
        write_kin_out(out, tick, self._id_arr, inp, self._deg, res, lay.lay)
        if not self._dynamic:
            self.stages[:] = [KINEMATIC if o else SPINUP for o in res[:, R_OM_INIT].tolist()]
            return res[:, R_FX:R_TAU + 1].copy()
        return self._dynamic_tick(tick, rows, ptr, out)

    def _dynamic_tick(self, tick: int, rows: np.ndarray, ptr: np.ndarray, out: np.ndarray) -> np.ndarray:
        """Every agent's dynamical phase after the kinematic one: the tick's values, one dyn_tick for all rows,
        the handlers of the rows it stopped (then dyn_tick again on those), the feedback; the wrenches (B, 3)."""
        kin, res, in_ptr, taken, at = self._dkin, self._dres, self._in_ptr, self._taken, self._at
        dyn_inputs(tick, self._inp, self._res, ptr, self._acc, rows, self._late_t, kin, in_ptr, taken)
        for d in self._py_rows:
            d.begin()
        at[:] = DT.AT_BEGIN
        args = (kin, taken, in_ptr, self._late_t, self._late_z, self._lay.lay, self._dids, res, out, self._dest,
                *self._dbanks)
        dyns = self.dyns
        ended = self._py_rows
        if DT.dyn_tick(self._all, at, *args):
            handled = set()
            while True:
                stopped = np.flatnonzero(at != DT.AT_END)
                for b, p in zip(stopped.tolist(), at[stopped].tolist(), strict=True):
                    dyns[b].handle(p)  # type: ignore[union-attr]
                    handled.add(b)
                if not DT.dyn_tick(stopped, at, *args):
                    break
            ended = [dyns[b] for b in sorted(handled.union(d.b for d in ended))]
        for d in ended:
            d.end(out[d.b])  # type: ignore[union-attr]
        if self._mon is not None:
            auto = self._auto
            for d in ended:
                auto[d.b] = False  # type: ignore[union-attr]
            mon_k, _, mon_ws = self._mon
            for b in self._full[:monitor_observe_rows(auto, res, mon_k, mon_ws, self._full)].tolist():
                dyns[b].monitor.judge()  # type: ignore[union-attr]
            if ended:
                auto[:] = self._mon_on
        w = np.empty((self.B, 3))
        dyn_outputs(res, self._inp, w, self._stage)
        self.stages[:] = self._stage.tolist()
        tr = self._tr
        trust_observe_rows(tr[0], tr[2], tr[3], tr[4], tick, self._stage, taken, in_ptr, self._pairs)
        return w

    def estimate_rows(self) -> tuple[list[list[float]], list[list[tuple[int, float, float]]]]:
        """Every agent's estimate of the last tick stepped as rows: its values in ``ESTIMATE_NAMES``' order (NaN
        where it has none) and its pairs (neighbour id, z_ij x, z_ij y) by neighbour id."""
        res = self._res
        vals = np.full((self.B, len(ESTIMATE_NAMES)), math.nan)
        vals[:, _COL["phase"]] = self.stages
        vals[:, _KIN_COLS] = res[:, _KIN_RES]
        vals[:, _COUNT_COLS] = np.trunc(res[:, _COUNT_RES])  # whole counts
        if self._dynamic:
            trust_entries_rows(self._tr[1], self._tr[3], self._dest, self._dres, self._trust_out)
            vals[:, _DEST_COLS] = self._dest
            vals[:, _TRUST_COLS] = self._trust_out
            for d in self.dyns:
                if d.monitor is not None or d.detect is not None:  # type: ignore[union-attr]
                    for name, x in d.monitor_entries().items():  # type: ignore[union-attr]
                        vals[d.b, _COL[name]] = x  # type: ignore[union-attr]
        pairs = []
        for r, ids in zip(res[:, R_PAIRS:].tolist(), self.nbr_ids, strict=True):
            pairs.append(sorted((j, r[4 * k], r[4 * k + 1]) for k, j in enumerate(ids)))
        return vals.tolist(), pairs

    def estimates(self) -> list[Estimate]:
        """Every agent's estimate of the last tick stepped (valid until the next step)."""
        rows, pairs = self.estimate_rows()
        return [Estimate(self._tick_no, self.ids[b], dict(zip(ESTIMATE_NAMES, row, strict=True)),
                         {j: (x, y) for j, x, y in agent_pairs})
                for b, (row, agent_pairs) in enumerate(zip(rows, pairs, strict=True))]

    def message(self, tick: int, b: int) -> StateMsg:
        """Agent b's message of ``tick`` (one of the last ``ring`` ticks stepped) as the wire carries it."""
        return state_from_row(self.out[tick % self.ring, b], self._lay, self.nbr_ids[b])

    def states(self, tick: int) -> np.ndarray:
        """Every agent's OUT row of ``tick`` (one of the last ``ring`` ticks stepped): (B, size_out)."""
        return self.out[tick % self.ring]


def inbox_rows(ptr: Sequence[int], ref: Sequence[Sequence[int]]) -> tuple[np.ndarray, np.ndarray]:
    """A CSR's two arrays (``ref`` may be empty)."""
    return np.asarray(ptr, dtype=np.int64), np.asarray(ref, dtype=np.int64).reshape(-1, 3)


def lockstep_inboxes(team: TeamCore, senders: Sequence[Sequence[int]], age: int) -> list[Inbox]:
    """The inboxes of fault-free links of one fixed delay, where every message is due ``age`` ticks after it
    was sent: receiver b gets the messages of ``senders[b]`` (ascending, ``DelayLine``'s order) of tick
    k - age. Static: the inbox of tick k >= age is ``[k % team.ring]`` of the list returned; ticks < age
    have :func:`empty_inbox`."""
    if not 1 <= age < team.ring:
        raise ValueError(f"a message due {age} ticks after it is sent needs a ring of more than {age} slots")
    blocks = team.blocks
    out = []
    for k in range(team.ring):
        slot = (k - age) % team.ring
        ptr = [0]
        ref = []
        for b, row in enumerate(senders):
            ref += [(slot, s, blocks[s].get(b, -1)) for s in row]
            ptr.append(len(ref))
        out.append(Inbox(*inbox_rows(ptr, ref)))
    return out


def empty_inbox(team: TeamCore) -> Inbox:
    """No message for anyone."""
    return Inbox(*inbox_rows([0] * (team.B + 1), []))


def handle_inbox(team: TeamCore, tick: int, due: Sequence[Sequence[tuple[int, int]]]) -> Inbox:
    """The inbox of ``tick`` from each receiver's due handles (send tick, sender), in taking order: the
    messages that a link model delayed, lost, reordered or duplicated (a duplicate is two rows naming one
    message)."""
    ring = team.ring
    blocks = team.blocks
    ptr = [0]
    ref = []
    for b, handles in enumerate(due):
        for t, s in handles:
            if not 0 < tick - t < ring:
                raise ValueError(f"a message of tick {t} is due at {tick}: beyond the OUT ring ({ring} slots)")
            ref.append((t % ring, s, blocks[s].get(b, -1)))
        ptr.append(len(ref))
    return Inbox(*inbox_rows(ptr, ref))
