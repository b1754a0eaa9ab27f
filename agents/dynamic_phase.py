"""The dynamical phase of paper 000 (Sec. V, Algorithm 1) and its background variant (Sec. VI, Algorithm 2).

:meth:`DynamicPhase.step` (the tick's :class:`agents.tick_records.KinematicTick`, the agent's OUT row) ->
:class:`agents.tick_records.DynamicOut`: the stage machine over the rigid-body filters, the flow-updating
consensus channels and the stage agreement. The maths is compiled (agents/kernels/dynamic.py, fused into
one call per stretch between Python handlers by agents/kernels/dynamic_step.py); this class holds the banks
of one agent, runs the handlers the kernels stop for (P1 the online detection, P2 a restart's fit, P3 the
user's law, the innovation monitor) and is a view of its state for tests and tools.

Stages: kinematic until every pair is estimated; m excitation (the common force, switched) and the
averaging of m and z_C; J excitation (f_i = k_z s(t) z_i^perp, tau_i = 0, Result 5) and the averaging
of J; done (optional braking or the user's law). Algorithm 2 runs one background stage instead.
Symbols, choices and measurements: docs/dynamics.md; the kernels' layout: docs/fast-core-plan.md.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable, Sequence

import numpy as np

from agents.consensus import FlowAverage
from agents.effect_decision import ALL, DETECT_NAMES, EFFECTS, N_POOL, SLOPE, OnlineDetection
from agents.innovation_monitor import MONITOR_NAMES, InnovationMonitor
from agents.kernels import dynamic as K
from agents.kernels import dynamic_step as T
from agents.kernels import filter as F
from agents.kernels.agreement import DEG, HORIZON, SBITS, SWITCH, TMAX, U, X
from agents.laws import ControlLawError, LawInput, checked_wrench
from agents.rigid_filter import RigidEKF, fit_rotation, init_slot
from agents.stage_agreement import MASK_BITS, StageBarrier, mask_keys
from agents.tick_records import DynamicFeedback, DynamicOut, KinematicTick
from config.agent_params import DynamicsSpec
from net.rows import Layout
from net.vocabulary import DONE

# Flow-average channels: the mean force (FX, FY: world-fixed, so a common force passes through at once);
# JG: g_i = k_z q_i . (q_i - z_C), whose mean times s(t) is the J stage's torque (rotation-invariant, fed
# from the m stage on, so it has converged when the J stage starts and s(t) flips); DT: q_i x (f_i - fbar)
# + tau_i; z_C in the shared body frame (ZX, ZY); numerator and weight of the averages of m and J
CH_FX, CH_FY, CH_JG, CH_DT, CH_ZX, CH_ZY, CH_MN, CH_MW, CH_JN, CH_JW = range(10)
N_CH = 10
# augmented model (DynamicsSpec.estimate_effects): the local b, c, F_c and f (x, y) numerators; their weights
# are the m and J weight channels (b, F_c and f are offered exactly when m is, c when J is)
CH_BN, CH_CN, CH_FN, CH_FBX, CH_FBY = 10, 11, 12, 13, 14
N_CH_AUG = 15
# online detection (DynamicsSpec.online_detection): the pooled window statistics (agents/effect_decision.py)
CH_POOL = N_CH_AUG
CH_KEYS = tuple(f"c{c}" for c in range(N_CH_AUG + N_POOL))  # their names in StateMsg.shared


class DynamicPhase:
    """One agent's dynamical phase (see module docstring): row 0 of the kernels' banks. Driven by AgentCore.step."""

    def __init__(self, agent_id: int, nbr_ids: Sequence[int], n: int, dt: float, sigma_v: float,
                 spec: DynamicsSpec, hist: int = 64, law: Callable[[LawInput], Sequence[float]] | None = None,
                 law_ref: str = "") -> None:
        self.id = agent_id
        self.law = law  # the user's control law (agents/laws.py): done stage of Algorithm 1, Algorithm 2
        self.law_ref = law_ref
        self.n = n
        self.dt = dt
        self.spec = spec
        self.sigma_v = sigma_v
        self.hist = hist
        self.background = spec.algorithm == "background"
        self.nbr_ids = ids = tuple(sorted(nbr_ids))
        self.nch = nch = N_CH_AUG + N_POOL if spec.online_detection else N_CH_AUG if spec.estimate_effects else N_CH
        self.ch_keys = CH_KEYS[:nch]
        self.nbk = len(mask_keys(n))

        def ticks(s: float) -> int:
            return max(1, int(round(s / dt)))

        self.win_n = ticks(spec.lock_window_s)
        aug = spec.estimate_effects or spec.online_detection
        self._banks = banks = K.new_banks(1, len(ids), nch, F.D_AUGMENTED if aug else F.D_NOMINAL, hist, self.win_n,
                                          self.nbk)
        (self._dyn, self._dnb, _, self._rx_order, _, _, _, self._win, self._S, self._F, self._I,
         *self._fbank) = banks
        self._fs, self._s, self._sens = self._fbank[0], self._fbank[1], self._fbank[3]
        K.init_dyn_row(self._dyn, 0, n, dt, sigma_v, spec, hist, law is not None, self._S, agent_id)
        init_slot(tuple(self._fbank), 0, K.KF, sigma_v, spec, self.background)
        self._I[0, DEG] = len(ids)
        self._r = self._dyn[0]
        # the fused kernel's arguments (agents/kernels/dynamic_step.py): one row, its inputs and results
        self._rows = np.zeros(1, np.int64)
        self._at = np.zeros(1, np.int64)
        self._kin = np.zeros((1, T.NK))
        self._in_ptr = np.zeros(2, np.int64)
        self._late_t = np.full((1, 1), -1, np.int64)
        self._late_z = np.zeros((1, 1))
        self._ids = np.array([ids], np.int64).reshape(1, len(ids))
        self._res = np.zeros((1, T.NR))
        self._est = np.zeros((1, len(K.ESTIMATES)))
        self._res[0, T.R_M_SD] = self._res[0, T.R_J_SD] = math.nan
        self._last = self._res[0].tolist()  # the last tick's results
        self.lay = Layout(True, nch, self.nbk, spec.online_detection, len(ids))
        self._on = 3 | int(self._r["declared"])  # the effects in the model without online detection
        # innovation monitor (report-only), fed from the filter's restart at kinematic readiness on
        self.monitor = (InnovationMonitor(ticks(spec.monitor_window_s), spec.monitor_lags, spec.monitor_alpha)
                        if spec.monitor_window_s > 0.0 else None)
        # online detection: the team pools its filters' scores and switches a missing effect on
        self.detect = (OnlineDetection(n, ticks(spec.monitor_window_s), spec.monitor_lags, spec.monitor_alpha,
                                       ticks(spec.horizon_s), CH_POOL, int(self._r["declared"]),
                                       ALL if spec.online_force_bias else ALL & ~(1 << EFFECTS.index("force_bias")))
                       if spec.online_detection else None)

    # ------------------------------------------------------------------ the view (tests and tools)
    def _slot(self, role: str) -> RigidEKF | None:
        k = int(self._r[role])
        return None if k < 0 else RigidEKF.view(tuple(self._fbank), 0, k)

    kf = property(lambda self: self._slot("kf_slot"), doc="The agent's filter (a view of its slot).")
    shadow = property(lambda self: self._slot("shadow_slot"), doc="The filter a restart on trial replaced.")
    twin = property(lambda self: self._slot("twin_slot"), doc="The slope's twin (online detection).")
    stage = property(lambda self: int(self._r["stage"]))
    stage_tick = property(lambda self: int(self._r["stage_tick"]))
    late_switches = property(lambda self: int(self._r["late_switches"]))
    reseeds = property(lambda self: int(self._r["reseeds"]), doc="Restarts by the lock check.")
    restarted = property(lambda self: bool(self._r["restarted"]))
    m_local = property(lambda self: float(self._r["m_local"]))
    j_local = property(lambda self: float(self._r["j_local"]))
    m_local_sd = property(lambda self: float(self._r["m_local_sd"]))
    j_local_sd = property(lambda self: float(self._r["j_local_sd"]))
    alpha = property(lambda self: float(self._r["alpha"]))
    psi = property(lambda self: float(self._r["psi"]))
    om_meas = property(lambda self: float(self._r["om_meas"]))
    nis_avg = property(lambda self: float(self._r["nis_avg"]))
    q_held = property(lambda self: complex(self._r["q_held"]) if self._r["has_q_held"] else None)

    @property
    def avg(self) -> FlowAverage:
        """The consensus channels (a view of the flow-average row)."""
        return FlowAverage.view(self.nbr_ids, (self._F, self._I), 0)

    @property
    def barrier(self) -> StageBarrier:
        """The stage barrier (a copy of its row)."""
        S = self._S[0].tolist()
        bar = StageBarrier(self.id, self.n, S[HORIZON])
        bar.mask = sum(int(c) << (k * MASK_BITS) for k, c in enumerate(S[SBITS:]))
        bar.tmax, bar.switch = S[TMAX], S[SWITCH]
        return bar

    @property
    def nbr_stage(self) -> dict[int, int]:
        """Each neighbour heard from: its stage (first-heard order)."""
        return {self.nbr_ids[k]: int(self._dnb[0, k]["stage"]) for k in self._rx_order[0, :self._r["rx_n"]]}

    # ------------------------------------------------------------------ the tick
    def step(self, kin: KinematicTick, out_row: np.ndarray) -> DynamicOut:
        """Advance one tick on the kinematic phase's results of it; the phase's slots of ``out_row``
        (net/rows.py's OUT row, ``self.lay``) written."""
        v, zi = kin.v, kin.zi
        det = self.detect
        on = self._on if det is None else det.on
        fx, fy, tau = kin.wrench
        self._kin[0] = (kin.tick, v.real, v.imag, kin.u, kin.u_den, kin.omega, kin.om_init, kin.phi, zi.real, zi.imag,
                        kin.trusted, fx, fy, tau, det is not None and det.undecided(SLOPE), on)
        inbox = kin.inbox
        self._in_ptr[1] = len(inbox)
        if kin.late:
            self._late(kin.late)
        elif self._late_t[0, 0] >= 0:
            self._late_t[0, 0] = -1
        out = out_row.reshape(1, -1)
        at = self._at
        at[0] = T.AT_BEGIN
        observed = False
        while T.dyn_tick(self._rows, at, self._kin, inbox, self._in_ptr, self._late_t, self._late_z, self.lay.lay,
                         self._ids, self._res, out, self._est, *self._banks):
            p = int(at[0])
            res = self._res[0].tolist()
            ev = int(res[T.R_EV])
            if p == T.AT_UPDATE:
                self._detection(kin.tick, ev)
                continue
            if not observed:
                observed = True
                self._observe(res)
            self._events(ev)
            if p == T.AT_CONTROL:
                self._reseed(kin.tick, v, zi, kin.omega, res)
            else:
                self._law_wrench(kin.tick, v, res)
        self._last = res = self._res[0].tolist()
        if not observed:
            self._observe(res)
        self._events(int(res[T.R_EV]))
        if det is not None:
            s, e, z = det.flood.best
            ds = self.lay.ds
            out_row[ds:ds + 3] = (float(s), float(e), z if z == z else 0.0)
        return DynamicOut(
            wrench=(res[T.R_FX], res[T.R_FY], res[T.R_TAU]),
            stage=int(res[T.R_STAGE]),
            estimates=dict(zip(K.ESTIMATES, self._est[0].tolist(), strict=True)),
            feedback=DynamicFeedback(res[T.R_OM_MEAS], res[T.R_ALPHA], res[T.R_HOLD] != 0.0, res[T.R_WAITING] != 0.0),
        )

    def _late(self, late: Sequence[tuple[int, float]]) -> None:
        """This tick's late samples (tick, pooling weight) into the kernel's arrays (-1 ends them)."""
        n = len(late)
        if self._late_t.shape[1] <= n:
            self._late_t = np.full((1, n + 1), -1, np.int64)
            self._late_z = np.zeros((1, n + 1))
        for m, (t, zz) in enumerate(late):
            self._late_t[0, m] = t
            self._late_z[0, m] = zz
        self._late_t[0, n] = -1

    def _events(self, ev: int) -> None:
        """The Python side of the kernels' events after the observers have seen the update: a trial that went
        back to the old filter resets the monitor and changes the detection's regime."""
        if ev & K.E_BACK:
            if self.monitor is not None:
                self.monitor.reset()
            if self.detect is not None:
                self.detect.regime_change()

    def _observe(self, res: list[float]) -> None:
        """The monitor's and the detection's observation of the kf's update (if the kernel ran it for them)."""
        if res[T.R_OBS] == 0.0:
            return
        e0, e1, s00, s01, s11 = res[T.R_INNOV:T.R_INNOV + 5]
        if self.monitor is not None:
            self.monitor.observe(complex(e0, e1), s00, s01, s11, complex(res[T.R_VC0], res[T.R_VC0 + 1]),
                                 res[T.R_OM0], complex(res[T.R_Q0], res[T.R_Q0 + 1]),
                                 complex(res[T.R_LF], res[T.R_LF + 1]))
        if self.detect is not None:
            k = int(res[T.R_KF0])
            self.detect.observe(self._fbank[6][0, k], self._fbank[7][0, k])

    def _detection(self, tick: int, ev: int) -> None:
        """P1: the stage's events for the detection, its window and the team's decision applied to the filters,
        the slope's twin after it; then the effects in the model for the kernel."""
        det = self.detect
        if ev & K.E_REGIME:
            det.regime_change()
        if ev & K.E_M_START:
            det.push_reverses(int(self._r["m_start"]) + int(self._r["m_switch"]))
        shadow = self.shadow
        kf = self.kf
        dec = det.step_filters(tick, self._F[0, U], self._F[0, X].tolist(), (kf,) if shadow is None else (kf, shadow),
                               self.twin)
        if K.dyn_twin_decision(0, dec, det.undecided(SLOPE), self._dyn, self._fs, self._sens) & K.E_REPLACED:
            if self.monitor is not None:
                self.monitor.reset()
            det.filter_replaced()
        self._kin[0, T.K_ON] = det.on

    def _reseed(self, tick: int, v: complex, zi: complex, omega_hat: float, res: list[float]) -> None:
        """P2: restart, on trial, the filter that seems to have lost lock: (omega, q_i) fitted to the own contact
        velocities of the last window (:func:`fit_rotation`; before it is full, the neighbours' omega_hat and
        the kinematic z_i + z_C), 1/m and 1/J forgotten: where half the team has lost lock the neighbours'
        omega_hat is no seed (docs/high-noise.md). The old filter runs beside it until the trial's judgement
        keeps the one whose velocity innovations are the more consistent: a wrong lock is fixed by a restart,
        an effect the model lacks (sensor lag, friction) raises every filter's NIS and is not, so there the old
        filter and what it learnt are kept."""
        dnb = self._dnb[0]
        oms = [float(dnb[k]["om"]) for k in range(len(self.nbr_ids)) if dnb[k]["has_om"]]
        om0 = statistics.median(oms) if oms else omega_hat
        x = self._F[0, X].tolist()
        zc = complex(x[CH_ZX], x[CH_ZY]) * complex(res[T.R_ROT], res[T.R_ROT + 1])
        q0 = zi + zc if zc == zc else zi
        win_k, win_n = int(self._r["win_k"]), self.win_n
        if win_k >= win_n:
            k = win_k % win_n  # the oldest sample
            lim = self.spec.lock_omega_max
            # not the lost filter's own omega (it may be anything); capped, so that the scan stays small
            om_max = min(max(lim, 2.0 * abs(omega_hat), *(2.0 * abs(o) for o in oms)), 5.0 * lim)
            win = self._win[0]
            om_fit, q_fit, _ = fit_rotation(np.roll(win[:, 0], -k), np.roll(win[:, 1], -k), self.dt, om_max)
            if abs(om_fit) * win_n * self.dt >= 2.0:
                # the load turned by 2 rad or more in the window: the fit is determined (slower, q is not),
                # else the fallback above
                om0, q0 = om_fit, q_fit
        K.dyn_reseed(0, tick, v, complex(q0), float(om0), self._dyn, *self._fbank)
        if self.monitor is not None:
            self.monitor.reset()
        if self.detect is not None:
            self.detect.restart_filter(self.kf)

    def _law_wrench(self, tick: int, v: complex, r: list[float]) -> None:
        """P3: the user's law with this tick's estimates (agents/laws.py); its output is checked here, at the edge,
        and replaces the stage's wrench in the kernel's results."""
        x = self._F[0, X].tolist()
        q = complex(r[T.R_Q], r[T.R_Q + 1])
        zc = complex(r[T.R_ZC], r[T.R_ZC + 1])
        li = LawInput()
        li.tick = tick
        li.t = tick * self.dt
        li.stage = "done" if int(self._r["stage"]) == DONE else "background"
        li.m = x[CH_MN] / x[CH_MW] if x[CH_MW] > 0.0 else math.nan
        li.J = x[CH_JN] / x[CH_JW] if x[CH_JW] > 0.0 else math.nan
        k = int(self._r["kf_slot"])
        if self._fs[0, k]["ready"]:
            s = self._s[0, k].tolist()
            li.omega = s[5]
            li.vc = (s[0], s[1])
            li.q = (q.real, q.imag)
        else:
            li.omega = math.nan
            li.vc = li.q = (math.nan, math.nan)
        li.zc = (zc.real, zc.imag)
        li.v = (v.real, v.imag)
        li.default = (r[T.R_FX], r[T.R_FY], r[T.R_TAU])
        try:
            out = self.law(li)
        except Exception as exc:  # the user's code: one line naming it, where and when, not a bare traceback
            raise ControlLawError(f"control.law {self.law_ref!r} raised {type(exc).__name__}: {exc} at tick {tick} "
                                  f"(agent {self.id})") from exc
        self._res[0, T.R_FX:T.R_TAU + 1] = checked_wrench(out, self.law_ref, tick, self.id)

    # ------------------------------------------------------------------ outputs
    def monitor_entries(self) -> dict[str, float]:
        """The innovation monitor's estimate entries (NaN without it)."""
        out = dict.fromkeys(MONITOR_NAMES, math.nan) if self.monitor is None else self.monitor.entries()
        out.update(dict.fromkeys(DETECT_NAMES, math.nan) if self.detect is None else self.detect.entries())
        return out

    def uncertainties(self) -> tuple[float, float]:
        """One standard deviation of the m and J consensus values after the last tick (NaN while there is none):
        the filter's sd of the own local value and the spread to the neighbours' values that the averaging has
        not removed, in quadrature (docs/estimate-trust.md; computed by the tick's kernel)."""
        return self._last[T.R_M_SD], self._last[T.R_J_SD]
