"""One tick of the dynamical phase over rows of agents: the row kernels of agents/kernels/dynamic.py fused into one
compiled call that stops only where a Python handler must run (docs/fast-core-plan.md, section 3 and S6).

:func:`dyn_tick` runs each row ``b`` of ``rows`` from its point ``at[b]`` and leaves there the point it stopped
at; the caller runs the handler of that point and calls again for the rows not at :data:`AT_END`:

* ``AT_BEGIN``: the accepted IN rows into the phase, the late samples' sums, the stage's advance. With online
  detection it stops at ``AT_UPDATE``: P1 (the detection's window, the team's decision, the slope's twin) runs
  in Python, which then sets ``kin[b, K_ON]``.
* ``AT_UPDATE``: psi, the filter's update (the kf's vc, omega, q before it kept in ``res`` for the innovation
  monitor), the lock check; a restart asked for stops at ``AT_CONTROL`` (P2: the caller fits (omega, q), calls
  :func:`agents.kernels.dynamic.dyn_reseed`).
* ``AT_CONTROL``: the shape hold, the stage's wrench; under the user's law (done or background stage) it stops
  at ``AT_FINISH``: P3 writes the law's wrench into ``res[b, R_FX:R_TAU + 1]``.
* ``AT_FINISH``: the dither, the consensus inputs and update, the averaging stages' readiness, the
  prediction, the OUT row's dynamical slots, the estimates, the feedback and the sd of m and J.

``res[b, R_EV]`` accumulates the events (dynamic.py's ``E_*``) of the points run since the row's call began.
"""

from __future__ import annotations

import numpy as np

from agents.kernels import dynamic as K
from agents.kernels import jit, register_warm
from agents.kernels.agreement import barrier_complete, barrier_set_ready, flow_average_update
from agents.kernels.uncertainty import uncertainties
from net.rows import PHASE, SENDER, Layout

AT_BEGIN, AT_UPDATE, AT_CONTROL, AT_FINISH, AT_END = range(5)
# the kinematic tick's values, kin[b, :] (the caller's; K_SLOPE: the detection's undecided(SLOPE) at the tick's
# start, K_ON: the effects in the model, ``_on``)
(K_TICK, K_VX, K_VY, K_U, K_UDEN, K_OMEGA, K_OMINIT, K_PHI, K_ZIX, K_ZIY, K_TRUSTED, K_FX, K_FY, K_TAU, K_SLOPE,
 K_ON) = range(16)
NK = 16
# the tick's results, res[b, :]: events; whether the observers (monitor, detection) see this update and the kf
# slot they read; the kf's vc, omega, q before the update and the own force of the last prediction; e^{i psi};
# q_i and z_C (world); the wrench; the stage's tick k; the feedback (om_meas, alpha, hold_shape, team_waiting:
# kinematic.py's inputs I_OM_MEAS.. of the next tick); the kf's innovation (e0, e1, s00, s01, s11) for the
# observers; the stage after the tick; the sd of m and J (agents/kernels/uncertainty.py)
(R_EV, R_OBS, R_KF0, R_VC0, R_OM0, R_Q0, R_LF, R_ROT, R_Q, R_ZC, R_FX, R_FY, R_TAU, R_K, R_OM_MEAS, R_ALPHA, R_HOLD,
 R_WAITING, R_INNOV, R_STAGE, R_M_SD, R_J_SD) = (0, 1, 2, 3, 5, 6, 8, 10, 12, 14, 16, 17, 18, 19, 20, 21, 22, 23, 24,
                                                29, 30, 31)
NR = 32


@jit
def _slot(ids, b, sender):  # noqa: ANN001, ANN202
    """The neighbour slot of ``sender`` in row b (ids sorted, as the banks' slots)."""
    for k in range(ids.shape[1]):
        if ids[b, k] == sender:
            return k
    return -1


@jit
def _begin(b, kin, inbox, in_ptr, late_t, late_z, lay, ids, res, dyn, dnb, nbr_mask, rx_order, psi_order, cum,  # noqa: ANN001, ANN202
           cum_t, S, Fa, Ia, fs, s, P, sens, Qd, aug, innov, sens_h):
    for e in range(in_ptr[b], in_ptr[b + 1]):
        v = inbox[e]
        K.dyn_receive(b, _slot(ids, b, int(v[SENDER])), v, lay, dyn, dnb, nbr_mask, rx_order, psi_order, Fa, Ia)
    for m in range(late_t.shape[1]):
        if late_t[b, m] < 0:
            break
        K.note_late(b, late_t[b, m], late_z[b, m], dyn, cum, cum_t)
    kr = kin[b]
    tick = int(kr[K_TICK])
    ev = K.dyn_advance_stage(b, tick, complex(kr[K_VX], kr[K_VY]), kr[K_OMEGA], kr[K_PHI],
                             complex(kr[K_ZIX], kr[K_ZIY]), kr[K_TRUSTED] != 0.0, kr[K_OMINIT] != 0.0,
                             kr[K_SLOPE] != 0.0, dyn, dnb, nbr_mask, rx_order, S, fs, s, P, sens, Qd, aug, innov,
                             sens_h)
    res[b, R_EV] = float(int(res[b, R_EV]) | ev)


@jit
def _update(b, kin, res, dyn, dnb, psi_order, cum, cum_t, win, Ia, fs, s, P, sens, innov, sens_h):  # noqa: ANN001, ANN202
    r = dyn[b]
    kr = kin[b]
    tick = int(kr[K_TICK])
    v = complex(kr[K_VX], kr[K_VY])
    u = kr[K_U]
    kf = r["kf_slot"]
    obs = fs[b, kf]["ready"] and r["restarted"] and not r["has_q_held"]
    res[b, R_OBS] = 1.0 if obs else 0.0
    res[b, R_KF0] = float(kf)
    if obs:  # the prediction's: known before the innovation
        res[b, R_VC0] = s[b, kf, 0]
        res[b, R_VC0 + 1] = s[b, kf, 1]
        res[b, R_OM0] = s[b, kf, 5]
        res[b, R_Q0] = s[b, kf, 2]
        res[b, R_Q0 + 1] = s[b, kf, 3]
        res[b, R_LF] = r["last_f"].real
        res[b, R_LF + 1] = r["last_f"].imag
    rot = K.body_frame(b, tick, kr[K_PHI], dyn, dnb, psi_order, Ia, fs, s)
    res[b, R_ROT] = rot.real
    res[b, R_ROT + 1] = rot.imag
    u_var, u_dc, u_dw = K.dyn_filter_update(b, tick, v, u, kr[K_UDEN], dyn, cum, cum_t, fs, s, P, sens, innov,
                                            sens_h)
    if obs:
        for i in range(5):
            res[b, R_INNOV + i] = innov[b, kf, i]
    ev = K.lock_check(b, tick, v, u, u_var, u_dc, u_dw, dyn, win, fs, s, P, sens, innov, sens_h)
    res[b, R_EV] = float(int(res[b, R_EV]) | ev)
    return ev


@jit
def _control(b, kin, res, dyn, Fa, fs, s, P, Qd):  # noqa: ANN001, ANN202
    r = dyn[b]
    kr = kin[b]
    tick = int(kr[K_TICK])
    rot = complex(res[b, R_ROT], res[b, R_ROT + 1])
    q, zc, ev = K.hold_shape_check(b, tick, complex(kr[K_ZIX], kr[K_ZIY]), rot, dyn, Fa, fs, s, P, Qd)
    res[b, R_EV] = float(int(res[b, R_EV]) | ev)
    stage = r["stage"]
    k = tick - r["stage_tick"]
    fx, fy, tau = K.stage_wrench(b, stage, k, complex(kr[K_VX], kr[K_VY]), q, zc, kr[K_FX], kr[K_FY], kr[K_TAU],
                                 dyn)
    res[b, R_Q] = q.real
    res[b, R_Q + 1] = q.imag
    res[b, R_ZC] = zc.real
    res[b, R_ZC + 1] = zc.imag
    res[b, R_FX] = fx
    res[b, R_FY] = fy
    res[b, R_TAU] = tau
    res[b, R_K] = float(k)
    return r["has_law"] and (stage == K.DONE or stage == K.BACKGROUND)


@jit
def _finish(b, kin, res, out, est, lay, dyn, rx_order, S, Fa, Ia, cum, cum_t, fs, s, P, sens, Qd, aug):  # noqa: ANN001, ANN202
    r = dyn[b]
    kr = kin[b]
    tick = int(kr[K_TICK])
    stage = r["stage"]
    k = int(res[b, R_K])
    rot = complex(res[b, R_ROT], res[b, R_ROT + 1])
    q = complex(res[b, R_Q], res[b, R_Q + 1])
    zc = complex(res[b, R_ZC], res[b, R_ZC + 1])
    fx = res[b, R_FX]
    fy = res[b, R_FY]
    tau = res[b, R_TAU]
    if stage == K.BACKGROUND:  # Prop. 6 (or the user's law) + the regulation torque + a dither for J
        tau += K.dither(b, k, dyn)
    jstage = stage == K.J_EXCITE  # the J stage's forces (torque from the JG channel, net force zero)
    on = int(kr[K_ON])
    K.consensus_inputs(b, stage, q, zc, r["has_q_held"], r["q_held"], rot, fx, fy, tau, jstage, on, dyn, Fa, fs, s,
                       P)
    flow_average_update(b, Fa, Ia)
    # readiness of the averaging stages
    if stage == K.M_AVERAGE and K.converged(b, K.CH_MN, K.CH_MW, tick, dyn, Fa, Ia):
        barrier_set_ready(b, S, tick)
    elif stage == K.J_AVERAGE and K.converged(b, K.CH_JN, K.CH_JW, tick, dyn, Fa, Ia):
        barrier_set_ready(b, S, tick)
    r["last_f"] = complex(fx, fy)
    K.dyn_predict(b, tick, rot, jstage, K.j_sign(k, r) if jstage else 0.0, dyn, cum, cum_t, Fa, fs, s, P, sens, Qd,
                  aug)
    res[b, R_TAU] = tau
    row = out[b]
    row[PHASE] = float(r["stage"])
    K.dyn_write_out(b, row, lay, dyn, S, Fa, Ia)
    K.dyn_estimates(b, on, dyn, Fa, s, est[b])
    res[b, R_OM_MEAS] = r["om_meas"]
    res[b, R_ALPHA] = r["alpha"]
    res[b, R_HOLD] = 1.0 if r["has_q_held"] else 0.0
    res[b, R_WAITING] = 1.0 if r["stage"] == K.KINEMATIC and not barrier_complete(b, S) else 0.0
    res[b, R_STAGE] = float(r["stage"])
    m_sd, j_sd = uncertainties(b, Fa, rx_order, r["m_local_sd"], r["j_local_sd"])
    res[b, R_M_SD] = m_sd
    res[b, R_J_SD] = j_sd


@jit
def dyn_tick(rows, at, kin, inbox, in_ptr, late_t, late_z, lay, ids, res, out, est, dyn, dnb, nbr_mask, rx_order,  # noqa: ANN001, ANN201
             psi_order, cum, cum_t, win, S, Fa, Ia, fs, s, P, sens, Qd, aug, innov, sens_h):
    """Each row b of ``rows`` from ``at[b]`` to the next point a Python handler must run (module docstring).
    ``kin`` (B, NK) the kinematic tick's values; row b's accepted IN rows ``inbox[in_ptr[b]:in_ptr[b + 1]]`` in
    taking order (``lay``: net/rows.py's table; ``ids`` (B, D) the neighbour ids of the slots); its late samples
    ``late_t[b], late_z[b]`` up to the first tick -1; ``res`` (B, NR) the results; ``out`` (B, size_out) the OUT
    rows (the dynamical slots and PHASE written here); ``est`` (B, len(ESTIMATES)); then the banks
    (dynamic.new_banks' order). Returns the rows not at AT_END."""
    left = 0
    for b in rows:
        p = at[b]
        if p == AT_BEGIN:
            res[b, R_EV] = 0.0
            _begin(b, kin, inbox, in_ptr, late_t, late_z, lay, ids, res, dyn, dnb, nbr_mask, rx_order, psi_order,
                   cum, cum_t, S, Fa, Ia, fs, s, P, sens, Qd, aug, innov, sens_h)
            p = AT_UPDATE
            if dyn[b]["has_detect"]:
                at[b] = p
                left += 1
                continue
        else:
            res[b, R_EV] = 0.0
        if p == AT_UPDATE:
            ev = _update(b, kin, res, dyn, dnb, psi_order, cum, cum_t, win, Ia, fs, s, P, sens, innov, sens_h)
            p = AT_CONTROL
            if ev & K.E_RESEED:
                at[b] = p
                left += 1
                continue
        if p == AT_CONTROL:
            p = AT_FINISH
            if _control(b, kin, res, dyn, Fa, fs, s, P, Qd):
                at[b] = p
                left += 1
                continue
        if p == AT_FINISH:
            _finish(b, kin, res, out, est, lay, dyn, rx_order, S, Fa, Ia, cum, cum_t, fs, s, P, sens, Qd, aug)
            p = AT_END
        at[b] = p
    return left


@register_warm
def warm() -> None:
    from config.agent_params import DynamicsSpec  # noqa: PLC0415

    banks = K.new_banks(1, 1, 10, 8)
    K.init_dyn_row(banks[0], 0, 2, 0.01, 0.05, DynamicsSpec(), S=banks[8])
    lay = Layout(True, 10, 1, False, 1)
    kin = np.zeros((1, NK))
    kin[0, K_OMINIT] = 1.0
    for at in (AT_BEGIN, AT_CONTROL, AT_FINISH):
        dyn_tick(np.zeros(1, np.int64), np.full(1, at, np.int64), kin, np.zeros((1, lay.size_in)),
                 np.zeros(2, np.int64), np.full((1, 1), -1, np.int64), np.zeros((1, 1)), lay.lay,
                 np.zeros((1, 1), np.int64), np.zeros((1, NR)), np.zeros((1, lay.size_out)),
                 np.zeros((1, len(K.ESTIMATES))), *banks)
