"""Cooperative H-infinity estimator design, paper 003 (Wu, Ugrinovskii, Allgöwer), pure core.

Symbols (paper's, one line each):
  A_k, B_k, B~_k, C_k  agent k of (1): x_k' = A_k x_k + B_k u_k + B~_k xi_k, y_k = C_k x_k
  a_kj                 adjacency: 1 iff agent k measures z_kj = y_j - y_k + omega eta_kj (edge j -> k)
  p_k, q_k             in-degree (measurements of k) and out-degree (estimators that also track x_k)
  x^(k), sigma_k       local estimator state [x_k; x_j1; ...; x_jp] and its dimension
  A^(k), C^(k), B~^(k) block-diagonal / relative-output matrices of estimator k
  M_j^(k), N_j^(k)     place / select the block of neighbour j inside x^(k)
  L^(k), K^(k)         gains of the local estimator (4): innovation and consensus on neighbour estimates
  P^(k), G^(k), F^(k)  LMI variables of (6); L = P^-1 G, K = P^-1 F (7)
  P11^(k)              top-left n_k x n_k block of P^(k) (agent k's own state)
  W^(k) = diag(W_k,0)  weight of the estimation error in (5)
  alpha, pi_k, omega   decay rate, coupling margins, measurement-noise weight
  gamma                H-infinity bound of (5)

Everything here is numpy/scipy/cvxpy maths on in-memory data; no files, no printing.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla
from scipy.sparse.csgraph import connected_components

from .spec import HinfSpec


class HinfDesignError(RuntimeError):
    """The design cannot be done; the message says why."""


class UndetectableError(HinfDesignError):
    """Proposition 2 fails for an independent strongly connected component."""

    def __init__(self, message: str, component: list[str]):
        super().__init__(message)
        self.component = component


class InfeasibleError(HinfDesignError):
    """The LMIs (6) have no solution (for the requested gamma, if one was fixed)."""


# ----------------------------------------------------------------------------- network


@dataclass
class Network:
    """Numeric form of a spec; agents are indexed 0..N-1 in spec order."""

    names: list[str]
    A: list[np.ndarray]
    Bt: list[np.ndarray]
    C: list[np.ndarray]
    W: list[np.ndarray]
    pi: np.ndarray
    omega: float
    alpha: float
    adj: np.ndarray  # adj[k, j] = a_kj
    B: list[np.ndarray | None] = field(default_factory=list)

    @property
    def N(self) -> int:
        return len(self.A)

    @property
    def n(self) -> list[int]:
        return [a.shape[0] for a in self.A]

    @property
    def r(self) -> int:
        return self.C[0].shape[0]

    def nbrs(self, k: int) -> list[int]:
        """In-neighbours j of k (a_kj = 1), in agent order: the order of z^(k) and x^(k)."""
        return [int(j) for j in np.flatnonzero(self.adj[k])]

    @property
    def q(self) -> np.ndarray:
        """Out-degrees q_k: how many estimators besides k's own also estimate x_k."""
        return self.adj.sum(axis=0).astype(int)

    def with_weights(self, W: list[np.ndarray]) -> "Network":
        return Network(self.names, self.A, self.Bt, self.C, [np.asarray(w, float) for w in W],
                       self.pi, self.omega, self.alpha, self.adj, self.B)


def network_from_spec(spec: HinfSpec) -> Network:
    idx = {a.name: i for i, a in enumerate(spec.agents)}
    N = len(spec.agents)
    adj = np.zeros((N, N), dtype=int)
    for j, k in spec.edges:
        adj[idx[k], idx[j]] = 1
    arr = lambda m: None if m is None else np.asarray(m, dtype=float)  # noqa: E731
    A = [arr(a.A) for a in spec.agents]
    return Network(
        names=[a.name for a in spec.agents],
        A=A,
        Bt=[arr(a.Bt) for a in spec.agents],
        C=[arr(a.C) for a in spec.agents],
        W=[arr(a.W) if a.W is not None else np.eye(A[i].shape[0]) for i, a in enumerate(spec.agents)],
        pi=np.array([a.pi for a in spec.agents], dtype=float),
        omega=float(spec.omega),
        alpha=float(spec.alpha),
        adj=adj,
        B=[arr(a.B) for a in spec.agents],
    )


@dataclass
class Local:
    """Structure of estimator k: which agents it tracks and its fixed matrices."""

    k: int
    blocks: list[int]  # [k, j1, ..., jp]
    offs: list[int]  # offset of each block in x^(k)
    sigma: int
    A: np.ndarray  # A^(k)
    C: np.ndarray  # C^(k), rows r*p_k
    Bt: np.ndarray  # B~^(k)
    W: np.ndarray  # W^(k) = diag(W_k, 0)


def local_structure(net: Network, k: int) -> Local:
    blocks = [k] + net.nbrs(k)
    ns = [net.n[b] for b in blocks]
    offs = list(np.concatenate([[0], np.cumsum(ns)[:-1]]).astype(int))
    sigma = int(sum(ns))
    r = net.r
    C = np.zeros((r * (len(blocks) - 1), sigma))
    for i, j in enumerate(blocks[1:]):
        C[i * r:(i + 1) * r, offs[0]:offs[0] + ns[0]] = -net.C[k]
        C[i * r:(i + 1) * r, offs[i + 1]:offs[i + 1] + ns[i + 1]] = net.C[j]
    W = np.zeros((sigma, sigma))
    W[:ns[0], :ns[0]] = net.W[k]
    return Local(k, blocks, offs, sigma, sla.block_diag(*[net.A[b] for b in blocks]), C,
                 sla.block_diag(*[net.Bt[b] for b in blocks]), W)


# ----------------------------------------------------------------------------- Proposition 2


@dataclass
class ComponentCheck:
    agents: list[str]
    detectable: bool
    bad_modes: list[complex]  # unstable eigenvalues invisible in the relative outputs


def _undetectable_modes(A: np.ndarray, C: np.ndarray, tol: float = 1e-7) -> list[complex]:
    """PBH test: eigenvalues with Re >= 0 where [lambda I - A; C] loses rank."""
    n = A.shape[0]
    bad = []
    scale = max(1.0, np.linalg.norm(A, 2), np.linalg.norm(C, 2) if C.size else 0.0)
    for lam in np.linalg.eigvals(A):
        if lam.real < -1e-9:
            continue
        if any(abs(lam - b) < 1e-6 for b in bad):
            continue
        M = np.vstack([lam * np.eye(n) - A, C.astype(complex)]) if C.size else lam * np.eye(n) - A
        smin = np.linalg.svd(M, compute_uv=False)[-1] if M.shape[0] >= n else 0.0
        # defective eigenvalues are only known to ~sqrt(eps), so compare against a loose tol
        if smin < tol * scale * 1e2:
            bad.append(complex(np.round(lam, 9)))
    return bad


def independent_sccs(adj: np.ndarray) -> list[list[int]]:
    """Strongly connected components that receive no edge from outside (Definition 2)."""
    # csgraph edge u -> v means information flows from u to v: edge j -> k iff a_kj = 1.
    ncomp, labels = connected_components(adj.T, directed=True, connection="strong")
    out = []
    for c in range(ncomp):
        members = [int(i) for i in np.flatnonzero(labels == c)]
        inflow = adj[np.ix_(members, [i for i in range(len(labels)) if labels[i] != c])]
        if not inflow.any():
            out.append(members)
    return out


def component_system(net: Network, members: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """System (9) of a component: block-diag A and (E~ kron I_r) diag(C), edges inside only."""
    A = sla.block_diag(*[net.A[m] for m in members])
    offs = np.concatenate([[0], np.cumsum([net.n[m] for m in members])]).astype(int)
    pos = {m: i for i, m in enumerate(members)}
    rows = []
    for k in members:
        for j in net.nbrs(k):
            if j in pos:
                row = np.zeros((net.r, offs[-1]))
                row[:, offs[pos[j]]:offs[pos[j] + 1]] += net.C[j]
                row[:, offs[pos[k]]:offs[pos[k] + 1]] -= net.C[k]
                rows.append(row)
    C = np.vstack(rows) if rows else np.zeros((0, offs[-1]))
    return A, C


def check_detectability(net: Network) -> list[ComponentCheck]:
    """Proposition 2 for every iSCC: a necessary condition, so failing it makes (6) pointless."""
    res = []
    for members in independent_sccs(net.adj):
        A, C = component_system(net, members)
        bad = _undetectable_modes(A, C)
        res.append(ComponentCheck([net.names[m] for m in members], not bad, bad))
    return res


def require_detectable(net: Network) -> None:
    for chk in check_detectability(net):
        if not chk.detectable:
            modes = ", ".join(f"{m.real:g}{m.imag:+g}j" if m.imag else f"{m.real:g}" for m in chk.bad_modes)
            raise UndetectableError(
                f"Proposition 2 fails: independent strongly connected component {{{', '.join(chk.agents)}}} "
                f"is not detectable from its relative outputs (undetectable eigenvalue(s): {modes}); "
                f"these agents receive no information from outside, so no gains can estimate them",
                chk.agents,
            )


# ----------------------------------------------------------------------------- LMIs (6)-(7)


@dataclass
class LocalGains:
    agent: str
    tracks: list[str]  # agents in x^(k): own first, then neighbours
    L: np.ndarray  # sigma_k x r p_k
    K: np.ndarray  # sigma_k x sigma_k
    P: np.ndarray


@dataclass
class EstimatorDesign:
    gamma: float
    gains: list[LocalGains]
    solver: str
    status: str
    solve_time_s: float
    build_time_s: float
    gamma_opt: float | None = None  # infimum found by the minimisation, before the back-off


def _sym(M):
    return (M + M.T) / 2


def design_estimators(net: Network, gamma: float | None = None, solver: str = "CLARABEL",
                      eps: float = 1e-6, check_detect: bool = True, backoff: float = 0.01,
                      clock: Callable[[], float] | None = None) -> EstimatorDesign:
    """Solve the coupled LMIs (6) for all agents at once (they share P11^(j)), minimising gamma.

    The minimiser sits on the boundary of the LMI set, where P can be nearly singular and
    K = P^-1 F meaningless; so the gains come from a second, pure feasibility solve at
    gamma*(1+backoff), whose interior-point answer is strictly feasible. The reported gamma is that
    certified level. With ``gamma`` given, only the feasibility solve at that level is done.
    ``clock`` (e.g. ``time.perf_counter``) times the build and the solve (0 without it).
    """
    if check_detect:
        require_detectable(net)
    if gamma is None:
        g_opt = _solve_lmis(net, None, solver, eps, clock)
        res = _solve_lmis(net, g_opt.gamma * (1 + backoff), solver, eps, clock)
        res.solve_time_s += g_opt.solve_time_s
        res.build_time_s += g_opt.build_time_s
        res.gamma_opt = g_opt.gamma
        return res
    return _solve_lmis(net, gamma, solver, eps, clock)


def _solve_lmis(net: Network, gamma: float | None, solver: str, eps: float,
                clock: Callable[[], float] | None = None) -> EstimatorDesign:
    import cvxpy as cp

    now = clock or (lambda: 0.0)
    t0 = now()
    locs = [local_structure(net, k) for k in range(net.N)]
    P = [cp.Variable((lc.sigma, lc.sigma), symmetric=True) for lc in locs]
    g = cp.Variable(nonneg=True) if gamma is None else float(gamma) ** 2
    q = net.q
    cons = []
    Gs, Fs = [], []
    for k, lc in enumerate(locs):
        nk, sig, p = net.n[k], lc.sigma, len(lc.blocks) - 1
        Pk = P[k]
        cons.append(Pk >> eps * np.eye(sig))
        E11 = np.zeros((sig, sig))
        E11[:nk, :nk] = 1.0
        P11_pad = cp.multiply(E11, Pk)
        Q = Pk @ lc.A + lc.A.T @ Pk + net.alpha * Pk + q[k] * net.pi[k] * P11_pad + lc.W
        d = lc.Bt.shape[1]
        blocks_row = []
        if p:
            G = cp.Variable((sig, net.r * p))
            F = cp.Variable((sig, sig - nk))
            Fn = cp.hstack([np.zeros((sig, nk)), F])  # F^(k) sum_j a_kj N_j^(k)
            Q = Q - G @ lc.C - (G @ lc.C).T - Fn - Fn.T
            Gs.append(G)
            Fs.append(F)
        else:
            Gs.append(None)
            Fs.append(None)
        # first block row / column of (6)
        cols = [Q]
        diag = []
        if p:
            cols.append(-net.omega * Gs[k])
            diag.append(net.r * p)
        cols.append(Pk @ lc.Bt)
        diag.append(d)
        FM = []
        for i, j in enumerate(lc.blocks[1:]):
            o = lc.offs[i + 1] - nk
            FM.append(Fs[k][:, o:o + net.n[j]])
        cols += FM
        sizes = [sig] + diag + [net.n[j] for j in lc.blocks[1:]]
        m = len(sizes)
        rows = [[None] * m for _ in range(m)]
        for c in range(m):
            rows[0][c] = cols[c]
            if c:
                rows[c][0] = cols[c].T
        for a in range(1, m):
            for b in range(1, m):
                if a != b:
                    rows[a][b] = np.zeros((sizes[a], sizes[b]))
        a = 1
        for _ in diag:
            rows[a][a] = -g * np.eye(sizes[a])
            a += 1
        for j in lc.blocks[1:]:
            rows[a][a] = -net.pi[j] * P[j][:net.n[j], :net.n[j]]
            a += 1
        cons.append(_sym(cp.bmat(rows)) << 0)
    prob = cp.Problem(cp.Minimize(g) if gamma is None else cp.Minimize(0), cons)
    t1 = now()
    try:
        prob.solve(solver=solver)
    except cp.SolverError as exc:
        raise HinfDesignError(f"SDP solver {solver} failed: {exc}") from None
    t2 = now()
    if prob.status not in ("optimal", "optimal_inaccurate"):
        lvl = "" if gamma is None else f" at gamma={gamma:g}"
        raise InfeasibleError(f"LMIs (6) infeasible{lvl} (solver status: {prob.status}); "
                              "try a smaller alpha or pi_k, or a larger gamma")
    gains = []
    for k, lc in enumerate(locs):
        Pk = _sym(P[k].value)
        nk, sig = net.n[k], lc.sigma
        if Gs[k] is None:
            L = np.zeros((sig, 0))
            K = np.zeros((sig, sig))
        else:
            L = np.linalg.solve(Pk, Gs[k].value)
            K = np.linalg.solve(Pk, np.hstack([np.zeros((sig, nk)), Fs[k].value]))
        gains.append(LocalGains(net.names[k], [net.names[b] for b in lc.blocks], L, K, Pk))
    gam = float(np.sqrt(g.value)) if gamma is None else float(gamma)
    return EstimatorDesign(gam, gains, solver, prob.status, t2 - t1, t1 - t0)


# ----------------------------------------------------------------------------- closed-loop error network


@dataclass
class ErrorSystem:
    """e' = A e + B [xi_scaled; eta], z = C e with z'z = sum_k e^(k)' W^(k) e^(k).

    xi_j is scaled by 1/sqrt(1+q_j): (5) charges ||xi^(k)||^2 for every estimator k, and xi_j sits
    in 1+q_j of them, so with this scaling ||T||_inf <= gamma is exactly what Theorem 1 promises.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    B_xi_raw: np.ndarray  # unscaled disturbance input (xi per agent)
    offs: list[int]  # offset of e^(k) in e
    n_xi: int


def error_system(net: Network, design: EstimatorDesign) -> ErrorSystem:
    locs = [local_structure(net, k) for k in range(net.N)]
    offs = np.concatenate([[0], np.cumsum([lc.sigma for lc in locs])]).astype(int)
    ne = int(offs[-1])
    d = [b.shape[1] for b in net.Bt]
    doff = np.concatenate([[0], np.cumsum(d)]).astype(int)
    meas = [net.r * (len(lc.blocks) - 1) for lc in locs]
    moff = np.concatenate([[0], np.cumsum(meas)]).astype(int)
    A = np.zeros((ne, ne))
    Bxi = np.zeros((ne, int(doff[-1])))
    Beta = np.zeros((ne, int(moff[-1])))
    Cz = np.zeros((ne, ne))
    for k, lc in enumerate(locs):
        g = design.gains[k]
        nk = net.n[k]
        Nsum = np.eye(lc.sigma)
        Nsum[:nk, :nk] = 0
        s = slice(offs[k], offs[k + 1])
        A[s, s] = lc.A - g.L @ lc.C - g.K @ Nsum
        for i, j in enumerate(lc.blocks[1:]):
            o = lc.offs[i + 1]
            # K^(k) M_j^(k) e_j^(j): neighbour j's own-state error enters block i+1 of estimator k
            A[s, offs[j]:offs[j] + net.n[j]] += g.K[:, o:o + net.n[j]]
        for i, b in enumerate(lc.blocks):
            o = lc.offs[i]
            Bxi[offs[k] + o:offs[k] + o + net.n[b], doff[b]:doff[b + 1]] += net.Bt[b]
        if meas[k]:
            Beta[s, moff[k]:moff[k + 1]] = -net.omega * g.L
        w, V = np.linalg.eigh(_sym(lc.W))
        Cz[s, s] = (V * np.sqrt(np.clip(w, 0, None))) @ V.T
    scale = np.concatenate([np.full(d[j], 1 / np.sqrt(1 + net.q[j])) for j in range(net.N)])
    return ErrorSystem(A, np.hstack([Bxi * scale, Beta]), Cz, Bxi, list(offs), int(doff[-1]))


def hinf_norm(A: np.ndarray, B: np.ndarray, C: np.ndarray, n_grid: int = 800,
              wmin: float = 1e-4, wmax: float = 1e4) -> tuple[float, float]:
    """Peak of sigma_max(C (jw I - A)^-1 B) by a log sweep refined around the peak; (norm, w_peak).

    A sweep (not the Hamiltonian bisection) so that the check is independent of the LMI maths.
    """
    from scipy.optimize import minimize_scalar

    if np.linalg.eigvals(A).real.max() >= 0:
        return float("inf"), float("nan")
    lam, V = np.linalg.eig(A)
    Vi = np.linalg.inv(V)
    CV, ViB = C @ V, Vi @ B
    if np.linalg.cond(V) > 1e8:  # nearly defective: fall back to direct solves
        def gain(w):
            return np.linalg.svd(C @ np.linalg.solve(1j * w * np.eye(A.shape[0]) - A, B), compute_uv=False)[0]
    else:
        def gain(w):
            return np.linalg.svd((CV / (1j * w - lam)) @ ViB, compute_uv=False)[0]
    ws = np.concatenate([[0.0], np.logspace(np.log10(wmin), np.log10(wmax), n_grid)])
    vals = np.array([gain(w) for w in ws])
    i = int(vals.argmax())
    best, wbest = vals[i], ws[i]
    lo, hi = ws[max(i - 1, 0)], ws[min(i + 1, len(ws) - 1)]
    if hi > lo:
        res = minimize_scalar(lambda w: -gain(w), bounds=(lo, hi), method="bounded",
                              options={"xatol": 1e-9 * max(1.0, hi)})
        if -res.fun > best:
            best, wbest = -res.fun, float(res.x)
    return float(best), float(wbest)


# ----------------------------------------------------------------------------- centralized yardstick


def centralized_bound(net: Network, alpha: float | None = 0.0, solver: str = "CLARABEL") -> float:
    """Optimal gamma of one full-order H-infinity observer of (2) from all relative outputs (3).

    Same weight (diag W_k on every agent's state) and same disturbances (each xi_k, eta_kj once).
    The observer-form LMI is exact for H-infinity filtering, so this is the centralized optimum;
    ``alpha`` adds the same decay constraint as the distributed design (0 = pure H-infinity).
    """
    import cvxpy as cp

    A = sla.block_diag(*net.A)
    Bt = sla.block_diag(*net.Bt)
    W = sla.block_diag(*net.W)
    _, Cz = component_system(net, list(range(net.N)))
    n, m, d = A.shape[0], Cz.shape[0], Bt.shape[1]
    P = cp.Variable((n, n), symmetric=True)
    Y = cp.Variable((n, m))
    g = cp.Variable(nonneg=True)
    Q = P @ A + A.T @ P - Y @ Cz - (Y @ Cz).T + W + (alpha or 0.0) * P
    M = cp.bmat([[Q, P @ Bt, -net.omega * Y],
                 [(P @ Bt).T, -g * np.eye(d), np.zeros((d, m))],
                 [-net.omega * Y.T, np.zeros((m, d)), -g * np.eye(m)]])
    prob = cp.Problem(cp.Minimize(g), [P >> 1e-6 * np.eye(n), _sym(M) << 0])
    prob.solve(solver=solver)
    if prob.status not in ("optimal", "optimal_inaccurate"):
        raise InfeasibleError(f"centralized H-infinity LMI: solver status {prob.status}")
    return float(np.sqrt(g.value))


# ----------------------------------------------------------------------------- Theorem 3


def francis_residual(A, B, C, Pi, Lam, S, Gamma) -> float:
    """max |A Pi + B Lambda - Pi S|, |C Pi - Gamma| of (12)."""
    return float(max(np.abs(A @ Pi + B @ Lam - Pi @ S).max(), np.abs(C @ Pi - Gamma).max()))


def solve_francis(A, B, C, S, Gamma) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares (Pi, Lambda) of (12) and the residual; residual > 0 means (12) has no solution."""
    n, m, nu = A.shape[0], B.shape[1], S.shape[0]
    In, Inu = np.eye(n), np.eye(nu)
    top = np.hstack([np.kron(Inu, A) - np.kron(S.T, In), np.kron(Inu, B)])
    bot = np.hstack([np.kron(Inu, C), np.zeros((C.shape[0] * nu, m * nu))])
    rhs = np.concatenate([np.zeros(n * nu), Gamma.reshape(-1, order="F")])
    sol = np.linalg.lstsq(np.vstack([top, bot]), rhs, rcond=None)[0]
    Pi = sol[:n * nu].reshape((n, nu), order="F")
    Lam = sol[n * nu:].reshape((m, nu), order="F")
    return Pi, Lam, francis_residual(A, B, C, Pi, Lam, S, Gamma)


def solve_riccati14(A, B, Bt, Pi, R, mu, lam) -> np.ndarray:
    """Stabilising X of (14): X A + A'X + R - X(BB'/lam^2 - (B~B~' + Pi Pi')/mu^2) X = 0.

    The quadratic term is indefinite (a game Riccati), so solve via the stable invariant
    subspace of the Hamiltonian; raises if X is not positive definite or A - BB'X/lam^2 not Hurwitz.
    """
    n = A.shape[0]
    Rq = B @ B.T / lam**2 - (Bt @ Bt.T + Pi @ Pi.T) / mu**2
    H = np.block([[A, -Rq], [-R, -A.T]])
    T, Z, sdim = sla.schur(H, sort="lhp")
    if sdim != n:
        raise HinfDesignError(f"Riccati (14): Hamiltonian has {2 * n - 2 * sdim} eigenvalues on the "
                              f"imaginary axis (mu={mu:g}, lambda={lam:g} too small)")
    U1, U2 = Z[:n, :n], Z[n:, :n]
    X = _sym(np.linalg.solve(U1.T, U2.T).T)
    res = np.abs(X @ A + A.T @ X + R - X @ Rq @ X).max()
    if res > 1e-6 * max(1.0, np.abs(X).max()):
        raise HinfDesignError(f"Riccati (14): residual {res:.2e}")
    if np.linalg.eigvalsh(X).min() <= 0:
        raise HinfDesignError("Riccati (14): stabilising solution is not positive definite")
    if np.linalg.eigvals(A - B @ B.T @ X / lam**2).real.max() >= 0:
        raise HinfDesignError("Riccati (14): A - B B' X / lambda^2 is not Hurwitz")
    return X


@dataclass
class SyncDesign:
    X: list[np.ndarray]
    H: list[np.ndarray]  # H_k of (16)
    Pi: list[np.ndarray]
    Lam: list[np.ndarray]
    francis_residual: list[float]
    estimator: EstimatorDesign  # re-solved (6) with the weights (15)
    gamma: float
    kappa: float  # kappa^2 = mu^2 + q_max gamma^2
    theta: float  # theta = gamma


def design_sync(net: Network, spec: HinfSpec, tol: float = 1e-8, solver: str = "CLARABEL") -> SyncDesign:
    """Theorem 3: check (12), solve (14) per agent, weights (15), re-solve (6), bounds kappa/theta."""
    sy = spec.sync
    if sy is None:
        raise HinfDesignError("spec has no [sync] section")
    S, Gamma = np.asarray(sy.S, float), np.asarray(sy.Gamma, float)
    if np.abs(np.linalg.eigvals(S).real).max() > 1e-9:
        raise HinfDesignError(f"sync.S must have its spectrum on the imaginary axis, has {np.linalg.eigvals(S)}")
    nu = S.shape[0]
    obs = np.vstack([Gamma @ np.linalg.matrix_power(S, i) for i in range(nu)])
    if np.linalg.matrix_rank(obs) < nu:
        raise HinfDesignError("sync: (S, Gamma) is not observable")
    Xs, Hs, Pis, Lams, resid, W = [], [], [], [], [], []
    for k, a in enumerate(spec.agents):
        A, B, Bt, C = net.A[k], net.B[k], net.Bt[k], net.C[k]
        if a.Pi is not None and a.Lambda is not None:
            Pi, Lam = np.asarray(a.Pi, float), np.asarray(a.Lambda, float)
            res = francis_residual(A, B, C, Pi, Lam, S, Gamma)
        else:
            Pi, Lam, res = solve_francis(A, B, C, S, Gamma)
        if res > tol:
            raise HinfDesignError(f"Francis equations (12) fail for agent {a.name!r}: residual {res:.3g}")
        R = np.asarray(a.R, float) if a.R is not None else np.eye(A.shape[0])
        X = solve_riccati14(A, B, Bt, Pi, R, sy.mu, sy.lam)
        Xs.append(X)
        Hs.append(-B.T @ X / sy.lam**2)
        Pis.append(Pi)
        Lams.append(Lam)
        resid.append(res)
        W.append(_sym(X @ B @ B.T @ X) / sy.lam**2)  # (15)
    est = design_estimators(net.with_weights(W), solver=solver)
    qmax = int(net.q.max())
    kappa = float(np.sqrt(sy.mu**2 + qmax * est.gamma**2))
    return SyncDesign(Xs, Hs, Pis, Lams, resid, est, est.gamma, kappa, est.gamma)
