"""The agent core: one robot's estimator and controller, composed of its kinematic and dynamical phases.

:meth:`AgentCore.step` (tick, own measured velocity, neighbour messages) -> :class:`StepResult`
(message to the neighbours, wrench to the plant, estimate): deterministic, no clock, socket or RNG.
Per tick: the inbox is encoded as rows (net/rows.py), the kinematic kernel
(agents/kernels/kinematic.py, a bank of one agent) runs, its results become a
:class:`agents.tick_records.KinematicTick`; :class:`agents.dynamic_phase.DynamicPhase` (if configured)
turns it into a :class:`agents.tick_records.DynamicOut`, whose feedback goes into the next tick's
kinematic phase. The wire content of :class:`net.messages.StateMsg`: docs/agent-step.md; the estimate
names: :data:`net.vocabulary.ESTIMATE_NAMES`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from agents import dynamic_phase
from agents.estimate_trust import EstimateTrust
from agents.kernels.kinematic import (
    HOLD_MAX,
    R_DROPPED_STALE,
    R_DROPPED_UNKNOWN,
    R_FX,
    R_FY,
    R_NACC,
    R_NLATE,
    R_OM_INIT,
    R_OMEGA,
    R_PAIRS,
    R_PHI,
    R_READY,
    R_TAU,
    R_TRUSTED,
    R_U,
    R_U_DEN,
    R_Y,
    R_ZI,
    kin_bank,
    kin_step,
    set_kin_params,
)
from agents.kernels.pair import pair_bank, pair_checkpoints
from agents.laws import LawInput
from agents.pair_estimator import PairEstimator
from agents.tick_records import DynamicFeedback, KinematicTick
from config.agent_params import ControlSpec, DynamicsSpec, EstimatorSpec
from net.messages import Estimate, StateMsg, Wrench
from net.rows import OM, PAIR_HEAD, PHASE, SENDER, TICK, VX, VY, YY, Layout, row_values, state_from_row
from net.vocabulary import ESTIMATE_NAMES, KINEMATIC, SPINUP

_DYN_NAMES = ESTIMATE_NAMES[ESTIMATE_NAMES.index("J"):]
_NO_DYN = dict.fromkeys(_DYN_NAMES, math.nan)


@dataclass(frozen=True, slots=True)
class StepResult:
    """One tick's outputs: ``state`` (to the neighbours), ``wrench`` (to the plant), ``estimate``."""

    state: StateMsg
    wrench: Wrench
    estimate: Estimate


class AgentCore:
    """Agent i's estimator and controller (module docstring)."""

    def __init__(
        self,
        agent_id: int,
        neighbours: Sequence[int],
        n: int,
        dt: float,
        sigma_v: float,
        estimator: EstimatorSpec,
        control: ControlSpec,
        dynamics: DynamicsSpec | None = None,
        law: Callable[[LawInput], Sequence[float]] | None = None,
    ) -> None:
        """``law``: a control law of the user's (agents/laws.py), called where the dynamical phase allows."""
        if agent_id in neighbours:
            raise ValueError("an agent cannot be its own neighbour")
        self.id = int(agent_id)
        self.n = int(n)
        self.dt = float(dt)
        sig = float(estimator.sigma_v if estimator.sigma_v is not None else sigma_v)
        self.sigma_v = sig
        self.spec = estimator
        dynamic = dynamics is not None and dynamics.algorithm != "none"
        if law is not None and not dynamic:
            raise ValueError("a control law needs the dynamical phase (dynamics.algorithm sequential or background)")
        ids = sorted(set(int(j) for j in neighbours))
        self._nbr_ids = ids
        self._dyn: dynamic_phase.DynamicPhase | None = None
        self._trust: EstimateTrust | None = None
        if dynamic:
            assert dynamics is not None
            # an averaging stage is judged on its convergence window and the agreement's horizon
            tail = round((dynamics.avg_window_s + dynamics.horizon_s) / self.dt)
            self._trust = EstimateTrust(len(ids), estimator.max_age_ticks, dynamics.trust_min_fresh,
                                        dynamics.trust_alpha, tail)
            self._dyn = dyn = dynamic_phase.DynamicPhase(self.id, ids, self.n, self.dt, sig, dynamics,
                                                         estimator.history_ticks, law=law, law_ref=control.law)
            self._lay = dyn.lay
        else:
            self._lay = Layout(False, 0, 0, False, len(ids))
        # the kinematic phase: a bank of one agent (agents/kernels/kinematic.py) and its pair estimators
        hist = estimator.history_ticks
        self._bank = kin_bank(1, len(ids), hist)
        self.kin, self.nbr = self._bank[0], self._bank[1]
        self.vbuf = self._bank[4]
        self._P, self._cps, self._prm = pair_bank(1, len(ids), pair_checkpoints(
            estimator.fit_min_ticks, estimator.fit_max_ticks, estimator.fit_check_ticks))
        set_kin_params(self.kin, self.nbr, self._P, self._prm, 0, self.id, ids, self.dt, sig, estimator, control,
                       dynamic)
        self._fb = DynamicFeedback()  # the dynamical phase's feedback to the next tick
        self.stage = SPINUP  # the stage of the last tick stepped
        self._last: tuple | None = None  # what that tick's estimate needs (advance)
        self._inp = np.zeros((1, 6))  # the kernel's inputs (agents/kernels/kinematic.py I_*)
        self._late_cap = len(ids) * (hist + HOLD_MAX)  # held samples a tick can release
        self._no_rows = np.zeros((0, self._lay.size_in))
        self._in_ptr = np.zeros(2, np.int64)
        self._res = np.zeros((1, R_PAIRS + 4 * len(ids)))
        # the agent's OUT row (net/rows.py): the header and the kinematic slots written here, then the
        # dynamical phase's; ``_heads``: each pair block's zx, zy, Fx, Fy, in the kernel's results' order
        lay = self._lay
        self._out = np.zeros(lay.size_out)
        self._out[SENDER] = self.id
        self._heads = np.array([lay.p0 + k * lay.block + c for k in range(len(ids)) for c in range(PAIR_HEAD)],
                               np.int64)
        self._grow(0)

    def _grow(self, n: int) -> None:
        """Scratch for an inbox of n messages."""
        self._order = np.zeros(n, np.int64)
        self._acc = np.zeros(n, np.int64)
        self._late_t = np.zeros((1, n + self._late_cap), np.int64)
        self._late_z = np.zeros((1, n + self._late_cap))

    # the kinematic phase's state, read by tests and tools
    @property
    def omega(self) -> float:
        """omega_hat (rad/s)."""
        return self.kin["omega"].item(0)

    @property
    def phi(self) -> float:
        """Body-frame angle (rad)."""
        return self.kin["phi"].item(0)

    @property
    def y(self) -> complex:
        """z_i in the body frame."""
        return self.kin["y"].item(0)

    @property
    def x(self) -> complex:
        """z_i estimate (world frame)."""
        ph = self.phi
        return self.y * complex(math.cos(ph), math.sin(ph))

    @property
    def trusted(self) -> bool:
        """Every pair is estimated."""
        return self.kin["trusted"].item(0)

    @property
    def dropped_unknown(self) -> int:
        return self.kin["dropped_unknown"].item(0)

    @property
    def dropped_stale(self) -> int:
        return self.kin["dropped_stale"].item(0)

    @property
    def pairs(self) -> dict[int, PairEstimator]:
        """Each neighbour's pair estimator (z_ij)."""
        return {j: PairEstimator.of(self._P, self._cps, self._prm, 0, k) for k, j in enumerate(self._nbr_ids)}

    def _kinematic(self, tick: int, vx: float, vy: float, inbox: Sequence[StateMsg]) -> KinematicTick:
        """The kinematic phase's tick: the inbox as rows through the kernel; its results as a record."""
        lay = self._lay
        n = len(inbox)
        if n > len(self._order):
            self._grow(n)
        me = self.id
        vals = [row_values(m, me, lay) for m in inbox]
        rows = np.array(vals) if n else self._no_rows
        self._inp[0] = (vx, vy, *self._fb)
        self._in_ptr[1] = n
        if kin_step(*self._bank, self._P, self._cps, self._prm, tick, self._inp, rows, self._in_ptr, self._order,
                    lay.lay, self._acc, self._late_t, self._late_z, self._res) >= 0:
            raise ValueError(f"ticks must increase: got {tick} after {self.kin['last_tick'].item(0)}")
        r = self._res[0].tolist()
        nl = int(r[R_NLATE])
        late = tuple(zip(self._late_t[0, :nl].tolist(), self._late_z[0, :nl].tolist(), strict=True)) if nl else ()
        na = int(r[R_NACC])
        dyn_in = rows[self._acc[:na]] if na else self._no_rows
        p = R_PAIRS
        pairs = tuple((j, complex(r[p + 4 * k], r[p + 4 * k + 1]), complex(r[p + 4 * k + 2], r[p + 4 * k + 3]))
                      for k, j in enumerate(self._nbr_ids))
        # (KinematicTick's fields in order)
        return KinematicTick(tick, complex(vx, vy), r[R_U], r[R_U_DEN], late, r[R_OMEGA], r[R_OM_INIT] != 0.0,
                             r[R_PHI], complex(r[R_Y], r[R_Y + 1]), complex(r[R_ZI], r[R_ZI + 1]), pairs,
                             int(r[R_READY]), r[R_TRUSTED] != 0.0, (r[R_FX], r[R_FY], r[R_TAU]), dyn_in,
                             int(r[R_DROPPED_UNKNOWN]), int(r[R_DROPPED_STALE]))

    def step(self, tick: int, vx: float, vy: float, inbox: Sequence[StateMsg]) -> StepResult:
        state, wrench = self.advance(tick, vx, vy, inbox)
        return StepResult(state, wrench, self.estimate())

    def advance(self, tick: int, vx: float, vy: float, inbox: Sequence[StateMsg]) -> tuple[StateMsg, Wrench]:
        """:meth:`step` without the estimate, which :meth:`estimate` builds on demand (an engine needs it only
        on recorded ticks)."""
        dyn = self._dyn
        kin = self._kinematic(tick, vx, vy, inbox)
        o = self._out
        o[TICK] = tick
        o[VX] = vx
        o[VY] = vy
        y = kin.y
        o[OM:YY + 1] = (kin.omega, 1.0 if kin.om_init else 0.0, kin.phi, y.real, y.imag)
        o[self._heads] = self._res[0, R_PAIRS:]
        if dyn is None:
            stage = KINEMATIC if kin.om_init else SPINUP
            o[PHASE] = stage
            fx, fy, tau = kin.wrench
            est = None
        else:
            out = dyn.step(kin, o)
            self._fb = out.feedback
            stage = out.stage
            fx, fy, tau = out.wrench
            taken = [(int(s), int(t)) for t, s in kin.inbox[:, TICK:SENDER + 1].tolist()]
            self._trust.observe(tick, stage, taken)  # type: ignore[union-attr]
            est = out.estimates
        self.stage = stage
        state = state_from_row(o, self._lay, self._nbr_ids)
        # what the estimate of this tick needs beyond the phases' state, which the next advance changes
        self._last = (tick, kin, est, state.pair)
        return state, Wrench(tick, self.id, fx, fy, tau)

    def estimate(self) -> Estimate:
        """The estimate of the last :meth:`advance`'s tick (valid until the next advance)."""
        tick, kin, est, pairs = self._last  # type: ignore[misc]
        dyn = self._dyn
        if dyn is None:
            dyn_est = _NO_DYN
        else:
            m_sd, j_sd = dyn.uncertainties()
            dyn_est = {**est, **self._trust.entries(est["m"], m_sd, est["J"], j_sd),  # type: ignore[union-attr]
                       **dyn.monitor_entries()}
        zi = kin.zi
        values = {
            "phase": float(self.stage),
            "omega": kin.omega,
            "omega_local": kin.u,
            "zi_x": zi.real,
            "zi_y": zi.imag,
            "pairs_ready": float(kin.ready),
            "dropped_unknown": float(kin.dropped_unknown),
            "dropped_stale": float(kin.dropped_stale),
            **dyn_est,
        }
        return Estimate(tick, self.id, values, {j: (p[0], p[1]) for j, p in pairs.items()})
