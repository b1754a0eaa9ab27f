"""Output-error fit of the rigid-body model over windows (multiple shooting).

The recording is cut into windows of ``window_s`` (and at every gap in the stamps); each window starts
from its own state and is simulated open loop by :func:`ident.model.simulate`, so a small model error
cannot grow over more than one window. The body angle is continuous from one window to the next (a
soft constraint, ``theta_sigma``), and so is the angular rate (``omega_sigma``): the angle pins the
scale of the contact geometry against the rate, which a window alone determines only weakly, and the
rate carries the torque's information on J across windows. The global parameters (geometry, 1/m, 1/J,
effects) are shared. Residuals are measured minus predicted velocities and/or positions, each divided
by its channel's noise floor; nothing is differentiated. Levenberg-Marquardt on the normal equations
(a window's states touch only its own residuals and its links); the Jacobian is a batched forward
difference (a window-state column is one simulation for every window at once). See docs/batch-fit.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ident import stats
from ident.model import Layout, Windows, simulate
from ident.recording import Recording, agent_period

Z95 = 1.959963984540054


class FitError(ValueError):
    """The recording cannot be fitted; the message says why."""


@dataclass(frozen=True)
class FitOptions:
    window_s: float = 2.5  # window length (s): short enough that an open-loop error stays small
    window_stamps: int = 500  # and at most this many stamps (the simulation loops over a window's stamps)
    gap_factor: float = 5.0  # a stamp interval this many times the median starts a new, unlinked window
    max_step: float = 0.05  # longest RK4 substep (s)
    theta_sigma: float = 0.01  # rad: the body angle's continuity between windows
    omega_sigma: float = 0.002  # rad/s: the angular rate's continuity between windows
    coulomb_speed: float | None = None  # smoothing speed of the Coulomb term; None: from the data
    max_iter: int = 30


@dataclass
class Problem:
    """A recording prepared for fitting: windows, links between them, channel weights."""

    win: Windows
    base: Layout
    sigma_v: float | np.ndarray  # noise floor of the velocity channel (m/s) or nan; (n, 1) per agent
    sigma_p: float | np.ndarray  # of the position channel (m) or nan; (n, 1) per agent
    coulomb_speed: float
    max_step: float
    t0: np.ndarray  # (S,) window start stamps
    last: np.ndarray  # (S,) index of each window's last stamp (its link stamp when linked)
    link: np.ndarray  # (S - 1,) bool: window s + 1 starts where window s ends (no gap)
    theta_sigma: float = 0.01
    omega_sigma: float = 0.002
    gap_factor: float = 5.0
    vel_lag1: float = 0.0  # correlation of consecutive velocity noise samples (-1/2: differences of positions)
    vel_ar: NoiseAR | None = None  # velocity noise correlated in time, an autoregression (None: white)

    def residual(self, g: np.ndarray, x: np.ndarray, lay: Layout) -> tuple[np.ndarray, np.ndarray]:
        """(B, S, M) weighted measurement residuals (0 where not measured) and (B, S - 1) continuity
        residuals of the body angle (0 where not linked or without rotation)."""
        vel, pos, XS = simulate(self.win, lay, g, x, coulomb_speed=self.coulomb_speed, max_step=self.max_step,
                                interval_mean=bool(self.vel_lag1))  # fmt: skip
        parts = []
        w = self.win
        ax = np.array(self.base.axes, float)
        if vel is not None:
            m = w.vmask[None, ..., None] * ax
            e = (w.vel[None] - vel) * m / self.sigma_v
            if self.vel_lag1:
                e = decorrelate(e, self.vel_lag1, first=1) * m
            elif self.vel_ar is not None:
                e = whiten_ar(e, w.t, w.vmask, self.vel_ar) * m
            parts.append(e.reshape(g.shape[0], w.S, -1))
        if pos is not None:
            m = w.pmask[None, ..., None] * ax
            parts.append(((w.pos[None] - pos) * m / self.sigma_p).reshape(g.shape[0], w.S, -1))
        rc = np.zeros((g.shape[0], 0))
        if lay.rotation and w.S > 1:  # rows (window s, [theta, omega]) of the links
            end = XS[:, np.arange(w.S - 1), self.last[:-1]]
            gap = np.mod(end[..., 3] - XS[:, 1:, 0, 3] + np.pi, 2 * np.pi) - np.pi  # an angle: modulo a turn
            rc = np.stack((gap / self.theta_sigma, (end[..., 2] - XS[:, 1:, 0, 2]) / self.omega_sigma), axis=-1)
            rc = (rc * self.link[None, :, None]).reshape(g.shape[0], -1)
        return np.concatenate(parts, axis=-1), rc

    @property
    def N(self) -> int:
        ax = int(sum(self.base.axes))
        n = 0
        if self.win.vel is not None:
            n += int(self.win.vmask.sum()) * ax
        if self.win.pos is not None:
            n += int(self.win.pmask.sum()) * ax
        return n


def make_problem(rec: Recording, sigma_v: float, sigma_p: float, opt: FitOptions,
                 rotation: bool | None = None) -> Problem:
    """Cut ``rec`` into windows (and at its gaps); channel weights 1/sigma; rotation modelled when n >= 2."""
    t = rec.t
    dts = np.diff(t)
    med = agent_period(rec)  # each robot's own period: interleaved stamps of robots on their own clocks are no gaps
    wlen = min(opt.window_s, opt.window_stamps * med)
    gapset = set((np.flatnonzero(dts > opt.gap_factor * med) + 1).tolist())
    cuts = [0]
    for k in range(1, t.size):
        if k in gapset or t[k] - t[cuts[-1]] >= wlen - 1e-9 * wlen:
            cuts.append(k)
    cuts.append(t.size)
    spans = [(a, b) for a, b in zip(cuts[:-1], cuts[1:])]
    short = spans[-1][1] - spans[-1][0] < 0.5 * (spans[0][1] - spans[0][0])
    if len(spans) > 1 and short and spans[-1][0] not in gapset:
        spans[-2:] = [(spans[-2][0], spans[-1][1])]  # a short trailing window joins the one before it
    spans = [(a, b) for a, b in spans if b - a >= 3]
    if not spans:
        raise FitError(f"no window of {wlen:g} s holds 3 stamps (median stamp interval {med:g} s): the stamps "
                       "must be in seconds, or run.toml must say their unit (time_unit = \"ms\", \"us\", \"ns\")")
    S = len(spans)
    link = np.array([spans[s][1] == spans[s + 1][0] and spans[s + 1][0] not in gapset for s in range(S - 1)], bool)
    # a linked window runs one stamp further, to the next window's first stamp (not measured there)
    ends = [b + 1 if s < S - 1 and link[s] else b for s, (a, b) in enumerate(spans)]
    L = max(e - a for (a, _), e in zip(spans, ends))
    n = rec.n
    tw = np.empty((S, L))
    fx = np.zeros((S, L, n))
    fy = np.zeros((S, L, n))
    tq = np.zeros((S, L))
    last = np.zeros(S, int)
    wr = rec.wrench
    for s, ((a, b), e) in enumerate(zip(spans, ends)):
        k = e - a
        tw[s, :k], tw[s, k:] = t[a:e], t[e - 1]
        fx[s, :k], fy[s, :k], tq[s, :k] = wr[a:e, :, 0], wr[a:e, :, 1], wr[a:e, :, 2].sum(axis=1)
        fx[s, k:], fy[s, k:], tq[s, k:] = fx[s, k - 1], fy[s, k - 1], tq[s, k - 1]
        last[s] = k - 1
    F = np.stack((fx.sum(axis=2), fy.sum(axis=2)), axis=-1)

    def meas(arr):
        if arr is None:
            return None, None
        y = np.zeros((S, L, n, 2))
        m = np.zeros((S, L, n))
        for s, (a, b) in enumerate(spans):
            y[s, : b - a] = np.nan_to_num(arr[a:b])
            m[s, : b - a] = ~np.isnan(arr[a:b]).any(axis=-1)
        return y, m

    vel, vmask = meas(rec.vel)
    pos, pmask = meas(rec.pos)
    u = np.concatenate((wr[:, :, :2].sum(axis=1), wr[:, :, 0], wr[:, :, 1], wr[:, :, 2].sum(axis=1)[:, None]), axis=1)
    # an axis with neither force nor motion is left out (one agent pushing along x: y is idle)
    axes = []
    for c in range(2):
        moving = any(a is not None and np.nanmax(a[..., c], initial=-np.inf) - np.nanmin(a[..., c], initial=np.inf) > 0
                     for a in (rec.vel, rec.pos))  # fmt: skip
        axes.append(bool(np.abs(wr[..., c]).max() > 0 or moving))
    if not any(axes):
        raise FitError("no force and no motion on either axis: nothing to fit")
    rot = (n >= 2) if rotation is None else rotation
    win = Windows(t=tw, F=F, fx=fx, fy=fy, tau=tq, vel=vel, vmask=vmask, pos=pos, pmask=pmask, u_t=t, u=u,
                  rotation=rot, axes=np.array(axes), hold=rec.hold)  # fmt: skip
    base = Layout(n=n, rotation=rot, axes=(axes[0], axes[1]), positions=pos is not None)
    return Problem(win=win, base=base, sigma_v=sigma_v, sigma_p=sigma_p, coulomb_speed=opt.coulomb_speed or 0.0,
                   max_step=opt.max_step, t0=tw[:, 0], last=last, link=link, theta_sigma=opt.theta_sigma,
                   omega_sigma=opt.omega_sigma, gap_factor=opt.gap_factor)  # fmt: skip


def differenced(pb: Problem, rho: float) -> Problem:
    """``pb`` for velocities that are differences of positions over each interval: predicted as the mean
    velocity over the interval before each stamp (a window's first stamp has no interval: not measured),
    the residual whitened for noise correlated ``rho`` between consecutive samples."""
    vmask = pb.win.vmask.copy()
    vmask[:, 0] = 0.0
    return replace(pb, win=replace(pb.win, vmask=vmask), vel_lag1=rho)


def decorrelate(e: np.ndarray, rho: float, first: int = 0) -> np.ndarray:
    """``e`` (..., L, n, 2), noise of unit variance whose consecutive samples (axis -3) correlate ``rho``
    (MA(1): tridiagonal covariance), whitened by the forward substitution of that covariance's Cholesky
    factor, each window from its stamp ``first`` (those before are left as they are): x_f = e_f,
    x_k = (e_k - b_k x_(k-1)) / a_k with b_k = rho / a_(k-1), a_k = sqrt(1 - b_k^2). A window's unmeasured
    tail (its link stamp, padding) must be zero in ``e`` and is masked again by the caller."""
    L = e.shape[-3]
    out = e.copy()
    a = 1.0
    for k in range(first + 1, L):
        b = rho / a
        a = math.sqrt(1.0 - b * b)
        out[..., k, :, :] = (e[..., k, :, :] - b * out[..., k - 1, :, :]) / a
    return out


@dataclass(frozen=True)
class NoiseAR:
    """Velocity noise that is an autoregression of order p over samples ``dt`` apart, from its reflection
    coefficients ``kappa`` (:func:`ident.prepare.correlated_velocities`); ``tau`` > 0 with p = 1: a
    first-order low-pass of that time constant in continuous time, phi = exp(-dt / tau) over any interval."""

    kappa: tuple[float, ...]
    dt: float
    tau: float = 0.0

    @property
    def order(self) -> int:
        return len(self.kappa)


def correlated(pb: Problem, noise: NoiseAR) -> Problem:
    """``pb`` whose velocity residual is whitened for noise correlated in time as ``noise``: generalised least
    squares, so the fit's intervals, F-tests and whiteness test hold for that noise."""
    return replace(pb, vel_ar=noise)


def whiten_ar(e: np.ndarray, t: np.ndarray, mask: np.ndarray, noise: NoiseAR) -> np.ndarray:
    """``e`` (..., S, L, n, 2), noise of unit variance that is the autoregression ``noise``, whitened per
    window and agent: each sample less its prediction from the agent's preceding samples in the window, over
    the prediction error's deviation (:func:`ident.stats.ar_table`: exact GLS, a window's first samples
    predicted from the fewer predecessors they have). An AR(p) counts samples: its predecessors are the
    run of measured samples one sample period apart before it, up to p (a missing sample or a longer
    interval starts the run afresh). An AR(1) in continuous time (``tau``) is Markov: its predecessor is the
    previous measured sample at any interval, phi = exp(-dt / tau), exact on irregular stamps and across
    missing samples. ``t`` (S, L) the stamps, ``mask`` (S, L, n) where measured; the unmeasured entries of
    ``e`` must be zero and are masked again by the caller."""
    S, L, n = mask.shape
    p = noise.order
    lead = (1,) * (e.ndim - 4)
    if p == 1 and noise.tau > 0:
        k = np.broadcast_to(np.arange(L)[None, :, None], (S, L, n))
        last = np.maximum.accumulate(np.where(mask > 0, k, -1), axis=1)
        prev = np.concatenate((np.full((S, 1, n), -1), last[:, :-1]), axis=1)  # the agent's previous measured stamp
        tn = np.broadcast_to(t[..., None], (S, L, n))
        dt = tn - np.take_along_axis(tn, np.maximum(prev, 0), axis=1)
        phi = np.where(prev >= 0, np.exp(-np.maximum(dt, 0.0) / noise.tau), 0.0)
        phi = np.minimum(phi, 1.0 - 1e-12)
        ep = np.take_along_axis(e, np.maximum(prev, 0)[..., None].reshape(lead + (S, L, n, 1)), axis=-3)
        return (e - phi[..., None] * ep) / np.sqrt(1.0 - phi * phi)[..., None]
    A, v = stats.ar_table(np.asarray(noise.kappa))
    # run[s, k, i]: measured samples one period apart right before stamp k, capped at p
    step = np.abs(np.diff(t, axis=1) - noise.dt) <= 0.5 * noise.dt
    run = np.zeros((S, L, n), int)
    for k in range(1, L):
        run[:, k] = np.where((mask[:, k - 1] > 0) & step[:, k - 1, None], np.minimum(run[:, k - 1] + 1, p), 0)
    coef = A[run]  # (S, L, n, p)
    out = e.copy()
    for j in range(1, p + 1):
        out[..., j:, :, :] -= coef[:, j:, :, j - 1, None] * e[..., :-j, :, :]
    return out / np.sqrt(v[run])[..., None]


def window_valid(pb: Problem) -> np.ndarray:
    """(S, L) the stamps each window owns (a linked window's last stamp is the next window's first)."""
    w = pb.win
    valid = np.zeros((w.S, w.L), bool)
    for s in range(w.S):
        valid[s, : pb.last[s] + 1] = True
        if s < w.S - 1 and pb.link[s]:
            valid[s, pb.last[s]] = False
    return valid


def states_of(pb: Problem, fit: Fit) -> np.ndarray:
    """(S, L, 6) the fitted model's state [vx, vy, omega, theta, px, py] at the stamps."""
    _, _, XS = simulate(pb.win, fit.lay, fit.g[None], fit.x[None], coulomb_speed=pb.coulomb_speed,
                        max_step=pb.max_step)  # fmt: skip
    return XS[0]


@dataclass
class Lin:
    """The residuals and their derivatives at one point (derivatives of the prediction = -d residual)."""

    r: np.ndarray  # (S, M)
    Jg: np.ndarray  # (S, M, G)
    Jx: np.ndarray  # (S, M, K)
    rc: np.ndarray  # (R,) continuity residuals, rows (window s, [theta, omega]) of each link s -> s + 1
    Jcg: np.ndarray  # (R, G)
    Jcx: np.ndarray  # (R, K) with respect to window s's state
    Jcn: np.ndarray  # (R, K) with respect to window s + 1's state

    @property
    def cost(self) -> float:
        return float((self.r * self.r).sum() + (self.rc * self.rc).sum())


@dataclass
class Fit:
    """A fitted model: global parameters ``g`` with covariance ``cov``, window states ``x``."""

    lay: Layout
    g: np.ndarray
    x: np.ndarray  # (S, K)
    cov: np.ndarray  # (G, G)
    rss: float  # weighted measurement residual sum of squares
    N: int
    res: np.ndarray  # (S, M) weighted residual
    nfev: int
    lin: Lin | None = None

    @property
    def P(self) -> int:
        return self.lay.G + self.x.size

    @property
    def sigma2(self) -> float:
        return self.rss / max(self.N - self.P, 1)

    @property
    def bic(self) -> float:
        return self.N * math.log(self.rss / self.N) + self.P * math.log(self.N)

    def param(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        sl = self.lay.slot(name)
        return self.g[sl], Z95 * np.sqrt(np.clip(np.diag(self.cov)[sl], 0, None))

    @property
    def over_floor(self) -> float:
        """The residual's RMS over the noise floor (the residuals are weighted by it)."""
        return math.sqrt(self.rss / self.N)

    def inverse(self, name: str) -> tuple[float, float]:
        """The fitted 1/m (``name`` "m") or 1/J ("J") and its 95 % half-width."""
        i = self.lay.ia if name == "m" else self.lay.ib
        return float(self.g[i]), Z95 * math.sqrt(max(float(self.cov[i, i]), 0.0))

    def mj(self) -> dict[str, float]:
        a, ha = self.inverse("m")
        out = {"m": 1 / a if a > 0 else math.nan, "m_ci95": ha / a**2 if a > 0 else math.nan,
               "J": math.nan, "J_ci95": math.nan}  # fmt: skip
        if self.lay.rotation:
            b, hb = self.inverse("J")
            out["J"] = 1 / b if b > 0 else math.nan
            out["J_ci95"] = hb / b**2 if b > 0 else math.nan
        return out


def _scales(lay: Layout, g: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    sg = np.maximum(np.abs(g), 1e-3)
    if lay.rotation:
        sg[: lay.n_geom] = np.maximum(np.abs(g[: lay.n_geom]), 0.1)
    sg[lay.ia] = max(abs(g[lay.ia]), 1e-5)
    for name in ("measurement_delay", "force_sensor_lag", "force_sensor_lowpass", "agent_actuator_gain",
                 "agent_clock_offset"):
        if name in lay.effects:
            sg[lay.slot(name)] = np.maximum(np.abs(g[lay.slot(name)]), 0.01)
    sx = np.maximum(np.abs(x).max(axis=0) if x.size else np.ones(lay.K), 1e-3)
    return sg, sx


def _theta_index(lay: Layout) -> int:
    return int(sum(lay.axes)) + 1


def linearise(pb: Problem, lay: Layout, g: np.ndarray, x: np.ndarray, cols: np.ndarray | None = None) -> Lin:
    """Residuals and batched forward-difference derivatives at (g, x); ``cols``: only these global columns
    (the others are zero), for the score tests."""
    G, K = lay.G, lay.K
    sg, sx = _scales(lay, g, x)
    cols = np.arange(G) if cols is None else np.asarray(cols)
    hg, hx = 1e-6 * sg[cols], 1e-6 * sx
    nb = 1 + cols.size + K
    Gb = np.repeat(g[None], nb, axis=0)
    Xb = np.repeat(x[None], nb, axis=0)
    Gb[1 + np.arange(cols.size), cols] += hg
    for k in range(K):
        Xb[1 + cols.size + k, :, k] += hx[k]
    R, RC = pb.residual(Gb, Xb, lay)
    r0, rc0 = R[0], RC[0]
    Jg = np.zeros(r0.shape + (G,))
    Jg[..., cols] = (r0[None] - R[1 : 1 + cols.size]).transpose(1, 2, 0) / hg
    Jx = (r0[None] - R[1 + cols.size :]).transpose(1, 2, 0) / hx
    Jcg = np.zeros((rc0.size, G))
    Jcg[:, cols] = ((rc0[None] - RC[1 : 1 + cols.size]) / hg[:, None]).T
    # a link's residual end(s) - start(s + 1) perturbed in every window at once: split own and next
    Jcx = np.zeros((rc0.size, K))
    Jcn = np.zeros((rc0.size, K))
    if lay.rotation and rc0.size:
        ti = _theta_index(lay)
        dall = ((rc0[None] - RC[1 + cols.size :]) / hx[:, None]).T  # (R, K)
        link = pb.link.astype(float)
        Jcn[0::2, ti] = link / pb.theta_sigma  # -d rc / d theta0(s + 1)
        Jcn[1::2, ti - 1] = link / pb.omega_sigma  # -d rc / d omega0(s + 1)
        Jcx[:] = dall - Jcn
    if lay.rotation:  # gauge: the body frame is the world frame at the first window's start
        ti = _theta_index(lay)
        Jx[0, :, ti] = 0.0
        if rc0.size:
            Jcx[0:2, ti] = 0.0
    return Lin(r0, Jg, Jx, rc0, Jcg, Jcx, Jcn)


def normal_equations(lin: Lin) -> tuple[np.ndarray, np.ndarray]:
    """(H, rhs) of the Gauss-Newton step over [g (G), x (S K)]."""
    S, M, G = lin.Jg.shape
    K = lin.Jx.shape[2]
    P = G + S * K
    H = np.zeros((P, P))
    rhs = np.zeros(P)
    H[:G, :G] = np.einsum("smg,smh->gh", lin.Jg, lin.Jg)
    rhs[:G] = np.einsum("smg,sm->g", lin.Jg, lin.r)
    A = np.einsum("smk,sml->skl", lin.Jx, lin.Jx)
    Bm = np.einsum("smk,smg->skg", lin.Jx, lin.Jg)
    c = np.einsum("smk,sm->sk", lin.Jx, lin.r)
    for s in range(S):
        sl = slice(G + s * K, G + (s + 1) * K)
        H[sl, sl] = A[s]
        H[sl, :G] = Bm[s]
        H[:G, sl] = Bm[s].T
        rhs[sl] = c[s]
    for j in range(lin.rc.size):  # continuity rows: [Jcg, Jcx at window s, Jcn at window s + 1]
        s = j // 2
        row = np.zeros(P)
        row[:G] = lin.Jcg[j]
        row[G + s * K : G + (s + 1) * K] = lin.Jcx[j]
        row[G + (s + 1) * K : G + (s + 2) * K] = lin.Jcn[j]
        nz = np.flatnonzero(row)
        H[np.ix_(nz, nz)] += np.outer(row[nz], row[nz])
        rhs[nz] += row[nz] * lin.rc[j]
    return H, rhs


def _step(H: np.ndarray, rhs: np.ndarray, lam: float) -> np.ndarray:
    d = np.diag(H).copy()
    d[d <= 0] = 1.0
    return np.linalg.solve(H + lam * np.diag(d) + 1e-12 * np.diag(d), rhs)


def lm_fit(pb: Problem, lay: Layout, g0: np.ndarray, x0: np.ndarray, *, max_iter: int = 30) -> Fit:
    """Levenberg-Marquardt from (g0, x0); non-negative effects stay >= 0."""
    g, x = g0.astype(float).copy(), x0.astype(float).copy()
    lo = lay.lower()
    g = np.maximum(g, lo)
    G, S, K = lay.G, pb.win.S, lay.K
    lam = 1e-4
    lin = linearise(pb, lay, g, x)
    nfev = 1 + G + K
    cost = lin.cost
    for _ in range(max_iter):
        H, rhs = normal_equations(lin)
        improved = False
        gain = 0.0
        for _try in range(8):
            d = _step(H, rhs, lam)
            gn = np.maximum(g + d[:G], lo)
            xn = x + d[G:].reshape(S, K)
            R, RC = pb.residual(gn[None], xn[None], lay)
            nfev += 1
            cn = float((R * R).sum() + (RC * RC).sum())
            if cn < cost:
                improved = True
                gain = (cost - cn) / max(cost, 1e-300)
                g, x, cost = gn, xn, cn
                lam = max(lam / 10, 1e-9)
                break
            lam *= 10
        if not improved:
            break
        lin = linearise(pb, lay, g, x)
        nfev += G + K
        if gain < 1e-9:
            break
    H, _ = normal_equations(lin)
    rss = float((lin.r * lin.r).sum())
    fit = Fit(lay, g, x, np.zeros((G, G)), rss, pb.N, lin.r, nfev, lin)
    fit.cov = fit.sigma2 * np.linalg.pinv(H, rcond=1e-13, hermitian=True)[:G, :G]
    return fit


def fit_robust(pb: Problem, lay: Layout, g0: np.ndarray, x0: np.ndarray, *, max_iter: int = 30,
               misfit: float = 1.3) -> Fit:
    """:func:`lm_fit` from (g0, x0); while the residual stays above ``misfit`` x the noise floor, also from
    the solution of a loosely linked fit (the rotation's continuity at 10 x its sigma, which a poor
    start's angle can follow), then from a fit of the first windows alone; the best is kept."""
    best = lm_fit(pb, lay, g0, x0, max_iter=max_iter)
    if not lay.rotation or best.sigma2 <= misfit**2:
        return best
    loose = replace(pb, theta_sigma=10 * pb.theta_sigma, omega_sigma=10 * pb.omega_sigma)
    f1 = lm_fit(loose, lay, g0, x0, max_iter=max_iter)
    f2 = lm_fit(pb, lay, f1.g, f1.x, max_iter=max_iter)
    best = f2 if f2.lin.cost < best.lin.cost else best
    if best.sigma2 <= misfit**2 or pb.win.S < 8:
        return best
    # the head of the recording first (a few windows, where the start's angle is still good), then all
    # of it from the head's parameters, every window's state fitted to them first
    head = np.arange(min(6, pb.win.S))
    ph = subset(pb, head)
    fh = lm_fit(ph, lay, g0, x0[head], max_iter=max_iter)
    x = refit_states(pb, lay, fh.g, x0.copy(), iters=3)
    f3 = lm_fit(pb, lay, fh.g, x, max_iter=max_iter)
    return f3 if f3.lin.cost < best.lin.cost else best


def _pick(w: Windows, idx: np.ndarray) -> Windows:
    """Windows ``idx`` of ``w``."""
    p = lambda a: None if a is None else a[idx]  # noqa: E731
    return Windows(t=w.t[idx], F=w.F[idx], fx=w.fx[idx], fy=w.fy[idx], tau=w.tau[idx], vel=p(w.vel), vmask=p(w.vmask),
                   pos=p(w.pos), pmask=p(w.pmask), u_t=w.u_t, u=w.u, rotation=w.rotation, axes=w.axes,
                   hold=w.hold)  # fmt: skip


def subset(pb: Problem, idx: np.ndarray) -> Problem:
    """The problem restricted to windows ``idx`` (increasing); a link survives between neighbours only."""
    link = np.array([pb.link[i] if j == i + 1 else False for i, j in zip(idx[:-1], idx[1:])], bool)
    return replace(pb, win=_pick(pb.win, idx), t0=pb.t0[idx], last=pb.last[idx], link=link)


def fit_parts(pb: Problem, lay: Layout, g: np.ndarray, x: np.ndarray, parts: int) -> list[tuple[np.ndarray, Fit]]:
    """The model ``lay`` refitted from ``g`` (its window states from ``x``) to each of ``parts`` runs of
    consecutive windows on its own (at most one run per window): each run's window indices and its fit. What
    changes from run to run over a recording (a drifting mass, a drifting offset) shows in these fits."""
    runs = np.array_split(np.arange(pb.win.S), min(parts, pb.win.S))
    return [(idx, lm_fit(subset(pb, idx), lay, g, x[idx], max_iter=15)) for idx in runs]


def refit_states(pb: Problem, lay: Layout, g: np.ndarray, x: np.ndarray, iters: int = 3) -> np.ndarray:
    """Gauss-Newton on the window states only (globals fixed): to predict other data with a fitted model."""
    G = lay.G
    for _ in range(iters):
        lin = linearise(pb, lay, g, x, cols=np.zeros(0, int))
        H, rhs = normal_equations(lin)
        x = x + _step(H[G:, G:], rhs[G:], 0.0).reshape(x.shape)
    return x


# --- the start: kinematics, then linear least squares ------------------------------------------------
def _cumint(t: np.ndarray, u: np.ndarray, hold: str) -> np.ndarray:
    """Running integral of u (T, ...) over t from t[0]: left rectangle for a held input (zoh), else the
    trapezoid (exact for foh; for the cubic, good enough for a starting point)."""
    dt = np.diff(t).reshape((-1,) + (1,) * (u.ndim - 1))
    inc = u[:-1] * dt if hold == "zoh" else 0.5 * (u[1:] + u[:-1]) * dt
    return np.concatenate((np.zeros((1,) + u.shape[1:]), np.cumsum(inc, axis=0)), axis=0)


def _cumint_windows(t: np.ndarray, wid: np.ndarray, u: np.ndarray, hold: str) -> np.ndarray:
    """:func:`_cumint` of u restarted at each window's first stamp (``wid``: each stamp's window)."""
    out = np.zeros(u.shape, dtype=u.dtype)
    for s in np.unique(wid):
        k = np.flatnonzero(wid == s)
        out[k] = _cumint(t[k], u[k], hold)
    return out


def _principal_shape(x: np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The contact samples ``x`` (T, n, complex) about their per-stamp centroid, the stamps where every
    agent has one, and the geometry's principal shape ``zb``: for a rigid body both the relative
    velocities and the relative positions are one body-frame shape turned and scaled per stamp (rank
    one), so every row of the centred samples is a complex multiple of ``zb``."""
    full = ~np.isnan(x).any(axis=1)
    if full.sum() < 20:
        raise FitError(f"fewer than 20 stamps with every agent's {what}: cannot initialise the rotation")
    rel = x - np.nanmean(x, axis=1, keepdims=True)
    _, _, vh = np.linalg.svd(rel[full], full_matrices=False)
    return rel, full, vh[0]


def _project(rel: np.ndarray, shape: np.ndarray) -> np.ndarray:
    """Per stamp, the complex h with rel ~ h * shape (least squares over the agents present); NaN where
    the agents present carry less than half the shape's weight."""
    ok = ~np.isnan(rel)
    den = (ok * np.abs(shape) ** 2).sum(axis=1)
    h = np.full(rel.shape[0], np.nan + 0j)
    has = den > 0.5 * (np.abs(shape) ** 2).max()
    h[has] = (np.where(ok, rel, 0)[has] * np.conj(shape)).sum(axis=1) / den[has]
    return h


def _moving_sum(t: np.ndarray, x: np.ndarray, width: float) -> tuple[np.ndarray, np.ndarray]:
    """Sum of the finite x over the stamps within +-width/2 of each stamp, and their count."""
    ok = ~np.isnan(x)
    c = np.concatenate(([0], np.cumsum(np.where(ok, x, 0))))
    cn = np.concatenate(([0], np.cumsum(ok)))
    lo = np.searchsorted(t, t - width / 2, side="left")
    hi = np.searchsorted(t, t + width / 2, side="right")
    return c[hi] - c[lo], cn[hi] - cn[lo]


def _rotation_kinematics(rec: Recording, min_snr: float = 4.0, width_s: float = 0.5, gap_factor: float = 5.0,
                         period: float | None = None):
    """theta(t), omega(t) and the contact geometry about the centroid (body frame = world at t[0]) from the
    rank-1 structure of the relative contact velocities (or positions). Returns (theta, omega, z, good).

    Velocities: rel_i(t) = i omega e^{i theta} z_i, so rel(t) = i h(t) zb with h = omega C e^{i theta}
    for a complex constant C. The direction of h modulo a half turn, psi = theta + arg C, is the angle of
    the sum of h^2 over a short window, halved (circular noise leaves that sum unbiased, and omega's sign
    drops out of h^2); the signed rate p = Re(h e^{-i psi}) = omega |C| follows, and psi - psi(t0) =
    P(t) / |C| with P the running integral of p: one linear least-squares fit gives the scale, hence
    theta and omega, without differentiating anything. A gap is an interval of the stamps over
    ``gap_factor`` x ``period`` (the agents' own sample period, :func:`ident.recording.agent_period`).
    """
    t = rec.t
    T = t.size
    if rec.vel is not None:
        rel, full, zb = _principal_shape(rec.vel[..., 0] + 1j * rec.vel[..., 1], "velocity")
        n = rec.n
        resid = rel[full] - (rel[full] @ np.conj(zb))[:, None] * zb[None]
        sigma = float(np.sqrt(np.mean(np.abs(resid) ** 2) / 2 * n / max(n - 2, 1)))
        h = _project(rel, 1j * zb)
        has = ~np.isnan(h)
        # noise of h per component is sigma (zb has unit norm); of the windowed sum of h^2, about
        # 2 |h| sigma per term. Noisy data get longer windows, until a quarter of the stamps are
        # significant (or the window is 8x the default). h^2 turns at 2 omega: a window over which it turns
        # more than a quarter turn sums it away, so a fast spin shortens the first window to pi / (4 |omega|)
        # (|omega| from h's own turn between stamps where h stands above its noise)
        big = has[1:] & has[:-1] & (np.abs(np.nan_to_num(h[1:])) > min_snr * sigma) \
            & (np.abs(np.nan_to_num(h[:-1])) > min_snr * sigma)
        if big.sum() >= 20:
            spin = float(np.median(np.abs(np.angle(h[1:][big] * np.conj(h[:-1][big]))) / np.diff(t)[big]))
            if spin > 0.0:
                width_s = min(width_s, math.pi / (4.0 * spin))
        for width in width_s * 2.0 ** np.arange(4):
            s2, cnt = _moving_sum(t, h * h, width)
            s1, _ = _moving_sum(t, np.abs(h) ** 2, width)
            noise = np.sqrt(4 * sigma**2 * s1 + 2 * cnt * sigma**4)
            idx = np.flatnonzero(has & (np.abs(s2) > min_snr * noise))
            if idx.size >= max(20, has.sum() // 4):
                break
        if idx.size < 20:
            raise FitError("the load hardly rotates (relative contact velocities at noise level): contact geometry, "
                           "omega and J are not observable from these data")  # fmt: skip
        # a gap in the stamps (as the fit's windows see one) breaks the angle's unwrapping: each stretch
        # between gaps gets its own offset, and its own half turn (the sign of C) below
        dts = np.diff(t)
        seg = np.concatenate(([0], np.cumsum(dts > gap_factor * (period or agent_period(rec)))))
        psi = np.unwrap(np.angle(s2[idx])) / 2
        p = np.real(h * np.exp(-1j * np.interp(t, t[idx], psi)))
        # psi is known modulo a half turn and its unwrapping cannot cross a gap, so a stretch may continue
        # on the other branch, where p has the opposite sign: each stretch's sign is the sign of its own
        # slope of psi against P relative to the longest stretch's
        P = _cumint(t, np.nan_to_num(p), "foh")
        slope = np.zeros(seg[-1] + 1)
        for q in range(seg[-1] + 1):
            sel = seg[idx] == q
            if sel.sum() >= 3:
                slope[q] = np.sum((P[idx][sel] - P[idx][sel].mean()) * (psi[sel] - psi[sel].mean()))
        ref = np.argmax(np.bincount(seg[idx], minlength=seg[-1] + 1))
        flip = np.sign(slope) * np.sign(slope[ref]) < 0
        if flip.any():
            p *= np.where(flip, -1.0, 1.0)[seg]
            P = _cumint(t, np.nan_to_num(p), "foh")
        A = np.column_stack((P[idx], seg[idx, None] == np.arange(seg[-1] + 1)))
        coef, *_ = np.linalg.lstsq(A, psi, rcond=None)
        k = float(coef[0])
        if not (math.isfinite(k) and k != 0.0):
            raise FitError("the load's angle does not change measurably: contact geometry, omega and J are not "
                           "observable from these data")  # fmt: skip
        theta = k * P + (coef[1 + seg] - coef[1])
        omega = k * np.nan_to_num(p)
        w = np.where(has, omega, 0.0)
        hw = np.where(has, h, 0) * np.exp(-1j * theta) * w
        C = np.sum(hw[seg == 0]) / np.sum(w[seg == 0] ** 2)
        for q in range(1, seg[-1] + 1):
            if np.real(np.sum(hw[seg == q]) * np.conj(C)) < 0:
                theta[seg == q] += np.pi
        C = np.sum(np.where(has, h, 0) * np.exp(-1j * theta) * w) / np.sum(w * w)
        return theta, omega, zb * C, has
    rel, _, zb = _principal_shape(rec.pos[..., 0] + 1j * rec.pos[..., 1], "position")
    h = _project(rel, zb)  # rel(t) = h(t) zb with h = C e^{i theta}
    idx = np.flatnonzero(~np.isnan(h))
    phi = np.unwrap(np.angle(h[idx]))
    theta = np.interp(t, t[idx], phi - phi[0])
    C = np.mean(h[idx] * np.exp(-1j * theta[idx]))
    omega = np.gradient(theta, t)  # the initial guess only: the fit itself differentiates nothing
    return theta, omega, zb * C, np.ones(T, bool)


def _filled(rec: Recording, gap_factor: float) -> Recording:
    """The recording with each agent's missing measurements interpolated between its own neighbouring
    samples (not across a gap: an interval over ``gap_factor`` x its own median), for the start only.
    Agents that log on their own clocks share few or no stamps, and the start's per-stamp kinematics
    (centroid, rank-one shape) need every agent at a stamp; the fit itself uses the samples as measured."""
    out = []
    for arr in (rec.vel, rec.pos):
        if arr is None or not np.isnan(arr).any():
            out.append(arr)
            continue
        arr = arr.copy()
        for i in range(rec.n):
            for c in range(2):
                y = arr[:, i, c]
                ok = ~np.isnan(y)
                if ok.sum() < 2 or ok.all():
                    continue
                ti = rec.t[ok]
                k = np.searchsorted(ti, rec.t[~ok])  # the agent's own samples either side: ti[k - 1], ti[k]
                inside = (k > 0) & (k < ti.size)
                kk = np.clip(k, 1, ti.size - 1)
                span = ti[kk] - ti[kk - 1]
                fill = inside & (span <= gap_factor * float(np.median(np.diff(ti))))
                idx = np.flatnonzero(~ok)[fill]
                y[idx] = np.interp(rec.t[idx], ti, y[ok])
        out.append(arr)
    return replace(rec, vel=out[0], pos=out[1])


def _lstsq_blocks(group: np.ndarray, local: np.ndarray, shared: np.ndarray, y: np.ndarray,
                  G: int) -> tuple[np.ndarray, np.ndarray]:
    """Least squares min |local_r . x_(group_r) + shared_r . c - y_r| over the shared coefficients c (p,)
    and each group's local ones x (G, l): row r has the local design ``local`` (R, l) in its group's
    columns only. Each group's local columns are eliminated within the group (the rows' projection on
    them removed), the shared ones fitted on what is left, and the local ones solved back per group:
    memory and time linear in the rows, where the dense design (R, G l + p) grows as the rows times the
    windows. A group without rank in its local columns takes its minimum-norm local coefficients."""
    nl = local.shape[1]

    def sums(v):  # (G, nl, k): each group's sum of local_r v_r^T
        return np.stack([np.stack([np.bincount(group, local[:, a] * v[:, b], minlength=G) for b in range(v.shape[1])],
                                  axis=-1) for a in range(nl)], axis=1)  # fmt: skip

    ginv = np.linalg.pinv(sums(local), hermitian=True)

    def project(v):  # the part of the columns of v (R, k) in each row's group's local span, and its coefficients
        coef = ginv @ sums(v)
        return np.einsum("rl,rlk->rk", local, coef[group]), coef

    rhs = np.concatenate((shared, y[:, None]), axis=1)
    fitted, _ = project(rhs)
    rest = rhs - fitted
    c = np.linalg.lstsq(rest[:, :-1], rest[:, -1], rcond=None)[0]
    _, x = project((y - shared @ c)[:, None])
    return c, x[:, :, 0]


def initial_guess(pb: Problem, rec: Recording, effects: tuple[str, ...] = ()) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """(g0, x0, warnings) for the nominal layout ``pb.base`` with ``effects``: equation error, linear least
    squares on the measured kinematics. From velocities, viscous and Coulomb friction and a force bias
    enter the translation's regression (their integrals of the measured velocity and time) and
    rotational damping the rate's (the integral of the rate); the other effects start at 0."""
    lay = pb.base.with_effects(effects)
    warns: list[str] = []
    period = agent_period(rec)  # of the rows as logged: the filled recording has every agent at every stamp
    rec = _filled(rec, pb.gap_factor)
    t = rec.t
    T, n = t.size, rec.n
    S = pb.win.S
    # window index of every stamp
    starts = pb.t0
    wid = np.searchsorted(starts, t, side="right") - 1
    t0w = starts[wid]
    F = rec.wrench[:, :, :2].sum(axis=1)
    if lay.rotation:
        theta, omega, z, good = _rotation_kinematics(rec, gap_factor=pb.gap_factor, period=period)
        e = 1j * omega * np.exp(1j * theta)
    else:
        theta = omega = np.zeros(T)
        z = np.zeros(n, complex)
        good = np.ones(T, bool)
        e = np.zeros(T, complex)
    # translation: linear in (per-window v0 [and p0], a, zc)
    Sint = _cumint_windows(t, wid, F, rec.hold)
    SSint = _cumint_windows(t, wid, Sint, "foh")
    use_vel = rec.vel is not None
    if use_vel:
        yb = np.nanmean(rec.vel[..., 0] + 1j * rec.vel[..., 1], axis=1)
    else:
        yb = np.nanmean(rec.pos[..., 0] + 1j * rec.pos[..., 1], axis=1)
    okb = ~np.isnan(yb) & good
    nloc = 1 if use_vel else 2
    axes = np.array(lay.axes)
    na = int(axes.sum())
    iax = np.flatnonzero(axes)
    # effect columns after the mass's (velocities only): -int v, -int v/|v|, and time per active axis
    cols_eff: dict[str, int] = {}
    k_ = 2 * nloc * S + 1
    for name, width in (("viscous_friction", 1), ("coulomb_friction", 1), ("force_bias", na)):
        if use_vel and name in lay.effects:
            cols_eff[name] = k_
            k_ += width
    ncol = k_ + (2 if lay.rotation else 0)
    # the window columns (each window's v0 [and p0] per axis) are local to its rows: solved per window by
    # _lstsq_blocks, the dense design would be 2 T x 2 S (quadratic in the length)
    k0 = 2 * nloc * S
    As = np.zeros((2 * T, ncol - k0))
    if cols_eff:
        ok_y = ~np.isnan(yb)
        yf = np.interp(t, t[ok_y], yb[ok_y].real) + 1j * np.interp(t, t[ok_y], yb[ok_y].imag)
        yc = yf / np.sqrt(np.abs(yf) ** 2 + pb.coulomb_speed**2 + 1e-300)
        Iv = _cumint_windows(t, wid, yf, "foh")
        Ic = _cumint_windows(t, wid, yc, "foh")
    for c in range(2):  # real part (x) rows 0..T-1, imaginary (y) rows T..2T-1
        rows = np.arange(T) + c * T
        As[rows, 0] = Sint[:, c] if use_vel else SSint[:, c]
        part = (lambda z: z.real) if c == 0 else (lambda z: z.imag)  # noqa: E731
        if "viscous_friction" in cols_eff:
            As[rows, cols_eff["viscous_friction"] - k0] = -part(Iv)
        if "coulomb_friction" in cols_eff:
            As[rows, cols_eff["coulomb_friction"] - k0] = -part(Ic)
        if "force_bias" in cols_eff and axes[c]:
            As[rows, cols_eff["force_bias"] - k0 + int(np.sum(axes[:c]))] = t - t0w
    if lay.rotation:
        rot = e if use_vel else np.exp(1j * theta)
        As[:T, -2], As[T:, -2] = rot.real, rot.imag  # zc real part
        As[:T, -1], As[T:, -1] = (1j * rot).real, (1j * rot).imag
    # local columns: v0 (velocities), or p0 and v0 times the time since the window's start (positions)
    local = np.ones((2 * T, 1)) if use_vel else np.stack((np.ones(2 * T), np.tile(t - t0w, 2)), axis=1)
    group = np.concatenate((2 * wid, 2 * wid + 1))
    yr = np.concatenate((yb.real, yb.imag))
    rowok = np.concatenate((okb & axes[0], okb & axes[1]))
    cs, xl = _lstsq_blocks(group[rowok], local[rowok], As[rowok], yr[rowok], 2 * S)
    coef = np.zeros(ncol)
    coef[k0:] = cs
    if use_vel:
        coef[:k0] = xl[:, 0]  # column 2 s + c
    else:
        coef[:k0] = xl.reshape(S, 2, 2).transpose(0, 2, 1).ravel()  # columns 4 s + c (p0) and 4 s + 2 + c (v0)
    a = float(coef[2 * nloc * S])
    if not a > 0:
        warns.append("initial mass estimate non-positive (weak force excitation); starting from m = 1e3 kg")
        a = 1e-3
    zc = complex(coef[-2], coef[-1]) if lay.rotation else 0j
    g0 = np.zeros(lay.G)
    g0[lay.ia] = a
    for name, col in cols_eff.items():
        val = coef[col : col + lay.q(name)] / a
        g0[lay.slot(name)] = val if name == "force_bias" else np.maximum(val, 0.0)
    x0 = np.zeros((S, lay.K))
    for s in range(S):
        if use_vel:
            v0 = coef[2 * s : 2 * s + 2]
            x0[s, :na] = v0[iax]
        else:
            x0[s, :na] = coef[4 * s + 2 : 4 * s + 4][iax]
    if lay.positions:
        # window start positions: from the measured mean position (minus the rotated zc)
        q = np.nanmean(rec.pos[..., 0] + 1j * rec.pos[..., 1], axis=1) - np.exp(1j * theta) * zc
        for s in range(S):
            k = np.flatnonzero(wid == s)
            if k.size:
                p0 = q[k[0]] if np.isfinite(q[k[0]]) else np.nanmean(q[k])
                x0[s, lay.K - na :] = np.array([p0.real, p0.imag])[iax]
    if lay.rotation:
        r = z + zc
        g0[: 2 * n] = np.stack((r.real, r.imag), axis=1).ravel()
        tq = rec.wrench[:, :, 2].sum(axis=1)
        fx, fy = rec.wrench[:, :, 0], rec.wrench[:, :, 1]
        P = fy @ r.real - fx @ r.imag
        Q = -(fx @ r.real + fy @ r.imag)
        Tq = tq + np.cos(theta) * P + np.sin(theta) * Q
        C = _cumint_windows(t, wid, Tq, rec.hold)
        damp = "rotational_damping" in lay.effects
        tbias = "torque_bias" in lay.effects
        Ab = np.zeros((T, 1 + damp + tbias))  # shared columns; each window's omega_0 is local (_lstsq_blocks)
        Ab[:, 0] = C
        if damp:  # b c_r multiplies -int omega
            Ab[:, 1] = -_cumint_windows(t, wid, omega, "foh")
        if tbias:  # b T_0 multiplies the time since the window's start
            Ab[:, 1 + damp] = t - t0w
        cshared, w0 = _lstsq_blocks(wid[good], np.ones((int(good.sum()), 1)), Ab[good], omega[good], S)
        cb = np.concatenate((w0[:, 0], cshared))
        b = float(cb[S])
        if not b > 0:
            warns.append("initial 1/J non-positive (weak torque excitation); starting from J = 100 kg m^2")
            b = 0.01
        g0[lay.ib] = b
        if damp:
            g0[lay.slot("rotational_damping")] = max(float(cb[S + 1]) / b, 0.0)
        if tbias:
            g0[lay.slot("torque_bias")] = float(cb[S + 1 + damp]) / b
        for s in range(S):
            k = np.flatnonzero(wid == s)
            if k.size:
                x0[s, na] = cb[s]
                x0[s, na + 1] = theta[k[0]]
    return g0, x0, warns
