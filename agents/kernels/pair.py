"""The pair estimator's kernels: z_ij = p_Ci - p_Cj per (agent b, neighbour slot k) (paper 000 Sec. IV-A).

|z_ij| from an algebraic circle fit of the integrated relative velocity in re-anchored windows, the
direction tracked by rotation with omega_hat and corrected by Result 1 in linear (or axis) form. O(1) per
sample. Why this shape: docs/agent-step.md ("The pair estimator"), docs/spinup.md; the layout:
docs/fast-core-plan.md section 1.2.

State: ``P`` (B, D) records of :data:`PAIR`, ``cps`` (B, D, C) complex128, the window's checkpoints (every
``check``-th integrated point from the anchor on; C from :func:`pair_checkpoints`). Parameters: ``prm``
(B,), any record array with the fields of :data:`PAIR_PRM` (the estimator's own ``dt``, the fit gates,
``axis``); the angle walk per tick ``q`` is a field of ``P`` so that :func:`pair_predict` needs no ``prm``.

Kernels read a record's fields into Python scalars (``float(...)``, ``complex(...)``: no-ops compiled) so
that ``kernel.py_func`` computes with CPython's arithmetic, not numpy's scalar one (numpy's complex
division differs from CPython's in the last bit); the tests compare the two bit for bit.
"""

from __future__ import annotations

from math import atan2, sqrt

import numpy as np

from agents.kernels import jit, register_warm
from agents.kernels.libm import pow_libm

PAIR = np.dtype([
    ("z", "c16"),  # estimate of z_ij (m, world) at the owner's state tick; 0 until the first fit
    ("ready", "b1"),
    ("r", "f8"),  # |z_ij| estimate (m)
    ("rw", "f8"),  # sum of window weights
    ("rsum", "f8"),  # sum of weight * window radius
    ("p", "f8"),  # angle error variance (rad^2)
    ("q", "f8"),  # its growth per tick (angle_walk^2 dt)
    ("last_t", "i8"),  # tick of the last sample used (-1: none)
    ("s", "c16"),  # window integral of the relative velocity (m)
    ("w_prev", "c16"),
    # moments of the window's points for the Kasa fit (circle_add, circle_fit)
    ("n", "i8"), ("sx", "f8"), ("sy", "f8"), ("sxx", "f8"), ("sxy", "f8"), ("syy", "f8"),
    ("sxq", "f8"), ("syq", "f8"), ("sq", "f8"), ("sqq", "f8"),
    ("rot", "f8"),  # |omega_hat| integrated over the window (rad)
    ("t0", "i8"),  # first tick of the window
    ("windows", "i8"),  # accepted circle-fit windows
    ("rejected", "i8"),  # windows closed without an accepted fit
    ("omega_fit", "f8"),  # omega over the last third of the last accepted window (rad/s)
])
"""One pair estimator's state (one neighbour of one agent)."""

PAIR_PRM = np.dtype([
    ("dt", "f8"),  # the estimator's tick (s): window spans and omega_fit
    ("arc", "f8"),  # arc a window must cover (rad)
    ("min_ticks", "i8"),
    ("max_ticks", "i8"),
    ("check", "i8"),  # a fit is tried every check-th sample of a window
    ("max_gap", "i8"),  # a longer gap restarts the window
    ("noise2", "f8"),  # variance of each component of v_Ci - v_Cj (2 sigma_v^2)
    ("gate2", "f8"),  # axis form: gate on (|omega| |z|)^2
    ("axis", "b1"),  # angle measurement: the axis form (EstimatorSpec.angle_meas = "axis")
])
"""The pair estimator's parameters, one row per agent (the same for all its pairs)."""


def pair_checkpoints(fit_min_ticks: int, fit_max_ticks: int, fit_check_ticks: int) -> int:
    """C: checkpoints a window can hold. A window is closed at the first checkpoint with wn >= min_ticks and
    t - t0 >= max_ticks (accepted or rejected), and t - t0 >= wn - 1, so wn < max(min, max + 1) + check."""
    return (max(fit_max_ticks, fit_min_ticks) + fit_check_ticks + 1) // fit_check_ticks + 2


def pair_bank(B: int, D: int, C: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fresh state (P, cps) and zeroed parameters prm for B agents of up to D pairs each."""
    P = np.zeros((B, D), PAIR)
    P["last_t"] = -1
    return P, np.zeros((B, D, C), np.complex128), np.zeros(B, PAIR_PRM)


def set_pair_params(
    P: np.ndarray,
    prm: np.ndarray,
    b: int,
    *,
    dt: float,
    sigma_v: float,
    fit_arc: float,
    fit_min_ticks: int,
    fit_max_ticks: int,
    fit_check_ticks: int,
    max_gap_ticks: int,
    angle_walk: float,
    gate_snr: float,
    angle_meas: str = "linear",
) -> None:
    """Agent b's parameters (EstimatorSpec's names) into ``prm[b]`` and its pairs' ``q``."""
    if angle_meas not in ("linear", "axis"):
        raise ValueError(f"angle_meas must be 'linear' or 'axis', got {angle_meas!r}")
    noise2 = 2.0 * sigma_v * sigma_v
    prm[b] = (dt, fit_arc, fit_min_ticks, fit_max_ticks, fit_check_ticks, max_gap_ticks, noise2,
              gate_snr * gate_snr * noise2, angle_meas == "axis")
    P["q"][b] = angle_walk * angle_walk * dt


# ------------------------------------------------------------------------------------------- circle fit
@jit
def solve3(
    a00: float, a01: float, a02: float, b0: float,
    a10: float, a11: float, a12: float, b1: float,
    a20: float, a21: float, a22: float, b2: float,
) -> tuple[bool, float, float, float]:
    """3x3 Gaussian elimination with partial pivoting on scalars, unrolled: (ok, x0, x1, x2), ok False if singular.

    The operations and their order are those of the textbook loop (pivot = the first row with the
    largest |entry|, a row is only updated when its factor is non-zero), so results are bit for bit
    those of the loop; entries below the pivot are not written since nothing reads them again.
    """
    # the loop's max(|a_ij|): the first of equal values, a NaN kept only where it comes first (explicit
    # steps: Python's max semantics, whatever a compiled max does with NaN)
    scale = abs(a00)
    for v in (abs(a01), abs(a02), abs(a10), abs(a11), abs(a12), abs(a20), abs(a21), abs(a22)):
        if v > scale:
            scale = v
    if scale == 0.0:
        scale = 1.0
    tol = 1e-13 * scale
    # column 0
    p = 0
    best = abs(a00)
    v = abs(a10)
    if v > best:
        p = 1
        best = v
    v = abs(a20)
    if v > best:
        p = 2
        best = v
    if best <= tol:
        return False, 0.0, 0.0, 0.0
    if p == 1:
        a00, a01, a02, b0, a10, a11, a12, b1 = a10, a11, a12, b1, a00, a01, a02, b0
    elif p == 2:
        a00, a01, a02, b0, a20, a21, a22, b2 = a20, a21, a22, b2, a00, a01, a02, b0
    f = a10 / a00
    if f != 0.0:
        a11 -= f * a01
        a12 -= f * a02
        b1 -= f * b0
    f = a20 / a00
    if f != 0.0:
        a21 -= f * a01
        a22 -= f * a02
        b2 -= f * b0
    # column 1
    if abs(a21) > abs(a11):
        if abs(a21) <= tol:
            return False, 0.0, 0.0, 0.0
        a11, a12, b1, a21, a22, b2 = a21, a22, b2, a11, a12, b1
    elif abs(a11) <= tol:
        return False, 0.0, 0.0, 0.0
    f = a21 / a11
    if f != 0.0:
        a22 -= f * a12
        b2 -= f * b1
    # column 2
    if abs(a22) <= tol:
        return False, 0.0, 0.0, 0.0
    x2 = b2 / a22
    x1 = (b1 - a12 * x2) / a11
    x0 = (b0 - a01 * x1 - a02 * x2) / a00
    return True, x0, x1, x2


@jit
def circle_reset(P: np.ndarray, b: int, k: int) -> None:
    """Empty the moments of pair (b, k)."""
    pr = P[b, k]
    pr["n"] = 0
    pr["sx"] = pr["sy"] = pr["sxx"] = pr["sxy"] = pr["syy"] = 0.0
    pr["sxq"] = pr["syq"] = pr["sq"] = pr["sqq"] = 0.0


@jit
def circle_add(P: np.ndarray, b: int, k: int, x: float, y: float) -> None:
    """Add the point (x, y) to the moments of pair (b, k)."""
    pr = P[b, k]
    q = x * x + y * y
    pr["n"] = int(pr["n"]) + 1
    pr["sx"] = float(pr["sx"]) + x
    pr["sy"] = float(pr["sy"]) + y
    pr["sxx"] = float(pr["sxx"]) + x * x
    pr["sxy"] = float(pr["sxy"]) + x * y
    pr["syy"] = float(pr["syy"]) + y * y
    pr["sxq"] = float(pr["sxq"]) + x * q
    pr["syq"] = float(pr["syq"]) + y * q
    pr["sq"] = float(pr["sq"]) + q
    pr["sqq"] = float(pr["sqq"]) + q * q


@jit
def circle_fit(P: np.ndarray, b: int, k: int) -> tuple[bool, float, float, float, float]:
    """Algebraic (Kasa) circle fit from the moments of pair (b, k): (ok, centre x, centre y, radius, rms).

    Minimises sum (x^2 + y^2 + D x + E y + F)^2, which is linear in (D, E, F); centre = -(D, E)/2,
    r^2 = (D^2 + E^2)/4 - F. With points spread over a large arc and small noise this is close to the
    geometric fit; the callers only accept windows covering a large arc. ok is False with fewer than 3
    points or degenerate ones.
    """
    pr = P[b, k]
    n = int(pr["n"])
    if n < 3:
        return False, 0.0, 0.0, 0.0, 0.0
    sx = float(pr["sx"])
    sy = float(pr["sy"])
    sxx = float(pr["sxx"])
    sxy = float(pr["sxy"])
    syy = float(pr["syy"])
    sxq = float(pr["sxq"])
    syq = float(pr["syq"])
    sq = float(pr["sq"])
    sqq = float(pr["sqq"])
    ok, d, e, f = solve3(sxx, sxy, sx, -sxq, sxy, syy, sy, -syq, sx, sy, float(n), -sq)
    if not ok:
        return False, 0.0, 0.0, 0.0, 0.0
    r2 = 0.25 * (d * d + e * e) - f
    if not r2 > 0.0:
        return False, 0.0, 0.0, 0.0, 0.0
    # mean squared algebraic residual, expanded from the moments: sum (q + D x + E y + F)^2 / n; the
    # algebraic residual is about 2 r times the radial one
    res = (
        sqq
        + d * d * sxx
        + e * e * syy
        + f * f * n
        + 2.0 * d * sxq
        + 2.0 * e * syq
        + 2.0 * f * sq
        + 2.0 * d * e * sxy
        + 2.0 * d * f * sx
        + 2.0 * e * f * sy
    ) / n
    r = sqrt(r2)
    if 0.0 > res:  # max(res, 0.0): a NaN stays
        res = 0.0
    return True, -0.5 * d, -0.5 * e, r, sqrt(res) / (2.0 * r)


# ----------------------------------------------------------------------------------------- pair estimator
@jit
def pair_predict(P: np.ndarray, b: int, k: int, rot: complex) -> None:
    """Advance pair (b, k) one tick: rotate by ``rot`` = e^{i omega_hat dt}; the angle uncertainty grows."""
    pr = P[b, k]
    if pr["ready"]:
        pr["z"] = complex(pr["z"]) * rot
        pr["p"] = float(pr["p"]) + float(pr["q"])


@jit
def pair_restart(P: np.ndarray, cps: np.ndarray, b: int, k: int, w: complex, t: int) -> None:
    """Re-anchor pair (b, k)'s window at the current sample (s := 0) so the integrated noise restarts."""
    pr = P[b, k]
    pr["s"] = 0j
    pr["w_prev"] = w
    circle_reset(P, b, k)
    circle_add(P, b, k, 0.0, 0.0)
    cps[b, k, 0] = 0j
    pr["rot"] = 0.0
    pr["t0"] = t


@jit
def pair_sample(
    P: np.ndarray, cps: np.ndarray, prm: np.ndarray, b: int, k: int, t: int, w: complex, back: complex, om: float,
    dt: float,
) -> None:
    """Use the relative velocity ``w`` = v_Ci - v_Cj measured at tick ``t`` (ticks strictly increasing).

    ``back`` rotates the state-tick estimate back to tick t (1 when t is the state tick), ``om`` is
    omega_hat, ``dt`` the step of the integral.
    """
    pr = P[b, k]
    pm = prm[b]
    last = int(pr["last_t"])
    pr["last_t"] = t
    if last < 0 or t - last > int(pm["max_gap"]):
        pair_restart(P, cps, b, k, w, t)
    else:
        gap = t - last - 1
        s = complex(pr["s"])
        wp = complex(pr["w_prev"])
        if gap > 0:
            # lost samples: bridge the integral with the model's relative velocity i*omega*z
            if pr["ready"]:
                wp = 1j * om * complex(pr["z"]) * back
            s += gap * dt * wp
            pr["rot"] = float(pr["rot"]) + abs(om) * dt * (gap + 1)
        else:
            pr["rot"] = float(pr["rot"]) + abs(om) * dt  # (gap + 1) == 1: the product is exact without it
        s += 0.5 * dt * (wp + w)
        pr["s"] = s
        pr["w_prev"] = w
        circle_add(P, b, k, s.real, s.imag)
        wn = int(pr["n"])  # points in the window
        check = int(pm["check"])
        if not (wn - 1) % check:
            c = (wn - 1) // check
            if c >= cps.shape[2]:
                raise IndexError("pair_sample: more checkpoints than pair_checkpoints() allows")
            cps[b, k, c] = s
            # solve the fit only when the window may have covered the arc (omega_hat says so), or at every
            # checkpoint while omega_hat is not known yet (bootstrap)
            if wn >= int(pm["min_ticks"]) and (
                om == 0.0 or float(pr["rot"]) >= 0.8 * float(pm["arc"]) or t - int(pr["t0"]) >= int(pm["max_ticks"])
            ):
                pair_try_fit(P, cps, prm, b, k, back, t)
    if not pr["ready"]:
        return
    if pm["axis"]:
        # the original form (EstimatorSpec.angle_meas = "axis"): the normalised axis perp(w), sign
        # nearest the prediction, gated at |omega_hat| |z_ij| >= gate_snr sigma sqrt(2)
        r = float(pr["r"])
        sig2 = om * om * r * r  # (|omega| |z|)^2
        if sig2 < float(pm["gate2"]) or sig2 <= 0.0:
            return
        z = complex(pr["z"])
        zt = z * back
        wr = w.real
        wi = w.imag
        ztr = zt.real
        zti = zt.imag
        cr = zti * wr - ztr * wi
        ci = ztr * wr + zti * wi
        if cr < 0.0:
            cr = -cr
            ci = -ci
        mag = sqrt(cr * cr + ci * ci)
        if mag <= 0.0:
            return
        p = float(pr["p"])
        g = p / (p + float(pm["noise2"]) / sig2)
        pr["p"] = p - g * p
        z = z * complex(1.0, g * ci / mag)
        pr["z"] = z * (r / abs(z))
        return
    # Result 1, linear form: w / z_ij = i omega e^{i delta} for an angle error delta of the prediction, so
    # the radial part -Re(w / zt) = omega sin(delta) (+ noise of variance 2 sigma^2 / |z|^2, zero-mean)
    # measures the angle error without normalising w or picking a sign: no gate, the weight goes to 0
    # with omega_hat
    if om == 0.0:
        return
    z = complex(pr["z"])
    zt = z * back
    ztr = zt.real
    zti = zt.imag
    zz = ztr * ztr + zti * zti
    if zz <= 0.0:
        return
    meas = -(w.real * ztr + w.imag * zti) / zz  # omega sin(delta)
    p = float(pr["p"])
    h = om
    g = p * h / (h * h * p + float(pm["noise2"]) / zz)
    pr["p"] = p - g * h * p
    z = z * complex(1.0, g * meas)
    pr["z"] = z * (float(pr["r"]) / abs(z))


@jit
def pair_try_fit(P: np.ndarray, cps: np.ndarray, prm: np.ndarray, b: int, k: int, back: complex, t: int) -> None:
    """At a checkpoint: fit the window's circle; accept a real arc, or close the window at max_ticks."""
    pr = P[b, k]
    pm = prm[b]
    dt = float(pm["dt"])
    t0 = int(pr["t0"])
    ok, cx, cy, radius, rms = circle_fit(P, b, k)
    if ok:
        noise2 = float(pm["noise2"])
        span = (t - t0) * dt  # elapsed time, not samples: some may be missing
        # accept only a real arc: large enough, radius well above the integrated noise of the window and
        # mean tangential speed above the per-sample noise (rejects noise curls). The two radius gates go
        # first: they are O(1), the arc costs an atan2 per checkpoint.
        if radius > 4.0 * rms and radius * radius > 16.0 * noise2 * dt * span:
            nseg = (int(pr["n"]) - 1) // int(pm["check"])  # checkpoints - 1
            third = nseg // 3
            recent_from = nseg - (third if third > 1 else 1)
            # sum of the angles between consecutive checkpoints seen from the centre; segments k >
            # recent_from also add to arc_recent
            arc = 0.0
            p0 = complex(cps[b, k, 0])
            px = p0.real - cx
            py = p0.imag - cy
            for i in range(1, recent_from + 1):
                cur = complex(cps[b, k, i])
                qx = cur.real - cx
                qy = cur.imag - cy
                arc += atan2(px * qy - py * qx, px * qx + py * qy)
                px = qx
                py = qy
            arc_recent = 0.0
            for i in range(recent_from + 1, nseg + 1):
                cur = complex(cps[b, k, i])
                qx = cur.real - cx
                qy = cur.imag - cy
                da = atan2(px * qy - py * qx, px * qx + py * qy)
                arc += da
                arc_recent += da
                px = qx
                py = qy
            if abs(arc) >= float(pm["arc"]) and pow_libm(radius * abs(arc) / span, 2.0) >= noise2:
                pair_accept(P, cps, prm, b, k, cx, cy, radius, rms, arc_recent, nseg, recent_from, back, t)
                return
    if t - t0 >= int(pm["max_ticks"]):
        pr["rejected"] = int(pr["rejected"]) + 1
        pair_restart(P, cps, b, k, complex(pr["w_prev"]), t)


@jit
def pair_accept(
    P: np.ndarray, cps: np.ndarray, prm: np.ndarray, b: int, k: int, cx: float, cy: float, radius: float,
    rms: float, arc_recent: float, nseg: int, recent_from: int, back: complex, t: int,
) -> None:
    """An accepted window: update |z_ij|, omega_fit and the angle of z_ij, then re-anchor."""
    pr = P[b, k]
    pm = prm[b]
    dt = float(pm["dt"])
    weight = 1.0 / (rms * rms + 1e-12)
    rw = float(pr["rw"]) + weight
    rsum = float(pr["rsum"]) + weight * radius
    r = rsum / rw
    pr["rw"] = rw
    pr["rsum"] = rsum
    pr["r"] = r
    pr["windows"] = int(pr["windows"]) + 1
    # rate over the last third of the window: a spin-up is accelerating, and the window mean would seed
    # omega_hat well below the current rate
    span = t - int(pr["t0"])
    pr["omega_fit"] = arc_recent / ((nseg - recent_from) * int(pm["check"]) * dt) * (
        int(pr["n"]) / (span if span > 1 else 1)
    )
    z_t = complex(pr["s"]) - complex(cx, cy)  # z_ij at the sample tick, sign included (integral form)
    r_fit = 2.0 * pow_libm(rms / radius, 2.0) + 1e-6  # angle variance of z_t (rad^2)
    m = abs(z_t)
    if m > 0.0:
        zt = complex(pr["z"]) * back
        if pr["ready"]:
            # the window's own position is an angle measurement too; a large disagreement means the
            # tracker lost lock: re-anchor on the fit
            cr = zt.real * z_t.real + zt.imag * z_t.imag
            ci = zt.real * z_t.imag - zt.imag * z_t.real
            h = abs(complex(cr, ci))
            if cr > 0.0 and abs(ci) < 0.5 * h:
                p = float(pr["p"])
                g = p / (p + r_fit)
                pr["p"] = p - g * p
                zt *= complex(1.0, g * ci / h)
                pr["z"] = zt / back * (r / abs(zt))
            else:
                pr["z"] = z_t / back * (r / m)
                pr["p"] = r_fit + 1e-3
        else:
            pr["z"] = z_t / back * (r / m)
            pr["p"] = r_fit + 1e-3
            pr["ready"] = True
    pair_restart(P, cps, b, k, complex(pr["w_prev"]), t)


@register_warm
def warm() -> None:
    """Compile every kernel of this module on a 1 x 1 bank."""
    P, cps, prm = pair_bank(1, 1, 4)
    set_pair_params(P, prm, 0, dt=0.01, sigma_v=0.1, fit_arc=1.0, fit_min_ticks=2, fit_max_ticks=4,
                    fit_check_ticks=2, max_gap_ticks=3, angle_walk=0.1, gate_snr=1.0)
    pair_sample(P, cps, prm, 0, 0, 0, 1j, 1 + 0j, 0.0, 0.01)
    pair_sample(P, cps, prm, 0, 0, 1, 1j, 1 + 0j, 0.0, 0.01)
    pair_predict(P, 0, 0, 1 + 0j)
    circle_add(P, 0, 0, 1.0, 0.0)
    circle_fit(P, 0, 0)
    solve3(1.0, 0.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 1.0, 1.0)
