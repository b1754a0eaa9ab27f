"""Paper 000's own estimator blocks of the dynamical phase and its consensus, as pure reference implementations.

The running agents use the EKF of ``agents/rigid_filter.py`` and the consensus of ``agents/consensus.py``
instead (docs/dynamics.md says why); these blocks exist so that the paper's method can be run, tested and
compared as printed (with the garbled equations rederived: docs/paper-observers.md, which also lists the
symbols and the rigid-body model). One tick per call, time only as the injected step ``dt``; no clock,
no RNG. States are small frozen dataclasses and every ``*_step`` returns a new one (filterpy style).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Literal

from agents.consensus import average_step, disagreement

Vec2 = tuple[float, float]


# --------------------------------------------------------------------------- small vector helpers
def perp(q: Vec2) -> Vec2:
    """q^perp = Q q, the +90 degree rotation (the paper's operator; pitfalls note: not -90)."""
    return (-q[1], q[0])


def cross(a: Vec2, b: Vec2) -> float:
    """a x b = a^perp . b (the z component of the 3-D cross product)."""
    return a[0] * b[1] - a[1] * b[0]


def _rotate(q: Vec2, angle: float) -> Vec2:
    c, s = math.cos(angle), math.sin(angle)
    return (c * q[0] - s * q[1], s * q[0] + c * q[1])


# ---------------------------------------------------------------- the paper's consensus (ref. [19], [23])
def centroid_step(x_i: complex, neighbours: Iterable[tuple[complex, complex]], eps: float) -> complex:
    """One centroid-estimation update of ref. [19] (Result 3): x_i += eps sum_j (x_j - x_i + e_ij) with an
    antisymmetric edge term e_ij = (z_ij - z_ji)/2 from both ends' estimates, so sum_i x_i stays 0. The
    agent runs its flow form instead (:func:`agents.consensus.flow_step`), which keeps the sum under
    lost and delayed messages."""
    acc = 0j
    for x_j, e_ij in neighbours:
        acc += x_j - x_i + e_ij
    return x_i + eps * acc


def fodac_step(x_i: float, neighbours: Iterable[float], eps: float, du_i: float) -> float:
    """One first-order input dynamic consensus update (ref. [23]); du_i = u_i(k+1) - u_i(k). It passes each
    agent's input noise straight through and a lost message breaks its invariant for good, so the agent
    runs :func:`agents.consensus.lowpass_step` and :class:`agents.consensus.FlowAverage` instead."""
    return x_i + eps * disagreement(x_i, neighbours) + du_i


def run_average(x0: Sequence[float], nbrs: Sequence[Sequence[int]], eps: float, iters: int) -> list[float]:
    """Synchronous static average consensus over a whole graph."""
    x = list(x0)
    for _ in range(iters):
        x = [average_step(x[i], (x[j] for j in nbrs[i]), eps) for i in range(len(x))]
    return x


def run_centroid(z: dict[tuple[int, int], complex], nbrs: Sequence[Sequence[int]], eps: float, iters: int) -> list[complex]:
    """Synchronous ref. [19] over a whole graph; ``z[(i, j)]`` is agent i's estimate of z_ij."""
    n = len(nbrs)
    x = [0j] * n
    for _ in range(iters):
        x = [centroid_step(x[i], ((x[j], 0.5 * (z[(i, j)] - z[(j, i)])) for j in nbrs[i]), eps) for i in range(n)]
    return x


# ------------------------------------------------------------ Results 6-8 and 11: observer inputs
def mean_force(forces: Sequence[Vec2]) -> Vec2:
    """f_mean = (1/n) sum_i f_i, eq. (12)."""
    n = len(forces)
    return (sum(f[0] for f in forces) / n, sum(f[1] for f in forces) / n)


def f_bar(forces: Sequence[Vec2], inertia: float) -> Vec2:
    """f_bar = n f_mean / J = (sum_i f_i) / J: the force input (u1, u2) of observer (18)."""
    return (sum(f[0] for f in forces) / inertia, sum(f[1] for f in forces) / inertia)


def eta1(forces: Sequence[Vec2], zi: Sequence[Vec2], inertia: float) -> float:
    """eta_1 = (1/J) sum_i z_i x (f_i - f_mean) = (1/J) sum_i z_i x f_i, by (13) since sum_i z_i = 0.

    Written with f_i - f_mean because that is the signal a team should run through dynamic
    consensus: under a common force it is zero at every agent, whereas z_i x f_i rotates with the
    load and differs per agent (pitfalls note: large per-agent consensus errors on a line graph).
    """
    fm = mean_force(forces)
    return sum(cross(z, (f[0] - fm[0], f[1] - fm[1])) for z, f in zip(zi, forces, strict=True)) / inertia


def eta2(taus: Sequence[float], inertia: float) -> float:
    """eta_2 = (1/J) sum_i tau_i."""
    return sum(taus) / inertia


def eta(forces: Sequence[Vec2], taus: Sequence[float], zi: Sequence[Vec2], inertia: float) -> float:
    """eta = eta_1 + eta_2: the input u3 of observer (18)."""
    return eta1(forces, zi, inertia) + eta2(taus, inertia)


def local_channels(f_i: Vec2, tau_i: float, z_i: Vec2, fmean_i: Vec2) -> tuple[float, float, float, float]:
    """Agent i's inputs to the team's dynamic consensus: (f_ix, f_iy, z_i x (f_i - fmean_i), tau_i).

    ``fmean_i`` is agent i's current estimate of f_mean (its own consensus state). The team averages
    of these four channels, times n (and divided by J for (18)), are the observer inputs: see
    :func:`inputs_18` and :func:`inputs_24`.
    """
    return (f_i[0], f_i[1], cross(z_i, (f_i[0] - fmean_i[0], f_i[1] - fmean_i[1])), tau_i)


def inputs_18(averages: Sequence[float], n: int, inertia: float) -> tuple[float, float, float]:
    """(u1, u2, u3) = (f_bar_x, f_bar_y, eta) of (18) from the four channel averages of :func:`local_channels`."""
    fx, fy, zf, tau = averages
    return (n * fx / inertia, n * fy / inertia, n * (zf + tau) / inertia)


def inputs_24(averages: Sequence[float], n: int) -> tuple[float, float, float]:
    """(u1, u2, u3) = (f_tilde_x, f_tilde_y, eta_tilde) of (24) from the four channel averages."""
    fx, fy, zf, tau = averages
    return (n * fx, n * fy, n * (zf + tau))


# ---------------------------------------------------------------------------- Result 9: v_C (20)
def vc_from_contact(v_ci: Vec2, omega: float, zc: Vec2, z_i: Vec2) -> Vec2:
    """v_C = v_Ci - omega (z_C + z_i)^perp, eq. (20) (the printed minus sign is lost in extraction).

    From the rigid-body field v_Ci = v_C + omega (p_Ci - p_C)^perp with p_Ci - p_C = z_i + z_C.
    """
    qx, qy = zc[0] + z_i[0], zc[1] + z_i[1]
    return (v_ci[0] + omega * qy, v_ci[1] - omega * qx)


# --------------------------------------------------------- Results 5 and 10: integral least squares
@dataclass(frozen=True, slots=True)
class IntegralLS:
    """Online linear least squares on the integral form of y_dot = theta phi_dot (Results 5, 10).

    The paper solves (7), (11) and (21) "via filtering": integrate both sides, so that
    y_k = c + theta Phi_k with Phi_k = sum_{j<k} dphi_j (the known impulse) and an unknown
    constant c = y_0 (estimated too, so y_0's noise does not bias theta). Measurement noise on
    y_k then enters once per sample, not differentiated. y and Phi have the same dimension d
    (1 for omega in (11), 2 for v_C in (21)); theta is a scalar. Moments are kept centred
    (Welford) so that long runs do not lose precision.

    count: samples so far; phi: the running Phi (before the next sample); mphi, my: sample means;
    sxx = sum |Phi_k - mean|^2, sxy = sum (Phi_k - mean).(y_k - mean), syy = sum |y_k - mean|^2.
    """

    count: int = 0
    phi: tuple[float, ...] = ()
    mphi: tuple[float, ...] = ()
    my: tuple[float, ...] = ()
    sxx: float = 0.0
    sxy: float = 0.0
    syy: float = 0.0

    @property
    def theta(self) -> float:
        """The LS estimate of theta (nan until the regressor has moved)."""
        return self.sxy / self.sxx if self.sxx > 0.0 else math.nan

    @property
    def theta_std(self) -> float:
        """Standard error of theta from the residuals (d components per sample, 1 + d parameters)."""
        d = len(self.my)
        dof = self.count * d - (1 + d)
        if self.sxx <= 0.0 or dof <= 0:
            return math.nan
        rss = max(self.syy - self.sxy * self.sxy / self.sxx, 0.0)
        return math.sqrt(rss / dof / self.sxx)


def ls_step(s: IntegralLS, y: Sequence[float], dphi: Sequence[float]) -> IntegralLS:
    """Add the sample (y_k, Phi_k), then advance Phi by this tick's impulse dphi_k (the input of tick k
    shows in y from tick k + 1 on, like the plant)."""
    d = len(y)
    phi = s.phi or (0.0,) * d
    mphi = s.mphi or (0.0,) * d
    my = s.my or (0.0,) * d
    k = s.count + 1
    dp = [phi[a] - mphi[a] for a in range(d)]
    dy = [y[a] - my[a] for a in range(d)]
    mphi2 = tuple(mphi[a] + dp[a] / k for a in range(d))
    my2 = tuple(my[a] + dy[a] / k for a in range(d))
    sxx = s.sxx + sum(dp[a] * (phi[a] - mphi2[a]) for a in range(d))
    sxy = s.sxy + sum(dp[a] * (y[a] - my2[a]) for a in range(d))
    syy = s.syy + sum(dy[a] * (y[a] - my2[a]) for a in range(d))
    return IntegralLS(k, tuple(phi[a] + dphi[a] for a in range(d)), mphi2, my2, sxx, sxy, syy)


def j_impulse(kz: float, zi: Sequence[Vec2], dt: float) -> tuple[float]:
    """Result 5's regressor increment dt k_z sum_i |z_i|^2 for (11) (so that theta = iota = 1/J).

    Valid while every agent applies f_i = k_z z_i^perp and tau_i = 0: then sum_i f_i = 0 removes
    z_C from (10) and omega_dot = iota k_z sum_i |z_i|^2.
    """
    return (dt * kz * sum(z[0] * z[0] + z[1] * z[1] for z in zi),)


def j_force(kz: float, z_i: Vec2) -> Vec2:
    """Result 5's force for agent i: f_i = k_z z_i^perp (and tau_i = 0)."""
    return (-kz * z_i[1], kz * z_i[0])


def m_impulse(n: int, fmean: Vec2, dt: float) -> Vec2:
    """(21)'s regressor increment dt n f_mean (so that theta = mu = 1/m)."""
    return (dt * n * fmean[0], dt * n * fmean[1])


# --------------------------------------------------------------------- Results 7-8: observer (18)
@dataclass(frozen=True, slots=True)
class Zc18:
    """State of observer (18): (x1, x2) = z_C estimate (m), x3 = omega estimate (rad/s)."""

    x1: float
    x2: float
    x3: float

    @property
    def zc(self) -> Vec2:
        return (self.x1, self.x2)


def zc18_step(s: Zc18, y: float, u1: float, u2: float, u3: float, dt: float, ke: float, gamma: float = 1.0) -> Zc18:
    """One tick of observer (18) for system (17) (z_C = (x1, x2), omega = x3 = y).

    Rederived so that V = (e1^2 + e2^2)/(2 gamma) + e3^2/2, e = x - x_hat, has V_dot = -k_e e3^2:
        x1' = -x2 y + gamma u2 (y - x3)
        x2' =  x1 y - gamma u1 (y - x3)
        x3' =  x1 u2 - x2 u1 + u3 + k_e (y - x3)
    (u1, u2) = f_bar, u3 = eta. gamma = 1 is the paper's printed observer; gamma > 0 rescales the
    z_C injection (the states are metres while f_bar is ~0.5 1/(m s^2): see docs/paper-observers.md).
    """
    r = y - s.x3
    a1, a2 = _rotate((s.x1, s.x2), y * dt)
    return Zc18(
        a1 + dt * gamma * u2 * r,
        a2 - dt * gamma * u1 * r,
        s.x3 + dt * (s.x1 * u2 - s.x2 * u1 + u3 + ke * r),
    )


# ------------------------------------------------------------- Algorithm 2: observer (24), z_C, 1/J
@dataclass(frozen=True, slots=True)
class Zc24:
    """State of observer (24): (x1, x2) = z_C / J, x3 = omega, x4 = iota = 1/J."""

    x1: float
    x2: float
    x3: float
    x4: float

    @property
    def zc(self) -> Vec2:
        """z_C = (x1/x4, x2/x4) (nan while the 1/J estimate is not positive)."""
        if self.x4 <= 0.0:
            return (math.nan, math.nan)
        return (self.x1 / self.x4, self.x2 / self.x4)

    @property
    def inertia(self) -> float:
        """J = 1/x4 (nan while x4 is not positive)."""
        return 1.0 / self.x4 if self.x4 > 0.0 else math.nan


def zc24_start(zc: Vec2, inertia: float, omega: float) -> Zc24:
    """Initial state from guesses of z_C, J and the current omega."""
    return Zc24(zc[0] / inertia, zc[1] / inertia, omega, 1.0 / inertia)


def zc24_step(
    s: Zc24, y: float, u1: float, u2: float, u3: float, dt: float, ke: float, gamma_z: float = 1.0, gamma_j: float = 1.0
) -> Zc24:
    """One tick of observer (24) for the rescaled system (23) (x1, x2 = z_C/J, x4 = 1/J).

    (u1, u2) = f_tilde = n f_mean, u3 = eta_tilde. With V = (e1^2 + e2^2)/(2 gamma_z) + e3^2/2
    + e4^2/(2 gamma_j), V_dot = -k_e e3^2 for
        x1' = -x2 y + gamma_z u2 (y - x3)
        x2' =  x1 y - gamma_z u1 (y - x3)
        x3' =  x1 u2 - x2 u1 + x4 u3 + k_e (y - x3)
        x4' =  gamma_j u3 (y - x3)
    gamma_z = gamma_j = 1 is the printed observer. It needs y, u3 and (u1, u2) all not identically
    zero (Prop. 4): a torque about the contact centroid must be applied, else J and z_C mix.
    """
    r = y - s.x3
    a1, a2 = _rotate((s.x1, s.x2), y * dt)
    return Zc24(
        a1 + dt * gamma_z * u2 * r,
        a2 - dt * gamma_z * u1 * r,
        s.x3 + dt * (s.x1 * u2 - s.x2 * u1 + s.x4 * u3 + ke * r),
        s.x4 + dt * gamma_j * u3 * r,
    )


# ----------------------------------------------------------------- Algorithm 2: observer (26), 1/m
Gain26 = Literal["proportional", "sign", "constant"]


@dataclass(frozen=True, slots=True)
class Mass26:
    """State of observer (26): z1 = estimate of the output y (v_C, or its projection), z2 = mu = 1/m."""

    z1: tuple[float, ...]
    z2: float

    @property
    def mass(self) -> float:
        """m = 1/z2 (nan while z2 is not positive)."""
        return 1.0 / self.z2 if self.z2 > 0.0 else math.nan


def mass26_start(y: Sequence[float], mass: float) -> Mass26:
    """Initial state: the current output and a guess of m."""
    return Mass26(tuple(y), 1.0 / mass)


def paper25_io(vc: Vec2, fmean: Vec2, n: int) -> tuple[tuple[float], tuple[float]]:
    """(y, u) of the paper's scalar system (25): y = v_Cx + v_Cy, u = n (f_mean,x + f_mean,y).

    The printed u lacks the factor n (then z2 = n/m, not 1/m). The projection on (1, 1) makes m
    unobservable for a force perpendicular to (1, 1); pass the two components instead
    (y = v_C, u = n f_mean) to use the vector form of :func:`mass26_step`.
    """
    return (vc[0] + vc[1],), (n * (fmean[0] + fmean[1]),)


def mass26_step(
    s: Mass26,
    y: Sequence[float],
    u: Sequence[float],
    dt: float,
    k1: float,
    k2: float,
    gain: Gain26 = "proportional",
    u_min: float = 0.0,
) -> Mass26:
    """One tick of observer (26) for z1_dot = z2 u, z2_dot = 0, output y = z1 (system (25)).

        z1' = z2 u + k1 (y - z1)
        z2' = K2(u) . (y - z1)

    y and u have the same dimension (1: the paper's projection, 2: both components of v_C and
    n f_mean). The paper asks k1 > 0, k2 u > 0, k1^2 > 4 k2 u; a common force that changes sign
    breaks k2 u > 0 for any constant k2 (then one error eigenvalue is positive: the estimate runs
    away while u has the wrong sign). ``gain`` chooses K2(u):

    - "proportional" (default): K2 = k2 u. With V = |e1|^2/2 + e2^2/(2 k2),
      V_dot = e1.(e2 u - k1 e1) - e2 u.e1 = -k1 |e1|^2 for every u(t), whatever its sign or size;
      the frozen-time condition holds as k2 |u|^2 > 0, and the update pauses by itself as u -> 0
      (where 1/m is unobservable). For real eigenvalues keep k2 |u|^2 < k1^2/4.
    - "sign": K2 = k2 u/|u| (the gain takes the sign/direction of u), paused (K2 = 0) while
      |u| < u_min. V = |e1|^2/2 + |u| e2^2/(2 k2) gives V_dot = -k1 |e1|^2 while |u| is constant;
      it grows with d|u|/dt, so this is the right choice only for a bang-bang force.
    - "constant": K2 = k2 (scalar y only): the printed observer, kept to show the failure.

    |u| <= u_min pauses the z2 update in every mode (noise in a near-zero consensus force would
    otherwise drive it).
    """
    d = len(y)
    r = [y[a] - s.z1[a] for a in range(d)]
    un = math.sqrt(sum(v * v for v in u))
    if un <= u_min:
        dz2 = 0.0
    elif gain == "proportional":
        dz2 = k2 * sum(u[a] * r[a] for a in range(d))
    elif gain == "sign":
        dz2 = k2 * sum(u[a] * r[a] for a in range(d)) / un
    elif gain == "constant":
        if d != 1:
            raise ValueError("gain='constant' is the paper's scalar observer: y and u must have one component")
        dz2 = k2 * r[0]
    else:
        raise ValueError(f"gain must be 'proportional', 'sign' or 'constant', got {gain!r}")
    z1 = tuple(s.z1[a] + dt * (s.z2 * u[a] + k1 * r[a]) for a in range(d))
    return Mass26(z1, s.z2 + dt * dz2)


__all__ = [
    "IntegralLS",
    "Mass26",
    "Zc18",
    "Zc24",
    "centroid_step",
    "cross",
    "eta",
    "eta1",
    "eta2",
    "f_bar",
    "fodac_step",
    "inputs_18",
    "inputs_24",
    "j_force",
    "j_impulse",
    "local_channels",
    "ls_step",
    "m_impulse",
    "mass26_start",
    "mass26_step",
    "mean_force",
    "paper25_io",
    "perp",
    "run_average",
    "run_centroid",
    "vc_from_contact",
    "zc18_step",
    "zc24_start",
    "zc24_step",
]
