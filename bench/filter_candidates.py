"""Candidate fast cores of the dynamical-phase filter (agents/rigid_filter.RigidEKF), for bench/filter_block.py.

Each candidate computes RigidEKF.update and RigidEKF.predict with the same model and the same
formulas; what differs is how the state is held and where the loop over agents runs:

- ``update_batch`` / ``predict_batch`` (numpy, leading agent axis): s (B, d), P (B, d, d); every
  per-row quantity is a (B,) or (B, d) array, the 2- and 3-measurement cases one formula (a missing
  rate measurement is a zero column with unit variance), a rejected update a row kept by ``np.where``.
  No operation mixes rows, so a row's result does not depend on the batch it is in.
- ``update_numba`` / ``predict_numba``: the same arithmetic as scalar loops compiled by numba (optional:
  ``NUMBA`` is None when numba is not installed).
- ``update_py`` / ``predict_py``: plain Python floats, P a list of row lists; A P A^T uses A's sparsity.

Arguments per row (arrays of length B): update(r, vr, vi, u, u_var, u_dc, u_dw, nis) -> (s, P, nis,
innov (B, 5)); predict(fr, fi, torque, dt, qd (B, 5), qb, qa (B, 2): the augmented walks) -> (s, P).
The model's dimension d is 8 (nominal) or 10 (augmented, beta and gamma at 7 and 8); the pooled rate's
error b is always the last state. Docs: docs/agent-step.md, "Choosing the fast core: measured".
"""

from __future__ import annotations

from math import cos, sin

import numpy as np


def update_batch(S, P, r, vr, vi, u, uvar, udc, udw, nis0):  # noqa: ANN001, ANN201
    B, d = S.shape
    ib = d - 1
    aug = d == 10
    qx, qy, om = S[:, 2], S[:, 3], S[:, 5]
    qxc, qyc, omc = qx[:, None], qy[:, None], om[:, None]
    P2, P3, P5, P6 = P[:, :, 2], P[:, :, 3], P[:, :, 5], P[:, :, 6]
    c0 = P[:, :, 0] - omc * P3 - qyc * P5  # P H^T, column for v_x
    c1 = P[:, :, 1] + omc * P2 + qxc * P5  # ... v_y
    e0 = vr - (S[:, 0] - om * qy)
    e1 = vi - (S[:, 1] + om * qx)
    s00 = c0[:, 0] - om * c0[:, 3] - qy * c0[:, 5] + r
    s01 = c1[:, 0] - om * c1[:, 3] - qy * c1[:, 5]
    s11 = c1[:, 1] + om * c1[:, 2] + qx * c1[:, 5] + r
    innov = np.stack((e0, e1, s00, s01, s11), axis=1)
    d2 = s00 * s11 - s01 * s01
    pos = d2 > 0.0
    nis = np.where(pos, (s11 * e0 * e0 - 2.0 * s01 * e0 * e1 + s00 * e1 * e1) / np.where(pos, d2, 1.0), nis0)
    # the rate u = omega + b (delayed: - u_dc iota + u_dw gamma); a row without it gets c2 = 0, e2 = 0,
    # s22 = 1, which turns the 3x3 inverse below into the 2x2 one exactly
    has_u = (u == u) & (uvar > 0.0)
    c2 = P5 + P[:, :, ib] - udc[:, None] * P6
    e2 = u - om - S[:, ib] + udc * S[:, 6]
    if aug:
        c2 = c2 + udw[:, None] * P[:, :, 8]
        e2 = e2 - udw * S[:, 8]
        s22 = c2[:, 5] + c2[:, ib] - udc * c2[:, 6] + udw * c2[:, 8] + uvar
    else:
        s22 = c2[:, 5] + c2[:, ib] - udc * c2[:, 6] + uvar
    c2 = np.where(has_u[:, None], c2, 0.0)
    e2 = np.where(has_u, e2, 0.0)
    s22 = np.where(has_u, s22, 1.0)
    s02 = c2[:, 0] - om * c2[:, 3] - qy * c2[:, 5]
    s12 = c2[:, 1] + om * c2[:, 2] + qx * c2[:, 5]
    a00 = s11 * s22 - s12 * s12
    a01 = s02 * s12 - s01 * s22
    a02 = s01 * s12 - s02 * s11
    a11 = s00 * s22 - s02 * s02
    a12 = s01 * s02 - s00 * s12
    a22 = s00 * s11 - s01 * s01
    det = s00 * a00 + s01 * a01 + s02 * a02
    ok = ~(det <= 0.0)  # as RigidEKF: a NaN det goes through
    k = 1.0 / np.where(ok, det, 1.0)
    k0 = c0 * (a00 * k)[:, None] + c1 * (a01 * k)[:, None] + c2 * (a02 * k)[:, None]  # K = C S^-1, by column
    k1 = c0 * (a01 * k)[:, None] + c1 * (a11 * k)[:, None] + c2 * (a12 * k)[:, None]
    k2 = c0 * (a02 * k)[:, None] + c1 * (a12 * k)[:, None] + c2 * (a22 * k)[:, None]
    Sn = S + (k0 * e0[:, None] + k1 * e1[:, None] + k2 * e2[:, None])
    Pn = P - (k0[:, :, None] * c0[:, None, :] + k1[:, :, None] * c1[:, None, :] + k2[:, :, None] * c2[:, None, :])
    Pn = 0.5 * (Pn + Pn.transpose(0, 2, 1))
    return np.where(ok[:, None], Sn, S), np.where(ok[:, None, None], Pn, P), nis, innov


def predict_batch(S, P, fr, fi, T, dt, qd, qb, qa):  # noqa: ANN001, ANN201
    B, d = S.shape
    ib = d - 1
    s0, s1, qx, qy, mu, om, iota = (S[:, k] for k in range(7))
    ang = om * dt
    c, sn = np.cos(ang), np.sin(ang)
    nq = S.copy()  # mu, iota, beta, gamma, b carried over
    nq[:, 0] = s0 + dt * mu * fr
    nq[:, 1] = s1 + dt * mu * fi
    nq[:, 2] = c * qx - sn * qy
    nq[:, 3] = sn * qx + c * qy
    nq[:, 5] = om + dt * iota * T
    A = np.broadcast_to(np.eye(d), (B, d, d)).copy()
    A[:, 0, 4] = dt * fr
    A[:, 1, 4] = dt * fi
    A[:, 2, 2] = c
    A[:, 2, 3] = -sn
    A[:, 3, 2] = sn
    A[:, 3, 3] = c
    A[:, 2, 5] = dt * (-sn * qx - c * qy)
    A[:, 3, 5] = dt * (c * qx - sn * qy)
    A[:, 5, 6] = dt * T
    if d == 10:
        beta, gamma = S[:, 7], S[:, 8]
        nq[:, 0] -= dt * beta * s0
        nq[:, 1] -= dt * beta * s1
        nq[:, 5] -= dt * gamma * om
        A[:, 0, 0] -= dt * beta
        A[:, 1, 1] -= dt * beta
        A[:, 0, 7] = -dt * s0
        A[:, 1, 7] = -dt * s1
        A[:, 5, 5] -= dt * gamma
        A[:, 5, 8] = -dt * om
    Pn = A @ P @ A.transpose(0, 2, 1)
    Pn[:, 0, 0] += qd[:, 0] * dt
    Pn[:, 1, 1] += qd[:, 0] * dt
    qq = qd[:, 1] * dt * (qx * qx + qy * qy)
    Pn[:, 2, 2] += qq
    Pn[:, 3, 3] += qq
    Pn[:, 4, 4] += qd[:, 2] * dt
    Pn[:, 5, 5] += qd[:, 3] * dt
    Pn[:, 6, 6] += qd[:, 4] * dt
    if d == 10:
        Pn[:, 7, 7] += qa[:, 0] * dt
        Pn[:, 8, 8] += qa[:, 1] * dt
    Pn[:, ib, ib] += qb * dt
    return nq, Pn


# ---- plain Python floats: s a list, P a list of row lists ---------------------------------------------

def _rows(A: list, M: list) -> list:
    """A M for a sparse A given as {row: ((col, a), ...)} (rows not listed: identity)."""
    out = list(M)
    for i, terms in A.items():
        if len(terms) == 2:
            (j1, a1), (j2, a2) = terms
            out[i] = [a1 * x + a2 * y for x, y in zip(M[j1], M[j2])]
        else:
            (j1, a1), (j2, a2), (j3, a3) = terms
            out[i] = [a1 * x + a2 * y + a3 * z for x, y, z in zip(M[j1], M[j2], M[j3])]
    return out


def predict_py(s, P, fr, fi, T, dt, qd, qb, qa):  # noqa: ANN001, ANN201
    d = len(s)
    ib = d - 1
    s0, s1, qx, qy, mu, om, iota = s[:7]
    c, sn = cos(om * dt), sin(om * dt)
    nq = list(s)
    nq[0] = s0 + dt * mu * fr
    nq[1] = s1 + dt * mu * fi
    nq[2] = c * qx - sn * qy
    nq[3] = sn * qx + c * qy
    nq[5] = om + dt * iota * T
    A = {
        0: ((0, 1.0), (4, dt * fr)),
        1: ((1, 1.0), (4, dt * fi)),
        2: ((2, c), (3, -sn), (5, dt * (-sn * qx - c * qy))),
        3: ((2, sn), (3, c), (5, dt * (c * qx - sn * qy))),
        5: ((5, 1.0), (6, dt * T)),
    }
    if d == 10:
        beta, gamma = s[7], s[8]
        nq[0] -= dt * beta * s0
        nq[1] -= dt * beta * s1
        nq[5] -= dt * gamma * om
        A[0] = ((0, 1.0 - dt * beta), (4, dt * fr), (7, -dt * s0))
        A[1] = ((1, 1.0 - dt * beta), (4, dt * fi), (7, -dt * s1))
        A[5] = ((5, 1.0 - dt * gamma), (6, dt * T), (8, -dt * om))
    AP = _rows(A, P)
    # A P A^T = (A (A P)^T)^T, exactly (each element the same products summed in the same order)
    Pn = [list(r) for r in zip(*_rows(A, [list(col) for col in zip(*AP)]))]
    Pn[0][0] += qd[0] * dt
    Pn[1][1] += qd[0] * dt
    qq = qd[1] * dt * (qx * qx + qy * qy)
    Pn[2][2] += qq
    Pn[3][3] += qq
    Pn[4][4] += qd[2] * dt
    Pn[5][5] += qd[3] * dt
    Pn[6][6] += qd[4] * dt
    if d == 10:
        Pn[7][7] += qa[0] * dt
        Pn[8][8] += qa[1] * dt
    Pn[ib][ib] += qb * dt
    return nq, Pn


def update_py(s, P, r, vr, vi, u, uvar, udc, udw, nis):  # noqa: ANN001, ANN201
    d = len(s)
    ib = d - 1
    qx, qy, om = s[2], s[3], s[5]
    cols = list(zip(*P))
    c0 = [a - om * b - qy * c for a, b, c in zip(cols[0], cols[3], cols[5])]
    c1 = [a + om * b + qx * c for a, b, c in zip(cols[1], cols[2], cols[5])]
    e0 = vr - (s[0] - om * qy)
    e1 = vi - (s[1] + om * qx)
    s00 = c0[0] - om * c0[3] - qy * c0[5] + r
    s01 = c1[0] - om * c1[3] - qy * c1[5]
    s11 = c1[1] + om * c1[2] + qx * c1[5] + r
    innov = (e0, e1, s00, s01, s11)
    d2 = s00 * s11 - s01 * s01
    if d2 > 0.0:
        nis = (s11 * e0 * e0 - 2.0 * s01 * e0 * e1 + s00 * e1 * e1) / d2
    if u == u and uvar > 0.0:
        c2 = [a + b - udc * c for a, b, c in zip(cols[5], cols[ib], cols[6])]
        e2 = u - om - s[ib] + udc * s[6]
        if d == 10:
            c2 = [a + udw * b for a, b in zip(c2, cols[8])]
            e2 -= udw * s[8]
            s22 = c2[5] + c2[ib] - udc * c2[6] + udw * c2[8] + uvar
        else:
            s22 = c2[5] + c2[ib] - udc * c2[6] + uvar
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
            return s, P, nis, innov
        k = 1.0 / det
        b00, b01, b02, b11, b12, b22 = a00 * k, a01 * k, a02 * k, a11 * k, a12 * k, a22 * k
        k0 = [x * b00 + y * b01 + z * b02 for x, y, z in zip(c0, c1, c2)]
        k1 = [x * b01 + y * b11 + z * b12 for x, y, z in zip(c0, c1, c2)]
        k2 = [x * b02 + y * b12 + z * b22 for x, y, z in zip(c0, c1, c2)]
        sn = [a + (x * e0 + y * e1 + z * e2) for a, x, y, z in zip(s, k0, k1, k2)]
        Pn = [[p - (x * a + y * b + z * c) for p, a, b, c in zip(row, c0, c1, c2)]
              for row, x, y, z in zip(P, k0, k1, k2)]
    else:
        det = d2
        if det <= 0.0:
            return s, P, nis, innov
        k = 1.0 / det
        b00, b01, b11 = s11 * k, -s01 * k, s00 * k
        k0 = [x * b00 + y * b01 for x, y in zip(c0, c1)]
        k1 = [x * b01 + y * b11 for x, y in zip(c0, c1)]
        sn = [a + (x * e0 + y * e1) for a, x, y in zip(s, k0, k1)]
        Pn = [[p - (x * a + y * b) for p, a, b in zip(row, c0, c1)] for row, x, y in zip(P, k0, k1)]
    Pn = [[0.5 * (a + b) for a, b in zip(row, col)] for row, col in zip(Pn, zip(*Pn))]
    return sn, Pn, nis, innov


# ---- numba: the batch formulas as scalar loops --------------------------------------------------------

def _numba_kernels():  # noqa: ANN202
    import numba

    @numba.njit(cache=True)
    def update_numba(S, P, r, vr, vi, u, uvar, udc, udw, nis0):  # noqa: ANN001, ANN202
        B, d = S.shape
        ib = d - 1
        aug = d == 10
        Sn = S.copy()
        Pn = P.copy()
        nis = nis0.copy()
        innov = np.empty((B, 5))
        c0 = np.empty(d)
        c1 = np.empty(d)
        c2 = np.empty(d)
        for b in range(B):
            qx, qy, om = S[b, 2], S[b, 3], S[b, 5]
            Pb = P[b]
            for k in range(d):
                c0[k] = Pb[k, 0] - om * Pb[k, 3] - qy * Pb[k, 5]
                c1[k] = Pb[k, 1] + om * Pb[k, 2] + qx * Pb[k, 5]
            e0 = vr[b] - (S[b, 0] - om * qy)
            e1 = vi[b] - (S[b, 1] + om * qx)
            s00 = c0[0] - om * c0[3] - qy * c0[5] + r[b]
            s01 = c1[0] - om * c1[3] - qy * c1[5]
            s11 = c1[1] + om * c1[2] + qx * c1[5] + r[b]
            innov[b, 0], innov[b, 1], innov[b, 2], innov[b, 3], innov[b, 4] = e0, e1, s00, s01, s11
            d2 = s00 * s11 - s01 * s01
            if d2 > 0.0:
                nis[b] = (s11 * e0 * e0 - 2.0 * s01 * e0 * e1 + s00 * e1 * e1) / d2
            if u[b] == u[b] and uvar[b] > 0.0:
                for k in range(d):
                    c2[k] = Pb[k, 5] + Pb[k, ib] - udc[b] * Pb[k, 6]
                    if aug:
                        c2[k] = c2[k] + udw[b] * Pb[k, 8]
                e2 = u[b] - om - S[b, ib] + udc[b] * S[b, 6]
                s22 = c2[5] + c2[ib] - udc[b] * c2[6]
                if aug:
                    e2 = e2 - udw[b] * S[b, 8]
                    s22 = s22 + udw[b] * c2[8]
                s22 = s22 + uvar[b]
            else:
                for k in range(d):
                    c2[k] = 0.0
                e2 = 0.0
                s22 = 1.0
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
                continue
            kk = 1.0 / det
            b00, b01, b02, b11, b12, b22 = a00 * kk, a01 * kk, a02 * kk, a11 * kk, a12 * kk, a22 * kk
            for i in range(d):
                k0 = c0[i] * b00 + c1[i] * b01 + c2[i] * b02
                k1 = c0[i] * b01 + c1[i] * b11 + c2[i] * b12
                k2 = c0[i] * b02 + c1[i] * b12 + c2[i] * b22
                Sn[b, i] = S[b, i] + (k0 * e0 + k1 * e1 + k2 * e2)
                for j in range(d):
                    Pn[b, i, j] = Pb[i, j] - (k0 * c0[j] + k1 * c1[j] + k2 * c2[j])
            for i in range(d):
                for j in range(i + 1, d):
                    m = 0.5 * (Pn[b, i, j] + Pn[b, j, i])
                    Pn[b, i, j] = m
                    Pn[b, j, i] = m
        return Sn, Pn, nis, innov

    @numba.njit(cache=True)
    def predict_numba(S, P, fr, fi, T, dt, qd, qb, qa):  # noqa: ANN001, ANN202
        B, d = S.shape
        ib = d - 1
        Sn = S.copy()
        Pn = np.empty_like(P)
        A = np.empty((d, d))
        AP = np.empty((d, d))
        for b in range(B):
            s0, s1, qx, qy, mu, om, iota = S[b, 0], S[b, 1], S[b, 2], S[b, 3], S[b, 4], S[b, 5], S[b, 6]
            h = dt[b]
            c, sn = np.cos(om * h), np.sin(om * h)
            Sn[b, 0] = s0 + h * mu * fr[b]
            Sn[b, 1] = s1 + h * mu * fi[b]
            Sn[b, 2] = c * qx - sn * qy
            Sn[b, 3] = sn * qx + c * qy
            Sn[b, 5] = om + h * iota * T[b]
            A[:, :] = 0.0
            for k in range(d):
                A[k, k] = 1.0
            A[0, 4] = h * fr[b]
            A[1, 4] = h * fi[b]
            A[2, 2] = c
            A[2, 3] = -sn
            A[3, 2] = sn
            A[3, 3] = c
            A[2, 5] = h * (-sn * qx - c * qy)
            A[3, 5] = h * (c * qx - sn * qy)
            A[5, 6] = h * T[b]
            if d == 10:
                beta, gamma = S[b, 7], S[b, 8]
                Sn[b, 0] -= h * beta * s0
                Sn[b, 1] -= h * beta * s1
                Sn[b, 5] -= h * gamma * om
                A[0, 0] -= h * beta
                A[1, 1] -= h * beta
                A[0, 7] = -h * s0
                A[1, 7] = -h * s1
                A[5, 5] -= h * gamma
                A[5, 8] = -h * om
            for i in range(d):
                for j in range(d):
                    acc = 0.0
                    for k in range(d):
                        acc += A[i, k] * P[b, k, j]
                    AP[i, j] = acc
            for i in range(d):
                for j in range(d):
                    acc = 0.0
                    for k in range(d):
                        acc += AP[i, k] * A[j, k]
                    Pn[b, i, j] = acc
            Pn[b, 0, 0] += qd[b, 0] * h
            Pn[b, 1, 1] += qd[b, 0] * h
            qq = qd[b, 1] * h * (qx * qx + qy * qy)
            Pn[b, 2, 2] += qq
            Pn[b, 3, 3] += qq
            Pn[b, 4, 4] += qd[b, 2] * h
            Pn[b, 5, 5] += qd[b, 3] * h
            Pn[b, 6, 6] += qd[b, 4] * h
            if d == 10:
                Pn[b, 7, 7] += qa[b, 0] * h
                Pn[b, 8, 8] += qa[b, 1] * h
            Pn[b, ib, ib] += qb[b] * h
        return Sn, Pn

    return update_numba, predict_numba


try:
    NUMBA = _numba_kernels()
except ImportError:
    NUMBA = None


# ---- numpy, leading agent axis, textbook matrix form: H, S = H P H^T + R, K = P H^T S^-1 ------------

def update_matrix(S, P, r, vr, vi, u, uvar, udc, udw, nis0):  # noqa: ANN001, ANN201
    B, d = S.shape
    ib = d - 1
    qx, qy, om = S[:, 2], S[:, 3], S[:, 5]
    has_u = (u == u) & (uvar > 0.0)
    one = np.where(has_u, 1.0, 0.0)  # a row without the rate: zero H row, unit variance (no effect on K)
    H = np.zeros((B, 3, d))
    H[:, 0, 0] = H[:, 1, 1] = 1.0
    H[:, 0, 3] = -om
    H[:, 0, 5] = -qy
    H[:, 1, 2] = om
    H[:, 1, 5] = qx
    H[:, 2, 5] = one
    H[:, 2, ib] = one
    H[:, 2, 6] = -udc * one
    if d == 10:
        H[:, 2, 8] = udw * one
    e = np.stack((vr - (S[:, 0] - om * qy), vi - (S[:, 1] + om * qx),
                  np.where(has_u, u - om - S[:, ib] + udc * S[:, 6] - (udw * S[:, 8] if d == 10 else 0.0), 0.0)),
                 axis=1)
    PHt = P @ H.transpose(0, 2, 1)
    Sm = H @ PHt
    Sm[:, 0, 0] += r
    Sm[:, 1, 1] += r
    Sm[:, 2, 2] += np.where(has_u, uvar, 1.0)
    s00, s01, s11 = Sm[:, 0, 0], Sm[:, 0, 1], Sm[:, 1, 1]
    e0, e1 = e[:, 0], e[:, 1]
    innov = np.stack((e0, e1, s00, s01, s11), axis=1)
    d2 = s00 * s11 - s01 * s01
    pos = d2 > 0.0
    nis = np.where(pos, (s11 * e0 * e0 - 2.0 * s01 * e0 * e1 + s00 * e1 * e1) / np.where(pos, d2, 1.0), nis0)
    ok = ~(np.linalg.det(Sm) <= 0.0)
    K = PHt @ np.linalg.inv(np.where(ok[:, None, None], Sm, np.eye(3)))
    Sn = S + (K @ e[:, :, None])[:, :, 0]
    Pn = P - K @ PHt.transpose(0, 2, 1)
    Pn = 0.5 * (Pn + Pn.transpose(0, 2, 1))
    return np.where(ok[:, None], Sn, S), np.where(ok[:, None, None], Pn, P), nis, innov



def predict_matrix(S, P, fr, fi, T, dt, qd, qb, qa):  # noqa: ANN001, ANN201
    B, d = S.shape
    s0, s1, qx, qy, mu, om, iota = (S[:, k] for k in range(7))
    ang = om * dt
    c, sn = np.cos(ang), np.sin(ang)
    A = np.broadcast_to(np.eye(d), (B, d, d)).copy()
    A[:, 0, 4] = dt * fr
    A[:, 1, 4] = dt * fi
    A[:, 2, 2] = A[:, 3, 3] = c
    A[:, 2, 3] = -sn
    A[:, 3, 2] = sn
    A[:, 2, 5] = dt * (-sn * qx - c * qy)
    A[:, 3, 5] = dt * (c * qx - sn * qy)
    A[:, 5, 6] = dt * T
    q = np.empty((B, d))  # process noise per second, diagonal
    q[:, 0] = q[:, 1] = qd[:, 0]
    q[:, 2] = q[:, 3] = qd[:, 1] * (qx * qx + qy * qy)
    q[:, 4:7] = qd[:, 2:5]
    q[:, d - 1] = qb
    if d == 10:
        beta, gamma = S[:, 7], S[:, 8]
        A[:, 0, 0] -= dt * beta
        A[:, 1, 1] -= dt * beta
        A[:, 0, 7] = -dt * s0
        A[:, 1, 7] = -dt * s1
        A[:, 5, 5] -= dt * gamma
        A[:, 5, 8] = -dt * om
        q[:, 7:9] = qa
    nq = S.copy()  # mu, iota, beta, gamma, b carried over
    nq[:, 0] = s0 + dt * mu * fr - (dt * S[:, 7] * s0 if d == 10 else 0.0)
    nq[:, 1] = s1 + dt * mu * fi - (dt * S[:, 7] * s1 if d == 10 else 0.0)
    nq[:, 2] = c * qx - sn * qy
    nq[:, 3] = sn * qx + c * qy
    nq[:, 5] = om + dt * iota * T - (dt * S[:, 8] * om if d == 10 else 0.0)
    Pn = A @ P @ A.transpose(0, 2, 1)
    i = np.arange(d)
    Pn[:, i, i] += q * dt[:, None]
    return nq, Pn
