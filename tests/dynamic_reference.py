"""The dynamical phase as it was in Python before its port to the kernels (agents/kernels/dynamic.py), frozen
as the oracle of tests/test_dynamic_kernels.py: its recorder runs the team on this class and compares each
kernel with the method it replaced, bit for bit, on a :class:`ReferenceTeam`. Not used by the agent
(agents/dynamic_phase.py is the phase).
:meth:`DynamicPhase.step` takes the agent's accepted IN rows and writes its OUT row as the kernels do
(docs/fast-core-plan.md, S6), so that AgentCore can drive it.
"""

from __future__ import annotations

import copy
import math
import statistics
from collections.abc import Callable, Iterable, Sequence
from math import cos, sin
from typing import NamedTuple

import numpy as np

from agents.consensus import FlowAverage
from agents.dynamic_phase import CH_KEYS, CH_POOL
from agents.effect_decision import (
    ALL,
    DETECT_NAMES,
    EFFECTS,
    N_POOL,
    SLOPE,
    OnlineDetection,
)
from agents.innovation_monitor import MONITOR_NAMES, InnovationMonitor
from agents.kernels import kinematic as KN
from agents.kernels.dynamic import (
    CH_BN,
    CH_CN,
    CH_DT,
    CH_FBX,
    CH_FBY,
    CH_FN,
    CH_FX,
    CH_FY,
    CH_JG,
    CH_JN,
    CH_JW,
    CH_MN,
    CH_MW,
    CH_ZX,
    CH_ZY,
    N_CH,
    N_CH_AUG,
)
from agents.laws import ControlLawError, LawInput, checked_wrench
from agents.rigid_filter import RigidEKF, fit_rotation
from agents.stage_agreement import MASK_BITS, StageBarrier
from agents.team import Member, TeamCore, assumed_sigma_v
from config.agent_params import DynamicsSpec
from net.rows import C0, KIN_KEYS, OM, PAIR_HEAD, PHASE, SENDER, TICK, Layout
from net.vocabulary import (
    BACKGROUND,
    DONE,
    J_AVERAGE,
    J_EXCITE,
    KINEMATIC,
    M_AVERAGE,
    M_EXCITE,
    SPINUP,
)
from tests.tick_records import DynamicFeedback, DynamicOut, KinematicTick


def weighted_average_step(x_i: complex | float, neighbours: Iterable[tuple[float, float]]) -> float:
    """x_i + sum_j eps_ij (x_j - x_i) over ``neighbours`` = [(x_j, eps_ij)] (Metropolis weights: psi)."""
    acc = 0.0
    for x_j, eps_ij in neighbours:
        acc += eps_ij * (x_j - x_i)
    return x_i + acc


def spread_sd(own: float, neighbours: Iterable[float]) -> float:
    """Root-mean-square difference between the own consensus value and the neighbours' latest ones (0.0
    without neighbour values): what the averaging has not yet removed."""
    acc = 0.0
    k = 0
    for v in neighbours:
        if v == v:
            acc += (v - own) ** 2
            k += 1
    return math.sqrt(acc / k) if k else 0.0


class DynamicMsg(NamedTuple):
    """A neighbour's dynamical-phase states of one message, decoded and checked (``DynamicPhase.decode``)."""

    sender: int
    tick: int
    stage: int
    psi: float  # its body-frame angle of the consensus on body-fixed vectors
    deg: int  # its degree (Metropolis weights)
    x: list[float]  # its consensus channels
    flows: list[float]  # its flows to us
    barrier: tuple[int, int, int]  # (ready mask, latest ready tick, switch tick)
    stage_tick: int  # tick its stage began
    omega_hat: float  # its kinematic omega_hat (NaN if absent)
    decision: tuple[int, int, float] | None = None  # its flooded effect switch (online detection only)


def _dynamic_msg(v: list[float], lay: Layout) -> DynamicMsg:
    """A neighbour's dynamical states from its IN row's values (agents/kernels/message_rows.py in_rows), whose
    status says they were decoded and checked."""
    nch = lay.nch
    mask = 0
    for c in range(lay.nbk):
        mask |= int(v[lay.b0 + c]) << (c * MASK_BITS)
    p = lay.p0 + PAIR_HEAD
    ds = lay.ds
    dec = (int(v[ds]), int(v[ds + 1]), v[ds + 2]) if lay.detection else None
    return DynamicMsg(int(v[SENDER]), int(v[TICK]), int(v[PHASE]), v[lay.ps], int(v[lay.dg]), v[C0:C0 + nch],
                      v[p:p + nch], (mask, int(v[lay.bt]), int(v[lay.bs])), int(v[lay.sk]), v[OM], dec)


def j_sign(k: int, j_ticks: int, spec: DynamicsSpec) -> float:
    """s(t) of the J stage at its tick ``k``: +-1, ``spec.j_cycles`` cycles over the stage, starting
    in the direction of ``spec.omega_sign``."""
    half = max(1, j_ticks // (2 * spec.j_cycles))
    sgn = 1.0 if (k // half) % 2 == 0 else -1.0
    if spec.omega_sign < 0:
        sgn = -sgn
    return sgn


def stage_wrench(stage: int, k: int, spec: DynamicsSpec, m_switch: int, j_ticks: int, v: complex, q: complex,
                 zc: complex, wrench: tuple[float, float, float]) -> tuple[float, float, float]:
    """(fx, fy, tau) at the stage's tick ``k``; ``wrench`` (the kinematic law's) where the stage has none.
    ``v`` own contact velocity, ``q`` = q_i, ``zc`` = z_C (world)."""
    fx, fy, tau = wrench
    if stage == M_EXCITE or stage == BACKGROUND:
        sgn = -1.0 if (k // m_switch) & 1 else 1.0
        fx = sgn * spec.m_force * cos(spec.m_force_angle)
        fy = sgn * spec.m_force * sin(spec.m_force_angle)
    elif stage == J_EXCITE:
        # with the refined z_i = q_i - z_C
        f = spec.k_z * j_sign(k, j_ticks, spec) * 1j * (q - zc)
        fx, fy, tau = f.real, f.imag, 0.0
    elif stage == DONE and spec.brake > 0.0:
        fx, fy, tau = -spec.brake * v.real, -spec.brake * v.imag, 0.0
    return fx, fy, tau


def dither(k: int, spec: DynamicsSpec, dither_ticks: int) -> float:
    """Algorithm 2's torque dither for J at the stage's tick ``k``."""
    return spec.dither_torque * sin(2.0 * math.pi * k / dither_ticks)


class DynamicPhase:
    """One agent's dynamical phase (see module docstring). Driven by AgentCore.step."""

    def __init__(self, agent_id: int, nbr_ids: Sequence[int], n: int, dt: float, sigma_v: float,
                 spec: DynamicsSpec, hist: int = 64, law: Callable[[LawInput], Sequence[float]] | None = None,
                 law_ref: str = "") -> None:
        self.id = agent_id
        self.law = law  # the user's control law (agents/laws.py): done stage of Algorithm 1, Algorithm 2
        self.law_ref = law_ref
        self.q_held: complex | None = None  # q_i in the shared body frame, held from done on (see step)
        # delayed eq. (9) samples (RigidEKF.update): cumulative dt T and dt omega of the filter's
        # predictions up to each of the last ``hist`` state ticks, and this tick's |z|^2-weighted sums
        # over the late samples (note_late)
        self.hist = hist
        self.cum_c = [0.0] * hist
        self.cum_w = [0.0] * hist
        self.cum_t = [-1] * hist
        self.cc = 0.0  # dt sum T up to the current state tick
        self.cw = 0.0  # dt sum omega
        self.late_z = self.late_c = self.late_w = 0.0
        self.n = n
        self.dt = dt
        self.spec = spec
        self.background = spec.algorithm == "background"
        nch = N_CH_AUG + N_POOL if spec.online_detection else N_CH_AUG if spec.estimate_effects else N_CH
        self.avg = FlowAverage(nbr_ids, nch)
        self.ch_keys = CH_KEYS[:self.avg.nch]
        self.nch = self.avg.nch
        self.m_local_sd = self.j_local_sd = math.nan  # the filter's sd of m_local and J_local when offered
        self.b_local = math.nan  # augmented model: own b = beta m and c = gamma J, before the averaging
        self.c_local = math.nan
        # whether b (c, F_c) was offered while its effect was in the model: with online detection the rates are
        # carried pinned at 0 from the start, and an effect switched on after m (J) froze has no average
        self.b_offered = self.c_offered = self.f_offered = self.fb_offered = False
        self.released = False
        ticks = lambda s: max(1, int(round(s / dt)))  # noqa: E731
        self.barrier = StageBarrier(agent_id, n, ticks(spec.horizon_s))
        self.kf = RigidEKF(sigma_v, spec, self.background)
        self.sigma_v = sigma_v
        self.stage = SPINUP
        self.stage_tick = 0
        self.late_switches = 0
        self.kin_since = -1
        self.settle = ticks(spec.kin_settle_s)
        self.m_ticks = ticks(spec.m_excite_s)
        self.m_switch = ticks(spec.m_switch_s)
        self.j_ticks = ticks(spec.j_excite_s)
        self.avg_window = ticks(spec.avg_window_s)
        self.dither_ticks = ticks(spec.dither_period_s)
        self.conv_since = -1
        self.m_local = math.nan
        self.j_local = math.nan
        self.nbr_stage: dict[int, int] = {}
        self.nbr_stage_tick: dict[int, int] = {}
        self.alpha = 0.0  # modelled angular acceleration for the next tick (rad/s^2)
        self.nbr_psi: dict[int, tuple[float, int]] = {}  # (psi_j predicted for t + 1, t)
        # psi: the body-frame angle of the consensus on body-fixed vectors (z_C). Integral of the
        # filter's omega, which follows omega ramps without lag (the kinematic phi = integral of
        # omega_hat fell ~1.6 rad behind during the J stage), kept common by phase consensus.
        self.psi = math.nan
        self.nbr_barrier: dict[int, tuple[int, int, int]] = {}
        self.frozen_m = False
        self.frozen_j = False
        self.restarted = False  # the filter's restart at kinematic readiness is done
        # lock check (DynamicsSpec.lock_nis): running mean of the filter's velocity NIS from the restart on;
        # a filter that locked onto a wrong (q_i, omega) is restarted on trial (_reseed, _judge)
        self.lock_thr = spec.lock_nis
        self.lock_alpha = min(1.0, dt / spec.lock_tau_s)
        self.lock_hold = ticks(spec.lock_hold_s)
        self.nis_avg = 2.0
        self.lock_from = 0  # no judgement before this tick (a fresh start's transient)
        self.reseeds = 0  # restarts by the lock check
        self.kf_tick = -1  # tick of the last such restart: excitation before it is not in the weights
        self.shadow: RigidEKF | None = None  # the filter a restart on trial replaced (see _reseed)
        # online detection with the slope a candidate: the filter that has carried the slope's rates from the m
        # stage's start, handed over if the team switches the slope on (see _twin_decision)
        self.twin: RigidEKF | None = None
        self.shadow_nis = 2.0
        self.trial_tick = -1
        self.lock_fails = 0  # restarts in a row that did no better than the filter they replaced
        self.m_start = self.j_start = -1  # first ticks of the m and J excitation stages
        self.nbr_om: dict[int, float] = {}  # neighbours' omega_hat (their kinematic shared state)
        # the own contact velocities of the last lock_window_s and v_C's change per unit 1/m up to each
        # (dt sum of the total force): the restart point of a lost filter is fitted to them (fit_rotation)
        self.win_n = ticks(spec.lock_window_s)
        self.win_v = np.zeros(self.win_n, complex)
        self.win_f = np.zeros(self.win_n, complex)
        self.win_k = 0
        self.f_int = 0j
        # omega_hat's measurement for the next tick (AgentCore): the filter's predicted omega once it has
        # restarted at kinematic readiness (``DynamicsSpec.filter_omega``), NaN before (the eq. (9) rate)
        self.om_meas = math.nan
        # innovation monitor (report-only), fed from the filter's restart at kinematic readiness on
        self.monitor = (InnovationMonitor(ticks(spec.monitor_window_s), spec.monitor_lags, spec.monitor_alpha)
                        if spec.monitor_window_s > 0.0 else None)
        self.last_f = 0j  # the own force applied over the last prediction (a signature of the monitor)
        # online detection: the team pools its filters' scores and switches a missing effect on
        self.declared = declared = sum(1 << k for k, e in enumerate(EFFECTS) if e in spec.estimate_effects)
        self.detect = (OnlineDetection(n, ticks(spec.monitor_window_s), spec.monitor_lags, spec.monitor_alpha,
                                       ticks(spec.horizon_s), CH_POOL, declared,
                                       ALL if spec.online_force_bias else ALL & ~(1 << EFFECTS.index("force_bias")))
                       if spec.online_detection else None)
        self.lay = Layout(True, nch, len(self.barrier.mask_keys), spec.online_detection, len(nbr_ids))

    # ------------------------------------------------------------------ messages
    def _receive(self, m: DynamicMsg) -> None:
        """A decoded neighbour state (in arrival order: a later one of the same neighbour replaces it)."""
        j = m.sender
        self.avg.receive(j, m.x, m.flows, m.deg)
        self.nbr_stage[j] = m.stage
        self.nbr_stage_tick[j] = m.stage_tick
        self.nbr_barrier[j] = m.barrier
        if m.decision is not None and self.detect is not None:
            self.detect.merge(m.decision)
        if m.stage >= KINEMATIC:  # its filter (and psi) runs from the kinematic stage on
            self.nbr_psi[j] = (m.psi, m.tick)
            if m.omega_hat - m.omega_hat == 0.0:
                self.nbr_om[j] = m.omega_hat

    def _note_late(self, t: int, zz: float) -> None:
        """An eq. (9) sample of tick t with pooling weight zz went into this tick's u (only samples older
        than the state tick on entry: fault-free ones are 1 tick old and not reported)."""
        i = t % self.hist
        if self.cum_t[i] == t:
            self.late_z += zz
            self.late_c += zz * self.cum_c[i]
            self.late_w += zz * self.cum_w[i]

    def _u_age(self, tick: int, u_den: float) -> tuple[float, float]:
        """(dt sum T, dt sum omega) from the pooled u's samples to the state tick: the pooled value is
        the |z|^2-weighted mean of per-sample omegas, so its prediction is the weighted mean of theirs."""
        i = (tick - 1) % self.hist
        c1, w1 = (self.cum_c[i], self.cum_w[i]) if self.cum_t[i] == tick - 1 else (self.cc, self.cw)
        w0 = u_den - self.late_z  # the samples of tick - 1 (and any older than the buffer)
        cbar = (self.late_c + w0 * c1) / u_den
        wbar = (self.late_w + w0 * w1) / u_den
        return self.cc - cbar, self.cw - wbar

    # ------------------------------------------------------------------ helpers
    def _filters(self) -> tuple[RigidEKF, ...]:
        """The filters that see every step: the agent's, the one a restart on trial replaced, the slope's twin."""
        return (self.kf, *(f for f in (self.shadow, self.twin) if f is not None))

    def _enter(self, stage: int, tick: int) -> None:
        filters = self._filters()
        if stage >= M_EXCITE and self.spec.estimate_effects and not self.released:
            self.released = True  # the excitation starts (or we jumped past it): see release_effects
            for kf in filters:
                kf.release_effects()
        self.stage = stage
        self.stage_tick = tick
        if self.detect is not None:
            self.detect.regime_change()
        if stage == M_EXCITE:
            self.m_start = tick
            if self.detect is not None:
                self.detect.push_reverses(tick + self.m_switch)
                if self.kf.ready and self.twin is None and self.detect.undecided(SLOPE):
                    # a slope switched on later restarts 1/m, which then rests on what is left of the stage; the
                    # twin has estimated the slope beside 1/m from the stage's start, as a declared slope is
                    self.twin = copy.copy(self.kf)  # its arrays are replaced on every step, never changed in place
                    self.twin.release_effect(SLOPE)
                    self.twin.sens = None  # the scores are the agent's filter's; the twin's start at the handover
        elif stage == J_EXCITE:
            self.j_start = tick
            self.twin = None  # m is averaged: a slope switched from here on changes neither m nor f's average
        self.barrier.reset()
        self.conv_since = -1
        for kf in filters:
            if kf.ready and stage == J_EXCITE:
                kf.forget_iota()  # J from the J stage's exactly known torque alone (Result 5)
                kf.set_omega_walk(self.spec.j_omega_walk)
            elif stage != J_EXCITE:
                kf.set_omega_walk(self.spec.omega_walk)

    def _advance(self, tick: int) -> None:
        """Stage agreement: neighbours ahead, barrier merges, own readiness, due switches."""
        st = self.stage
        # a neighbour two or more stages ahead (we restarted / joined late): jump there
        if not self.background and st >= KINEMATIC:
            ahead, j_ahead = max(((s, j) for j, s in self.nbr_stage.items()), default=(-1, -1))
            if st + 1 < ahead <= DONE:
                self._enter(ahead, self.nbr_stage_tick[j_ahead])
                self.late_switches += 1
                return
        for j, s in self.nbr_stage.items():
            if s == st:
                mask, tmax, sw = self.nbr_barrier[j]
                self.barrier.merge(mask, tmax, sw)
            elif s == st + 1 and st in (KINEMATIC, M_AVERAGE, J_AVERAGE):
                # the neighbour has switched already: its stage start is the agreed tick
                self.barrier.merge(0, -1, self.nbr_stage_tick[j])
        sw = self.barrier.switch
        if sw >= 0 and tick >= sw and st in (KINEMATIC, M_AVERAGE, J_AVERAGE):
            if tick > sw:
                self.late_switches += 1
            nxt = {KINEMATIC: BACKGROUND if self.background else M_EXCITE, M_AVERAGE: J_EXCITE,
                   J_AVERAGE: DONE}[st]
            self._enter(nxt, tick)
        elif st == M_EXCITE and tick >= self.stage_tick + self.m_ticks:
            self._enter(M_AVERAGE, tick)
        elif st == J_EXCITE and tick >= self.stage_tick + self.j_ticks:
            self._enter(J_AVERAGE, tick)

    def _offer(self, inv: float, var: float, num: int, wch: int, w: float = 1.0, sure: bool = False) -> float | None:
        """Hands the local estimate 1/inv (the filter's 1/m or 1/J) to its average channels with weight w;
        None if the filter has no usable value yet (with ``sure``, also while its sd is not below the value:
        a restarted filter's 1/m starts at 0 with sd 1). Weight 1 (a plain average over the agents that have one)
        unless the lock check restarted the filter during the excitation (:meth:`_clean_share`): the
        filters' variances proved overconfident as inverse-variance weights."""
        if not (inv > 0.0 and var > 0.0) or (sure and var >= inv * inv):
            return None
        au = self.avg.u
        au[num] = w / inv
        au[wch] = w
        return 1.0 / inv

    def _clean_share(self, start: int, ticks: int) -> float:
        """The weight of an estimate learnt over the excitation ticks [start, start + ticks): the share of
        them since the filter's last restart by the lock check (1 without one), near 0 if the filter is
        lost now (not 0: a team whose filters are all lost must still reach an average)."""
        w = 1.0
        if start >= 0 and self.kf_tick > start:
            w = max(0.0, (start + ticks - self.kf_tick) / ticks)
        if self.nis_avg > self.lock_thr > 0.0:  # lost
            w = 0.0
        return w if w > 1e-3 else 1e-3

    def _reseed(self, tick: int, v: complex, zi: complex, omega_hat: float, zc: complex) -> None:
        """Restart, on trial, the filter that seems to have lost lock: (omega, q_i) fitted to the own contact
        velocities of the last window (:func:`fit_rotation`; before it is full, the neighbours' omega_hat and
        the kinematic z_i + z_C), 1/m and 1/J forgotten: where half the team has lost lock the neighbours'
        omega_hat is no seed (docs/high-noise.md). The old filter runs beside it until :meth:`_judge` keeps the
        one whose velocity innovations are the more consistent: a wrong lock is fixed by a restart, an effect
        the model lacks (sensor lag, friction) raises every filter's NIS and is not, so there the old filter
        and what it learnt are kept."""
        oms = list(self.nbr_om.values())
        om0 = statistics.median(oms) if oms else omega_hat
        q0 = zi + zc if zc == zc else zi
        if self.win_k >= self.win_n:
            k = self.win_k % self.win_n  # the oldest sample
            lim = self.spec.lock_omega_max
            # not the lost filter's own omega (it may be anything); capped, so that the scan stays small
            om_max = min(max(lim, 2.0 * abs(omega_hat), *(2.0 * abs(o) for o in oms)), 5.0 * lim)
            om_fit, q_fit, _ = fit_rotation(np.roll(self.win_v, -k), np.roll(self.win_f, -k), self.dt, om_max)
            if abs(om_fit) * self.win_n * self.dt >= 2.0:
                # the load turned by 2 rad or more in the window: the fit is determined (slower, q is not),
                # else the fallback above
                om0, q0 = om_fit, q_fit
        kf = self.kf
        self.shadow = copy.copy(kf)  # its arrays are replaced on every step, never changed in place
        self.shadow_nis = self.nis_avg
        self.twin = None  # it shares the lost filter's lock: a slope switched later is released in the restart
        kf.start(v, q0, om0)
        if self.monitor is not None:
            self.monitor.reset()
        if self.released:
            kf.release_effects()
        if self.detect is not None:
            self.detect.restart_filter(kf)
        # the trial's running mean starts at the threshold, not at the consistent 2: what is left of the
        # start after the trial (13 % at 4 s over 2 s) then leans towards keeping the old filter
        self.nis_avg = self.lock_thr
        self.trial_tick = tick
        self.lock_from = tick + self.lock_hold

    def _twin_decision(self, dec: int) -> None:
        """The slope's twin after the team's decision ``dec`` (-1: none; effect_decision's codes): the slope
        switched on, the twin becomes the agent's filter, its sensitivities to the candidates' rates starting
        from zero as at a filter's start; ruled out or decided, it is dropped; any other effect's switch or
        withdrawal was applied to it too (docs/online-detection.md, "The slope's twin")."""
        if self.twin is None:
            return
        if dec == SLOPE:
            if self.kf.sens is not None:  # from zero, as at a filter's start
                self.twin.sens = np.zeros_like(self.kf.sens)
            self.kf = self.twin
            if self.monitor is not None:
                self.monitor.reset()
            self.detect.filter_replaced()
        if not self.detect.undecided(SLOPE):
            self.twin = None

    def _judge(self, tick: int) -> None:
        """End of a restart's trial (see :meth:`_reseed`)."""
        if self.nis_avg < min(self.lock_thr, 0.5 * self.shadow_nis):
            # consistent, and clearly better: a fresh filter's wide covariance lowers its NIS for a while,
            # so a small gain (or one that is still inconsistent) is not evidence of a wrong lock
            self.kf_tick = self.trial_tick
            self.reseeds += 1
            self.lock_fails = 0
            self.lock_from = tick
        else:  # the restart did no better: back to the old filter, and wait longer before the next try
            if self.monitor is not None:
                self.monitor.reset()
            if self.detect is not None:
                self.detect.regime_change()
            self.kf = self.shadow
            self.nis_avg = self.shadow_nis
            self.lock_fails += 1
            self.lock_from = tick + (self.lock_hold << min(self.lock_fails, 5))
        self.shadow = None

    def _converged(self, num: int, wch: int, tick: int) -> bool:
        """Local convergence of a weighted average: own value and every neighbour's within tolerance."""
        x = self.avg.x
        if x[wch] <= 0.0:
            return False
        mine = x[num] / x[wch]
        tol = self.spec.avg_tol * abs(mine)
        ok = True
        for xj in self.avg.nx.values():
            if xj[wch] <= 0.0 or abs(xj[num] / xj[wch] - mine) > tol:
                ok = False
                break
        if not ok:
            self.conv_since = -1
            return False
        if self.conv_since < 0:
            self.conv_since = tick
        return tick - self.conv_since >= self.avg_window

    # ------------------------------------------------------------------ the tick
    def step(self, kin: KinematicTick, out_row: np.ndarray) -> DynamicOut:
        """Advance one tick on the kinematic phase's results of it; its states into ``out_row``."""
        for v in kin.inbox:
            self._receive(_dynamic_msg(v.tolist(), self.lay))
        for t, zz in kin.late:
            self._note_late(t, zz)
        fx, fy, tau = self._step(kin.tick, kin.v, kin.u, kin.u_den, kin.omega, kin.phi, kin.zi, kin.trusted,
                                 kin.om_init, kin.wrench)
        lay = self.lay
        out_row[PHASE] = self.stage
        out_row[OM + len(KIN_KEYS):lay.p0] = list(self._shared().values())
        for k, f in enumerate(self.avg.flow.values()):
            p = lay.p0 + k * lay.block + PAIR_HEAD
            out_row[p:p + lay.nch] = f
        return DynamicOut(
            wrench=(fx, fy, tau),
            stage=self.stage,
            estimates=self._estimates(),
            feedback=DynamicFeedback(
                om_meas=self.om_meas,
                alpha=self.alpha,
                hold_shape=self.q_held is not None,
                team_waiting=self.stage == KINEMATIC and not self.barrier.complete,
            ),
        )

    def _step(
        self, tick: int, v: complex, u: float, u_den: float, omega_hat: float, phi: float, zi: complex,
        trusted: bool, om_init: bool, wrench: tuple[float, float, float],
    ) -> tuple[float, float, float]:
        self._advance_stage(tick, v, omega_hat, phi, zi, trusted, om_init)
        if self.detect is not None:
            self._twin_decision(self.detect.step_filters(
                tick, self.avg.u, self.avg.x, (self.kf,) if self.shadow is None else (self.kf, self.shadow),
                self.twin))
        stage = self.stage
        rot = self._body_frame(tick, phi)
        q, zc, held = self._filter_update(tick, v, u, u_den, omega_hat, zi, rot)

        # control
        spec = self.spec
        k = tick - self.stage_tick
        fx, fy, tau = stage_wrench(stage, k, spec, self.m_switch, self.j_ticks, v, q, zc, wrench)
        jstage = stage == J_EXCITE  # the J stage's forces (torque from the JG channel, net force zero)
        if self.law is not None and (stage == DONE or stage == BACKGROUND):
            fx, fy, tau = self._law_wrench(tick, stage, v, q, zc, (fx, fy, tau))
        if stage == BACKGROUND:  # Prop. 6 (above; or the user's law) + the regulation torque + a dither for J
            tau += dither(k, spec, self.dither_ticks)

        self._consensus_inputs(stage, q, zc, held, rot, fx, fy, tau, jstage)
        self.avg.update()
        # readiness of the averaging stages
        if stage == M_AVERAGE and self._converged(CH_MN, CH_MW, tick):
            self.barrier.set_ready(tick)
        elif stage == J_AVERAGE and self._converged(CH_JN, CH_JW, tick):
            self.barrier.set_ready(tick)
        self.last_f = complex(fx, fy)
        self._predict(tick, rot, j_sign(k, self.j_ticks, spec) if jstage else None)
        return fx, fy, tau

    def _advance_stage(self, tick: int, v: complex, omega_hat: float, phi: float, zi: complex, trusted: bool,
                       om_init: bool) -> None:
        """The filter's start and restart, the kinematic stage's readiness, then the stage agreement."""
        kf = self.kf
        if self.stage == SPINUP and om_init:
            self._enter(KINEMATIC, tick)
        if self.stage >= KINEMATIC:
            if not kf.ready:
                kf.start(v, zi, omega_hat)
                self.psi = phi
            if self.stage == KINEMATIC:
                if trusted:
                    if self.kin_since < 0:
                        self.kin_since = tick
                    if tick - self.kin_since >= self.settle:
                        if not self.restarted:
                            # restart the filter from the settled kinematic z_i and omega_hat: started at
                            # spin-up from z_i = 0 it can lock onto a wrong (q, omega) and take most of
                            # the m stage to recover
                            self.restarted = True
                            kf.start(v, zi, omega_hat)
                            if self.detect is not None:
                                self.detect.regime_change()
                            self.lock_from = tick + self.lock_hold
                        self.barrier.set_ready(tick)
                else:
                    self.kin_since = -1
            self._advance(tick)

    def _body_frame(self, tick: int, phi: float) -> complex:
        """e^{i psi}, psi kept common by phase consensus with the neighbours' values predicted to now."""
        kf = self.kf
        if not kf.ready:
            return complex(cos(phi), sin(phi))
        om = kf.omega
        dt = self.dt
        deg = self.avg.deg
        self.psi = psi = weighted_average_step(self.psi, (
            (pj + om * dt * (tick - 1 - tj), 1.0 / (1.0 + max(deg, self.avg.ndeg[j])))
            for j, (pj, tj) in self.nbr_psi.items()))
        return complex(cos(psi), sin(psi))

    def _filter_update(self, tick: int, v: complex, u: float, u_den: float, omega_hat: float, zi: complex,
                       rot: complex) -> tuple[complex, complex, complex | None]:
        """The filter's update with this tick's data, the lock check, the shape hold from done on.
        Returns (q_i, z_C, q_i held in the body frame or None), world frame."""
        spec = self.spec
        kf = self.kf
        i = tick % self.hist
        if self.cum_t[i] != tick:  # the first tick
            self.cum_t[i], self.cum_c[i], self.cum_w[i] = tick, self.cc, self.cw
        if kf.ready:
            u_var = spec.u_var_scale * 2.0 * self.sigma_v**2 / u_den if u_den > 0.0 and spec.u_var_scale > 0 else 0.0
            u_dc = u_dw = 0.0
            if spec.u_delayed and u_var > 0.0:
                u_dc, u_dw = self._u_age(tick, u_den)
            mon = self.monitor if self.restarted and self.q_held is None else None
            if mon is not None:
                vc0, om0, q0 = kf.vc, kf.omega, kf.q  # the prediction's: known before the innovation
            kf.update(v, u, u_var, u_dc, u_dw)
            if self.twin is not None:
                self.twin.update(v, u, u_var, u_dc, u_dw)
            if mon is not None:
                e0, e1, s00, s01, s11 = kf.innov
                mon.observe(complex(e0, e1), s00, s01, s11, vc0, om0, q0, self.last_f)
            if self.detect is not None and self.restarted and self.q_held is None:
                self.detect.observe(kf.innov, kf.sens_h)
            q = kf.q
        else:
            q = zi
        x = self.avg.x
        zc = complex(x[CH_ZX], x[CH_ZY]) * rot  # z_C, world (the consensus runs in the shared body frame)
        held = self.q_held
        if self.restarted and held is None and self.lock_thr > 0.0:
            w = self.win_k % self.win_n
            self.win_v[w] = v
            self.win_f[w] = self.f_int
            self.win_k += 1
            a = self.lock_alpha
            self.nis_avg = na = self.nis_avg + a * (kf.nis - self.nis_avg)
            old = self.shadow
            if old is not None:  # a restart on trial: the filter it replaced runs beside it
                old.update(v, u, u_var, u_dc, u_dw)
                self.shadow_nis += a * (old.nis - self.shadow_nis)
                if tick >= self.lock_from:
                    self._judge(tick)
                    kf = self.kf
                    q = kf.q
            elif na > self.lock_thr and tick >= self.lock_from:
                self._reseed(tick, v, zi, omega_hat, zc)
                q = kf.q
        if held is None and self.stage == DONE and kf.ready and (self.law is not None or spec.brake > 0.0):
            # the user's law or Prop. 7 braking may stop the rotation, and q_i (so z_C) is observable only
            # while the load turns (v_Ci = v_C + omega q_i^perp): from done on, q_i is held in the shared
            # body frame
            if self.shadow is not None:  # a restart on trial: judged now, no more lock checks from here on
                self._judge(tick)
                kf = self.kf
                q = kf.q
            held = self.q_held = q * rot.conjugate()
            kf.hold_shape()
            kf.set_omega_walk(spec.j_omega_walk)
        if held is not None:
            q = held * rot
        return q, zc, held

    def _consensus_inputs(self, stage: int, q: complex, zc: complex, held: complex | None, rot: complex,
                          fx: float, fy: float, tau: float, jstage: bool) -> None:
        """This tick's inputs to the consensus channels (``avg.u``)."""
        spec = self.spec
        kf = self.kf
        x = self.avg.x
        au = self.avg.u
        if jstage:
            # sum_i f_i = 0 and the torque is s sum_i g_i (JG); DT gets 0 so that it has no J-stage
            # values to forget when the kinematic control resumes
            au[CH_FX] = au[CH_FY] = au[CH_DT] = 0.0
        else:
            au[CH_FX] = fx
            au[CH_FY] = fy
            df = complex(fx, fy) - complex(x[CH_FX], x[CH_FY])
            au[CH_DT] = (q.real * df.imag - q.imag * df.real) + tau  # q_i x (f_i - fbar) + tau_i
        if kf.ready and M_EXCITE <= stage <= J_EXCITE:
            # g_i = q_i x (J-stage f_i / s) with this tick's q_i and z_C, exactly as the force is built
            au[CH_JG] = spec.k_z * (q.real * (q.real - zc.real) + q.imag * (q.imag - zc.imag))
        if kf.ready:
            qp = q * rot.conjugate() if held is None else held  # q_i in the shared body frame; their mean is z_C
            au[CH_ZX] = qp.real
            au[CH_ZY] = qp.imag
        # not while a restart is on trial (its 1/m and 1/J start from nothing; the offer waits for the
        # judgement, at most lock_hold_s): the old filter's last offer stays in the background average
        take_m = self.shadow is None and (stage == BACKGROUND or (stage == M_AVERAGE and not self.frozen_m))
        take_j = self.shadow is None and (stage == BACKGROUND or (stage == J_AVERAGE and not self.frozen_j))
        # after a kept restart, only a determined value (sd below the value) is offered
        sure = self.kf_tick >= 0
        if kf.ready and take_m:
            w = 1.0 if stage == BACKGROUND else self._clean_share(self.m_start, self.m_ticks)
            m_local = self._offer(kf.mu, kf.mu_var, CH_MN, CH_MW, w, sure)
            if m_local is not None:
                self.m_local = m_local
                self.m_local_sd = math.sqrt(kf.mu_var) * m_local * m_local  # delta method: sd(1/mu)
                self.frozen_m = stage == M_AVERAGE
                if kf.aug is not None:  # b = beta m, F_c = kappa m and f = a m, averaged with m's weights
                    self.b_local = kf.beta * m_local
                    au[CH_BN] = w * self.b_local
                    au[CH_FN] = w * kf.kappa * m_local
                    fb = w * kf.accel * m_local
                    au[CH_FBX], au[CH_FBY] = fb.real, fb.imag
                    self.b_offered = self.b_offered or bool(self._on() & 1)
                    self.f_offered = self.f_offered or bool(self._on() & 4)
                    self.fb_offered = self.fb_offered or bool(self._on() & 8)
        if kf.ready and take_j:
            w = 1.0 if stage == BACKGROUND else self._clean_share(self.j_start, self.j_ticks)
            j_local = self._offer(kf.iota, kf.iota_var, CH_JN, CH_JW, w, sure)
            if j_local is not None:
                self.j_local = j_local
                self.j_local_sd = math.sqrt(kf.iota_var) * j_local * j_local
                self.frozen_j = stage == J_AVERAGE
                if kf.aug is not None:  # c = gamma J, averaged with J's weights
                    self.c_local = kf.gamma * j_local
                    au[CH_CN] = w * self.c_local
                    self.c_offered = self.c_offered or bool(self._on() & 2)

    def _predict(self, tick: int, rot: complex, j_sign: float | None) -> None:
        """Prediction to tick + 1 with the total force and torque (decomposition (12)-(14)); ``j_sign``:
        s(t) in the J stage (its torque is s(t) n mean_i g_i), None elsewhere."""
        spec = self.spec
        kf = self.kf
        dt = self.dt
        n = self.n
        x = self.avg.x
        if kf.ready:
            fbar = complex(x[CH_FX], x[CH_FY])
            if j_sign is not None:
                torque = n * j_sign * x[CH_JG]
            else:
                zc = complex(x[CH_ZX], x[CH_ZY]) * rot
                torque = n * ((zc.real * fbar.imag - zc.imag * fbar.real) + x[CH_DT])
            self.psi += dt * kf.omega  # the body turns by the pre-update omega (semi-implicit Euler)
            self.cc += dt * torque
            self.cw += dt * kf.omega
            self.f_int += dt * n * fbar
            # the detection's nuisance: the known error of the consensus force, which lags the applied one
            # (the m stage's common force is n times the own; the J stage's net force is zero)
            ferr = 0j
            if self.detect is not None:
                if self.stage == M_EXCITE:
                    ferr = n * (self.last_f - fbar)
                elif j_sign is not None:
                    ferr = -n * fbar
            kf.predict(n * fbar, torque, dt, ferr)
            for f in (self.shadow, self.twin):
                if f is not None:
                    f.predict(n * fbar, torque, dt, ferr)
            iota = kf.iota
            # only once 1/J is known to 10 % (or, with j_feedforward, through the whole J stage: its torque
            # is exact and 1/J keeps its pre-stage value when it is forgotten)
            if iota > 0.0 and (kf.iota_var < (0.1 * iota) ** 2 or (j_sign is not None and spec.j_feedforward)):
                self.alpha = iota * torque
                if kf.aug is not None:
                    self.alpha -= kf.gamma * kf.omega
            else:
                self.alpha = 0.0  # not a stale acceleration from before 1/J was forgotten
            if self.restarted and spec.filter_omega:
                om = kf.omega
                self.om_meas = om if om - om == 0.0 else math.nan  # a diverged filter: back to eq. (9)
        i = (tick + 1) % self.hist
        self.cum_t[i], self.cum_c[i], self.cum_w[i] = tick + 1, self.cc, self.cw
        self.late_z = self.late_c = self.late_w = 0.0

    def _law_wrench(self, tick: int, stage: int, v: complex, q: complex, zc: complex,
                    default: tuple[float, float, float]) -> tuple[float, float, float]:
        """The user's law with this tick's estimates (agents/laws.py); its output is checked here, at the edge."""
        x = self.avg.x
        kf = self.kf
        li = LawInput()
        li.tick = tick
        li.t = tick * self.dt
        li.stage = "done" if stage == DONE else "background"
        li.m = x[CH_MN] / x[CH_MW] if x[CH_MW] > 0.0 else math.nan
        li.J = x[CH_JN] / x[CH_JW] if x[CH_JW] > 0.0 else math.nan
        if kf.ready:
            vc = kf.vc
            li.omega = kf.omega
            li.vc = (vc.real, vc.imag)
            li.q = (q.real, q.imag)
        else:
            li.omega = math.nan
            li.vc = li.q = (math.nan, math.nan)
        li.zc = (zc.real, zc.imag)
        li.v = (v.real, v.imag)
        li.default = default
        try:
            out = self.law(li)
        except Exception as exc:  # the user's code: one line naming it, where and when, not a bare traceback
            raise ControlLawError(f"control.law {self.law_ref!r} raised {type(exc).__name__}: {exc} at tick {tick} "
                                  f"(agent {self.id})") from exc
        return checked_wrench(out, self.law_ref, tick, self.id)

    # ------------------------------------------------------------------ outputs
    def monitor_entries(self) -> dict[str, float]:
        """The innovation monitor's estimate entries (NaN without it)."""
        out = dict.fromkeys(MONITOR_NAMES, math.nan) if self.monitor is None else self.monitor.entries()
        out.update(dict.fromkeys(DETECT_NAMES, math.nan) if self.detect is None else self.detect.entries())
        return out

    def uncertainties(self) -> tuple[float, float]:
        """One standard deviation of the m and J consensus values (NaN while there is none): the filter's sd
        of the own local value and the spread to the neighbours' values that the averaging has not removed,
        in quadrature (docs/estimate-trust.md)."""
        x = self.avg.x
        nx = self.avg.nx.values()
        out = []
        for num, wch, sd in ((CH_MN, CH_MW, self.m_local_sd), (CH_JN, CH_JW, self.j_local_sd)):
            if x[wch] <= 0.0:
                out.append(math.nan)
                continue
            s = spread_sd(x[num] / x[wch], (xj[num] / xj[wch] for xj in nx if xj[wch] > 0.0))
            out.append(abs(complex(sd if sd == sd else 0.0, s)))  # libm's hypot, as in the kernels
        return out[0], out[1]

    def _shared(self) -> dict[str, float]:
        """The StateMsg.shared entries of the dynamical phase."""
        out = dict(zip(self.ch_keys, self.avg.x, strict=True))
        out["dg"] = float(self.avg.deg)
        out["Sk"] = float(self.stage_tick)
        out["ps"] = self.psi if self.psi == self.psi else 0.0
        out.update(self.barrier.encode())
        if self.detect is not None:
            out.update(self.detect.flood.encode())
        return out

    def _on(self) -> int:
        """The effects in the model (bit k: EFFECTS[k]): declared (estimate_effects: the augmented filter
        carries b and c, reported both) or switched on online."""
        return 3 | self.declared if self.detect is None else self.detect.on

    def _estimates(self) -> dict[str, float]:
        """The estimate values of the dynamical phase (``ESTIMATE_NAMES`` from "J" on)."""
        x = self.avg.x
        s = self.kf.s
        nan = math.nan
        m = x[CH_MN] / x[CH_MW] if x[CH_MW] > 0.0 else nan
        J = x[CH_JN] / x[CH_JW] if x[CH_JW] > 0.0 else nan
        on = self._on()
        if self.stage >= M_AVERAGE:
            zc = complex(x[CH_ZX], x[CH_ZY]) * complex(cos(self.psi), sin(self.psi))
            vc = complex(s[0], s[1])
        else:
            zc = vc = complex(nan, nan)
        return {
            "J": J,
            "m": m,
            "zc_x": zc.real,
            "zc_y": zc.imag,
            "vc_x": vc.real,
            "vc_y": vc.imag,
            "J_local": self.j_local,
            "m_local": self.m_local,
            "late_switches": float(self.late_switches),
            # augmented model (estimate_effects): b with m's weights, c with J's
            "b": x[CH_BN] / x[CH_MW] if len(x) > CH_BN and x[CH_MW] > 0.0 and on & 1 and self.b_offered else nan,
            "c": x[CH_CN] / x[CH_JW] if len(x) > CH_CN and x[CH_JW] > 0.0 and on & 2 and self.c_offered else nan,
            "fc": x[CH_FN] / x[CH_MW] if len(x) > CH_FN and x[CH_MW] > 0.0 and on & 4 and self.f_offered else nan,
            "fb_x": x[CH_FBX] / x[CH_MW] if len(x) > CH_FBX and x[CH_MW] > 0.0 and on & 8 and self.fb_offered else nan,
            "fb_y": x[CH_FBY] / x[CH_MW] if len(x) > CH_FBY and x[CH_MW] > 0.0 and on & 8 and self.fb_offered else nan,
            "b_local": self.b_local if on & 1 else nan,
            "c_local": self.c_local if on & 2 else nan,
            "filter_restarts": float(self.reseeds),
        }


class ReferenceTeam(TeamCore):
    """A team whose dynamical phase is this module's :class:`DynamicPhase`, one per agent, driven as TeamCore drove
    it before the team's tick was compiled: a :class:`KinematicTick` per agent from the kinematic kernel's results,
    its DynamicOut's wrench, stage and feedback (the recorder's team; its estimates are not made)."""

    def __init__(self, members: Sequence[Member], ring: int = 2) -> None:
        super().__init__(members, ring)
        self.ref = [DynamicPhase(self.ids[b], self.nbr_ids[b], int(m.n), float(m.dt), assumed_sigma_v(m), m.dynamics,
                                 m.estimator.history_ticks, law=m.law, law_ref=m.control.law)
                    for b, m in enumerate(members)]

    def _dynamic_tick(self, tick: int, rows: np.ndarray, ptr: np.ndarray, out: np.ndarray) -> np.ndarray:
        inp = self._inp
        acc = self._acc[:len(rows)].tolist()
        w = np.empty((self.B, 3))
        for b, (dp, r, lo) in enumerate(zip(self.ref, self._res.tolist(), ptr.tolist(), strict=False)):
            taken = rows[acc[lo:lo + int(r[KN.R_NACC])]]
            nl = int(r[KN.R_NLATE])
            late = tuple(zip(self._late_t[b, :nl].tolist(), self._late_z[b, :nl].tolist(), strict=True))
            pairs = tuple((j, complex(r[p], r[p + 1]), complex(r[p + 2], r[p + 3]))
                          for j, p in ((j, KN.R_PAIRS + 4 * k) for k, j in enumerate(self.nbr_ids[b])))
            vx, vy = inp[b, :2].tolist()
            kt = KinematicTick(tick, complex(vx, vy), r[KN.R_U], r[KN.R_U_DEN], late, r[KN.R_OMEGA],
                               r[KN.R_OM_INIT] != 0.0, r[KN.R_PHI], complex(r[KN.R_Y], r[KN.R_Y + 1]),
                               complex(r[KN.R_ZI], r[KN.R_ZI + 1]), pairs, int(r[KN.R_READY]), r[KN.R_TRUSTED] != 0.0,
                               (r[KN.R_FX], r[KN.R_FY], r[KN.R_TAU]), taken, int(r[KN.R_DROPPED_UNKNOWN]),
                               int(r[KN.R_DROPPED_STALE]))
            o = dp.step(kt, out[b])
            inp[b, KN.I_OM_MEAS:KN.I_WAITING + 1] = o.feedback
            self.stages[b] = o.stage
            w[b] = o.wrench
        return w
