"""The dynamical phase as row kernels over a leading agent axis: layouts and kernels (docs/fast-core-plan.md, S6).

agents/kernels/dynamic_step.py fuses them into the tick :class:`agents.dynamic_phase.DynamicPhase` runs (one
compiled call per stretch between its Python handlers); each kernel is tested bit for bit against the Python
method it replaced (tests/dynamic_reference.py, frozen) on calls recorded from quick-dynamics runs, compiled ==
``py_func``, batch 1 == batch n (tests/test_dynamic_kernels.py).

Contents (section 3's names): the layouts ``DYN`` (B,), ``DNB`` (B, D) and the arrays of section 1.3
(:func:`new_dyn_bank`, :func:`new_banks`), :func:`init_dyn_row`, :func:`load_row` (a Python phase into row b: the
tests' recorder); A3 :func:`dyn_receive`, :func:`note_late`; A6 :func:`dyn_advance_stage` (events E_REGIME,
E_M_START for the detection); B1 :func:`body_frame`; B2 :func:`dyn_filter_update`; B3 :func:`lock_check`
(E_BACK, E_RESEED), :func:`dyn_reseed` (P2's restart once Python has fitted (omega, q)); C1
:func:`hold_shape_check`, :func:`stage_wrench`, :func:`j_sign`, :func:`dither`; D1 :func:`consensus_inputs`; D3
:func:`converged`; D4 :func:`dyn_predict`; D5 :func:`dyn_estimates`, :func:`dyn_write_out`; P1's
:func:`dyn_twin_decision` (E_REPLACED). The barrier is agreement.py's ``S`` row.

Still Python (DynamicPhase): the OUT row's flood slots, the innovation monitor's and the detection's
observations, P1-P3 (the sd of m and J is agents/kernels/uncertainty.py's, called by dynamic_step.py).

Banks. The consensus channels are agreement.py's flow-average bank ``(F, I)`` (channel values x at ``F[b, X]``,
the degrees in ``I``); the filters are a filter.py bank of 3 slots per agent, ``DYN.kf_slot``,
``shadow_slot``, ``twin_slot`` naming them (-1: none), so ``self.kf = self.shadow`` is an index swap.
Neighbour slot k is the k-th id of the agent's sorted neighbour list, as in the flow-average bank.
``psi_order[b, :psi_n]`` is the first-insert order of ``nbr_psi`` (it reaches the psi sum: section 1.6).
"""

from __future__ import annotations

import math
from math import cos, sin

import numpy as np

from agents.kernels import filter as F
from agents.kernels import jit, register_warm
from agents.kernels.agreement import (
    DEG,
    FLOW,
    HEARD,
    HORIZON,
    MASK_BITS,
    ME,
    SBITS,
    SWITCH,
    TMAX,
    U,
    X,
    barrier_bank,
    barrier_merge,
    barrier_reset,
    barrier_set_ready,
    flow_average_bank,
)
from agents.kernels.agreement import N as BN
from agents.kernels.libm import pow_libm
from net.rows import (
    C0,
    L_B0,
    L_BLOCK,
    L_BS,
    L_BT,
    L_DG,
    L_NBK,
    L_NCH,
    L_P0,
    L_PS,
    L_SK,
    OM,
    PAIR_HEAD,
    PHASE,
    TICK,
    Layout,
)

# the stages (net/vocabulary.py) the kernels read
SPINUP, KINEMATIC, M_EXCITE, M_AVERAGE, J_EXCITE, J_AVERAGE, DONE, BACKGROUND = range(8)
# Flow-average channels: the mean force (FX, FY: world-fixed, so a common force passes through at once);
# JG: g_i = k_z q_i . (q_i - z_C), whose mean times s(t) is the J stage's torque (rotation-invariant, fed
# from the m stage on, so it has converged when the J stage starts and s(t) flips); DT: q_i x (f_i - fbar)
# + tau_i; z_C in the shared body frame (ZX, ZY); numerator and weight of the averages of m and J
CH_FX, CH_FY, CH_JG, CH_DT, CH_ZX, CH_ZY, CH_MN, CH_MW, CH_JN, CH_JW = range(10)
N_CH = 10
# augmented model (DynamicsSpec.estimate_effects): the local b, c, F_c and f (x, y) numerators; their weights
# are the m and J weight channels (b, F_c and f are offered exactly when m is, c when J is)
CH_BN, CH_CN, CH_FN, CH_FBX, CH_FBY = range(10, 15)
N_CH_AUG = 15
KF, SHADOW, TWIN = 0, 1, 2  # the slots the builder gives the filters (the indices in DYN may swap)
# event flags a kernel returns for the Python side (docs/fast-core-plan.md, section 3)
E_RESEED = 1  # the lock check asks for a restart on trial: P2 fits (omega, q_i), then dyn_reseed, hold_shape_check
E_BACK = 2  # a trial went back to the old filter: the monitor resets and the detection's regime changes
E_REGIME = 4  # a stage entered or the filter restarted: the detection's regime_change()
E_M_START = 8  # the m stage entered: the detection's push_reverses(m_start + m_switch)
E_REPLACED = 16  # the twin became the kf: the monitor resets, the detection's filter_replaced()
SLOPE = 3  # agents/effect_decision.SLOPE (force_bias, EFFECTS order): the effect the slope's twin carries

DYN = np.dtype([
    # parameters (constant after init_dyn_row)
    ("n", np.int64), ("dt", np.float64), ("hist", np.int64), ("background", np.bool_), ("settle", np.int64),
    ("m_ticks", np.int64), ("m_switch", np.int64), ("j_ticks", np.int64), ("avg_window", np.int64),
    ("dither_ticks", np.int64), ("lock_thr", np.float64), ("lock_alpha", np.float64), ("lock_hold", np.int64),
    ("win_n", np.int64), ("sigma_v", np.float64), ("declared", np.int64), ("u_var_scale", np.float64),
    ("u_delayed", np.bool_), ("k_z", np.float64), ("m_force", np.float64), ("m_force_angle", np.float64),
    ("omega_sign", np.int64), ("j_cycles", np.int64), ("dither_torque", np.float64), ("avg_tol", np.float64),
    ("brake", np.float64), ("filter_omega", np.bool_), ("j_feedforward", np.bool_), ("omega_walk", np.float64),
    ("j_omega_walk", np.float64), ("has_detect", np.bool_), ("has_monitor", np.bool_), ("has_law", np.bool_),
    ("effects", np.bool_),
    # state
    ("stage", np.int64), ("stage_tick", np.int64), ("late_switches", np.int64), ("kin_since", np.int64),
    ("conv_since", np.int64), ("lock_from", np.int64), ("reseeds", np.int64), ("kf_tick", np.int64),
    ("trial_tick", np.int64), ("lock_fails", np.int64), ("m_start", np.int64), ("j_start", np.int64),
    ("win_k", np.int64),
    ("cc", np.float64), ("cw", np.float64), ("late_z", np.float64), ("late_c", np.float64), ("late_w", np.float64),
    ("m_local", np.float64), ("m_local_sd", np.float64), ("j_local", np.float64), ("j_local_sd", np.float64),
    ("b_local", np.float64), ("c_local", np.float64), ("alpha", np.float64), ("psi", np.float64),
    ("nis_avg", np.float64), ("shadow_nis", np.float64), ("om_meas", np.float64),
    ("f_int", np.complex128), ("last_f", np.complex128), ("q_held", np.complex128), ("has_q_held", np.bool_),
    ("b_offered", np.bool_), ("c_offered", np.bool_), ("f_offered", np.bool_), ("fb_offered", np.bool_),
    ("released", np.bool_), ("frozen_m", np.bool_), ("frozen_j", np.bool_), ("restarted", np.bool_),
    ("kf_slot", np.int64), ("shadow_slot", np.int64), ("twin_slot", np.int64),
    ("rx_n", np.int64), ("psi_n", np.int64),
])
"""One agent's dynamical phase: DynamicPhase's parameters and scalar state under their Python names
(docs/fast-core-plan.md, section 1.3); ``effects``: the augmented model's declared effects (estimate_effects)."""

DNB = np.dtype([
    ("heard", np.bool_), ("stage", np.int64), ("stage_tick", np.int64), ("bar_tmax", np.int64),
    ("bar_switch", np.int64), ("psi", np.float64), ("psi_t", np.int64), ("has_psi", np.bool_),
    ("om", np.float64), ("has_om", np.bool_),
])
"""Per neighbour slot: ``nbr_stage``, ``nbr_stage_tick``, ``nbr_barrier`` (its mask in ``nbr_mask``),
``nbr_psi`` and ``nbr_om`` of DynamicPhase."""


def new_dyn_bank(B: int, D: int, hist: int, win_n: int, nbk: int) -> tuple[np.ndarray, ...]:
    """Zeroed dynamical-phase arrays for B agents: (dyn, dnb, nbr_mask, rx_order, psi_order, cum, cum_t, win, S).
    ``S (B, SBITS + nbk)``: the own stage barrier (agreement.py's barrier rows; ME, N, HORIZON set by
    :func:`init_dyn_row`).
    ``cum (B, hist, 2)``: the ring of (dt sum T, dt sum omega) per state tick, ``cum_t`` its ticks (-1: none);
    ``win (B, win_n, 2)`` the lock window's (v, f_int); ``nbr_mask (B, D, nbk)`` the neighbours' barrier masks
    in 50-bit chunks."""
    cum_t = np.full((B, hist), -1, np.int64)
    return (np.zeros(B, DYN), np.zeros((B, D), DNB), np.zeros((B, D, nbk), np.int64), np.full((B, D), -1, np.int64),
            np.full((B, D), -1, np.int64), np.zeros((B, hist, 2)), cum_t, np.zeros((B, win_n, 2), np.complex128),
            barrier_bank(B, nbk))


def init_dyn_row(dyn: np.ndarray, b: int, n: int, dt: float, sigma_v: float, spec, hist: int = 64,  # noqa: ANN001
                 has_law: bool = False, S: np.ndarray | None = None, me: int = 0) -> None:
    """Row b's parameters and initial state, as DynamicPhase.__init__ sets them (with ``S``, also the barrier
    row's agent ``me``, team size and horizon)."""
    from agents.effect_decision import EFFECTS  # noqa: PLC0415 (the Python side's names, not a kernel's)

    def ticks(s: float) -> int:
        return max(1, int(round(s / dt)))

    r = dyn[b]
    r["n"], r["dt"], r["hist"], r["background"] = n, dt, hist, spec.algorithm == "background"
    r["settle"], r["m_ticks"], r["m_switch"] = ticks(spec.kin_settle_s), ticks(spec.m_excite_s), ticks(spec.m_switch_s)
    r["j_ticks"], r["avg_window"] = ticks(spec.j_excite_s), ticks(spec.avg_window_s)
    r["dither_ticks"] = ticks(spec.dither_period_s)
    r["lock_thr"], r["lock_alpha"] = spec.lock_nis, min(1.0, dt / spec.lock_tau_s)
    r["lock_hold"] = ticks(spec.lock_hold_s)
    r["win_n"], r["sigma_v"] = ticks(spec.lock_window_s), sigma_v
    r["declared"] = sum(1 << k for k, e in enumerate(EFFECTS) if e in spec.estimate_effects)
    for f in ("u_var_scale", "u_delayed", "k_z", "m_force", "m_force_angle", "omega_sign", "j_cycles", "dither_torque",
              "avg_tol", "brake", "filter_omega", "j_feedforward", "omega_walk", "j_omega_walk"):
        r[f] = getattr(spec, f)
    r["has_detect"], r["has_monitor"] = spec.online_detection, spec.monitor_window_s > 0.0
    r["has_law"], r["effects"] = has_law, bool(spec.estimate_effects)
    for f in ("kin_since", "conv_since", "kf_tick", "trial_tick", "m_start", "j_start", "shadow_slot", "twin_slot"):
        r[f] = -1
    for f in ("m_local", "m_local_sd", "j_local", "j_local_sd", "b_local", "c_local", "psi", "om_meas"):
        r[f] = math.nan
    r["nis_avg"] = r["shadow_nis"] = 2.0
    r["kf_slot"] = KF
    if S is not None:
        S[b, ME], S[b, BN], S[b, HORIZON] = me, n, ticks(spec.horizon_s)


_INT = ("stage", "stage_tick", "late_switches", "kin_since", "conv_since", "lock_from", "reseeds", "kf_tick",
        "trial_tick", "lock_fails", "m_start", "j_start", "win_k")
_FLOAT = ("cc", "cw", "late_z", "late_c", "late_w", "m_local", "m_local_sd", "j_local", "j_local_sd", "b_local",
          "c_local", "alpha", "psi", "nis_avg", "shadow_nis", "om_meas", "f_int", "last_f")
_BOOL = ("b_offered", "c_offered", "f_offered", "fb_offered", "released", "frozen_m", "frozen_j", "restarted")


def _chunks(mask: int, nbk: int) -> list[int]:
    """A Python-int mask as its 50-bit chunks (the wire's)."""
    return [(mask >> (c * MASK_BITS)) & ((1 << MASK_BITS) - 1) for c in range(nbk)]


def load_row(dp, banks: tuple, b: int) -> None:  # noqa: ANN001
    """Copies the state of a Python phase ``dp`` (tests/dynamic_reference.py, the tests' recorder) into row b of
    ``banks`` (:func:`new_banks`: dyn, dnb, nbr_mask, rx_order, psi_order, cum, cum_t, win, the flow average's
    F, I, then the 8 arrays of a 3-slot filter bank). The parameters come from :func:`init_dyn_row`, called
    here first."""
    dyn, dnb, nbr_mask, rx_order, psi_order, cum, cum_t, win, S, Fa, Ia = banks[:11]
    fbank = banks[11:]
    init_dyn_row(dyn, b, dp.n, dp.dt, dp.sigma_v, dp.spec, dp.hist, dp.law is not None, S, dp.id)
    r = dyn[b]
    for f in _INT + _FLOAT + _BOOL:
        r[f] = getattr(dp, f)
    r["has_q_held"] = dp.q_held is not None
    r["q_held"] = 0j if dp.q_held is None else dp.q_held
    bar = dp.barrier
    S[b, TMAX], S[b, SWITCH] = bar.tmax, bar.switch
    S[b, SBITS:] = _chunks(bar.mask, S.shape[1] - SBITS)
    cum[b, :, 0], cum[b, :, 1], cum_t[b] = dp.cum_c, dp.cum_w, dp.cum_t
    win[b, :, 0], win[b, :, 1] = dp.win_v, dp.win_f
    slot = {j: k for k, j in enumerate(dp.avg.ids)}
    for j in dp.nbr_stage:
        e = dnb[b, slot[j]]
        e["heard"], e["stage"], e["stage_tick"] = True, dp.nbr_stage[j], dp.nbr_stage_tick[j]
        mask, e["bar_tmax"], e["bar_switch"] = dp.nbr_barrier[j]
        nbr_mask[b, slot[j]] = _chunks(mask, nbr_mask.shape[2])
    rx_order[b, :len(dp.avg.nx)] = [slot[j] for j in dp.avg.nx]
    r["rx_n"] = len(dp.avg.nx)
    for m, (j, (pj, tj)) in enumerate(dp.nbr_psi.items()):
        e = dnb[b, slot[j]]
        e["psi"], e["psi_t"], e["has_psi"] = pj, tj, True
        psi_order[b, m] = slot[j]
    r["psi_n"] = len(dp.nbr_psi)
    for j, om in dp.nbr_om.items():
        dnb[b, slot[j]]["om"], dnb[b, slot[j]]["has_om"] = om, True
    Fa[b], Ia[b] = dp.avg._F[dp.avg._b], dp.avg._I[dp.avg._b]
    Fa[b, U] = dp.avg.u  # the inputs as written so far this tick (the bank's row holds the last update's)
    for k, kf in ((KF, dp.kf), (SHADOW, dp.shadow), (TWIN, dp.twin)):
        if kf is not None:
            for dst, src in zip(fbank, kf._bank, strict=True):
                dst[b, k] = src[0, 0]
    r["kf_slot"] = KF
    r["shadow_slot"] = SHADOW if dp.shadow is not None else -1
    r["twin_slot"] = TWIN if dp.twin is not None else -1


@jit
def note_late(b, t, zz, dyn, cum, cum_t):  # noqa: ANN001, ANN201
    """An eq. (9) sample of tick t with pooling weight zz went into this tick's u: its share of the late sums
    (only if the ring still holds tick t)."""
    r = dyn[b]
    i = t % r["hist"]
    if cum_t[b, i] == t:
        r["late_z"] += zz
        r["late_c"] += zz * cum[b, i, 0]
        r["late_w"] += zz * cum[b, i, 1]


@jit
def body_frame(b, tick, phi, dyn, dnb, psi_order, I, fs, s):  # noqa: ANN001, ANN201
    """e^{i psi} with psi kept common by phase consensus over the neighbours' psi predicted to now (in
    ``psi_order``, Metropolis weights); e^{i phi} (the kinematic angle) while the filter has not started."""
    r = dyn[b]
    kf = r["kf_slot"]
    if not fs[b, kf]["ready"]:
        return complex(cos(phi), sin(phi))
    om = s[b, kf, 5]
    dt = r["dt"]
    deg = I[b, DEG]
    D = (I.shape[1] - HEARD) // 2
    psi = r["psi"]
    acc = 0.0
    for m in range(r["psi_n"]):
        k = psi_order[b, m]
        e = dnb[b, k]
        acc += (1.0 / (1.0 + max(deg, I[b, HEARD + D + k]))) * (e["psi"] + om * dt * (tick - 1 - e["psi_t"]) - psi)
    psi = psi + acc
    r["psi"] = psi
    return complex(cos(psi), sin(psi))


@jit
def _u_age(r, b, tick, u_den, cum, cum_t):  # noqa: ANN001, ANN202
    """(dt sum T, dt sum omega) from the pooled u's samples to the state tick: the |z|^2-weighted mean of the
    samples' own (the late ones' sums, the rest at tick - 1)."""
    i = (tick - 1) % r["hist"]
    if cum_t[b, i] == tick - 1:
        c1, w1 = cum[b, i, 0], cum[b, i, 1]
    else:
        c1, w1 = r["cc"], r["cw"]
    w0 = u_den - r["late_z"]
    cbar = (r["late_c"] + w0 * c1) / u_den
    wbar = (r["late_w"] + w0 * w1) / u_den
    return r["cc"] - cbar, r["cw"] - wbar


@jit
def dyn_filter_update(b, tick, v, u, u_den, dyn, cum, cum_t, fs, s, P, sens, innov, sens_h):  # noqa: ANN001, ANN201
    """The first half of the filter's update of the tick: the cum ring's entry of this tick, the pooled rate's
    variance and age, the kf's and the twin's update. Returns (u_var, u_dc, u_dw) (the shadow's update of the
    lock check takes the same). The monitor's and the detection's observations follow in the caller."""
    r = dyn[b]
    i = tick % r["hist"]
    if cum_t[b, i] != tick:  # the first tick
        cum_t[b, i] = tick
        cum[b, i, 0] = r["cc"]
        cum[b, i, 1] = r["cw"]
    u_var = 0.0
    u_dc = 0.0
    u_dw = 0.0
    kf = r["kf_slot"]
    if fs[b, kf]["ready"]:
        if u_den > 0.0 and r["u_var_scale"] > 0:
            u_var = r["u_var_scale"] * 2.0 * pow_libm(r["sigma_v"], 2.0) / u_den
        if r["u_delayed"] and u_var > 0.0:
            u_dc, u_dw = _u_age(r, b, tick, u_den, cum, cum_t)
        F.ekf_update(fs, s, P, sens, innov, sens_h, b, kf, v, u, u_var, u_dc, u_dw)
        tw = r["twin_slot"]
        if tw >= 0:
            F.ekf_update(fs, s, P, sens, innov, sens_h, b, tw, v, u, u_var, u_dc, u_dw)
    return u_var, u_dc, u_dw


@jit
def dyn_predict(b, tick, rot, jstage, j_sign, dyn, cum, cum_t, Fa, fs, s, P, sens, Qd, aug):  # noqa: ANN001, ANN201
    """Prediction to tick + 1 with the team's total force and torque from the consensus (decomposition
    (12)-(14)): psi, the cum sums and f_int advance, the filters (kf, shadow, twin) predict, then the modelled
    angular acceleration and omega_hat's measurement for the next tick; the cum ring's entry of tick + 1.
    ``jstage``: the J stage, whose torque is s(t) n mean_i g_i with s(t) = ``j_sign``."""
    r = dyn[b]
    kf = r["kf_slot"]
    dt = r["dt"]
    n = r["n"]
    if fs[b, kf]["ready"]:
        fbar = complex(Fa[b, X, CH_FX], Fa[b, X, CH_FY])
        if jstage:
            torque = n * j_sign * Fa[b, X, CH_JG]
        else:
            zc = complex(Fa[b, X, CH_ZX], Fa[b, X, CH_ZY]) * rot
            torque = n * ((zc.real * fbar.imag - zc.imag * fbar.real) + Fa[b, X, CH_DT])
        om = s[b, kf, 5]
        r["psi"] += dt * om  # the body turns by the pre-update omega (semi-implicit Euler)
        r["cc"] += dt * torque
        r["cw"] += dt * om
        r["f_int"] += dt * n * fbar
        # the detection's nuisance: the known error of the consensus force (m stage: n times the own force
        # minus it; J stage: the net force is zero)
        ferr = 0j
        if r["has_detect"]:
            if r["stage"] == M_EXCITE:
                ferr = n * (r["last_f"] - fbar)
            elif jstage:
                ferr = -n * fbar
        F.ekf_predict(fs, s, P, sens, Qd, aug, b, kf, n * fbar, torque, dt, ferr)
        for k in (r["shadow_slot"], r["twin_slot"]):
            if k >= 0:
                F.ekf_predict(fs, s, P, sens, Qd, aug, b, k, n * fbar, torque, dt, ferr)
        iota = s[b, kf, 6]
        # only once 1/J is known to 10 % (or with j_feedforward through the whole J stage)
        if iota > 0.0 and (P[b, kf, 6, 6] < pow_libm(0.1 * iota, 2.0) or (jstage and r["j_feedforward"])):
            r["alpha"] = iota * torque
            if fs[b, kf]["has_aug"]:
                r["alpha"] -= s[b, kf, 8] * s[b, kf, 5]
        else:
            r["alpha"] = 0.0  # not a stale acceleration from before 1/J was forgotten
        if r["restarted"] and r["filter_omega"]:
            om = s[b, kf, 5]
            r["om_meas"] = om if om - om == 0.0 else math.nan  # a diverged filter: back to eq. (9)
    i = (tick + 1) % r["hist"]
    cum_t[b, i] = tick + 1
    cum[b, i, 0] = r["cc"]
    cum[b, i, 1] = r["cw"]
    r["late_z"] = 0.0
    r["late_c"] = 0.0
    r["late_w"] = 0.0


@jit
def j_sign(k, r):  # noqa: ANN001, ANN201
    """s(t) of the J stage at its tick k (row record r): +-1, ``j_cycles`` cycles over the stage, starting in
    the direction of ``omega_sign``."""
    half = max(1, r["j_ticks"] // (2 * r["j_cycles"]))
    sgn = 1.0 if (k // half) % 2 == 0 else -1.0
    if r["omega_sign"] < 0:
        sgn = -sgn
    return sgn


@jit
def stage_wrench(b, stage, k, v, q, zc, fx, fy, tau, dyn):  # noqa: ANN001, ANN201
    """(fx, fy, tau) of ``stage`` at its tick k (agents/excitation.py's ``stage_wrench``); (fx, fy, tau) given
    (the kinematic law's) where the stage has none. v own contact velocity, q = q_i, zc = z_C (world)."""
    r = dyn[b]
    if stage == M_EXCITE or stage == BACKGROUND:
        sgn = -1.0 if (k // r["m_switch"]) & 1 else 1.0
        fx = sgn * r["m_force"] * cos(r["m_force_angle"])
        fy = sgn * r["m_force"] * sin(r["m_force_angle"])
    elif stage == J_EXCITE:
        f = r["k_z"] * j_sign(k, r) * 1j * (q - zc)  # with the refined z_i = q_i - z_C
        fx, fy, tau = f.real, f.imag, 0.0
    elif stage == DONE and r["brake"] > 0.0:
        fx, fy, tau = -r["brake"] * v.real, -r["brake"] * v.imag, 0.0
    return fx, fy, tau


@jit
def dither(b, k, dyn):  # noqa: ANN001, ANN201
    """Algorithm 2's torque dither for J at the stage's tick k."""
    r = dyn[b]
    return r["dither_torque"] * sin(2.0 * math.pi * k / r["dither_ticks"])


@jit
def converged(b, num, wch, tick, dyn, Fa, Ia):  # noqa: ANN001, ANN201
    """Local convergence of the weighted average (num, wch): the own value and every heard neighbour's within
    ``avg_tol``, for ``avg_window`` ticks (``conv_since``)."""
    r = dyn[b]
    if Fa[b, X, wch] <= 0.0:
        return False
    mine = Fa[b, X, num] / Fa[b, X, wch]
    tol = r["avg_tol"] * abs(mine)
    D = (Ia.shape[1] - HEARD) // 2
    for k in range(Ia[b, DEG]):  # whether all are within: the order does not matter
        if Ia[b, HEARD + k]:
            xw = Fa[b, FLOW + 2 * D + k, wch]
            if xw <= 0.0 or abs(Fa[b, FLOW + 2 * D + k, num] / xw - mine) > tol:
                r["conv_since"] = -1
                return False
    if r["conv_since"] < 0:
        r["conv_since"] = tick
    return tick - r["conv_since"] >= r["avg_window"]


@jit
def _offer(b, inv, var, num, wch, w, sure, Fa):  # noqa: ANN001, ANN202
    """The local estimate 1/inv into channels (num, wch) with weight w; NaN if there is none to offer."""
    if not (inv > 0.0 and var > 0.0) or (sure and var >= inv * inv):
        return math.nan
    Fa[b, U, num] = w / inv
    Fa[b, U, wch] = w
    return 1.0 / inv


@jit
def _clean_share(r, start, ticks):  # noqa: ANN001, ANN202
    """The weight of an estimate learnt over the excitation ticks [start, start + ticks): the share since the
    filter's last lock-check restart, 1e-3 if the filter is lost now."""
    w = 1.0
    if start >= 0 and r["kf_tick"] > start:
        w = max(0.0, (start + ticks - r["kf_tick"]) / ticks)
    if r["nis_avg"] > r["lock_thr"] > 0.0:  # lost
        w = 0.0
    return w if w > 1e-3 else 1e-3


@jit
def consensus_inputs(b, stage, q, zc, has_held, held, rot, fx, fy, tau, jstage, on,  # noqa: ANN001, ANN201
                     dyn, Fa, fs, s, P):
    """This tick's inputs to the consensus channels (the row's ``U``) and the offers of the own 1/m and 1/J
    (agents/dynamic_phase.py ``_consensus_inputs``); ``on``: the effects in the model (``_on``)."""
    r = dyn[b]
    kf = r["kf_slot"]
    ready = fs[b, kf]["ready"]
    if jstage:
        # sum_i f_i = 0 and the torque is s sum_i g_i (JG); DT gets 0 so that it has no J-stage values to
        # forget when the kinematic control resumes
        Fa[b, U, CH_FX] = 0.0
        Fa[b, U, CH_FY] = 0.0
        Fa[b, U, CH_DT] = 0.0
    else:
        Fa[b, U, CH_FX] = fx
        Fa[b, U, CH_FY] = fy
        df = complex(fx, fy) - complex(Fa[b, X, CH_FX], Fa[b, X, CH_FY])
        Fa[b, U, CH_DT] = (q.real * df.imag - q.imag * df.real) + tau  # q_i x (f_i - fbar) + tau_i
    if ready and M_EXCITE <= stage <= J_EXCITE:
        Fa[b, U, CH_JG] = r["k_z"] * (q.real * (q.real - zc.real) + q.imag * (q.imag - zc.imag))
    if ready:
        qp = q * rot.conjugate() if not has_held else held  # q_i in the shared body frame
        Fa[b, U, CH_ZX] = qp.real
        Fa[b, U, CH_ZY] = qp.imag
    # not while a restart is on trial; after a kept restart only a determined value is offered
    trial = r["shadow_slot"] >= 0
    take_m = not trial and (stage == BACKGROUND or (stage == M_AVERAGE and not r["frozen_m"]))
    take_j = not trial and (stage == BACKGROUND or (stage == J_AVERAGE and not r["frozen_j"]))
    sure = r["kf_tick"] >= 0
    if ready and take_m:
        w = 1.0 if stage == BACKGROUND else _clean_share(r, r["m_start"], r["m_ticks"])
        m_local = _offer(b, s[b, kf, 4], P[b, kf, 4, 4], CH_MN, CH_MW, w, sure, Fa)
        if m_local == m_local:
            r["m_local"] = m_local
            r["m_local_sd"] = math.sqrt(P[b, kf, 4, 4]) * m_local * m_local  # delta method: sd(1/mu)
            r["frozen_m"] = stage == M_AVERAGE
            if fs[b, kf]["has_aug"]:  # b = beta m, F_c = kappa m and f = a m, averaged with m's weights
                r["b_local"] = s[b, kf, 7] * m_local
                Fa[b, U, CH_BN] = w * r["b_local"]
                Fa[b, U, CH_FN] = w * s[b, kf, 9] * m_local
                fb = w * complex(s[b, kf, 10], s[b, kf, 11]) * m_local
                Fa[b, U, CH_FBX] = fb.real
                Fa[b, U, CH_FBY] = fb.imag
                r["b_offered"] = r["b_offered"] or bool(on & 1)
                r["f_offered"] = r["f_offered"] or bool(on & 4)
                r["fb_offered"] = r["fb_offered"] or bool(on & 8)
    if ready and take_j:
        w = 1.0 if stage == BACKGROUND else _clean_share(r, r["j_start"], r["j_ticks"])
        j_local = _offer(b, s[b, kf, 6], P[b, kf, 6, 6], CH_JN, CH_JW, w, sure, Fa)
        if j_local == j_local:
            r["j_local"] = j_local
            r["j_local_sd"] = math.sqrt(P[b, kf, 6, 6]) * j_local * j_local
            r["frozen_j"] = stage == J_AVERAGE
            if fs[b, kf]["has_aug"]:  # c = gamma J, averaged with J's weights
                r["c_local"] = s[b, kf, 8] * j_local
                Fa[b, U, CH_CN] = w * r["c_local"]
                r["c_offered"] = r["c_offered"] or bool(on & 2)


@jit
def _judge(r, tick):  # noqa: ANN001, ANN202
    """End of a restart's trial: keep the restarted filter if it is consistent and clearly better, else go
    back to the old one and wait longer before the next try. Returns E_BACK when it goes back."""
    thr = r["lock_thr"]
    half = 0.5 * r["shadow_nis"]
    ev = 0
    if r["nis_avg"] < (half if half < thr else thr):  # Python's min(thr, half)
        r["kf_tick"] = r["trial_tick"]
        r["reseeds"] += 1
        r["lock_fails"] = 0
        r["lock_from"] = tick
    else:
        r["kf_slot"] = r["shadow_slot"]
        r["nis_avg"] = r["shadow_nis"]
        r["lock_fails"] += 1
        r["lock_from"] = tick + (r["lock_hold"] << min(r["lock_fails"], 5))
        ev = E_BACK
    r["shadow_slot"] = -1
    return ev


@jit
def lock_check(b, tick, v, u, u_var, u_dc, u_dw, dyn, win, fs, s, P, sens, innov, sens_h):  # noqa: ANN001, ANN201
    """The lock check after the filter's update: the lock window's sample, the running mean of the kf's NIS,
    the shadow's update and the trial's judgement (E_BACK), or a restart asked for (E_RESEED: the caller
    restarts, :func:`dyn_reseed`). Then :func:`hold_shape_check`."""
    r = dyn[b]
    ev = 0
    if r["restarted"] and not r["has_q_held"] and r["lock_thr"] > 0.0:
        w = r["win_k"] % r["win_n"]
        win[b, w, 0] = v
        win[b, w, 1] = r["f_int"]
        r["win_k"] += 1
        a = r["lock_alpha"]
        na = r["nis_avg"] + a * (fs[b, r["kf_slot"]]["nis"] - r["nis_avg"])
        r["nis_avg"] = na
        old = r["shadow_slot"]
        if old >= 0:  # a restart on trial: the filter it replaced runs beside it
            F.ekf_update(fs, s, P, sens, innov, sens_h, b, old, v, u, u_var, u_dc, u_dw)
            r["shadow_nis"] += a * (fs[b, old]["nis"] - r["shadow_nis"])
            if tick >= r["lock_from"]:
                ev |= _judge(r, tick)
        elif na > r["lock_thr"] and tick >= r["lock_from"]:
            ev |= E_RESEED
    return ev


@jit
def dyn_reseed(b, tick, v, q0, om0, dyn, fs, s, P, sens, Qd, aug, innov, sens_h):  # noqa: ANN001, ANN201
    """Restarts the kf on trial at (q0, om0) (P2's fit): the old filter becomes the shadow (a free slot), the
    twin is dropped, the releases are applied again; the trial's running mean starts at the threshold. The
    caller resets the monitor and calls the detection's ``restart_filter``, in that order."""
    r = dyn[b]
    kf = r["kf_slot"]
    sh = 1 if kf == 0 else 0
    F.ekf_copy_slot(fs, s, P, sens, Qd, aug, innov, sens_h, b, kf, sh)
    r["shadow_slot"] = sh
    r["shadow_nis"] = r["nis_avg"]
    r["twin_slot"] = -1  # it shares the lost filter's lock
    F.ekf_start(fs, s, P, sens, b, kf, v, q0, om0)
    if r["released"]:
        F.ekf_release_effects(fs, s, P, aug, b, kf)
    r["nis_avg"] = r["lock_thr"]
    r["trial_tick"] = tick
    r["lock_from"] = tick + r["lock_hold"]


@jit
def hold_shape_check(b, tick, zi, rot, dyn, Fa, fs, s, P, Qd):  # noqa: ANN001, ANN201
    """The tail of the filter's update: q_i (the kf's, zi before it starts) and z_C in the world frame; from
    done on under a law or braking, q_i is held in the shared body frame (a trial is judged first).
    Returns (q_i, z_C, events)."""
    r = dyn[b]
    kf = r["kf_slot"]
    q = complex(s[b, kf, 2], s[b, kf, 3]) if fs[b, kf]["ready"] else zi
    zc = complex(Fa[b, X, CH_ZX], Fa[b, X, CH_ZY]) * rot  # the consensus runs in the shared body frame
    ev = 0
    if not r["has_q_held"] and r["stage"] == DONE and fs[b, kf]["ready"] and (r["has_law"] or r["brake"] > 0.0):
        # the law or braking may stop the rotation, and q_i is observable only while the load turns
        if r["shadow_slot"] >= 0:  # a restart on trial: judged now, no more lock checks from here on
            ev |= _judge(r, tick)
            kf = r["kf_slot"]
            q = complex(s[b, kf, 2], s[b, kf, 3])
        r["q_held"] = q * rot.conjugate()
        r["has_q_held"] = True
        F.ekf_hold_shape(fs, s, P, Qd, b, kf)
        F.ekf_set_omega_walk(Qd, b, kf, r["j_omega_walk"])
    if r["has_q_held"]:
        q = r["q_held"] * rot
    return q, zc, ev


@jit
def _free_slot(r):  # noqa: ANN001, ANN202
    """The lowest filter slot that holds none of the kf, shadow and twin."""
    for k in range(3):
        if k != r["kf_slot"] and k != r["shadow_slot"] and k != r["twin_slot"]:
            return k
    return -1


@jit
def _enter(b, stage, tick, slope_undecided, dyn, S, fs, s, P, sens, Qd, aug, innov, sens_h):  # noqa: ANN001, ANN202
    """Enters ``stage`` at ``tick`` (DynamicPhase._enter): the releases of the augmented model at the excitation's
    start, the m stage's slope twin, the barrier's reset, the filters' omega walk and J's forgetting. The
    filters treated are those of the call's start (a twin made here keeps the kf's walk before the change)."""
    r = dyn[b]
    kf = r["kf_slot"]
    sh = r["shadow_slot"]
    tw = r["twin_slot"]
    if stage >= M_EXCITE and r["effects"] and not r["released"]:
        r["released"] = True  # the excitation starts (or we jumped past it)
        for k in (kf, sh, tw):
            if k >= 0:
                F.ekf_release_effects(fs, s, P, aug, b, k)
    r["stage"] = stage
    r["stage_tick"] = tick
    ev = E_REGIME if r["has_detect"] else 0
    if stage == M_EXCITE:
        r["m_start"] = tick
        if r["has_detect"]:
            ev |= E_M_START
            if fs[b, kf]["ready"] and r["twin_slot"] < 0 and slope_undecided:
                # the twin estimates the slope beside 1/m from the stage's start, as a declared slope is
                new = _free_slot(r)
                F.ekf_copy_slot(fs, s, P, sens, Qd, aug, innov, sens_h, b, kf, new)
                r["twin_slot"] = new
                F.ekf_release_effect(fs, s, P, aug, b, new, SLOPE)
                fs[b, new]["has_sens"] = False  # the scores are the kf's; the twin's start at the handover
    elif stage == J_EXCITE:
        r["j_start"] = tick
        r["twin_slot"] = -1  # m is averaged: a slope switched from here on changes neither m nor f's average
    barrier_reset(b, S)
    r["conv_since"] = -1
    for k in (kf, sh, tw):
        if k >= 0:
            if fs[b, k]["ready"] and stage == J_EXCITE:
                F.ekf_forget_iota(fs, P, b, k, 1e-2)  # J from the J stage's exactly known torque alone
                F.ekf_set_omega_walk(Qd, b, k, r["j_omega_walk"])
            elif stage != J_EXCITE:
                F.ekf_set_omega_walk(Qd, b, k, r["omega_walk"])
    return ev


@jit
def _advance(b, tick, slope_undecided, dyn, dnb, nbr_mask, rx_order, S, fs, s, P, sens, Qd, aug, innov,  # noqa: ANN001, ANN202
             sens_h):
    """Stage agreement (DynamicPhase._advance): a neighbour two or more stages ahead, the barrier merges in
    first-heard order (the first switch tick seen wins), the due switches."""
    r = dyn[b]
    st = r["stage"]
    if not r["background"] and st >= KINEMATIC:
        ahead = -1
        k_ahead = -1
        for m in range(r["rx_n"]):  # max over (stage, id): slots are in id order
            k = rx_order[b, m]
            sk = dnb[b, k]["stage"]
            if sk > ahead or (sk == ahead and k > k_ahead):
                ahead = sk
                k_ahead = k
        if st + 1 < ahead <= DONE:
            ev = _enter(b, ahead, dnb[b, k_ahead]["stage_tick"], slope_undecided, dyn, S, fs, s, P, sens, Qd, aug,
                        innov, sens_h)
            r["late_switches"] += 1
            return ev
    averaging = st == KINEMATIC or st == M_AVERAGE or st == J_AVERAGE
    for m in range(r["rx_n"]):
        k = rx_order[b, m]
        e = dnb[b, k]
        if e["stage"] == st:
            barrier_merge(b, S, nbr_mask[b, k], e["bar_tmax"], e["bar_switch"])
        elif e["stage"] == st + 1 and averaging:
            barrier_merge(b, S, nbr_mask[b, k, :0], -1, e["stage_tick"])  # its stage start is the agreed tick
    sw = S[b, SWITCH]
    if sw >= 0 and tick >= sw and averaging:
        if tick > sw:
            r["late_switches"] += 1
        if st == KINEMATIC:
            nxt = BACKGROUND if r["background"] else M_EXCITE
        elif st == M_AVERAGE:
            nxt = J_EXCITE
        else:
            nxt = DONE
        return _enter(b, nxt, tick, slope_undecided, dyn, S, fs, s, P, sens, Qd, aug, innov, sens_h)
    if st == M_EXCITE and tick >= r["stage_tick"] + r["m_ticks"]:
        return _enter(b, M_AVERAGE, tick, slope_undecided, dyn, S, fs, s, P, sens, Qd, aug, innov, sens_h)
    if st == J_EXCITE and tick >= r["stage_tick"] + r["j_ticks"]:
        return _enter(b, J_AVERAGE, tick, slope_undecided, dyn, S, fs, s, P, sens, Qd, aug, innov, sens_h)
    return 0


@jit
def dyn_advance_stage(b, tick, v, omega_hat, phi, zi, trusted, om_init, slope_undecided,  # noqa: ANN001, ANN201
                      dyn, dnb, nbr_mask, rx_order, S, fs, s, P, sens, Qd, aug, innov, sens_h):
    """A6 (DynamicPhase._advance_stage): the filter's start and its restart at kinematic readiness, the
    kinematic stage's readiness, then the stage agreement. ``slope_undecided``: the detection's
    ``undecided(SLOPE)`` (False without it). Returns the events E_REGIME, E_M_START for the detection."""
    r = dyn[b]
    kf = r["kf_slot"]
    ev = 0
    if r["stage"] == SPINUP and om_init:
        ev |= _enter(b, KINEMATIC, tick, slope_undecided, dyn, S, fs, s, P, sens, Qd, aug, innov, sens_h)
    if r["stage"] >= KINEMATIC:
        if not fs[b, kf]["ready"]:
            F.ekf_start(fs, s, P, sens, b, kf, v, zi, omega_hat)
            r["psi"] = phi
        if r["stage"] == KINEMATIC:
            if trusted:
                if r["kin_since"] < 0:
                    r["kin_since"] = tick
                if tick - r["kin_since"] >= r["settle"]:
                    if not r["restarted"]:
                        # restart from the settled kinematic z_i and omega_hat: started at spin-up from z_i = 0
                        # the filter can lock onto a wrong (q, omega)
                        r["restarted"] = True
                        F.ekf_start(fs, s, P, sens, b, kf, v, zi, omega_hat)
                        if r["has_detect"]:
                            ev |= E_REGIME
                        r["lock_from"] = tick + r["lock_hold"]
                    barrier_set_ready(b, S, tick)
            else:
                r["kin_since"] = -1
        ev |= _advance(b, tick, slope_undecided, dyn, dnb, nbr_mask, rx_order, S, fs, s, P, sens, Qd, aug, innov,
                       sens_h)
    return ev


@jit
def dyn_receive(b, k, v, lay, dyn, dnb, nbr_mask, rx_order, psi_order, Fa, Ia):  # noqa: ANN001, ANN201
    """A neighbour's accepted IN row ``v`` (net/rows.py, checked by the kinematic kernel) from slot k, in
    arrival order (a later one replaces it): its channels, flows to us and degree into the flow average, its
    stage, stage tick and barrier, and from the kinematic stage on its psi and omega_hat. First-heard orders
    are appended on first write. The flooded decision (online detection) is the caller's."""
    r = dyn[b]
    nch = lay[L_NCH]
    D = (Ia.shape[1] - HEARD) // 2
    p = lay[L_P0] + PAIR_HEAD
    for c in range(nch):
        Fa[b, FLOW + D + k, c] = v[p + c]
        Fa[b, FLOW + 2 * D + k, c] = v[C0 + c]
    if not Ia[b, HEARD + k]:
        rx_order[b, r["rx_n"]] = k
        r["rx_n"] += 1
    Ia[b, HEARD + k] = 1
    Ia[b, HEARD + D + k] = int(v[lay[L_DG]])
    e = dnb[b, k]
    stage = int(v[PHASE])
    e["heard"] = True
    e["stage"] = stage
    e["stage_tick"] = int(v[lay[L_SK]])
    for c in range(lay[L_NBK]):
        nbr_mask[b, k, c] = int(v[lay[L_B0] + c])
    e["bar_tmax"] = int(v[lay[L_BT]])
    e["bar_switch"] = int(v[lay[L_BS]])
    if stage >= KINEMATIC:  # its filter (and psi) runs from the kinematic stage on
        if not e["has_psi"]:
            psi_order[b, r["psi_n"]] = k
            r["psi_n"] += 1
        e["has_psi"] = True
        e["psi"] = v[lay[L_PS]]
        e["psi_t"] = int(v[TICK])
        om = v[OM]
        if om - om == 0.0:
            e["om"] = om
            e["has_om"] = True


@jit
def dyn_twin_decision(b, dec, slope_undecided, dyn, fs, sens):  # noqa: ANN001, ANN201
    """The slope's twin after the team's decision ``dec`` (DynamicPhase._twin_decision; -1: none): the slope
    switched on, the twin becomes the kf (an index swap), its sensitivities from zero as at a filter's start;
    once the slope is decided (``slope_undecided`` False, read after the decision) it is dropped. Returns
    E_REPLACED when the kf changed."""
    r = dyn[b]
    tw = r["twin_slot"]
    if tw < 0:
        return 0
    ev = 0
    if dec == SLOPE:
        kf = r["kf_slot"]
        if fs[b, kf]["has_sens"]:  # from zero, as at a filter's start
            for i in range(fs[b, kf]["d"]):
                for c in range(sens.shape[3]):
                    sens[b, tw, i, c] = 0.0
            fs[b, tw]["has_sens"] = True
        r["kf_slot"] = tw
        ev = E_REPLACED
    if not slope_undecided:
        r["twin_slot"] = -1
    return ev


@jit
def dyn_write_out(b, row, lay, dyn, S, Fa, Ia):  # noqa: ANN001, ANN201
    """The dynamical slots of the agent's OUT row (net/rows.py; DynamicPhase._shared and its flows): the channels,
    the degree, the stage tick, psi (0 before it exists), the barrier's chunks, latest ready tick and switch
    tick, and each neighbour's block's flows F_ij. The stage (PHASE) and the flood's slots are the caller's."""
    r = dyn[b]
    nch = lay[L_NCH]
    for c in range(nch):
        row[C0 + c] = Fa[b, X, c]
    row[lay[L_DG]] = float(Ia[b, DEG])
    row[lay[L_SK]] = float(r["stage_tick"])
    psi = r["psi"]
    row[lay[L_PS]] = psi if psi == psi else 0.0
    for c in range(lay[L_NBK]):
        row[lay[L_B0] + c] = float(S[b, SBITS + c])
    row[lay[L_BT]] = float(S[b, TMAX])
    row[lay[L_BS]] = float(S[b, SWITCH])
    for k in range(Ia[b, DEG]):
        p = lay[L_P0] + k * lay[L_BLOCK] + PAIR_HEAD
        for c in range(nch):
            row[p + c] = Fa[b, FLOW + k, c]


ESTIMATES = ("J", "m", "zc_x", "zc_y", "vc_x", "vc_y", "J_local", "m_local", "late_switches", "b", "c", "fc", "fb_x",
             "fb_y", "b_local", "c_local", "filter_restarts")
"""The estimate entries of the dynamical phase, in :func:`dyn_estimates`' order (``ESTIMATE_NAMES`` from "J" on)."""


@jit
def _ratio(Fa, b, num, wch, ok):  # noqa: ANN001, ANN202
    """The average num / wch if the channel exists, has weight and ``ok``; NaN else."""
    if Fa.shape[2] > num and Fa[b, X, wch] > 0.0 and ok:
        return Fa[b, X, num] / Fa[b, X, wch]
    return math.nan


@jit
def dyn_estimates(b, on, dyn, Fa, s, out):  # noqa: ANN001, ANN201
    """The dynamical phase's estimate values (DynamicPhase._estimates) into ``out`` (:data:`ESTIMATES` order);
    ``on``: the effects in the model (``_on``)."""
    r = dyn[b]
    kf = r["kf_slot"]
    nan = math.nan
    out[0] = _ratio(Fa, b, CH_JN, CH_JW, True)
    out[1] = _ratio(Fa, b, CH_MN, CH_MW, True)
    if r["stage"] >= M_AVERAGE:
        psi = r["psi"]
        zc = complex(Fa[b, X, CH_ZX], Fa[b, X, CH_ZY]) * complex(cos(psi), sin(psi))
        vc = complex(s[b, kf, 0], s[b, kf, 1])
    else:
        zc = vc = complex(nan, nan)
    out[2] = zc.real
    out[3] = zc.imag
    out[4] = vc.real
    out[5] = vc.imag
    out[6] = r["j_local"]
    out[7] = r["m_local"]
    out[8] = float(r["late_switches"])
    # augmented model (estimate_effects): b with m's weights, c with J's
    out[9] = _ratio(Fa, b, CH_BN, CH_MW, on & 1 and r["b_offered"])
    out[10] = _ratio(Fa, b, CH_CN, CH_JW, on & 2 and r["c_offered"])
    out[11] = _ratio(Fa, b, CH_FN, CH_MW, on & 4 and r["f_offered"])
    out[12] = _ratio(Fa, b, CH_FBX, CH_MW, on & 8 and r["fb_offered"])
    out[13] = _ratio(Fa, b, CH_FBY, CH_MW, on & 8 and r["fb_offered"])
    out[14] = r["b_local"] if on & 1 else nan
    out[15] = r["c_local"] if on & 2 else nan
    out[16] = float(r["reseeds"])


def new_banks(B: int, D: int, nch: int, d: int, hist: int = 64, win_n: int = 200, nbk: int = 1) -> tuple:
    """Every array of B dynamical phases, one flat tuple: the 8 of :func:`new_dyn_bank`, the flow average's
    (F, I), the 8 of a filter bank of 3 slots (filter.py's order)."""
    return (*new_dyn_bank(B, D, hist, win_n, nbk), *flow_average_bank(B, D, nch), *F.new_bank(B, 3, d))


@register_warm
def warm() -> None:
    from config.agent_params import DynamicsSpec  # noqa: PLC0415

    banks = new_banks(1, 1, 10, F.D_NOMINAL)
    dyn, dnb, nbr_mask, rx_order, psi_order, cum, cum_t, win, S, Fa, Ia, fs, s, P, sens, Qd, aug, innov, sens_h = banks
    init_dyn_row(dyn, 0, 2, 0.01, 0.05, DynamicsSpec(), S=S)
    dyn_advance_stage(0, 3, 0.1 + 0.2j, 0.3, 0.1, 1 + 0j, True, True, False, dyn, dnb, nbr_mask, rx_order, S, fs, s, P,
                      sens, Qd, aug, innov, sens_h)
    note_late(0, 3, 1.0, dyn, cum, cum_t)
    body_frame(0, 3, 0.1, dyn, dnb, psi_order, Ia, fs, s)
    dyn_filter_update(0, 3, 0.1 + 0.2j, 0.3, 1.0, dyn, cum, cum_t, fs, s, P, sens, innov, sens_h)
    dyn_predict(0, 3, 1 + 0j, False, 1.0, dyn, cum, cum_t, Fa, fs, s, P, sens, Qd, aug)
    for stage in (M_EXCITE, J_EXCITE, DONE):
        stage_wrench(0, stage, 3, 0.1 + 0.2j, 1 + 0j, 0.5j, 0.1, 0.2, 0.3, dyn)
    dither(0, 3, dyn)
    lay = Layout(True, 10, 1, False, 1)
    dyn_estimates(0, 3, dyn, Fa, s, np.zeros(len(ESTIMATES)))
    dyn_receive(0, 0, np.zeros(lay.size_in), lay.lay, dyn, dnb, nbr_mask, rx_order, psi_order, Fa, Ia)
    dyn_write_out(0, np.zeros(lay.size_out), lay.lay, dyn, S, Fa, Ia)
    dyn_twin_decision(0, SLOPE, False, dyn, fs, sens)
    lock_check(0, 3, 0.1 + 0.2j, 0.3, 0.01, 0.0, 0.0, dyn, win, fs, s, P, sens, innov, sens_h)
    dyn_reseed(0, 3, 0.1 + 0.2j, 1 + 0j, 0.3, dyn, fs, s, P, sens, Qd, aug, innov, sens_h)
    hold_shape_check(0, 3, 1 + 0j, 1 + 0j, dyn, Fa, fs, s, P, Qd)
    converged(0, CH_MN, CH_MW, 3, dyn, Fa, Ia)
    consensus_inputs(0, M_AVERAGE, 1 + 0j, 0.5j, False, 0j, 1 + 0j, 0.1, 0.2, 0.3, False, 3, dyn, Fa, fs, s, P)
