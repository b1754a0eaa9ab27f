"""Runtime of paper 003: the local estimators (4) with the controllers (10)-(11), and the LTI plant.

Pure cores (no clock, no sockets, no global RNG): the daemons in ``hinf.daemon`` and the in-process
engine ``run_inproc`` below drive the same objects, so a lockstep run over Zenoh equals it bit for bit.

Sampled-data implementation (tick dt), and why this one:
- Plant: x_k(t+1) = Ad_k x_k + Bud_k u_k(t) + Bxd_k xi_k(t), the exact discretisation (expm of the
  augmented matrix) with u and xi held over the tick.
- Estimator k, per tick: a *correction* that integrates the innovation and consensus terms of (4)
  exactly over dt with the truth frozen, then a *prediction* with the exact model of the plant:
      x+      = e^{G dt} x^(k) + int_0^dt e^{Gs} ds (L z^(k)(t) + K sum_j M_j x^_j^(j)(t)),
      G       = -(L C^(k) + K sum_j N_j)
      x^(k)(t+1) = Ad^(k) x+ + Bud^(k) u^(k)(t)
  so that the error obeys e(t+1) = Ad^(k)(e^{G dt} e + ...): it does not depend on the plant state
  nor on u (Remark 2 holds exactly), and it tends to the continuous error network as dt -> 0.
  The paper's gains are large (|L|, |K| ~ 1e3 for Sec. 5, error modes down to -5e3 rad/s), so the
  textbook ZOH discretisations fail at dt = 0.01 s: with the model propagated but the correction held
  (Euler) the network is unstable, and with the whole of (4) integrated under a held z the error picks
  up a term ~ dt * x' that never decays while the agents move.
- Neighbour data for time t (x^_j^(j)(t), u_j(t), zeta_j(t)) is computed by j at the end of its tick
  t - 1 and is in k's inbox at t (no extra delay without link faults). Missing (lost, late) data is
  held at its last value. At t = 0 the values are known from the run config (x^(0) = 0 as in (4),
  zeta_j(0) from [run]).
- Internal model (10): zeta(t+1) = e^{S dt} zeta + int_0^dt e^{Ss} ds sum_j a_kj (zeta_j - zeta).
- Control (11): u_k(t) = Lambda_k zeta_k(t) + H_k (x^_k^(k)(t) - Pi_k zeta_k(t)), held over the tick.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.linalg as sla

from net.hinf_messages import HinfInput, HinfState
from net.link import DelayLine, LinkModel, LinkStats, deliver_tick

from . import design as D
from .spec import HinfSpec

DIST_STREAM = 0x4F3D
"""Last word of the disturbance RNG seed: keeps it apart from the link streams of the same run seed."""
INIT_STREAM = 0x1417
"""Last word of the seed of the drawn initial states."""


def zoh(F: np.ndarray, G: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(e^{F dt}, int_0^dt e^{Fs} ds G): exact discretisation of x' = F x + G w with w held."""
    n, m = F.shape[0], G.shape[1]
    M = np.zeros((n + m, n + m))
    M[:n, :n] = F
    M[:n, n:] = G
    E = sla.expm(M * dt)
    return E[:n, :n], E[:n, n:]


# ----------------------------------------------------------------------------- setup


@dataclass
class Setup:
    """Everything a run needs, from the spec and the design's JSON; shared by every daemon."""

    spec: HinfSpec
    design: dict
    net: D.Network  # with the weights of the design in use
    locs: list[D.Local]
    control: bool
    L: list[np.ndarray]
    K: list[np.ndarray]
    P: list[np.ndarray]
    gamma: float
    H: list[np.ndarray]
    Pi: list[np.ndarray]
    Lam: list[np.ndarray]
    S: np.ndarray
    x0: list[np.ndarray]
    zeta0: list[np.ndarray]
    B: list[np.ndarray]  # B_k, n_k x 0 when the agent has no input
    outs: list[list[int]] = field(default_factory=list)  # who hears from k

    @property
    def N(self) -> int:
        return self.net.N

    @property
    def dt(self) -> float:
        return self.spec.run.dt

    @property
    def ticks(self) -> int:
        return self.spec.run.ticks

    @property
    def nu(self) -> int:
        return self.S.shape[0]

    def nbrs(self, k: int) -> list[int]:
        return self.net.nbrs(k)

    def input_law(self, k: int, xhat_own: np.ndarray, zeta: np.ndarray) -> np.ndarray:
        """u_k of (11); zero without control."""
        if not self.control:
            return np.zeros(self.B[k].shape[1])
        return self.Lam[k] @ zeta + self.H[k] @ (xhat_own - self.Pi[k] @ zeta)


def build_setup(spec: HinfSpec, design: dict) -> Setup:
    """Numeric setup of a run. ``design`` is ``hinf.run_design(spec)`` (or its JSON, read back)."""
    net = D.network_from_spec(spec)
    control = spec.control
    src = design["sync"]["gains"] if control else design["gains"]
    L = [np.asarray(g["L"], float).reshape(sum(net.n[b] for b in [k, *net.nbrs(k)]), net.r * len(net.nbrs(k)))
         for k, g in enumerate(src)]
    K = [np.asarray(g["K"], float) for g in src]
    P = [np.asarray(g["P"], float) for g in src]
    B = [np.asarray(b, float) if b is not None else np.zeros((net.n[k], 0)) for k, b in enumerate(net.B)]
    N = net.N
    if control:
        sy = spec.sync
        X = [np.asarray(x, float) for x in design["sync"]["X"]]
        H = [np.asarray(h, float) for h in design["sync"]["H"]]
        W = [X[k] @ B[k] @ B[k].T @ X[k] / sy.lam**2 for k in range(N)]  # (15)
        net = net.with_weights([(w + w.T) / 2 for w in W])
        S = np.asarray(sy.S, float)
        Pi, Lam = [], []
        for k, a in enumerate(spec.agents):
            if a.Pi is not None and a.Lambda is not None:
                Pi.append(np.asarray(a.Pi, float))
                Lam.append(np.asarray(a.Lambda, float))
            else:
                p, lam, _ = D.solve_francis(net.A[k], B[k], net.C[k], S, np.asarray(sy.Gamma, float))
                Pi.append(p)
                Lam.append(lam)
        gamma = float(design["sync"]["gamma"])
    else:
        H = [np.zeros((B[k].shape[1], net.n[k])) for k in range(N)]
        S = np.zeros((0, 0))
        Pi = [np.zeros((net.n[k], 0)) for k in range(N)]
        Lam = [np.zeros((B[k].shape[1], 0)) for k in range(N)]
        gamma = float(design["gamma"])
    run = spec.run
    rng = np.random.default_rng([run.seed, INIT_STREAM])
    # both drawn always (fixed stream layout), then overridden by explicit values
    x0 = [run.x0_std * rng.standard_normal(nk) for nk in net.n]
    z0 = [run.zeta0_std * rng.standard_normal(S.shape[0]) for _ in range(N)]
    if run.x0 is not None:
        x0 = [np.asarray(x, float) for x in run.x0]
    if run.zeta0 is not None and control:
        z0 = [np.asarray(z, float) for z in run.zeta0]
    outs = [[j for j in range(N) if net.adj[j, k]] for k in range(N)]
    return Setup(spec, design, net, [D.local_structure(net, k) for k in range(N)], control, L, K, P, gamma,
                 H, Pi, Lam, S, x0, z0, B, outs)


# ----------------------------------------------------------------------------- disturbances


class Disturbance:
    """xi_k(t) and eta_kj(t) for each tick: seeded Gaussian samples or the worst-case sinusoid.

    Layout: xi stacks xi_k in agent order; eta stacks eta^(k) (neighbours of k in order) for k in order,
    the same layout as ``design.error_system``. White draws are made every tick, inside or outside
    the [t_on, t_off) window, so that the window changes nothing but the values it covers.
    """

    def __init__(self, setup: Setup) -> None:
        net = setup.net
        self.spec = setup.spec.run.disturbance
        self.dt = setup.dt
        self.d = [b.shape[1] for b in net.Bt]
        self.n_xi = int(sum(self.d))
        self.n_eta = int(sum(net.r * len(net.nbrs(k)) for k in range(net.N)))
        self.rng = np.random.default_rng([setup.spec.run.seed, DIST_STREAM])
        self.q = net.q
        self.worst: tuple[np.ndarray, float] | None = None
        if self.spec.kind == "worst":
            self.worst = worst_direction(setup)

    def at(self, tick: int) -> tuple[np.ndarray, np.ndarray]:
        s = self.spec
        if s.kind == "none":
            return np.zeros(self.n_xi), np.zeros(self.n_eta)
        if s.kind == "white":
            w = self.rng.standard_normal(self.n_xi + self.n_eta)
            xi, eta = s.xi_std * w[:self.n_xi], s.eta_std * w[self.n_xi:]
        else:
            v, wpk = self.worst  # type: ignore[misc]
            w = s.amplitude * np.real(v * np.exp(1j * wpk * tick * self.dt))
            scale = np.concatenate([np.full(self.d[j], 1 / np.sqrt(1 + self.q[j])) for j in range(len(self.d))])
            xi, eta = w[:self.n_xi] * scale, w[self.n_xi:]
        t = tick * self.dt
        if t < s.t_on or (s.t_off is not None and t >= s.t_off):
            return np.zeros(self.n_xi), np.zeros(self.n_eta)
        return xi, eta

    def charged_energy(self, xi: np.ndarray, eta: np.ndarray) -> float:
        """What (5) charges for one tick's inputs: sum_j (1 + q_j)|xi_j|^2 + |eta|^2 (xi_j is in 1+q_j
        estimators)."""
        w = np.concatenate([np.full(self.d[j], 1.0 + self.q[j]) for j in range(len(self.d))])
        return float(w @ xi**2 + eta @ eta)


def _design_of(setup: Setup) -> D.EstimatorDesign:
    gains = [D.LocalGains(setup.net.names[k], [setup.net.names[b] for b in setup.locs[k].blocks],
                          setup.L[k], setup.K[k], setup.P[k]) for k in range(setup.N)]
    return D.EstimatorDesign(setup.gamma, gains, "", "", 0.0, 0.0)


def worst_direction(setup: Setup) -> tuple[np.ndarray, float]:
    """Input direction (unit, complex) and frequency at which the continuous error network's gain peaks."""
    es = D.error_system(setup.net, _design_of(setup))
    _, w = D.hinf_norm(es.A, es.B, es.C)
    T = es.C @ np.linalg.solve(1j * w * np.eye(es.A.shape[0]) - es.A, es.B)
    _, _, Vh = np.linalg.svd(T)
    v = Vh[0].conj()
    i = int(np.abs(v).argmax())
    v = v * np.exp(-1j * np.angle(v[i]))  # largest entry real: at w = 0 the whole vector is real
    return v, float(w)


def continuous_norm(setup: Setup) -> tuple[float, float]:
    """H-infinity norm (and peak frequency) of the continuous error network of the gains in use."""
    es = D.error_system(setup.net, _design_of(setup))
    return D.hinf_norm(es.A, es.B, es.C)


# ----------------------------------------------------------------------------- plant


class PlantCore:
    """The N LTI agents, discretised exactly for dt; measurements z^(k) = [y_j - y_k + omega eta_kj]."""

    def __init__(self, setup: Setup) -> None:
        net, dt = setup.net, setup.dt
        self.setup = setup
        self.x = [x.copy() for x in setup.x0]
        self.Ad, self.Bud, self.Bxd = [], [], []
        for k in range(net.N):
            Ad, G = zoh(net.A[k], np.hstack([setup.B[k], net.Bt[k]]), dt)
            m = setup.B[k].shape[1]
            self.Ad.append(Ad)
            self.Bud.append(G[:, :m])
            self.Bxd.append(G[:, m:])
        self.dist = Disturbance(setup)
        self.xi_off = np.concatenate([[0], np.cumsum(self.dist.d)]).astype(int)
        self.xi = np.zeros(self.dist.n_xi)
        self.eta = np.zeros(self.dist.n_eta)
        self.tick = 0

    def measure(self, tick: int) -> list[tuple[float, ...]]:
        """z^(k)(tick) for every k, from the current state; fixes the tick's disturbances."""
        self.tick = tick
        self.xi, self.eta = self.dist.at(tick)
        net, om = self.setup.net, self.setup.net.omega
        y = [net.C[k] @ self.x[k] for k in range(net.N)]
        out, o = [], 0
        for k in range(net.N):
            z = []
            for j in net.nbrs(k):
                z.extend((y[j] - y[k] + om * self.eta[o:o + net.r]).tolist())
                o += net.r
            out.append(tuple(z))
        return out

    def step(self, u: list[np.ndarray]) -> None:
        """x(t+1) from x(t), the held u(t) and the xi(t) fixed by :meth:`measure`."""
        for k in range(self.setup.N):
            xi = self.xi[self.xi_off[k]:self.xi_off[k + 1]]
            self.x[k] = self.Ad[k] @ self.x[k] + self.Bud[k] @ u[k] + self.Bxd[k] @ xi

    def truth(self) -> np.ndarray:
        return np.concatenate(self.x)


# ----------------------------------------------------------------------------- estimator + controller


class EstimatorCore:
    """Agent k: local estimator (4) with Remark 2's input term, internal model (10), control (11).

    u_k(t) depends only on the prior x^(k)(t) and zeta_k(t), so it is ready one tick early:
    ``step(tick, z, inbox)`` returns the input message for the simulator *for tick + 1* (u_k, x^(k),
    zeta_k at t + 1) and the state message for the out-neighbours (the same values, own block only);
    :meth:`input_msg` gives the current one (tick 0). Sending u early lets a real-time plant apply the
    u the estimators assume (Remark 2) instead of a stale one.
    """

    def __init__(self, setup: Setup, k: int) -> None:
        net, dt, lc = setup.net, setup.dt, setup.locs[k]
        self.setup, self.k, self.loc = setup, k, lc
        self.nbrs = net.nbrs(k)
        nk, sig = net.n[k], lc.sigma
        L, K = setup.L[k], setup.K[k]
        Ns = np.eye(sig)
        Ns[:nk, :nk] = 0.0
        Gm = -(L @ lc.C + K @ Ns)
        PhiG, GamG = zoh(Gm, np.eye(sig), dt)
        Ad = sla.block_diag(*[zoh(net.A[b], np.zeros((net.n[b], 0)), dt)[0] for b in lc.blocks])
        Bu = sla.block_diag(*[zoh(net.A[b], setup.B[b], dt)[1] for b in lc.blocks])
        self.Tx = Ad @ PhiG
        self.Tz = Ad @ GamG @ L
        self.Tn = [Ad @ GamG @ K[:, lc.offs[i + 1]:lc.offs[i + 1] + net.n[j]] for i, j in enumerate(self.nbrs)]
        self.Tu = Bu
        self.m = [setup.B[b].shape[1] for b in lc.blocks]
        self.nk = nk
        if setup.control:
            self.ES, self.GS = zoh(setup.S, np.eye(setup.nu), dt)
        self.xhat = np.zeros(sig)
        self.zeta = setup.zeta0[k].copy()
        # latest data of each in-neighbour: (send tick, x^_j^(j), u_j, zeta_j) for the time after it
        self.nb: dict[int, tuple[int, np.ndarray, np.ndarray, np.ndarray]] = {}
        for j in self.nbrs:
            x0 = np.zeros(net.n[j])
            self.nb[j] = (-1, x0, setup.input_law(j, x0, setup.zeta0[j]), setup.zeta0[j])
        self.u = setup.input_law(k, self.xhat[:nk], self.zeta)
        self.held = 0  # ticks at which some neighbour's data was older than the tick (counted)
        self.dropped = 0  # inbox entries of the wrong shape or not finite (counted, skipped)
        self.last_tick = -1

    def absorb(self, inbox: list[HinfState]) -> None:
        """Keep the newest data per neighbour (the line may hold duplicates or reordered copies)."""
        for msg in inbox:
            cur = self.nb.get(msg.sender)
            if cur is not None and msg.tick > cur[0]:
                new = (msg.tick, np.asarray(msg.xhat), np.asarray(msg.u), np.asarray(msg.zeta))
                try:
                    ok = all(a.shape == b.shape and np.all(np.isfinite(a)) for a, b in zip(new[1:], cur[1:]))
                except TypeError:  # not numbers
                    ok = False
                if not ok:
                    self.dropped += 1
                    continue
                self.nb[msg.sender] = new

    def input_msg(self, tick: int) -> HinfInput:
        """u_k, x^(k) and zeta_k of the current (prior) state, as the input message for ``tick``."""
        return HinfInput(tick, self.k, tuple(self.u.tolist()), tuple(self.xhat.tolist()), tuple(self.zeta.tolist()))

    def step(self, tick: int, z: tuple[float, ...], inbox: list[HinfState]) -> tuple[HinfInput, HinfState]:
        if tick <= self.last_tick:
            raise ValueError(f"ticks must increase: got {tick} after {self.last_tick}")
        self.last_tick = tick
        self.absorb(inbox)
        k = self.k
        u_now = self.u
        if any(self.nb[j][0] < tick - 1 for j in self.nbrs):
            self.held += 1
        x = self.Tx @ self.xhat + self.Tz @ np.asarray(z)
        us = [u_now]
        for i, j in enumerate(self.nbrs):
            _, xj, uj, _ = self.nb[j]
            x = x + self.Tn[i] @ xj
            us.append(uj)
        if self.Tu.shape[1]:
            x = x + self.Tu @ np.concatenate(us)
        self.xhat = x
        if self.setup.control:
            coup = np.zeros(self.setup.nu)
            for j in self.nbrs:
                coup = coup + (self.nb[j][3] - self.zeta)
            self.zeta = self.ES @ self.zeta + self.GS @ coup
        self.u = self.setup.input_law(k, self.xhat[:self.nk], self.zeta)
        out_st = HinfState(tick, k, tuple(self.xhat[:self.nk].tolist()), tuple(self.u.tolist()),
                           tuple(self.zeta.tolist()))
        return self.input_msg(tick + 1), out_st


# ----------------------------------------------------------------------------- recording


@dataclass
class Trace:
    """What a run records, one row per tick (values at the start of the tick)."""

    x: np.ndarray  # ticks x sum n_k, truth
    xhat: np.ndarray  # ticks x sum sigma_k, every local estimate (NaN: input not received)
    zeta: np.ndarray  # ticks x N nu
    u: np.ndarray  # ticks x sum m_k, as applied by the plant
    xi: np.ndarray  # ticks x sum d_k
    eta: np.ndarray  # ticks x sum r p_k
    got: np.ndarray  # ticks x N, bool: the simulator had k's input for this tick

    @staticmethod
    def empty(setup: Setup) -> Trace:
        T, net = setup.ticks, setup.net
        dist_n = (int(sum(b.shape[1] for b in net.Bt)), int(sum(net.r * len(net.nbrs(k)) for k in range(net.N))))
        return Trace(np.zeros((T, sum(net.n))), np.full((T, sum(lc.sigma for lc in setup.locs)), np.nan),
                     np.full((T, net.N * setup.nu), np.nan), np.zeros((T, sum(b.shape[1] for b in setup.B))),
                     np.zeros((T, dist_n[0])), np.zeros((T, dist_n[1])), np.zeros((T, net.N), bool))

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k) for k in TRACE_FIELDS}


TRACE_FIELDS = ("x", "xhat", "zeta", "u", "xi", "eta", "got")


class TraceWriter:
    """Fills a Trace from what the simulator sees: truth and disturbances, then each agent's input."""

    def __init__(self, setup: Setup) -> None:
        self.setup = setup
        self.trace = Trace.empty(setup)
        self.soff = np.concatenate([[0], np.cumsum([lc.sigma for lc in setup.locs])]).astype(int)
        self.moff = np.concatenate([[0], np.cumsum([b.shape[1] for b in setup.B])]).astype(int)

    def truth(self, tick: int, plant: PlantCore) -> None:
        tr = self.trace
        tr.x[tick] = plant.truth()
        tr.xi[tick] = plant.xi
        tr.eta[tick] = plant.eta

    def input(self, msg: HinfInput) -> None:
        k, t, tr = msg.agent, msg.tick, self.trace
        tr.xhat[t, self.soff[k]:self.soff[k + 1]] = msg.xhat
        nu = self.setup.nu
        tr.zeta[t, k * nu:(k + 1) * nu] = msg.zeta
        tr.got[t, k] = True

    def applied(self, tick: int, u: list[np.ndarray]) -> None:
        if self.moff[-1]:
            self.trace.u[tick] = np.concatenate(u)


# ----------------------------------------------------------------------------- in-process engine


def in_links(setup: Setup, receiver: int, mode: str = "lockstep") -> dict[int, LinkModel]:
    """Fault models of the links ending at ``receiver`` (sender -> receiver), keyed by sender."""
    run = setup.spec.run
    return {j: LinkModel(run.link, run.seed, j, receiver, mode, run.dt) for j in setup.nbrs(receiver)}  # type: ignore[arg-type]


def run_inproc(setup: Setup, progress: Callable[[int, int], None] | None = None) -> tuple[Trace, dict[str, Any]]:
    """Lockstep run of plant, estimators and link models in this process; the reference the daemons equal.

    Per tick: the plant measures, each estimator steps in agent order with what its delay line releases,
    its state goes through the receive-side link model of each out-neighbour, then the plant steps.
    """
    N, ticks, dt = setup.N, setup.ticks, setup.dt
    plant = PlantCore(setup)
    cores = [EstimatorCore(setup, k) for k in range(N)]
    links = [in_links(setup, k) for k in range(N)]
    stats = {(j, k): LinkStats() for k in range(N) for j in setup.nbrs(k)}
    lines: list[DelayLine] = [DelayLine() for _ in range(N)]
    rec = TraceWriter(setup)
    every = max(1, ticks // 100)
    inputs = [c.input_msg(0) for c in cores]  # input(t) is made at the end of tick t - 1
    for t in range(ticks):
        zs = plant.measure(t)
        rec.truth(t, plant)
        us = []
        for k in range(N):
            rec.input(inputs[k])
            us.append(np.asarray(inputs[k].u))
            inputs[k], st = cores[k].step(t, zs[k], lines[k].pop_due(t))
            for r in setup.outs[k]:
                link, s = links[r][k], stats[(k, r)]
                delays = link.deliveries(t)
                s.sent += 1
                if not delays:
                    s.count_lost(link, t)
                for copy, d in enumerate(delays):
                    lines[r].push(deliver_tick(t, d, dt, "lockstep"), k, t, copy, st)
                s.delivered += len(delays)
                s.duplicated += max(0, len(delays) - 1)
        rec.applied(t, us)
        plant.step(us)
        if progress is not None and (t % every == 0 or t == ticks - 1):
            progress(t + 1, ticks)
    info = {
        "links": {f"{j}->{k}": s.as_dict() for (j, k), s in sorted(stats.items())},
        "drops": {},
        "timeouts": {"input": 0, "neighbour": 0},
        "held": {str(k): c.held for k, c in enumerate(cores)},
    }
    return rec.trace, info


# ----------------------------------------------------------------------------- closed-form references


def discrete_error_network(setup: Setup) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Ad, Bd, Cz) of the sampled error network e(t+1) = Ad e + Bd w, z = Cz e, for fault-free links.

    w = [xi scaled by 1/sqrt(1+q_j); eta] as in ``design.error_system``; this is what the cores
    implement (checked in the tests) and what the realised gain of a run is compared with.
    """
    net, dt, locs = setup.net, setup.dt, setup.locs
    offs = np.concatenate([[0], np.cumsum([lc.sigma for lc in locs])]).astype(int)
    d = [b.shape[1] for b in net.Bt]
    doff = np.concatenate([[0], np.cumsum(d)]).astype(int)
    moff = np.concatenate([[0], np.cumsum([net.r * (len(lc.blocks) - 1) for lc in locs])]).astype(int)
    ne = int(offs[-1])
    Ad_e = np.zeros((ne, ne))
    Bxi = np.zeros((ne, int(doff[-1])))
    Beta = np.zeros((ne, int(moff[-1])))
    Cz = np.zeros((ne, ne))
    for k, lc in enumerate(locs):
        L, K = setup.L[k], setup.K[k]
        nk, sig = net.n[k], lc.sigma
        Ns = np.eye(sig)
        Ns[:nk, :nk] = 0.0
        PhiG, GamG = zoh(-(L @ lc.C + K @ Ns), np.eye(sig), dt)
        Ad = sla.block_diag(*[zoh(net.A[b], np.zeros((net.n[b], 0)), dt)[0] for b in lc.blocks])
        s = slice(offs[k], offs[k + 1])
        Ad_e[s, s] = Ad @ PhiG
        for i, j in enumerate(lc.blocks[1:]):
            o = lc.offs[i + 1]
            Ad_e[s, offs[j]:offs[j] + net.n[j]] += Ad @ GamG @ K[:, o:o + net.n[j]]
        for i, b in enumerate(lc.blocks):
            o = lc.offs[i]
            Bxi[offs[k] + o:offs[k] + o + net.n[b], doff[b]:doff[b + 1]] += zoh(net.A[b], net.Bt[b], dt)[1]
        if moff[k + 1] > moff[k]:
            Beta[s, moff[k]:moff[k + 1]] = -net.omega * Ad @ GamG @ L
        w, V = np.linalg.eigh((lc.W + lc.W.T) / 2)
        Cz[s, s] = (V * np.sqrt(np.clip(w, 0, None))) @ V.T
    scale = np.concatenate([np.full(d[j], 1 / np.sqrt(1 + net.q[j])) for j in range(net.N)])
    return Ad_e, np.hstack([Bxi * scale, Beta]), Cz


def discrete_norm(Ad: np.ndarray, Bd: np.ndarray, Cz: np.ndarray, n_grid: int = 2000) -> tuple[float, float]:
    """Peak over theta in [0, pi] of sigma_max(Cz (e^{j theta} - Ad)^-1 Bd), refined; (norm, theta)."""
    from scipy.optimize import minimize_scalar

    if np.abs(np.linalg.eigvals(Ad)).max() >= 1:
        return float("inf"), float("nan")
    n = Ad.shape[0]

    def gain(th: float) -> float:
        return float(np.linalg.svd(Cz @ np.linalg.solve(np.exp(1j * th) * np.eye(n) - Ad, Bd), compute_uv=False)[0])

    ths = np.concatenate([[0.0], np.logspace(-7, np.log10(np.pi), n_grid)])
    vals = np.array([gain(t) for t in ths])
    i = int(vals.argmax())
    best, tbest = float(vals[i]), float(ths[i])
    lo, hi = ths[max(i - 1, 0)], ths[min(i + 1, len(ths) - 1)]
    if hi > lo:
        res = minimize_scalar(lambda t: -gain(t), bounds=(lo, hi), method="bounded", options={"xatol": 1e-12})
        if -res.fun > best:
            best, tbest = float(-res.fun), float(res.x)
    return best, tbest


def errors(setup: Setup, trace: Trace) -> np.ndarray:
    """e^(k)(t) = x^(k)(t) - x^^(k)(t) for all k, stacked like trace.xhat (ticks x sum sigma_k)."""
    net = setup.net
    xoff = np.concatenate([[0], np.cumsum(net.n)]).astype(int)
    cols = [np.arange(xoff[b], xoff[b + 1]) for lc in setup.locs for b in lc.blocks]
    return trace.x[:, np.concatenate(cols)] - trace.xhat
