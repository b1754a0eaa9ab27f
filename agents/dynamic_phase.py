"""The dynamical phase of paper 000 (Sec. V, Algorithm 1) and its background variant (Sec. VI, Algorithm 2).

The stage machine over the rigid-body filters, the flow-updating consensus channels and the stage agreement.
The maths is compiled (agents/kernels/dynamic.py, fused by agents/kernels/dynamic_step.py into one call per
stretch between Python handlers, which agents/team.py TeamCore makes for all its agents at once); this class is
row ``b`` of the team's banks: it runs the handlers the kernel stops that row for (P1 the online detection, P2 a
restart's fit, P3 the user's law), the innovation monitor's and the detection's observations, and is a view of
the row's state for tests and tools.

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
from agents.kernels.agreement import DEG, HORIZON, U, X
from agents.kernels.dynamic import CH_JN, CH_JW, CH_MN, CH_MW, CH_ZX, CH_ZY, N_CH, N_CH_AUG
from agents.laws import ControlLawError, LawInput, checked_wrench
from agents.rigid_filter import RigidEKF, fit_rotation, init_slot
from agents.stage_agreement import StageBarrier, mask_keys
from config.agent_params import DynamicsSpec
from net.rows import Layout
from net.vocabulary import DONE

# online detection (DynamicsSpec.online_detection): the pooled window statistics (agents/effect_decision.py)
CH_POOL = N_CH_AUG
CH_KEYS = tuple(f"c{c}" for c in range(N_CH_AUG + N_POOL))  # their names in StateMsg.shared


class DynamicPhase:
    """One agent's dynamical phase (see module docstring): row ``b`` of the kernels' banks, driven by TeamCore."""

    def __init__(self, agent_id: int, nbr_ids: Sequence[int], n: int, dt: float, sigma_v: float,
                 spec: DynamicsSpec, hist: int = 64, law: Callable[[LawInput], Sequence[float]] | None = None,
                 law_ref: str = "", team: tuple | None = None, b: int = 0) -> None:
        """``team``: (banks, kin, res, est, monitor rows or None) of a team (agents/team.py TeamCore) to be row ``b``
        of; without it, one row of its own."""
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
        nch, d, self.win_n, self.nbk = self.shape(n, dt, spec)
        self.nch = nch
        self.ch_keys = CH_KEYS[:nch]
        if team is None:
            team = (K.new_banks(1, len(ids), nch, d, hist, self.win_n, self.nbk), np.zeros((1, T.NK)),
                    np.zeros((1, T.NR)), np.zeros((1, len(K.ESTIMATES))), None)
            team[2][0, T.R_M_SD] = team[2][0, T.R_J_SD] = math.nan
        self.b = b
        self._banks = banks = team[0]
        self._kin, self._res, self._est = team[1:4]  # the tick's values, results and estimates (dynamic_step.py)
        (self._dyn, self._dnb, _, self._rx_order, _, _, _, self._win, self._S, self._F, self._I,
         *self._fbank) = banks
        self._fs, self._s, self._sens = self._fbank[0], self._fbank[1], self._fbank[3]
        K.init_dyn_row(self._dyn, b, n, dt, sigma_v, spec, hist, law is not None, self._S, agent_id)
        init_slot(tuple(self._fbank), b, K.KF, sigma_v, spec, self.background)
        self._I[b, DEG] = len(ids)
        self._r = self._dyn[b]
        self.lay = Layout(True, nch, self.nbk, spec.online_detection, len(ids))
        self._kin[b, T.K_ON] = 3 | int(self._r["declared"])  # the effects in the model without online detection

        def ticks(s: float) -> int:
            return max(1, int(round(s / dt)))

        # innovation monitor (report-only), fed from the filter's restart at kinematic readiness on (by the team's
        # kernel on the ticks no handler of this row runs)
        self.monitor = (InnovationMonitor(ticks(spec.monitor_window_s), spec.monitor_lags, spec.monitor_alpha,
                                          team[4], b if team[4] is not None else 0)
                        if spec.monitor_window_s > 0.0 else None)
        # online detection: the team pools its filters' scores and switches a missing effect on
        self.detect = (OnlineDetection(n, ticks(spec.monitor_window_s), spec.monitor_lags, spec.monitor_alpha,
                                       ticks(spec.horizon_s), CH_POOL, int(self._r["declared"]),
                                       ALL if spec.online_force_bias else ALL & ~(1 << EFFECTS.index("force_bias")))
                       if spec.online_detection else None)
        self._observed = False  # the observers have seen this tick's update (in a handler)

    @staticmethod
    def shape(n: int, dt: float, spec: DynamicsSpec) -> tuple[int, int, int, int]:
        """(channels, filter state size, lock window ticks, barrier mask chunks) of a phase of ``spec``."""
        nch = N_CH_AUG + N_POOL if spec.online_detection else N_CH_AUG if spec.estimate_effects else N_CH
        aug = spec.estimate_effects or spec.online_detection
        return (nch, F.D_AUGMENTED if aug else F.D_NOMINAL, max(1, int(round(spec.lock_window_s / dt))),
                len(mask_keys(n)))

    # ------------------------------------------------------------------ the view (tests and tools)
    def _slot(self, role: str) -> RigidEKF | None:
        k = int(self._r[role])
        return None if k < 0 else RigidEKF.view(tuple(self._fbank), self.b, k)

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
        return FlowAverage.view(self.nbr_ids, (self._F, self._I), self.b)

    @property
    def barrier(self) -> StageBarrier:
        """The stage barrier (a view of a copy of its row)."""
        b = self.b
        return StageBarrier(self.id, self.n, int(self._S[b, HORIZON]), bank=self._S[b:b + 1].copy())

    @property
    def nbr_stage(self) -> dict[int, int]:
        """Each neighbour heard from: its stage (first-heard order)."""
        b = self.b
        return {self.nbr_ids[k]: int(self._dnb[b, k]["stage"]) for k in self._rx_order[b, :self._r["rx_n"]]}

    # ------------------------------------------------------------------ the tick (driven by TeamCore)
    def begin(self) -> None:
        """Before the tick's kernel call (online detection): its state into the tick's values (K_SLOPE, K_ON)."""
        det = self.detect
        kr = self._kin[self.b]
        kr[T.K_SLOPE] = det.undecided(SLOPE)
        kr[T.K_ON] = det.on

    def handle(self, at: int) -> None:
        """The handler of the point ``at`` the kernel stopped the row at (P1, P2, P3; the observers see the
        update before the events of P2 and P3)."""
        b = self.b
        res = self._res[b].tolist()
        tick, vx, vy, _, _, omega, _, _, zx, zy = self._kin[b, :T.K_TRUSTED].tolist()
        tick = int(tick)
        ev = int(res[T.R_EV])
        if at == T.AT_UPDATE:
            self._detection(tick, ev)
            return
        if not self._observed:
            self._observed = True
            self._observe(res)
        self._events(ev)
        if at == T.AT_CONTROL:
            self._reseed(tick, complex(vx, vy), complex(zx, zy), omega, res)
        else:
            self._law_wrench(tick, complex(vx, vy), res)

    def end(self, out_row: np.ndarray) -> None:
        """After the tick's last kernel call (online detection, or a handler ran): the observers if no handler
        has shown them the update, the last events, the detection's flood slots of ``out_row``."""
        res = self._res[self.b].tolist()
        if self._observed:
            self._observed = False
        else:
            self._observe(res)
        self._events(int(res[T.R_EV]))
        det = self.detect
        if det is not None:
            s, e, z = det.flood.best
            ds = self.lay.ds
            out_row[ds:ds + 3] = (float(s), float(e), z if z == z else 0.0)

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
            self.detect.observe(self._fbank[6][self.b, k], self._fbank[7][self.b, k])

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
        b = self.b
        dec = det.step_filters(tick, self._F[b, U], self._F[b, X].tolist(), (kf,) if shadow is None else (kf, shadow),
                               self.twin)
        if K.dyn_twin_decision(b, dec, det.undecided(SLOPE), self._dyn, self._fs, self._sens) & K.E_REPLACED:
            if self.monitor is not None:
                self.monitor.reset()
            det.filter_replaced()
        self._kin[b, T.K_ON] = det.on

    def _reseed(self, tick: int, v: complex, zi: complex, omega_hat: float, res: list[float]) -> None:
        """P2: restart, on trial, the filter that seems to have lost lock: (omega, q_i) fitted to the own contact
        velocities of the last window (:func:`fit_rotation`; before it is full, the neighbours' omega_hat and
        the kinematic z_i + z_C), 1/m and 1/J forgotten: where half the team has lost lock the neighbours'
        omega_hat is no seed (docs/high-noise.md). The old filter runs beside it until the trial's judgement
        keeps the one whose velocity innovations are the more consistent: a wrong lock is fixed by a restart,
        an effect the model lacks (sensor lag, friction) raises every filter's NIS and is not, so there the old
        filter and what it learnt are kept."""
        b = self.b
        dnb = self._dnb[b]
        oms = [float(dnb[k]["om"]) for k in range(len(self.nbr_ids)) if dnb[k]["has_om"]]
        om0 = statistics.median(oms) if oms else omega_hat
        x = self._F[b, X].tolist()
        zc = complex(x[CH_ZX], x[CH_ZY]) * complex(res[T.R_ROT], res[T.R_ROT + 1])
        q0 = zi + zc if zc == zc else zi
        win_k, win_n = int(self._r["win_k"]), self.win_n
        if win_k >= win_n:
            k = win_k % win_n  # the oldest sample
            lim = self.spec.lock_omega_max
            # not the lost filter's own omega (it may be anything); capped, so that the scan stays small
            om_max = min(max(lim, 2.0 * abs(omega_hat), *(2.0 * abs(o) for o in oms)), 5.0 * lim)
            win = self._win[b, :win_n]
            om_fit, q_fit, _ = fit_rotation(np.roll(win[:, 0], -k), np.roll(win[:, 1], -k), self.dt, om_max)
            if abs(om_fit) * win_n * self.dt >= 2.0:
                # the load turned by 2 rad or more in the window: the fit is determined (slower, q is not),
                # else the fallback above
                om0, q0 = om_fit, q_fit
        K.dyn_reseed(b, tick, v, complex(q0), float(om0), self._dyn, *self._fbank)
        if self.monitor is not None:
            self.monitor.reset()
        if self.detect is not None:
            self.detect.restart_filter(self.kf)

    def _law_wrench(self, tick: int, v: complex, r: list[float]) -> None:
        """P3: the user's law with this tick's estimates (agents/laws.py); its output is checked here, at the edge,
        and replaces the stage's wrench in the kernel's results."""
        b = self.b
        x = self._F[b, X].tolist()
        q = complex(r[T.R_Q], r[T.R_Q + 1])
        zc = complex(r[T.R_ZC], r[T.R_ZC + 1])
        li = LawInput()
        li.tick = tick
        li.t = tick * self.dt
        li.stage = "done" if int(self._r["stage"]) == DONE else "background"
        li.m = x[CH_MN] / x[CH_MW] if x[CH_MW] > 0.0 else math.nan
        li.J = x[CH_JN] / x[CH_JW] if x[CH_JW] > 0.0 else math.nan
        k = int(self._r["kf_slot"])
        if self._fs[b, k]["ready"]:
            s = self._s[b, k].tolist()
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
        self._res[b, T.R_FX:T.R_TAU + 1] = checked_wrench(out, self.law_ref, tick, self.id)

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
        r = self._res[self.b]
        return r.item(T.R_M_SD), r.item(T.R_J_SD)
