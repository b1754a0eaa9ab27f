"""A team's tick between its kinematic and dynamical phases, over all B rows at once (docs/fast-core-plan.md, S7).

:func:`dyn_inputs` turns kin_step's results (agents/kernels/kinematic.py ``R_*``) into what dyn_tick reads
(agents/kernels/dynamic_step.py): the tick's values ``kin (B, NK)``, the accepted IN rows as a CSR in taking
order and the end (-1) of each row's late samples. :func:`dyn_outputs` returns dyn_tick's results to the
kinematic inputs of the next tick (the feedback) and to the caller (wrenches, stages). :func:`trust_observe_rows`
is each agent's estimate trust's tick (agents/kernels/window_stats.py) on the states it took,
:func:`monitor_observe_rows` its innovation monitor's on the filter's update; :func:`trust_entries_rows` the trust
entries of every row's estimate.
"""

from __future__ import annotations

import numpy as np

from agents.kernels import dynamic as K
from agents.kernels import dynamic_step as T
from agents.kernels import jit, register_warm
from agents.kernels import kinematic as KN
from agents.kernels.window_stats import monitor_observe, monitor_rows, trust_entries, trust_observe, trust_rows
from net.rows import SENDER, TICK

I_M, I_J = K.ESTIMATES.index("m"), K.ESTIMATES.index("J")  # in dyn_tick's estimates


@jit
def dyn_inputs(tick, inp, res, ptr, acc, rows, late_t, kin, in_ptr, taken):  # noqa: ANN001, ANN201
    """Row b's tick values ``kin[b]`` from its measured velocity ``inp[b, :2]`` and kin_step's results
    ``res[b]``; its accepted IN rows (``rows[acc[ptr[b]:ptr[b] + res[b, R_NACC]]]``) copied to
    ``taken[in_ptr[b]:in_ptr[b + 1]]``; ``late_t[b]`` ended after its ``res[b, R_NLATE]`` samples."""
    e = 0
    in_ptr[0] = 0
    for b in range(kin.shape[0]):
        r = res[b]
        k = kin[b]
        k[T.K_TICK] = tick
        k[T.K_VX] = inp[b, 0]
        k[T.K_VY] = inp[b, 1]
        k[T.K_U] = r[KN.R_U]
        k[T.K_UDEN] = r[KN.R_U_DEN]
        k[T.K_OMEGA] = r[KN.R_OMEGA]
        k[T.K_OMINIT] = 1.0 if r[KN.R_OM_INIT] != 0.0 else 0.0
        k[T.K_PHI] = r[KN.R_PHI]
        k[T.K_ZIX] = r[KN.R_ZI]
        k[T.K_ZIY] = r[KN.R_ZI + 1]
        k[T.K_TRUSTED] = 1.0 if r[KN.R_TRUSTED] != 0.0 else 0.0
        k[T.K_FX] = r[KN.R_FX]
        k[T.K_FY] = r[KN.R_FY]
        k[T.K_TAU] = r[KN.R_TAU]
        lo = ptr[b]
        for i in range(int(r[KN.R_NACC])):
            src = rows[acc[lo + i]]
            dst = taken[e]
            for c in range(rows.shape[1]):
                dst[c] = src[c]
            e += 1
        in_ptr[b + 1] = e
        nl = int(r[KN.R_NLATE])
        if nl < late_t.shape[1]:
            late_t[b, nl] = -1


@jit
def dyn_outputs(res, inp, w, stage):  # noqa: ANN001, ANN201
    """From dyn_tick's results ``res``: the feedback into the kinematic inputs ``inp`` of the next tick, the
    wrenches ``w (B, 3)`` and the stages."""
    for b in range(res.shape[0]):
        r = res[b]
        inp[b, KN.I_OM_MEAS] = r[T.R_OM_MEAS]
        inp[b, KN.I_ALPHA] = r[T.R_ALPHA]
        inp[b, KN.I_HOLD] = r[T.R_HOLD]
        inp[b, KN.I_WAITING] = r[T.R_WAITING]
        w[b, 0] = r[T.R_FX]
        w[b, 1] = r[T.R_FY]
        w[b, 2] = r[T.R_TAU]
        stage[b] = int(r[T.R_STAGE])


@jit
def trust_observe_rows(tr_i, tr_nb, trc, trr, tick, stage, taken, in_ptr, buf):  # noqa: ANN001, ANN201
    """Each row's trust tick in ``stage[b]``: the (sender, send tick) of its taken IN rows
    ``taken[in_ptr[b]:in_ptr[b + 1]]``, in taking order (``buf``: room for two ints per taken row)."""
    for b in range(stage.shape[0]):
        n = 0
        for e in range(in_ptr[b], in_ptr[b + 1]):
            buf[n] = int(taken[e, SENDER])
            buf[n + 1] = int(taken[e, TICK])
            n += 2
        trust_observe(b, tr_i, tr_nb, trc, trr, tick, stage[b], buf[:n])


@jit
def trust_entries_rows(tr_f, trc, est, res, out):  # noqa: ANN001, ANN201
    """Row b's trust entries (window_stats.trust_entries) into ``out[b]``, for its estimates of m and J
    (``est[b]``) and their sd (``res[b]``: dyn_tick's results)."""
    for b in range(out.shape[0]):
        trust_entries(b, tr_f, trc, est[b, I_M], res[b, T.R_M_SD], est[b, I_J], res[b, T.R_J_SD], out[b])


@jit
def monitor_observe_rows(auto, res, mon_k, mon_ws, full):  # noqa: ANN001, ANN201
    """The innovation monitor of each row b with ``auto[b]`` (one it has, and no handler has shown it this tick's
    update): the filter's update if dyn_tick ran it for the observers, then its window dropped on E_BACK (a trial
    went back to the old filter). The rows whose window is complete (their p-values due: InnovationMonitor.judge)
    into ``full``; returns their count."""
    n = 0
    for b in range(auto.shape[0]):
        if not auto[b]:
            continue
        r = res[b]
        if r[T.R_OBS] != 0.0:
            i = T.R_INNOV
            if monitor_observe(b, mon_k, mon_ws, complex(r[i], r[i + 1]), r[i + 2], r[i + 3], r[i + 4],
                               complex(r[T.R_VC0], r[T.R_VC0 + 1]), r[T.R_OM0], complex(r[T.R_Q0], r[T.R_Q0 + 1]),
                               complex(r[T.R_LF], r[T.R_LF + 1])):
                full[n] = b
                n += 1
        if int(r[T.R_EV]) & K.E_BACK:
            mon_k[b] = 0
    return n


@register_warm
def warm() -> None:
    B, size = 1, 8
    res = np.zeros((B, KN.R_PAIRS))
    res[0, KN.R_NACC] = 1.0
    kin = np.zeros((B, T.NK))
    in_ptr = np.zeros(B + 1, np.int64)
    taken = np.zeros((1, size))
    inp = np.zeros((B, 6))
    dyn_inputs(3, inp, res, np.zeros(B + 1, np.int64), np.zeros(1, np.int64), np.zeros((1, size)),
               np.zeros((B, 2), np.int64), kin, in_ptr, taken)
    stage = np.zeros(B, np.int64)
    dyn_outputs(np.zeros((B, T.NR)), inp, np.zeros((B, 3)), stage)
    tr_i, tr_f, tr_nb, trc, trr = trust_rows(B, 1, 5, 0.5, 1.6, 2)
    trust_observe_rows(tr_i, tr_nb, trc, trr, 3, stage, taken, in_ptr, np.zeros(2, np.int64))
    trust_entries_rows(tr_f, trc, np.zeros((B, len(K.ESTIMATES))), np.zeros((B, T.NR)), np.zeros((B, 6)))
    mon_k, _, mon_ws = monitor_rows(B, 4, 0.05)
    res = np.zeros((B, T.NR))
    res[0, T.R_OBS] = res[0, T.R_INNOV + 2] = res[0, T.R_INNOV + 4] = 1.0
    monitor_observe_rows(np.ones(B, np.bool_), res, mon_k, mon_ws, np.zeros(B, np.int64))
