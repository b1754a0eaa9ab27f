"""The agent core: one robot's estimator and controller, composed of its kinematic and dynamical phases.

:meth:`AgentCore.step` (tick, own measured velocity, neighbour messages) -> :class:`StepResult`
(message to the neighbours, wrench to the plant, estimate): deterministic, no clock, socket or RNG.
Per tick: :class:`agents.kinematic_phase.KinematicPhase` gives a
:class:`agents.tick_records.KinematicTick`; :class:`agents.dynamic_phase.DynamicPhase` (if configured)
turns it into a :class:`agents.tick_records.DynamicOut`, whose feedback goes into the next tick's
kinematic phase. The wire content of :class:`net.messages.StateMsg`: docs/agent-step.md; the estimate
names: :data:`net.vocabulary.ESTIMATE_NAMES`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from agents import dynamic_phase
from agents.estimate_trust import EstimateTrust
from agents.kinematic_phase import KinematicPhase
from agents.laws import LawInput
from agents.pair_estimator import PairEstimator
from agents.tick_records import DynamicFeedback
from config.agent_params import ControlSpec, DynamicsSpec, EstimatorSpec
from net.messages import Estimate, StateMsg, Wrench
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
        self._kin = KinematicPhase(self.id, neighbours, self.dt, sig, estimator, control, dynamic)
        self._dyn: dynamic_phase.DynamicPhase | None = None
        self._trust: EstimateTrust | None = None
        if dynamic:
            assert dynamics is not None
            # an averaging stage is judged on its convergence window and the agreement's horizon
            tail = round((dynamics.avg_window_s + dynamics.horizon_s) / self.dt)
            self._trust = EstimateTrust(len(self._kin.nbrs), estimator.max_age_ticks, dynamics.trust_min_fresh,
                                        dynamics.trust_alpha, tail)
            self._dyn = dynamic_phase.DynamicPhase(self.id, sorted(self._kin.nbrs), self.n, self.dt, sig, dynamics,
                                                   estimator.history_ticks, law=law, law_ref=control.law)
        self._fb = DynamicFeedback()  # the dynamical phase's feedback to the next tick
        self.stage = SPINUP  # the stage of the last tick stepped
        self._last: tuple | None = None  # what that tick's estimate needs (advance)

    # the kinematic phase's state, read by tests and tools
    @property
    def omega(self) -> float:
        """omega_hat (rad/s)."""
        return self._kin.omega

    @property
    def phi(self) -> float:
        """Body-frame angle (rad)."""
        return self._kin.phi

    @property
    def y(self) -> complex:
        """z_i in the body frame."""
        return self._kin.y

    @property
    def x(self) -> complex:
        """z_i estimate (world frame)."""
        ph = self._kin.phi
        return self._kin.y * complex(math.cos(ph), math.sin(ph))

    @property
    def trusted(self) -> bool:
        """Every pair is estimated."""
        return self._kin.trusted

    @property
    def dropped_unknown(self) -> int:
        return self._kin.dropped_unknown

    @property
    def dropped_stale(self) -> int:
        return self._kin.dropped_stale

    @property
    def pairs(self) -> dict[int, PairEstimator]:
        """Each neighbour's pair estimator (z_ij)."""
        return {j: nb.pair for j, nb in self._kin.nbrs.items()}

    def step(self, tick: int, vx: float, vy: float, inbox: Sequence[StateMsg]) -> StepResult:
        state, wrench = self.advance(tick, vx, vy, inbox)
        return StepResult(state, wrench, self.estimate())

    def advance(self, tick: int, vx: float, vy: float, inbox: Sequence[StateMsg]) -> tuple[StateMsg, Wrench]:
        """:meth:`step` without the estimate, which :meth:`estimate` builds on demand (an engine needs it only
        on recorded ticks)."""
        dyn = self._dyn
        kin = self._kin.step(tick, vx, vy, inbox, self._fb, None if dyn is None else dyn.decode)
        shared = {"om": kin.omega, "oi": 1.0 if kin.om_init else 0.0, "ph": kin.phi, "yx": kin.y.real, "yy": kin.y.imag}
        if dyn is None:
            stage = KINEMATIC if kin.om_init else SPINUP
            fx, fy, tau = kin.wrench
            pairs = {j: (z.real, z.imag, f.real, f.imag) for j, z, f in kin.pairs}
            est = None
        else:
            out = dyn.step(kin)
            self._fb = out.feedback
            stage = out.stage
            fx, fy, tau = out.wrench
            shared.update(out.shared)
            pairs = {j: (z.real, z.imag, f.real, f.imag, *out.flows[j]) for j, z, f in kin.pairs}
            self._trust.observe(tick, stage, [(m.sender, m.tick) for m in kin.inbox])  # type: ignore[union-attr]
            est = out.estimates
        self.stage = stage
        # what the estimate of this tick needs beyond the phases' state, which the next advance changes
        self._last = (tick, kin, est, pairs)
        return StateMsg(tick, self.id, vx, vy, stage, shared, pairs), Wrench(tick, self.id, fx, fy, tau)

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
