"""The dynamical phase's rigid-body filter (the EKF of agents/rigid_filter.py) as row kernels over a bank.

A bank holds S filter slots per agent (3 in the team core: the agent's filter, a restart's shadow, the
slope's twin; 1 in a :class:`agents.rigid_filter.RigidEKF` view). Its arrays, always in this order:
``fs`` (B, S) record :data:`FS` (the per-filter scalars), ``s`` (B, S, d) state, ``P`` (B, S, d, d)
covariance, ``sens`` (B, S, d, N_PAR + 1) sensitivities of the online detection, ``Qd`` (B, S, 5) the
per-second process noise (v, q angle, 1/m, omega, 1/J), ``aug`` (B, S, 2 N_PAR) the augmented model's
rates on/pinned and their walks, ``innov`` (B, S, 5) the last own-velocity innovation and its covariance,
``sens_h`` (B, S, 2 N_PAR + 2) the last update's own-velocity rows of H D. d is the bank's widest model;
a row's own dimension is ``fs.d`` (8 nominal, 13 augmented) and the entries past it stay 0.

Each kernel works on one slot (b, k) and takes the arrays it reads or writes, in the order above. The
products are scalar loops in the order the maths is written (K = C S^-1, s + K e, P - K C^T, A P A^T),
so a row's result is the same bits whatever the batch. The model and its tuning: docs/dynamics.md.
"""

from __future__ import annotations

from math import cos, sin, tanh

import numpy as np

from agents.kernels import jit, register_warm

N_PAR = 5  # the augmented model's rate states 7 .. 7 + N_PAR - 1 (beta, gamma, kappa, a_x, a_y)
D_NOMINAL = 8
D_AUGMENTED = 8 + N_PAR
# each effect's first rate state (offset from 7) and how many it has (agents/rigid_filter.EFFECT_PARAMS)
_EFF_FIRST = (0, 1, 2, 3)
_EFF_COUNT = (1, 1, 1, 2)

FS = np.dtype([
    ("ready", np.bool_), ("nis", np.float64), ("r", np.float64), ("d", np.int64), ("ib", np.int64),
    ("has_aug", np.bool_), ("detect", np.bool_), ("has_sens", np.bool_), ("qb", np.float64), ("b0", np.float64),
    ("walk_eff", np.float64), ("vs", np.float64),
])
"""Per-filter scalars: started; the last NIS; the own velocity's variance; the dimension and the index of
the rate error b (the last state); augmented model; online detection; sensitivities carried; b's walk and
start variance; the effect rates' walk; the filter's Coulomb speed."""


def new_bank(B: int, slots: int, d: int) -> tuple[np.ndarray, ...]:
    """Zeroed bank arrays for B agents of ``slots`` filters of dimension up to d, in the kernels' order."""
    return (np.zeros((B, slots), FS), np.zeros((B, slots, d)), np.zeros((B, slots, d, d)),
            np.zeros((B, slots, d, N_PAR + 1)), np.zeros((B, slots, 5)), np.zeros((B, slots, 2 * N_PAR)),
            np.zeros((B, slots, 5)), np.zeros((B, slots, 2 * N_PAR + 2)))


@jit
def coulomb_sat(vx, vy, vs):  # noqa: ANN001, ANN201
    """The smoothed Coulomb direction sat(v) = tanh(|v|/vs) v/|v| and its Jacobian (j00, j01, j11, symmetric):
    tanh(r/vs)/r (I - u u^T) + sech^2(r/vs)/vs u u^T, u = v/|v|, r = |v|; I/vs at rest (the limit)."""
    r = abs(complex(vx, vy))
    if r < 1e-9 * vs:
        return vx / vs, vy / vs, 1.0 / vs, 0.0, 1.0 / vs
    th = tanh(r / vs)
    a = th / r
    dd = (1.0 - th * th) / vs - a  # the radial slope minus the tangential one
    ux, uy = vx / r, vy / r
    return a * vx, a * vy, a + dd * ux * ux, dd * ux * uy, a + dd * uy * uy


@jit
def ekf_start(fs, s, P, sens, b, k, v, q0, omega):  # noqa: ANN001, ANN201
    """(Re)starts slot (b, k) at the own contact velocity v, q0 and omega: v_C = v - omega i q0, 1/m and 1/J
    at 0 with unit and 1e-2 variance, the rates and b at 0 (b's variance ``b0``), the sensitivities zeroed."""
    f = fs[b, k]
    ib = f["ib"]
    x = s[b, k]
    p = P[b, k]
    vc = v - omega * 1j * q0
    x[:] = 0.0
    x[0] = vc.real
    x[1] = vc.imag
    x[2] = q0.real
    x[3] = q0.imag
    x[5] = omega
    p[:, :] = 0.0
    for i in range(5):
        p[i, i] = 1.0
    p[5, 5] = 0.1
    p[6, 6] = 1e-2
    p[ib, ib] = f["b0"]
    if f["detect"]:
        sens[b, k, :, :] = 0.0
        f["has_sens"] = True
    f["ready"] = True


@jit
def _drop(p, d, i):  # noqa: ANN001, ANN202
    """State i's row and column of P zeroed."""
    for j in range(d):
        p[i, j] = 0.0
        p[j, i] = 0.0


@jit
def _restart(x, p, d, i, var):  # noqa: ANN001, ANN202
    """State i's correlations dropped and its variance set to var; an effect rate (i >= 7) back at 0."""
    if i >= 7:
        x[i] = 0.0
    _drop(p, d, i)
    p[i, i] = var


@jit
def ekf_release_effects(fs, s, P, aug, b, k):  # noqa: ANN001, ANN201
    """Augmented model: the declared rates free from 0 (prior variance 0.1), 1/m and 1/J restarted from
    their current values with the start's priors."""
    f = fs[b, k]
    if not f["has_aug"] or not f["ready"]:
        return
    x, p, d = s[b, k], P[b, k], f["d"]
    _restart(x, p, d, 4, 1.0)
    _restart(x, p, d, 6, 1e-2)
    for j in range(N_PAR):
        _restart(x, p, d, 7 + j, 0.1 * aug[b, k, j])


@jit
def ekf_release_effect(fs, s, P, aug, b, k, e):  # noqa: ANN001, ANN201
    """Online detection: effect e's rates free from 0 (variance 0.1, walk ``walk_eff``), and the parameter it
    shares the data with restarted (1/J for e = 1, else 1/m; a constant force, e = 3, restarts v_C too)."""
    f = fs[b, k]
    if not f["has_aug"] or not f["ready"]:
        return
    first, count = _EFF_FIRST[e], _EFF_COUNT[e]
    for j in range(first, first + count):
        aug[b, k, j] = 1.0
        aug[b, k, N_PAR + j] = f["walk_eff"]
    x, p, d = s[b, k], P[b, k], f["d"]
    if e == 1:
        _restart(x, p, d, 6, 1e-2)
    else:
        _restart(x, p, d, 4, 1.0)
        if count > 1:
            _restart(x, p, d, 0, 1.0)
            _restart(x, p, d, 1, 1.0)
    for j in range(first, first + count):
        _restart(x, p, d, 7 + j, 0.1)


@jit
def ekf_forget_iota(fs, P, b, k, var):  # noqa: ANN001, ANN201
    """1/J's correlations dropped, its variance set to var."""
    p = P[b, k]
    _drop(p, fs[b, k]["d"], 6)
    p[6, 6] = var


@jit
def ekf_hold_shape(fs, s, P, Qd, b, k):  # noqa: ANN001, ANN201
    """q held (no angle walk, no variance) and the rate error b pinned at 0."""
    f = fs[b, k]
    d, ib = f["d"], f["ib"]
    p = P[b, k]
    _drop(p, d, 2)
    _drop(p, d, 3)
    _drop(p, d, ib)
    s[b, k, ib] = 0.0
    f["qb"] = 0.0
    Qd[b, k, 1] = 0.0


@jit
def ekf_set_omega_walk(Qd, b, k, walk):  # noqa: ANN001, ANN201
    """omega's process noise (rad/s/sqrt(s))."""
    Qd[b, k, 3] = walk * walk


@jit
def ekf_update(fs, s, P, sens, innov, sens_h, b, k, v, u, u_var, u_dc, u_dw):  # noqa: ANN001, ANN201
    """Measurement update of slot (b, k) by the own contact velocity v and the pooled rate u (NaN or u_var <= 0:
    none), u possibly delayed (u_dc = dt sum T, u_dw = dt sum omega since it was measured). H is sparse,
    so C = P H^T is three column combinations of P; S^-1 is the explicit inverse of the 2x2 or 3x3 S."""
    f = fs[b, k]
    d, ib, aug, r = f["d"], f["ib"], f["has_aug"], f["r"]
    x = s[b, k]
    p = P[b, k]
    qx, qy, om = x[2], x[3], x[5]
    c0 = np.empty(d)
    c1 = np.empty(d)
    c2 = np.zeros(d)
    for i in range(d):
        c0[i] = p[i, 0] - om * p[i, 3] - qy * p[i, 5]  # P H^T, column for v_x
        c1[i] = p[i, 1] + om * p[i, 2] + qx * p[i, 5]  # ... v_y
    e0 = v.real - (x[0] - om * qy)
    e1 = v.imag - (x[1] + om * qx)
    s00 = c0[0] - om * c0[3] - qy * c0[5] + r
    s01 = c1[0] - om * c1[3] - qy * c1[5]
    s11 = c1[1] + om * c1[2] + qx * c1[5] + r
    h = innov[b, k]
    h[0], h[1], h[2], h[3], h[4] = e0, e1, s00, s01, s11
    d2 = s00 * s11 - s01 * s01
    if d2 > 0.0:  # the lock check's statistic: ~2 while the filter explains v_Ci
        f["nis"] = (s11 * e0 * e0 - 2.0 * s01 * e0 * e1 + s00 * e1 * e1) / d2
    K = np.empty((d, 3))
    e2 = 0.0
    if u == u and u_var > 0.0:
        m = 3
        for i in range(d):
            c2[i] = p[i, 5] + p[i, ib]  # ... u = omega + b
        e2 = u - om - x[ib]
        if u_dc != 0.0 or u_dw != 0.0:  # delayed: omega of a ticks ago, d/d iota = -u_dc, d/d gamma = u_dw
            for i in range(d):
                c2[i] = c2[i] - u_dc * p[i, 6]
            e2 += u_dc * x[6]
            if aug:
                for i in range(d):
                    c2[i] = c2[i] + u_dw * p[i, 8]
                e2 -= u_dw * x[8]
            s22 = c2[5] + c2[ib] - u_dc * c2[6] + (u_dw * c2[8] if aug else 0.0) + u_var
        else:
            s22 = c2[5] + c2[ib] + u_var
        s02 = c2[0] - om * c2[3] - qy * c2[5]
        s12 = c2[1] + om * c2[2] + qx * c2[5]
        a00 = s11 * s22 - s12 * s12
        a01 = s02 * s12 - s01 * s22
        a02 = s01 * s12 - s02 * s11
        a11 = s00 * s22 - s02 * s02
        a12 = s01 * s02 - s00 * s12
        a22 = s00 * s11 - s01 * s01
        det = s00 * a00 + s01 * a01 + s02 * a02
        if det <= 0.0:
            return
        i00, i01, i02, i11, i12, i22 = a00 / det, a01 / det, a02 / det, a11 / det, a12 / det, a22 / det
        for i in range(d):  # K = C S^-1
            K[i, 0] = c0[i] * i00 + c1[i] * i01 + c2[i] * i02
            K[i, 1] = c0[i] * i01 + c1[i] * i11 + c2[i] * i12
            K[i, 2] = c0[i] * i02 + c1[i] * i12 + c2[i] * i22
    else:
        m = 2
        det = s00 * s11 - s01 * s01
        if det <= 0.0:
            return
        i00, i01, i11 = s11 / det, -s01 / det, s00 / det
        for i in range(d):
            K[i, 0] = c0[i] * i00 + c1[i] * i01
            K[i, 1] = c0[i] * i01 + c1[i] * i11
    for i in range(d):  # s + K e
        acc = K[i, 0] * e0 + K[i, 1] * e1
        if m == 3:
            acc = acc + K[i, 2] * e2
        x[i] = x[i] + acc
    if f["has_sens"]:
        _sens_update(sens[b, k], sens_h[b, k], K, m, d, ib, aug, qx, qy, om, u_dc, u_dw)
    for i in range(d):  # P - K C^T
        for j in range(d):
            acc = K[i, 0] * c0[j] + K[i, 1] * c1[j]
            if m == 3:
                acc = acc + K[i, 2] * c2[j]
            p[i, j] = p[i, j] - acc
    for i in range(d):  # 0.5 (P + P^T)
        for j in range(i, d):
            a = 0.5 * (p[i, j] + p[j, i])
            p[i, j] = a
            p[j, i] = a


@jit
def _sens_update(D, hs, K, m, d, ib, aug, qx, qy, om, u_dc, u_dw):  # noqa: ANN001, ANN202
    """The sensitivities through the update, D <- D - K H D, and H D's own-velocity rows kept (``sens_h``).
    The gain's own dependence on the rates is left out: it multiplies the innovation, zero-mean under the
    nominal model (tests/test_effect_decision.py checks D against finite differences)."""
    w = N_PAR + 1
    hd = np.empty((3, w))
    for j in range(w):
        hd[0, j] = D[0, j] - om * D[3, j] - qy * D[5, j]
        hd[1, j] = D[1, j] + om * D[2, j] + qx * D[5, j]
        hd[2, j] = D[5, j] + D[ib, j] - u_dc * D[6, j] + (u_dw * D[8, j] if aug else 0.0)
        hs[2 * j] = hd[0, j]
        hs[2 * j + 1] = hd[1, j]
    for i in range(d):
        for j in range(w):
            acc = K[i, 0] * hd[0, j] + K[i, 1] * hd[1, j]
            if m == 3:
                acc = acc + K[i, 2] * hd[2, j]
            D[i, j] = D[i, j] - acc


@jit
def ekf_predict(fs, s, P, sens, Qd, aug, b, k, force, torque, dt, force_err):  # noqa: ANN001, ANN201
    """Prediction of slot (b, k) by dt under the total ``force`` and ``torque`` (the plant's semi-implicit
    Euler step; augmented: - dt beta v_C - dt kappa sat(v_C) + dt a, - dt gamma omega). ``force_err``: the
    known error of ``force``, read only by the sensitivities (their last column is d(state)/d(delta) for
    the force force + delta force_err at delta = 0)."""
    f = fs[b, k]
    d, ib, aug_on = f["d"], f["ib"], f["has_aug"]
    x = s[b, k]
    p = P[b, k]
    qx, qy, mu, om, iota = x[2], x[3], x[4], x[5], x[6]
    c, sn = cos(om * dt), sin(om * dt)
    nq = x[:d].copy()  # 1/m, 1/J, the rates and b carried over
    nq[0] = x[0] + dt * mu * force.real
    nq[1] = x[1] + dt * mu * force.imag
    nq[2] = c * qx - sn * qy
    nq[3] = sn * qx + c * qy
    nq[5] = om + dt * iota * torque
    A = np.zeros((d, d))
    for i in range(d):
        A[i, i] = 1.0
    A[0, 4] = dt * force.real
    A[1, 4] = dt * force.imag
    A[2, 2] = c
    A[2, 3] = -sn
    A[3, 2] = sn
    A[3, 3] = c
    A[2, 5] = dt * (-sn * qx - c * qy)
    A[3, 5] = dt * (c * qx - sn * qy)
    A[5, 6] = dt * torque
    if aug_on:
        beta, gamma, kappa, ax, ay = x[7], x[8], x[9], x[10], x[11]
        sx, sy, j00, j01, j11 = coulomb_sat(x[0], x[1], f["vs"])
        nq[0] -= dt * (beta * x[0] + kappa * sx - ax)
        nq[1] -= dt * (beta * x[1] + kappa * sy - ay)
        nq[5] -= dt * gamma * om
        A[0, 0] -= dt * (beta + kappa * j00)
        A[1, 1] -= dt * (beta + kappa * j11)
        A[0, 1] -= dt * kappa * j01
        A[1, 0] -= dt * kappa * j01
        A[0, 7] = -dt * x[0]
        A[1, 7] = -dt * x[1]
        A[5, 5] -= dt * gamma
        A[5, 8] = -dt * om
        A[0, 9] = -dt * sx
        A[1, 9] = -dt * sy
        A[0, 10] = dt
        A[1, 11] = dt
    if f["has_sens"]:
        # d/d rate at the pinned 0: carried through A, plus each rate's own column of A on the states it
        # drives (-dt v_C, -dt omega, -dt sat(v_C), dt along x and along y)
        D = sens[b, k]
        w = N_PAR + 1
        AD = np.empty((d, w))
        for i in range(d):
            for j in range(w):
                acc = 0.0
                for m in range(d):
                    acc += A[i, m] * D[m, j]
                AD[i, j] = acc
        if aug_on:
            for i in range(7):
                for j in range(N_PAR):
                    AD[i, j] += A[i, 7 + j]
        AD[0, N_PAR] += dt * mu * force_err.real
        AD[1, N_PAR] += dt * mu * force_err.imag
        D[:d, :] = AD
    AP = np.empty((d, d))
    for i in range(d):  # A P
        for j in range(d):
            acc = 0.0
            for m in range(d):
                acc += A[i, m] * p[m, j]
            AP[i, j] = acc
    for i in range(d):  # (A P) A^T
        for j in range(d):
            acc = 0.0
            for m in range(d):
                acc += AP[i, m] * A[j, m]
            p[i, j] = acc
    q = Qd[b, k]
    p[0, 0] += q[0] * dt
    p[1, 1] += q[0] * dt
    qq = q[1] * dt * (qx * qx + qy * qy)
    p[2, 2] += qq
    p[3, 3] += qq
    p[4, 4] += q[2] * dt
    p[5, 5] += q[3] * dt
    p[6, 6] += q[4] * dt
    if aug_on:
        for j in range(N_PAR):
            p[7 + j, 7 + j] += aug[b, k, N_PAR + j] * dt
    p[ib, ib] += f["qb"] * dt
    x[:d] = nq


@jit
def ekf_copy_slot(fs, s, P, sens, Qd, aug, innov, sens_h, b, src, dst):  # noqa: ANN001, ANN201
    """Slot dst of agent b becomes a copy of slot src (a restart's shadow, the slope's twin)."""
    fs[b, dst] = fs[b, src]
    s[b, dst] = s[b, src]
    P[b, dst] = P[b, src]
    sens[b, dst] = sens[b, src]
    Qd[b, dst] = Qd[b, src]
    aug[b, dst] = aug[b, src]
    innov[b, dst] = innov[b, src]
    sens_h[b, dst] = sens_h[b, src]


@register_warm
def warm() -> None:
    """Every kernel once, on a 2-slot bank of the augmented model with the sensitivities on."""
    fs, s, P, sens, Qd, aug, innov, sens_h = bank = new_bank(1, 2, D_AUGMENTED)
    f = fs[0, 0]
    f["d"], f["ib"], f["has_aug"], f["detect"], f["r"], f["vs"] = D_AUGMENTED, D_AUGMENTED - 1, True, True, 0.01, 0.1
    coulomb_sat(0.1, 0.2, 0.1)
    ekf_start(fs, s, P, sens, 0, 0, 0.1 + 0.2j, 1.0 + 0.5j, 0.3)
    ekf_predict(fs, s, P, sens, Qd, aug, 0, 0, 1.0 + 0.0j, 0.5, 0.01, 0j)
    ekf_update(fs, s, P, sens, innov, sens_h, 0, 0, 0.1 + 0.2j, 0.3, 0.01, 0.0, 0.0)
    ekf_release_effects(fs, s, P, aug, 0, 0)
    ekf_release_effect(fs, s, P, aug, 0, 0, 3)
    ekf_forget_iota(fs, P, 0, 0, 1e-2)
    ekf_hold_shape(fs, s, P, Qd, 0, 0)
    ekf_set_omega_walk(Qd, 0, 0, 0.05)
    ekf_copy_slot(*bank, 0, 0, 1)
