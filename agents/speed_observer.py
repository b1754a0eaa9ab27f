"""Immersion-and-invariance speed observer for Euler-Lagrange systems with bounded inertia (paper 004).

The plant is M(q) q'' + C(q, q') q' + G(q) = u with y = q measured and x = q' not. The observer
(paper 004 eqs. 3-55, rederived in docs/speed-observer.md) has the states

* xi  (n): the I&I state; the speed estimate is x_hat = xi + beta(y, s_y, s_x),
* s_y (n): filtered positions, s_x (n): filtered speeds (the observer's smoothed outputs),
* r   (1): the dynamic scaling that dominates the error of the approximate PDE solution beta.

Why this shape:

* beta (eq. 12) is a sum of n line integrals of the columns of H(y, x) = M(y)^-1 (k1 I - C(y, x))
  (eq. 11) with every coordinate but the integrated one replaced by s_y. The integrals, and those of
  the partial derivatives (14)-(15), are evaluated by one vectorised Gauss-Legendre rule of fixed
  order (one batched M/C evaluation per right-hand side), or by a caller-supplied closed form.
  For a coordinate whose H is periodic (a revolute joint: period 2 pi) the integral over whole
  periods is split off and done with the trapezoidal rule (spectrally exact for smooth periodic
  integrands), so the cost and accuracy do not degrade as a joint winds up.
* dH/ds_x is exact and free: C is linear in its second argument (P3), so dH/ds_x,l = -M^-1 C(y, e_l).
  dH/dy (for eq. 14) is a central finite difference unless a closed form is given.
* Bounds: M Delta_x = C(y, e_x) exactly (Lemma 1 with P3), so ||M Delta_x|| <= k_c ||e_x||; the
  Lemma-2 constant for Delta_y is built at construction from sampled suprema of dM^-1/dy and
  d(M^-1 C(., e_l))/dy over the configuration box (the paper's "sum of suprema of the terms").
* The core is a pure continuous-time right-hand side ``rhs(obs, y, u)`` (no t: the observer is
  time-invariant) so that a simulation can integrate plant and observer as one ODE with an
  error-controlled solver, plus a pure ``step(state, y, u, dt)`` (RK4, y linearly interpolated
  between the previous and the new encoder sample) for an agent that only sees sampled encoders.
* Properties P1-P5 are checked numerically at construction on points drawn from a seeded
  Generator; a violation raises :class:`PropertyViolation` naming the property and the point.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

Array = np.ndarray
# Batched model callables: q of shape (..., n) -> M (..., n, n); (q, x) -> C (..., n, n); q -> G (..., n).
MFn = Callable[[Array], Array]
CFn = Callable[[Array, Array], Array]
GFn = Callable[[Array], Array]


class PropertyViolation(ValueError):
    """A model that breaks one of P1-P5 (paper 004 Sec. II-A); names the property and the point."""

    def __init__(self, prop: str, message: str, q: Array | None = None, detail: dict | None = None) -> None:
        self.prop = prop
        self.q = None if q is None else np.asarray(q, dtype=float)
        self.detail = detail or {}
        where = "" if q is None else f" at q={np.array2string(self.q, precision=6)}"
        super().__init__(f"{prop} violated{where}: {message}")


@dataclass(frozen=True)
class ELModel:
    """An n-dof Euler-Lagrange plant with the constants of P1 and P4.

    k_m, k_M: P1 bounds k_m I <= M(q) <= k_M I; k_c: P4 bound ||C(q, x)|| <= k_c ||x||.
    q_low, q_high: the configuration box that covers every q the plant can reach up to periods
    (used to sample the property checks and the Lemma-2 suprema). periods[i]: period of M, C in q_i
    (2 pi for a revolute joint, None for prismatic/aperiodic).
    """

    n: int
    M: MFn
    C: CFn
    G: GFn
    k_m: float
    k_M: float
    k_c: float
    q_low: tuple[float, ...]
    q_high: tuple[float, ...]
    periods: tuple[float | None, ...] = ()

    def __post_init__(self) -> None:
        if not self.periods:
            object.__setattr__(self, "periods", (None,) * self.n)
        if len(self.q_low) != self.n or len(self.q_high) != self.n or len(self.periods) != self.n:
            raise ValueError(f"q_low, q_high, periods must have length n={self.n}")
        if not 0 < self.k_m <= self.k_M or self.k_c < 0:
            raise ValueError(f"need 0 < k_m <= k_M and k_c >= 0 (got {self.k_m}, {self.k_M}, {self.k_c})")


@dataclass(frozen=True)
class Gains:
    """k1 > 4: rate of the ideal error dynamics (eq. 10; > 4 for eq. 55); k2, k3 > 0: extra damping of
    e_y, e_x in psi1, psi2 (eqs. 53-54); c_r > 0: lower bound of r (eq. 38)."""

    k1: float = 40.0
    k2: float = 8.0
    k3: float = 25.0
    c_r: float = 1e-3

    def __post_init__(self) -> None:
        if self.k1 <= 4:
            raise ValueError(f"k1 must exceed 4 (eq. 55 needs k1/4 - 1 > 0), got {self.k1}")
        if self.k2 <= 0 or self.k3 <= 0 or self.c_r <= 0:
            raise ValueError("k2, k3 and c_r must be positive")


@dataclass(frozen=True)
class ClosedForm:
    """beta and its partials in closed form, (y, s_y, s_x) -> value; replaces the quadrature."""

    beta: Callable[[Array, Array, Array], Array]
    dbeta_dy: Callable[[Array, Array, Array], Array]
    dbeta_dsy: Callable[[Array, Array, Array], Array]
    dbeta_dsx: Callable[[Array, Array, Array], Array]


@dataclass(frozen=True)
class ObserverState:
    """Observer state for the sampled ``step``; ``y`` is the encoder sample the state belongs to."""

    xi: Array
    s_y: Array
    s_x: Array
    r: float
    y: Array

    def vector(self) -> Array:
        return np.concatenate([self.xi, self.s_y, self.s_x, [self.r]])


@dataclass(frozen=True)
class Terms:
    """Every intermediate of one right-hand side evaluation (for plots, tests and diagnostics)."""

    x_hat: Array
    beta: Array
    dbeta_dy: Array
    dbeta_dsy: Array
    dbeta_dsx: Array
    e_y: Array
    e_x: Array
    psi1: float
    psi2: float
    norm_MDy: float
    norm_MDx: float
    lemma2_L: float
    deriv: Array = field(repr=False)


def _fd_step(scale: float) -> float:
    return 1e-5 * (1.0 + scale)


# --------------------------------------------------------------------------------------------------
# Property checks (P1-P5)


def check_properties(model: ELModel, rng: np.random.Generator, samples: int = 128, speed_scale: float = 10.0) -> dict:
    """Check P1-P5 on ``samples`` configurations drawn from ``rng``; raise PropertyViolation on failure.

    Returns the worst residual of each property (relative), for reporting.
    """
    n = model.n
    lo, hi = np.asarray(model.q_low, float), np.asarray(model.q_high, float)
    Q = rng.uniform(lo, hi, size=(samples, n))
    X = rng.normal(scale=speed_scale, size=(samples, n))
    Z = rng.normal(scale=speed_scale, size=(samples, n))
    a, b = rng.normal(size=(2, samples, 1))
    M = np.asarray(model.M(Q), float)
    if M.shape != (samples, n, n):
        raise PropertyViolation("P1", f"M(q) must return shape (..., {n}, {n}) for batched q, got {M.shape}")
    worst: dict[str, float] = {}
    # P1: symmetric, eigenvalues in [k_m, k_M].
    asym = np.abs(M - np.swapaxes(M, -1, -2)).max(axis=(-1, -2)) / (1 + np.abs(M).max(axis=(-1, -2)))
    i = int(np.argmax(asym))
    if asym[i] > 1e-9:
        raise PropertyViolation("P1 (M symmetric)", f"M(q) is not symmetric: {M[i].tolist()}", Q[i])
    lam = np.linalg.eigvalsh(M)
    i = int(np.argmin(lam[:, 0]))
    if lam[i, 0] < model.k_m * (1 - 1e-9):
        raise PropertyViolation("P1 (k_m I <= M(q))", f"lambda_min(M) = {lam[i, 0]:.6g} < k_m = {model.k_m:.6g}", Q[i])
    i = int(np.argmax(lam[:, -1]))
    if lam[i, -1] > model.k_M * (1 + 1e-9):
        raise PropertyViolation("P1 (M(q) <= k_M I)", f"lambda_max(M) = {lam[i, -1]:.6g} > k_M = {model.k_M:.6g}", Q[i])
    worst["P1_lambda_min"] = float(lam[:, 0].min())
    worst["P1_lambda_max"] = float(lam[:, -1].max())

    def mv(Mat: Array, v: Array) -> Array:
        return np.einsum("...ij,...j->...i", Mat, v)

    CX = np.asarray(model.C(Q, X), float)
    CZ = np.asarray(model.C(Q, Z), float)
    if CX.shape != (samples, n, n):
        raise PropertyViolation("P2", f"C(q, x) must return shape (..., {n}, {n}) for batched q, x, got {CX.shape}")
    scale = 1 + np.linalg.norm(X, axis=-1) * np.linalg.norm(Z, axis=-1)
    # P2: C(q, x) z = C(q, z) x.
    res = np.linalg.norm(mv(CX, Z) - mv(CZ, X), axis=-1) / scale
    i = int(np.argmax(res))
    worst["P2"] = float(res[i])
    if res[i] > 1e-9:
        raise PropertyViolation(
            "P2 (C(q,x)z = C(q,z)x)",
            f"x={X[i].tolist()}, z={Z[i].tolist()}: C(q,x)z={mv(CX, Z)[i].tolist()} != C(q,z)x={mv(CZ, X)[i].tolist()}",
            Q[i],
        )
    # P3: C linear in its second argument.
    lin = np.asarray(model.C(Q, a * X + b * Z), float)
    res = np.abs(lin - a[..., None] * CX - b[..., None] * CZ).max(axis=(-1, -2)) / scale
    i = int(np.argmax(res))
    worst["P3"] = float(res[i])
    if res[i] > 1e-9:
        raise PropertyViolation("P3 (C linear in its 2nd argument)", f"x1={X[i].tolist()}, x2={Z[i].tolist()}: residual {res[i]:.3g}", Q[i])
    # P4: ||C(q, x)|| <= k_c ||x||.
    ratio = np.linalg.norm(CX, ord=2, axis=(-2, -1)) / np.linalg.norm(X, axis=-1)
    i = int(np.argmax(ratio))
    worst["P4_ratio"] = float(ratio[i])
    if ratio[i] > model.k_c * (1 + 1e-9):
        raise PropertyViolation("P4 (||C(q,x)|| <= k_c ||x||)", f"x={X[i].tolist()}: ||C||/||x|| = {ratio[i]:.6g} > k_c = {model.k_c:.6g}", Q[i])
    # P5: M_dot = C + C^T (directional central difference of M along x).
    U = X / np.linalg.norm(X, axis=-1, keepdims=True)
    h = 1e-5
    Mdot = (np.asarray(model.M(Q + h * U)) - np.asarray(model.M(Q - h * U))) / (2 * h)
    CU = np.asarray(model.C(Q, U), float)
    sym = CU + np.swapaxes(CU, -1, -2)
    res = np.abs(Mdot - sym).max(axis=(-1, -2)) / (1 + np.abs(Mdot).max(axis=(-1, -2)))
    i = int(np.argmax(res))
    worst["P5"] = float(res[i])
    if res[i] > 1e-6:
        raise PropertyViolation(
            "P5 (M_dot = C + C^T)",
            f"along q_dot={U[i].round(6).tolist()}: M_dot={Mdot[i].round(6).tolist()} but C+C^T={sym[i].round(6).tolist()}"
            " (is the Coriolis matrix built from the Christoffel symbols, with the right sign?)",
            Q[i],
        )
    # Equivalent skew-symmetry of M_dot - 2C, reported for the docs.
    worst["skew_Mdot_minus_2C"] = float(np.abs((Mdot - 2 * CU) + np.swapaxes(Mdot - 2 * CU, -1, -2)).max())
    return worst


# --------------------------------------------------------------------------------------------------
# The observer


class SpeedObserver:
    """I&I speed observer of paper 004 for a given :class:`ELModel` (see module docstring).

    ``nodes``: Gauss-Legendre order per integral (and trapezoid nodes per full period).
    ``seed``: seeds the Generator used for the P1-P5 checks and the Lemma-2 suprema.
    ``lemma2_bound``: optional s_x -> L with ||Delta_y|| <= L ||e_y|| (replaces the sampled one).
    """

    def __init__(
        self,
        model: ELModel,
        gains: Gains = Gains(),
        *,
        nodes: int = 16,
        closed_form: ClosedForm | None = None,
        dH_dy: Callable[[Array, Array], Array] | None = None,
        seed: int = 0,
        check_samples: int = 128,
        lemma2_samples: int = 2048,
        lemma2_margin: float = 0.05,
        lemma2_bound: Callable[[Array], float] | None = None,
        check: bool = True,
    ) -> None:
        self.model, self.gains, self.n = model, gains, model.n
        self.closed_form, self.dH_dy_fn = closed_form, dH_dy
        rng = np.random.default_rng(seed)
        self.property_residuals = check_properties(model, rng, check_samples) if check else {}
        self.nodes = int(nodes)
        gl_x, gl_w = np.polynomial.legendre.leggauss(self.nodes)
        self._gl_x, self._gl_w = gl_x, gl_w
        self._periodic = np.array([p is not None for p in model.periods])
        self._period = np.array([p if p is not None else 0.0 for p in model.periods], float)
        self._K = 2 * self.nodes if self._periodic.any() else self.nodes
        self._lemma2_bound = lemma2_bound
        if lemma2_bound is None:
            self._a, self._b = self._lemma2_suprema(rng, lemma2_samples, 1 + lemma2_margin)

    # -- model pieces -------------------------------------------------------------------------------

    def H(self, q: Array, x: Array) -> Array:
        """H(q, x) = M(q)^-1 (k1 I - C(q, x)) (eq. 11), batched over leading axes."""
        n = self.n
        A = self.gains.k1 * np.eye(n) - np.asarray(self.model.C(q, np.broadcast_to(x, np.shape(q))), float)
        return np.linalg.solve(np.asarray(self.model.M(q), float), A)

    def _dH_dy(self, q: Array, x: Array) -> Array:
        """dH/dq_k stacked on a new axis -3: (..., n, n, n) with index [..., k, row, col]."""
        if self.dH_dy_fn is not None:
            return np.asarray(self.dH_dy_fn(q, x), float)
        n = self.n
        h = _fd_step(float(np.max(np.abs(q)))) if np.size(q) else 1e-5
        E = np.eye(n) * h
        qp = q[..., None, :] + E  # (..., n(k), n)
        qm = q[..., None, :] - E
        xb = np.broadcast_to(np.asarray(x)[..., None, :], qp.shape)
        return (self.H(qp, xb) - self.H(qm, xb)) / (2 * h)

    def _lemma2_suprema(self, rng: np.random.Generator, samples: int, factor: float) -> tuple[Array, Array]:
        """Sampled suprema over the configuration box of |k1 dM^-1/dq_k| (a) and |d(M^-1 C(., e_l))/dq_k| (b).

        dH_ji/dq_k(q, s_x) = a-term + sum_l s_x,l b-term (H is affine in s_x by P3), so
        sup_q |dH_ji/dq_k| <= a[j,i,k] + sum_l b[j,i,k,l] |s_x,l|  (Lemma 2's R_ij, paper Sec. III).
        """
        n, k1 = self.n, self.gains.k1
        Q = rng.uniform(self.model.q_low, self.model.q_high, size=(samples, n))
        zero = np.zeros((samples, n))
        dA = self._dH_dy(Q, zero)  # (S, k, j, i): derivative of k1 M^-1
        a = np.abs(dA).max(axis=0).transpose(1, 2, 0)  # [j, i, k]
        b = np.empty((n, n, n, n))
        for l in range(n):
            e = np.zeros((samples, n))
            e[:, l] = 1.0
            dB = dA - self._dH_dy(Q, e)  # d(M^-1 C(q, e_l))/dq_k
            b[..., l] = np.abs(dB).max(axis=0).transpose(1, 2, 0)
        del k1
        return a * factor, b * factor

    def lemma2_L(self, s_x: Array) -> float:
        """L(s_x) with ||Delta_y(y, s_y, s_x)|| <= L ||e_y|| (Lemma 2, Frobenius bound of eq. 27)."""
        if self._lemma2_bound is not None:
            return float(self._lemma2_bound(s_x))
        R = self._a + np.einsum("jikl,l->jik", self._b, np.abs(s_x))  # [j, i, k]
        mask = 1.0 - np.eye(self.n)[None, :, :]  # column i does not depend on e_i
        return float(np.sqrt(np.sum((R * mask) ** 2)))

    # -- beta and its partial derivatives (eqs. 12-15) ----------------------------------------------

    def _nodes(self, y: Array, s_y: Array) -> tuple[Array, Array]:
        """Quadrature points (n, K, n) and weights (n, K) for the n line integrals of eq. (12)."""
        n, m, K = self.n, self.nodes, self._K
        pts = np.broadcast_to(s_y, (n, K, n)).copy()
        w = np.zeros((n, K))
        for i in range(n):
            yi, P = float(y[i]), self._period[i]
            if self._periodic[i]:
                k = math.floor(yi / P + 0.5)
                rho = yi - k * P
                pts[i, m:, i] = P * np.arange(m) / m
                w[i, m:] = k * P / m
            else:
                rho = yi
            pts[i, :m, i] = 0.5 * rho * (self._gl_x + 1.0)
            w[i, :m] = 0.5 * rho * self._gl_w
        return pts, w

    def beta_terms(self, y: Array, s_y: Array, s_x: Array) -> tuple[Array, Array, Array, Array]:
        """beta (12), dbeta/dy (13), dbeta/ds_y (14), dbeta/ds_x (15) at (y, s_y, s_x)."""
        cf = self.closed_form
        if cf is not None:
            return (np.asarray(cf.beta(y, s_y, s_x), float), np.asarray(cf.dbeta_dy(y, s_y, s_x), float),
                    np.asarray(cf.dbeta_dsy(y, s_y, s_x), float), np.asarray(cf.dbeta_dsx(y, s_y, s_x), float))
        n = self.n
        idx = np.arange(n)
        pts, w = self._nodes(y, s_y)
        Mq = np.asarray(self.model.M(pts), float)  # (n, K, n, n)
        Cs = np.asarray(self.model.C(pts, np.broadcast_to(s_x, pts.shape)), float)
        Minv_A = np.linalg.solve(Mq, np.concatenate([self.gains.k1 * np.eye(n) - Cs] + [
            np.asarray(self.model.C(pts, np.broadcast_to(np.eye(n)[l], pts.shape)), float) for l in range(n)
        ], axis=-1))  # (n, K, n, n(1+n)): H and M^-1 C(., e_l) side by side
        Hq = Minv_A[..., :n]
        # column i of H on the i-th path: (n_i, K, n_rows)
        Hcol = Hq[idx, :, :, idx]
        beta = np.einsum("ik,ikr->r", w, Hcol)
        dsx = np.empty((n, n))
        for l in range(n):
            MC = Minv_A[..., n * (l + 1): n * (l + 2)]
            dsx[:, l] = -np.einsum("ik,ikr->r", w, MC[idx, :, :, idx])
        # dbeta/dy: column i = H_i at (y_i, s_y without i)
        ends = np.broadcast_to(s_y, (n, n)).copy()
        ends[idx, idx] = y
        dy = self.H(ends, s_x)[idx, :, idx].T
        # dbeta/ds_y,k = sum_{i != k} int dH_i/dq_k
        dH = self._dH_dy(pts, np.broadcast_to(s_x, pts.shape))  # (n_i, K, k, rows, cols)
        dHcol = dH[idx, :, :, :, idx]  # (n_i, K, k, rows)
        contrib = np.einsum("ik,ikcr->icr", w, dHcol)  # (i, k, rows)
        mask = 1.0 - np.eye(n)
        dsy = np.einsum("ic,icr->rc", mask, contrib)
        return beta, dy, dsy, dsx

    # -- the observer dynamics ----------------------------------------------------------------------

    def unpack(self, obs: Array) -> tuple[Array, Array, Array, float]:
        n = self.n
        return obs[:n], obs[n: 2 * n], obs[2 * n: 3 * n], float(obs[3 * n])

    def terms(self, obs: Array, y: Array, u: Array) -> Terms:
        """All quantities of one evaluation of the observer right-hand side (eqs. 6, 38, 44, 45, 53, 54)."""
        g, mdl = self.gains, self.model
        xi, s_y, s_x, r = self.unpack(np.asarray(obs, float))
        y = np.asarray(y, float)
        beta, Bq, Bsy, Bsx = self.beta_terms(y, s_y, s_x)
        x_hat = xi + beta
        My = np.asarray(mdl.M(y), float)
        acc = np.linalg.solve(My, np.asarray(u, float) - np.asarray(mdl.C(y, x_hat)) @ x_hat - np.asarray(mdl.G(y)))
        e_y, e_x = s_y - y, s_x - x_hat
        L = self.lemma2_L(s_x)
        lift = r * r / (g.k1 * mdl.k_m)
        psi1 = g.k2 + 0.5 * r * r + lift * (mdl.k_M * L) ** 2  # eq. (53)
        psi2 = g.k3 + 0.5 * r * r * np.linalg.norm(Bq, 2) ** 2 + lift * mdl.k_c**2  # eq. (54)
        a2 = x_hat - psi1 * e_y  # eq. (44)
        a3 = acc - psi2 * e_x  # eq. (45)
        a1 = acc - Bq @ x_hat - Bsy @ a2 - Bsx @ a3  # eq. (6)
        MDx = np.asarray(mdl.C(y, e_x), float)  # M Delta_x = C(y, e_x) (eq. 22)
        MDy = g.k1 * np.eye(self.n) - np.asarray(mdl.C(y, s_x), float) - My @ Bq  # M (H(y, s_x) - dbeta/dy)
        nDy, nDx = float(np.linalg.norm(MDy, 2)), float(np.linalg.norm(MDx, 2))
        rdot = -g.k1 / (4 * mdl.k_M) * (r - g.c_r) + r / (g.k1 * mdl.k_m) * (nDy**2 + nDx**2)  # eq. (38)
        deriv = np.concatenate([a1, a2, a3, [rdot]])
        return Terms(x_hat, beta, Bq, Bsy, Bsx, e_y, e_x, float(psi1), float(psi2), nDy, nDx, L, deriv)

    def rhs(self, obs: Array, y: Array, u: Array) -> Array:
        """d(obs)/dt for obs = [xi, s_y, s_x, r] given the measured y and the known input u."""
        return self.terms(obs, y, u).deriv

    def estimate(self, obs: Array, y: Array) -> Array:
        """x_hat = xi + beta(y, s_y, s_x) (eq. 3b)."""
        xi, s_y, s_x, _ = self.unpack(np.asarray(obs, float))
        return xi + self.beta_terms(np.asarray(y, float), s_y, s_x)[0]

    def initial(self, xi: Sequence[float], s_y: Sequence[float], s_x: Sequence[float], r: float) -> Array:
        obs = np.concatenate([np.asarray(xi, float), np.asarray(s_y, float), np.asarray(s_x, float), [float(r)]])
        if obs.shape != (3 * self.n + 1,):
            raise ValueError(f"xi, s_y, s_x must have length n={self.n}")
        if r <= self.gains.c_r:
            raise ValueError(f"r(0) must exceed c_r = {self.gains.c_r} (got {r})")
        return obs

    def start(self, y: Sequence[float], xi: Sequence[float], s_y: Sequence[float], s_x: Sequence[float], r: float) -> ObserverState:
        """An ObserverState for the sampled ``step``, anchored at the first encoder sample y."""
        obs = self.initial(xi, s_y, s_x, r)
        xi_, sy_, sx_, r_ = self.unpack(obs)
        return ObserverState(xi_, sy_, sx_, r_, np.asarray(y, float).copy())

    def step(self, state: ObserverState, y: Array, u: Array, dt: float) -> ObserverState:
        """One RK4 step over dt from state.y to the new encoder sample y (linear in between), u held.

        For agents that only see sampled encoders; a plant simulation should integrate ``rhs``
        together with the plant instead (error-controlled, no interpolation of y).
        """
        y0, y1 = state.y, np.asarray(y, float)
        obs = state.vector()

        def f(o: Array, s: float) -> Array:
            return self.rhs(o, y0 + s * (y1 - y0), u)

        k1 = f(obs, 0.0)
        k2 = f(obs + 0.5 * dt * k1, 0.5)
        k3 = f(obs + 0.5 * dt * k2, 0.5)
        k4 = f(obs + dt * k3, 1.0)
        new = obs + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        xi, s_y, s_x, r = self.unpack(new)
        return replace(state, xi=xi, s_y=s_y, s_x=s_x, r=max(r, self.gains.c_r), y=y1.copy())


# --------------------------------------------------------------------------------------------------
# The two-link manipulator of Sec. III


def two_link(c1: float, c2: float, c3: float, c4: float, c5: float, k_c: float | None = None) -> ELModel:
    """Two-link arm with absolute joint angles (paper 004 eqs. 56-58, Table II constants).

    M = [[c1, c2 cos(q1-q2)], [c2 cos(q1-q2), c3]], C from the Christoffel symbols
    C = [[0, c2 sin(q1-q2) x2], [-c2 sin(q1-q2) x1, 0]] (the sign that satisfies P5), G = [c4 cos q1, c5 cos q2].
    k_m, k_M = eigenvalues of M(0) (det M is smallest at q1 = q2, so these bound M globally, eq. 58);
    k_c defaults to c2 (||C(q,x)|| = c2 |sin| max|x_i| <= c2 ||x||); the paper prints c3 (>= c2, also valid).
    """

    def M(q: Array) -> Array:
        q = np.asarray(q, float)
        c = np.cos(q[..., 0] - q[..., 1])
        out = np.empty(q.shape[:-1] + (2, 2))
        out[..., 0, 0], out[..., 1, 1] = c1, c3
        out[..., 0, 1] = out[..., 1, 0] = c2 * c
        return out

    def C(q: Array, x: Array) -> Array:
        q, x = np.asarray(q, float), np.asarray(x, float)
        s = c2 * np.sin(q[..., 0] - q[..., 1])
        out = np.zeros(np.broadcast_shapes(q.shape, x.shape)[:-1] + (2, 2))
        out[..., 0, 1] = s * x[..., 1]
        out[..., 1, 0] = -s * x[..., 0]
        return out

    def G(q: Array) -> Array:
        q = np.asarray(q, float)
        return np.stack([c4 * np.cos(q[..., 0]), c5 * np.cos(q[..., 1])], axis=-1)

    lam = np.linalg.eigvalsh(np.array([[c1, c2], [c2, c3]]))
    two_pi = 2 * math.pi
    return ELModel(2, M, C, G, float(lam[0]), float(lam[1]), float(c2 if k_c is None else k_c),
                   (-math.pi, -math.pi), (math.pi, math.pi), (two_pi, two_pi))


def plant_rhs(model: ELModel, y: Array, x: Array, u: Array) -> tuple[Array, Array]:
    """(y', x') of the plant (eq. 2)."""
    acc = np.linalg.solve(np.asarray(model.M(y), float), u - np.asarray(model.C(y, x)) @ x - np.asarray(model.G(y)))
    return x, acc
