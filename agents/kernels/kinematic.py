"""The kinematic phase over a leading agent axis (paper 000 Sec. IV, blocks 1-6 of Fig. 2): z_ij, omega, z_i, control.

:func:`kin_step` runs one tick for every agent b (A1-A5 of docs/fast-core-plan.md section 3): the own
velocity into its ring, the inbox (IN rows of net/rows.py) in (tick, sender) order into the neighbours'
states and the pair estimators (agents/kernels/pair.py), held samples of a reordering link released in
tick order, then omega (low-pass consensus), the body-frame angle phi (phase consensus), z_i (centroid
iteration in flow form), every z_ij predicted to the tick, and the kinematic control law. Why each
choice: docs/agent-step.md.

State: ``kin`` (B,) records of :data:`KIN` (parameters, state), ``nbr`` (B, D) records of :data:`NBR`
sorted by neighbour id (id -1: empty slot), the held samples ``pend_t, pend_v`` (B, D, K), the own
velocity ring ``vbuf, vtick`` (B, H) and the feed-forward ring ``abuf, abuf_t`` (B, H). A tick's inputs
are ``inp`` (I_*: velocity, the dynamical phase's feedback), its results ``res`` (R_*: floats, for one
conversion to Python). Until the dynamical phase is compiled too, a tick also reports the rows whose
dynamical states were taken (``acc``) and the late eq. (9) samples (``late_*``).

Kernels read a record's fields into Python scalars (``float(...)``, ``complex(...)``: no-ops compiled)
so that ``kernel.py_func`` computes with CPython's arithmetic; the tests compare the two bit for bit.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from math import cos, sin

import numpy as np

from agents.kernels import jit, register_warm
from agents.kernels.pair import pair_bank, pair_checkpoints, pair_predict, pair_sample, set_pair_params
from config.agent_params import ControlSpec, EstimatorSpec
from net.rows import KIN_MALFORMED, L_P0, MALFORMED, OI, OM, PH, SENDER, STATUS, TICK, VX, VY, YX, YY, Layout

HOLD_MAX = 16  # longest wait for a reordered velocity sample (ticks); well inside history_ticks
E_TICKS = 1  # kin["error"]: the tick did not increase (the caller raises ValueError)
# a tick's results as floats, res[b, :] (one conversion to Python floats for the caller): R_* slots, then
# per neighbour slot k at R_PAIRS + 4 k: z_ij as sent (re, im) and the flow F_ij (re, im)
(R_U, R_U_DEN, R_OMEGA, R_OM_INIT, R_PHI, R_Y, R_ZI, R_READY, R_TRUSTED, R_FX, R_FY, R_TAU, R_DROPPED_UNKNOWN,
 R_DROPPED_STALE, R_NACC, R_NLATE) = (0, 1, 2, 3, 4, 5, 7, 9, 10, 11, 12, 13, 14, 15, 16, 17)
R_PAIRS = 18
# a tick's inputs, inp[b, :]: the own measured velocity, then the dynamical phase's feedback of the
# previous tick (dynamic_step.py R_OM_MEAS.., in its order; NaN om_meas: none)
I_VX, I_VY, I_OM_MEAS, I_ALPHA, I_HOLD, I_WAITING = range(6)

KIN = np.dtype([
    # parameters (constant after build)
    ("id", "i8"),
    ("dt", "f8"),
    ("dynamic", "b1"),  # a dynamical phase runs on top (its feedback and feed-forward are used)
    ("boost_tick", "i8"),  # from this tick the team's omega boost may apply (-1: never)
    ("boost_target", "f8"),
    ("hist", "i8"),  # own velocity ring length (history_ticks)
    ("max_age", "i8"),  # a neighbour state older than this is not used
    ("beta", "f8"),  # omega low-pass gain per tick, min(1, dt / omega_tau)
    ("eps_om", "f8"),
    ("eps_z", "f8"),  # centroid and phase consensus gain
    ("deg", "i8"),  # neighbours (slots 0 .. deg - 1 of nbr)
    ("ctl_fx", "f8"),  # the control law's constants (kin_wrench)
    ("ctl_fy", "f8"),
    ("ctl_switch", "i8"),
    ("ctl_spin", "f8"),
    ("ctl_target", "f8"),
    ("ctl_k", "f8"),
    ("ctl_tmax", "f8"),
    # state
    ("omega", "f8"),  # omega_hat
    ("om_init", "b1"),  # omega_hat seeded from a circle fit (or from a neighbour's value)
    ("phi", "f8"),  # body-frame angle, integral of omega_hat kept in agreement by consensus
    ("y", "c16"),  # z_i in the agents' common body frame: x = e^{i phi} y
    ("adopt_ph", "b1"),
    ("trusted", "b1"),
    ("dropped_unknown", "i8"),
    ("dropped_stale", "i8"),
    ("last_tick", "i8"),
    ("omdot", "f8"),  # omega_hat's own trend per tick (its measurement path, low-passed)
    ("held", "b1"),  # some neighbour's samples are held back
    ("asum", "f8"),  # sum of the dynamical phase's feed-forward increments alpha dt so far (rad/s)
    # this tick: the pooled eq. (9) sums, then the results
    ("pool_num", "f8"),
    ("pool_den", "f8"),
    ("pool_fw", "f8"),  # |z|^2-weighted corrections that bring late samples' omega to the state tick
    ("u", "f8"),  # pooled eq. (9) rate (NaN: none)
    ("zi", "c16"),  # z_i in the world frame
    ("ready", "i8"),  # neighbours whose z_ij is estimated
    ("fx", "f8"),  # the control law's wrench
    ("fy", "f8"),
    ("tau", "f8"),
    ("nacc", "i8"),  # rows whose dynamical states were taken this tick (acc)
    ("nlate", "i8"),  # late eq. (9) samples this tick (late_t, late_z)
    ("error", "i8"),  # E_* (0: none)
])
"""One agent's kinematic phase."""

NBR = np.dtype([
    ("id", "i8"),  # -1: empty slot
    ("last", "i8"),  # newest tick used from j
    ("om", "f8"),  # j's omega consensus state
    ("om_ok", "b1"),  # j's omega (and phase) state is initialised
    ("ph", "f8"),  # j's body-frame angle phi_j (rad)
    ("y", "c16"),  # j's centroid state in its body frame
    ("zji", "c16"),  # j's estimate of z_ji
    ("fji", "c16"),  # j's flow to us (centroid iteration in flow form)
    ("flow", "c16"),  # our flow to j: F_ij, kept ~ -F_ji
    ("st_t", "i8"),  # tick of j's states (om, ph, y, zji, fji)
    ("z_sent", "c16"),  # our z_ij as sent in our last message
    ("rel", "i8"),  # newest tick whose velocity went to the pair estimator (or was given up on)
    ("hold", "i8"),  # deepest reordering seen on the link (ticks): how long a gap is waited for
    ("npend", "i8"),  # held samples (pend_t, pend_v [b, k, :npend], unordered)
])
"""What agent b remembers of its neighbour in slot k."""


def kin_bank(B: int, D: int, H: int) -> tuple[np.ndarray, ...]:
    """Fresh state for B agents of up to D neighbours and rings of H ticks: (kin, nbr, pend_t, pend_v,
    vbuf, vtick, abuf, abuf_t). K = H + HOLD_MAX held samples per neighbour suffice (every held tick is
    one of the last H, and a release leaves only ticks within ``hold`` <= HOLD_MAX of the newest)."""
    kin = np.zeros(B, KIN)
    kin["last_tick"] = -1
    nbr = np.zeros((B, D), NBR)
    nbr["id"] = -1
    nbr["last"] = -1
    nbr["st_t"] = -(10**9)
    nbr["rel"] = -1
    K = H + HOLD_MAX
    return (kin, nbr, np.zeros((B, D, K), np.int64), np.zeros((B, D, K), np.complex128),
            np.zeros((B, H), np.complex128), np.full((B, H), -1, np.int64), np.zeros((B, H)),
            np.full((B, H), -1, np.int64))


def set_kin_params(kin: np.ndarray, nbr: np.ndarray, P: np.ndarray, prm: np.ndarray, b: int, agent_id: int,
                   neighbours: Sequence[int], dt: float, sigma_v: float, estimator: EstimatorSpec,
                   control: ControlSpec, dynamic: bool) -> None:
    """Agent b's parameters from its specs (``dynamic``: a dynamical phase runs on top), its neighbours
    (sorted) into the slots of ``nbr`` and its pair estimators' parameters into ``P, prm``."""
    ids = sorted(set(int(j) for j in neighbours))
    if len(ids) > nbr.shape[1]:
        raise ValueError(f"{len(ids)} neighbours, the bank has {nbr.shape[1]} slots")
    kr = kin[b]
    kr["id"] = agent_id
    kr["dt"] = dt
    kr["dynamic"] = dynamic
    spin = control.spin_torque
    # the target while the team waits for a late pair (ControlSpec.omega_boost; dynamical phase only)
    kr["boost_tick"] = round(control.boost_after_s / dt) if control.omega_boost > 0 else -1
    kr["boost_target"] = (1.0 if spin >= 0.0 else -1.0) * max(control.omega_boost, control.omega_target)
    kr["hist"] = estimator.history_ticks
    kr["max_age"] = estimator.max_age_ticks
    kr["beta"] = min(1.0, dt / estimator.omega_tau)
    kr["eps_om"] = estimator.omega_eps
    kr["eps_z"] = estimator.centroid_eps
    kr["deg"] = len(ids)
    kr["ctl_fx"] = control.force * math.cos(control.force_angle)
    kr["ctl_fy"] = control.force * math.sin(control.force_angle)
    kr["ctl_switch"] = max(1, int(round(control.switch_period / dt)))
    kr["ctl_spin"] = spin
    kr["ctl_target"] = (1.0 if spin >= 0.0 else -1.0) * control.omega_target
    kr["ctl_k"] = control.k_omega
    kr["ctl_tmax"] = control.torque_max
    nbr["id"][b, :len(ids)] = ids
    set_pair_params(P, prm, b, dt=dt, sigma_v=sigma_v, fit_arc=estimator.fit_arc,
                    fit_min_ticks=estimator.fit_min_ticks, fit_max_ticks=estimator.fit_max_ticks,
                    fit_check_ticks=estimator.fit_check_ticks, max_gap_ticks=estimator.max_gap_ticks,
                    angle_walk=estimator.angle_walk, gate_snr=estimator.gate_snr, angle_meas=estimator.angle_meas)


# --------------------------------------------------------------------------------------------- helpers
@jit
def _forward(kin: np.ndarray, abuf: np.ndarray, abuf_t: np.ndarray, b: int, t: int, age: int) -> float:
    """How much omega_hat has changed from tick t to the state tick (t + age), for bringing an omega
    value of tick t forward: the trend of the measurement path times age, plus the dynamical phase's
    feed-forward increments of those ticks exactly (so a modelled ramp starts and reverses at once)."""
    kr = kin[b]
    f = float(kr["omdot"]) * age
    if kr["dynamic"]:
        ta = t % int(kr["hist"])
        if abuf_t[b, ta] == t:
            f += float(kr["asum"]) - float(abuf[b, ta])
    return f


@jit
def _use_sample(kin, abuf, abuf_t, P, cps, prm, b, k, t, w, ref, late_t, late_z) -> None:
    """j's relative velocity sample w = v_Ci - v_Cj of tick t: into the pooled eq. (9) sums and j's pair
    estimator (whose first circle fit seeds omega_hat when nothing else has)."""
    kr = kin[b]
    dt = float(kr["dt"])
    om = float(kr["omega"])
    lag = ref - t
    omdt = om * dt
    back = complex(cos(omdt * lag), -sin(omdt * lag)) if lag else 1.0 + 0j
    pr = P[b, k]
    if pr["ready"]:
        # predicted z_ij at tick t (before this sample's correction); a lag of 0 multiplies by 1.0, as
        # CPython's complex * float does (a complex product)
        zt = complex(pr["z"]) * back
        zz = zt.real * zt.real + zt.imag * zt.imag
        kr["pool_num"] = float(kr["pool_num"]) + (zt.real * w.imag - zt.imag * w.real)
        if lag:
            # eq. (9) of tick t measures omega of tick t: bring it to ref like j's omega state
            kr["pool_fw"] = float(kr["pool_fw"]) + zz * _forward(kin, abuf, abuf_t, b, t, lag)
            if kr["dynamic"]:
                n = int(kr["nlate"])
                late_t[b, n] = t  # the dynamical phase's filter takes u as a delayed measurement
                late_z[b, n] = zz
                kr["nlate"] = n + 1
        kr["pool_den"] = float(kr["pool_den"]) + zz
        pair_sample(P, cps, prm, b, k, t, w, back, om, dt)
    else:
        pair_sample(P, cps, prm, b, k, t, w, back, om, dt)
        if pr["ready"] and not kr["om_init"]:
            # bootstrap: the first fitted window's mean rate seeds omega_hat, so that the prediction
            # rotates z_ij and the gate opens (omega_hat = 0 would freeze both)
            kr["om_init"] = True
            kr["adopt_ph"] = True
            kr["omega"] = float(pr["omega_fit"])


@jit
def _pend_has(pend_t: np.ndarray, nbr: np.ndarray, b: int, k: int, t: int) -> bool:
    """j's velocity of tick t is held."""
    for i in range(int(nbr[b, k]["npend"])):
        if pend_t[b, k, i] == t:
            return True
    return False


@jit
def _pend_add(kin, nbr, pend_t, pend_v, b, k, t, v) -> None:
    """Hold j's velocity of tick t (t is not held yet: the callers check)."""
    nr = nbr[b, k]
    i = int(nr["npend"])
    if i >= pend_t.shape[2]:
        raise IndexError("kin_step: more held samples than kin_bank() allows")
    pend_t[b, k, i] = t
    pend_v[b, k, i] = v
    nr["npend"] = i + 1
    kin[b]["held"] = True


@jit
def _deepen(nr, depth: int) -> None:
    """A late arrival ``depth`` ticks behind j's newest state: the link reorders; wait this long from now on."""
    if depth > int(nr["hold"]):
        nr["hold"] = depth if depth < HOLD_MAX else HOLD_MAX


@jit
def _hold_overtaken(kin, nbr, pend_t, pend_v, vtick, b, k, row, t) -> None:
    """A message older than j's newest state (overtaken on a jittery link): its states are out of date,
    but its velocity is exact for tick t, so it is held for the pair estimator (_release)."""
    kr = kin[b]
    nr = nbr[b, k]
    held = _pend_has(pend_t, nbr, b, k, t)
    if t <= int(nr["rel"]) or held or vtick[b, t % int(kr["hist"])] != t:
        kr["dropped_stale"] = int(kr["dropped_stale"]) + 1  # replayed, or too late: its gap was bridged
        if t < int(nr["last"]) and not held:
            _deepen(nr, int(nr["last"]) - t)
        return
    vjx = row[VX]
    vjy = row[VY]
    chk = vjx + vjy
    if chk - chk != 0.0:
        kr["dropped_stale"] = int(kr["dropped_stale"]) + 1
        return
    _deepen(nr, int(nr["last"]) - t)
    _pend_add(kin, nbr, pend_t, pend_v, b, k, t, complex(vjx, vjy))


@jit
def _release(kin, nbr, pend_t, pend_v, vbuf, vtick, abuf, abuf_t, P, cps, prm, b, k, ref, late_t,
             late_z) -> None:
    """Feed j's held-back velocities to its pair estimator in tick order: a sample goes once every earlier
    one has been used, or once it is ``hold`` ticks older than j's newest state (the earlier ones are
    then lost)."""
    nr = nbr[b, k]
    hist = int(kin[b]["hist"])
    limit = int(nr["last"]) - int(nr["hold"])
    while int(nr["npend"]) > 0:
        n = int(nr["npend"])
        i = 0
        for m in range(1, n):
            if pend_t[b, k, m] < pend_t[b, k, i]:
                i = m
        t = pend_t[b, k, i]
        if t != int(nr["rel"]) + 1 and t > limit:
            break
        vj = pend_v[b, k, i]
        pend_t[b, k, i] = pend_t[b, k, n - 1]
        pend_v[b, k, i] = pend_v[b, k, n - 1]
        nr["npend"] = n - 1
        nr["rel"] = t
        ts = t % hist
        if vtick[b, ts] != t:
            continue
        _use_sample(kin, abuf, abuf_t, P, cps, prm, b, k, t, complex(vbuf[b, ts]) - complex(vj), ref, late_t, late_z)


@jit
def kin_wrench(kin: np.ndarray, b: int, tick: int, omega_hat: float, regulate: bool, boost: bool) -> None:
    """The kinematic control law (docs/agent-step.md): the Prop. 6 common force flipped every ``ctl_switch``
    ticks, a common spin-up torque until omega_hat exists, then tau = sat(k (target - omega_hat)); ``boost``
    replaces the target by the team's omega boost."""
    kr = kin[b]
    if (tick // int(kr["ctl_switch"])) & 1:
        fx = -float(kr["ctl_fx"])
        fy = -float(kr["ctl_fy"])
    else:
        fx = float(kr["ctl_fx"])
        fy = float(kr["ctl_fy"])
    if regulate:
        target = float(kr["boost_target"]) if boost else float(kr["ctl_target"])
        tau = float(kr["ctl_k"]) * (target - omega_hat)
        tmax = float(kr["ctl_tmax"])
        if tau > tmax:
            tau = tmax
        elif tau < -tmax:
            tau = -tmax
    else:
        tau = float(kr["ctl_spin"])
    kr["fx"] = fx
    kr["fy"] = fy
    kr["tau"] = tau


@jit
def _inbox_order(rows: np.ndarray, lo: int, hi: int, order: np.ndarray) -> None:
    """order[lo:hi] = the rows lo .. hi - 1 in (tick, sender) order, stable: per-sender tick order
    matters, and a fixed order makes the result independent of the arrival order within a tick."""
    for i in range(lo, hi):
        order[i] = i
        m = i
        while m > lo:
            a = order[m - 1]
            if rows[a, TICK] > rows[i, TICK] or (rows[a, TICK] == rows[i, TICK] and rows[a, SENDER] > rows[i, SENDER]):
                order[m] = a
                m -= 1
            else:
                break
        order[m] = i


@jit
def _take_inbox(kin, nbr, pend_t, pend_v, vbuf, vtick, abuf, abuf_t, P, cps, prm, b, tick, rows, lo, hi, order,
                lay, acc, late_t, late_z) -> None:
    """Every message's states, and its velocity sample to ``_use_sample``; the rows whose dynamical
    states are taken go to acc[lo:lo + kin[b].nacc] in order."""
    kr = kin[b]
    _inbox_order(rows, lo, hi, order)
    ref = tick - 1
    hist = int(kr["hist"])
    deg = int(kr["deg"])
    p0 = lay[L_P0]
    na = 0
    for i in range(lo, hi):
        e = order[i]
        row = rows[e]
        sender = int(row[SENDER])
        k = -1
        for m in range(deg):
            if nbr[b, m]["id"] == sender:
                k = m
                break
        if k < 0:
            kr["dropped_unknown"] = int(kr["dropped_unknown"]) + 1
            continue
        nr = nbr[b, k]
        t = int(row[TICK])
        if t > tick:
            kr["dropped_stale"] = int(kr["dropped_stale"]) + 1
            continue
        if t <= int(nr["last"]):
            _hold_overtaken(kin, nbr, pend_t, pend_v, vtick, b, k, row, t)
            continue
        status = row[STATUS]
        if status == MALFORMED:
            kr["dropped_stale"] = int(kr["dropped_stale"]) + 1  # malformed: counted with the unusable messages
            continue
        if kr["dynamic"]:
            # the dynamical states are checked on their own: taken even if the velocity is not
            acc[lo + na] = e
            na += 1
        vjx = row[VX]
        vjy = row[VY]
        chk = (row[OM] + row[PH] + row[YX] + row[YY] + row[p0] + row[p0 + 1] + row[p0 + 2] + row[p0 + 3] + vjx
               + vjy)
        if status == KIN_MALFORMED or chk - chk != 0.0:  # not a number, NaN or infinite somewhere
            kr["dropped_stale"] = int(kr["dropped_stale"]) + 1
            continue
        nr["last"] = t
        nr["om"] = row[OM]
        nr["om_ok"] = row[OI] > 0.0
        nr["ph"] = row[PH]
        nr["y"] = complex(row[YX], row[YY])
        nr["zji"] = complex(row[p0], row[p0 + 1])
        nr["fji"] = complex(row[p0 + 2], row[p0 + 3])
        nr["st_t"] = t
        ts = t % hist
        if vtick[b, ts] != t:
            continue  # no own sample of that tick any more (too old)
        if int(nr["npend"]) > 0 or (int(nr["hold"]) != 0 and t != int(nr["rel"]) + 1):
            # this link reorders and earlier samples may still be on their way: hold this one
            _pend_add(kin, nbr, pend_t, pend_v, b, k, t, complex(vjx, vjy))
            continue
        nr["rel"] = t
        _use_sample(kin, abuf, abuf_t, P, cps, prm, b, k, t, complex(vbuf[b, ts]) - complex(vjx, vjy), ref, late_t,
                    late_z)
    kr["nacc"] = na
    if kr["held"]:  # some neighbour's samples are held back (a reordering link)
        held = False
        for k in range(deg):
            if int(nbr[b, k]["npend"]) > 0:
                _release(kin, nbr, pend_t, pend_v, vbuf, vtick, abuf, abuf_t, P, cps, prm, b, k, ref, late_t, late_z)
                held = held or int(nbr[b, k]["npend"]) > 0
        kr["held"] = held


@jit
def _kin_row(kin, nbr, pend_t, pend_v, vbuf, vtick, abuf, abuf_t, P, cps, prm, b, tick, inp, rows, lo, hi,
             order, lay, acc, late_t, late_z, res) -> None:
    """Agent b's tick (module docstring); its states refer to tick - 1 on entry and to tick on exit."""
    kr = kin[b]
    if tick <= int(kr["last_tick"]):
        kr["error"] = E_TICKS
        return
    kr["error"] = 0
    kr["last_tick"] = tick
    dt = float(kr["dt"])
    hist = int(kr["hist"])
    slot = tick % hist
    vbuf[b, slot] = complex(inp[b, I_VX], inp[b, I_VY])
    vtick[b, slot] = tick
    ref = tick - 1  # the tick the states refer to on entry
    kr["pool_num"] = 0.0
    kr["pool_den"] = 0.0
    kr["pool_fw"] = 0.0
    kr["nlate"] = 0
    _take_inbox(kin, nbr, pend_t, pend_v, vbuf, vtick, abuf, abuf_t, P, cps, prm, b, tick, rows, lo, hi, order, lay,
                acc, late_t, late_z)

    # 3-4. neighbour states: omega (low-pass consensus), body-frame angle phi (phase consensus), z_i in
    # that frame (centroid iteration in flow form with antisymmetric edge terms)
    deg = int(kr["deg"])
    om = float(kr["omega"])
    omdt = om * dt  # "om * dt * k" parses as (om * dt) * k: hoisting it is exact
    ph = float(kr["phi"])
    y = complex(kr["y"])
    eps_z = float(kr["eps_z"])
    max_age = int(kr["max_age"])
    # the initialised neighbours' omega and phi, brought to ref, enter as sums of their differences to
    # ours in neighbour order (consensus.disagreement)
    dom = 0.0
    dph = 0.0
    cnt = 0
    sflow = 0j  # sum_j F_ij, in neighbour order (a neighbour not heard from keeps its last flow)
    for k in range(deg):
        nr = nbr[b, k]
        st_t = int(nr["st_t"])
        age = ref - st_t
        if age > max_age:
            sflow += complex(nr["flow"])
            continue
        nph = float(nr["ph"])
        if nr["om_ok"]:
            # j's values of tick ref - age, brought to ref (``_forward``)
            dom += float(nr["om"]) + (_forward(kin, abuf, abuf_t, b, st_t, age) if age else 0.0) - om
            dph += nph + omdt * age - ph
            cnt += 1
        zs = complex(nr["z_sent"])
        zji = complex(nr["zji"])
        flow = complex(nr["flow"])
        fji = complex(nr["fji"])
        if zs == 0j or zji == 0j:
            f = 0.5 * (flow - fji)
        else:
            if age:
                zji *= complex(cos(omdt * age), sin(omdt * age))
            # common edge frame: both ends rotate the edge term by the same angle -> antisymmetric
            a = -0.5 * (ph + nph + omdt * age)
            e = 0.5 * (zs - zji) * complex(cos(a), sin(a))
            # y_i += eps sum_j (y_j - y_i + e_ij) in flow form: y_i = -sum_j F_ij
            f = 0.5 * (flow - fji) + eps_z * (y - complex(nr["y"]) - e)
        nr["flow"] = f
        sflow += f
    om_init = bool(kr["om_init"])
    adopt = cnt > 0 and (not om_init or bool(kr["adopt_ph"]))  # (re)initialised: take the neighbours' phase too
    kr["adopt_ph"] = False
    beta = float(kr["beta"])
    if adopt and not om_init:
        # not seeded by an own fit yet: adopt the neighbours' mean instead of pulling them to 0
        kr["om_init"] = om_init = True
        om = om + dom / cnt
        dom = 0.0
    den = float(kr["pool_den"])
    has_u = den > 0.0
    if has_u:
        u = float(kr["pool_num"]) / den  # as measured: the estimate's omega_local and the dynamical phase's input
        # brought to tick ref for the consensus (the dynamical phase's filter takes u as it is, as a
        # delayed measurement of its samples' ticks)
        fw = float(kr["pool_fw"])
        um = u + fw / den if fw else u
        om_meas = float(inp[b, I_OM_MEAS])
        if om_meas == om_meas:
            # the dynamical phase's filter omega (DynamicsSpec.filter_omega): the pairs' angles are
            # dead-reckoned with omega_hat at high noise and eq. (9) would feed its lag back
            um = om_meas
        bb = beta * (um - om)
    else:
        um = 0.0
        bb = np.nan
        u = np.nan
    # (u_den > 0 only once a pair is ready, and a ready pair seeds omega_hat: om_init holds then)
    if om_init:
        om_new = om + float(kr["eps_om"]) * dom  # consensus.lowpass_step
        if has_u:
            om_new += beta * (um - om)
    else:
        om_new = 0.0
    alpha = float(inp[b, I_ALPHA])
    if kr["dynamic"] and om_init:
        # feed-forward of the dynamical filter's angular acceleration: without it omega_hat lags a
        # ramp by omega_dot * omega_tau, and phi, z_ij and z_i fall behind the body while omega ramps
        om_new += alpha * dt
    if om_init and not adopt and bb == bb:
        # omega_hat's trend from its measurements, not from the consensus term (which would feed back
        # on itself); low-passed with the filter's time constant
        omdot = float(kr["omdot"])
        kr["omdot"] = omdot + beta * (bb - omdot)
    if kr["dynamic"]:
        if om_init:
            kr["asum"] = float(kr["asum"]) + alpha * dt
        ta = tick % hist
        abuf[b, ta] = kr["asum"]
        abuf_t[b, ta] = tick
    if deg > 0 and not inp[b, I_HOLD]:
        y = -sflow  # y_i = -sum_j F_ij
        kr["y"] = y
    if adopt:
        ph = ph + dph / cnt  # join the neighbours' body frame (y is still 0 then)
    else:
        ph = ph + float(kr["eps_z"]) * dph  # consensus.average_step
    ph += om_new * dt
    kr["phi"] = ph
    kr["omega"] = om_new
    kr["u"] = u

    # 2. prediction of every z_ij to tick k
    rot = complex(cos(om_new * dt), sin(om_new * dt))
    ready = 0
    for k in range(deg):
        if P[b, k]["ready"]:
            ready += 1
        pair_predict(P, b, k, rot)
        nbr[b, k]["z_sent"] = P[b, k]["z"]
    kr["ready"] = ready
    kr["trusted"] = ready == deg and ready > 0

    # 5. control: while the team is late (some pair has no circle fit yet: the flooded readiness mask
    # is not full), spin faster until every agent is ready; the same rule at every agent, no message
    boost_tick = int(kr["boost_tick"])
    boost = om_init and bool(kr["dynamic"]) and 0 <= boost_tick <= tick and inp[b, I_WAITING] != 0.0
    kin_wrench(kin, b, tick, om_new, om_init, boost)
    zi = y * complex(cos(ph), sin(ph))
    kr["zi"] = zi
    r = res[b]
    r[R_U] = u
    r[R_U_DEN] = den
    r[R_OMEGA] = om_new
    r[R_OM_INIT] = om_init
    r[R_PHI] = ph
    r[R_Y] = y.real
    r[R_Y + 1] = y.imag
    r[R_ZI] = zi.real
    r[R_ZI + 1] = zi.imag
    r[R_READY] = ready
    r[R_TRUSTED] = kr["trusted"]
    r[R_FX] = kr["fx"]
    r[R_FY] = kr["fy"]
    r[R_TAU] = kr["tau"]
    r[R_DROPPED_UNKNOWN] = kr["dropped_unknown"]
    r[R_DROPPED_STALE] = kr["dropped_stale"]
    r[R_NACC] = kr["nacc"]
    r[R_NLATE] = kr["nlate"]
    for k in range(deg):
        nr = nbr[b, k]
        zs = complex(nr["z_sent"])
        f = complex(nr["flow"])
        r[R_PAIRS + 4 * k] = zs.real
        r[R_PAIRS + 4 * k + 1] = zs.imag
        r[R_PAIRS + 4 * k + 2] = f.real
        r[R_PAIRS + 4 * k + 3] = f.imag


@jit
def kin_step(kin, nbr, pend_t, pend_v, vbuf, vtick, abuf, abuf_t, P, cps, prm, tick, inp, rows, in_ptr, order,
             lay, acc, late_t, late_z, res) -> int:
    """One tick of every agent's kinematic phase (module docstring). ``inp`` (B, I_*): own velocities and
    the dynamical phase's feedback; agent b's inbox: ``rows[in_ptr[b]:in_ptr[b + 1]]`` (IN rows of
    net/rows.py, layout ``lay``); ``order, acc`` (E,) scratch; ``late_t, late_z`` (B, L >= its inbox + D K);
    ``res`` (B, R_PAIRS + 4 D) the tick's results. Returns the first agent whose tick did not
    increase (-1: none; its state is unchanged)."""
    for b in range(kin.shape[0]):
        _kin_row(kin, nbr, pend_t, pend_v, vbuf, vtick, abuf, abuf_t, P, cps, prm, b, tick, inp, rows, in_ptr[b],
                 in_ptr[b + 1], order, lay, acc, late_t, late_z, res)
        if kin[b]["error"]:
            return b
    return -1


@register_warm
def warm() -> None:
    """Compile every kernel of this module: two agents (one with a dynamical phase), a few ticks of
    messages, one of them overtaken."""
    est = EstimatorSpec()
    H = est.history_ticks
    bank = kin_bank(2, 2, H)
    kin, nbr = bank[0], bank[1]
    P, cps, prm = pair_bank(2, 2, pair_checkpoints(est.fit_min_ticks, est.fit_max_ticks, est.fit_check_ticks))
    for b in range(2):
        set_kin_params(kin, nbr, P, prm, b, b, [1 - b], 0.01, 0.1, est, ControlSpec(), b == 1)
    lay = Layout(False, 0, 0, False, 1)
    rows = np.zeros((4, lay.size_in))
    inp = np.zeros((2, 6))
    inp[:, I_OM_MEAS] = np.nan
    for tick in (1, 2):
        for e, (b, t) in enumerate(((1, tick - 1), (0, tick - 1), (0, 0), (1, 0))):
            rows[e, TICK] = t
            rows[e, SENDER] = 1 - b
        in_ptr = np.array([0, 2, 4], np.int64)
        order = np.zeros(4, np.int64)
        late_t = np.zeros((2, 4 + 2 * (H + HOLD_MAX)), np.int64)
        kin_step(*bank, P, cps, prm, tick, inp, rows[[1, 2, 0, 3]], in_ptr, order, lay.lay, order.copy(), late_t,
                 np.zeros(late_t.shape), np.zeros((2, R_PAIRS + 4 * 2)))
