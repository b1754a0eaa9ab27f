"""The dynamical phase of paper 000 (Sec. V, Algorithm 1) and its background variant (Sec. VI, Algorithm 2).

Pure, like the rest of the agent core: :class:`DynamicPhase` is driven by :class:`agents.agent.AgentCore`
once per tick with the kinematic results of that tick (omega_hat, the body-frame angle phi, z_i, the
pooled local omega measurement) and the neighbours' dynamic states, and returns the wrench of the tick.

What each agent runs (symbols as in the paper; z_C = p_G - p_C, q_i = p_Ci - p_C = z_i + z_C):

* **Contact-to-CoM Kalman filter** (our replacement for (18) + (20) + (21), see docs/dynamics.md). The
  rigid body gives, for agent i's own measurement, v_Ci = v_C + omega q_i^perp, with
  v_C(k+1) = v_C(k) + dt F(k)/m (F the total force, known from the force consensus) and
  q_i(k+1) = R(omega dt) q_i(k). With omega = omega_hat this is *linear* in the state
  (v_C, q_i, 1/m): an exact linear Kalman filter, no linearisation. It yields 1/m with its variance
  (Result 10 without differentiating velocities), q_i (hence z_C = mean_i q_i by average consensus,
  and a refined z_i = q_i - z_C: mm instead of cm), and v_C (Result 9). With a random walk on 1/m it
  is the background mass observer of Algorithm 2 (the role of (26); no sign condition on the input).
  The pooled eq. (9) rate is taken as u = omega + b with a slowly varying error b of its own (the pair
  trackers' angle error: at sigma >= 0.9 short pairs get no angle correction and u drifts below omega),
  so that omega's slow part rests on the rotation of the own contact velocity; and from the filter's
  restart at kinematic readiness on, omega_hat measures this filter's omega instead of u, which cuts
  the loop omega_hat -> pair angles -> u -> omega_hat that lost lock there (docs/high-noise.md).
* **Lock check** (``DynamicsSpec.lock_nis``, docs/high-noise.md): the filter is nonlinear in (q_i, omega) and
  at high noise it can lock onto a wrong pair; its own velocity innovations then stop being consistent
  (normalised innovation squared far above its 2 degrees of freedom). Such a filter is restarted, on
  trial, from a global fit of its own last contact velocities (:func:`fit_rotation`) and the restart is
  kept only if clearly better; what it learnt while lost gets no weight in the averages.
* **Rotation regression** (Result 5 / (11), and the role of (24)): omega(t) = omega_0 + (1/J) C(t),
  C(t) = dt sum_{k<t} T(k), T the total torque about the CoM, T = n (z_C x fbar + mean_i(q_i x df_i +
  tau_i)) (decomposition (12)-(14): df_i = f_i - fbar, so no consensus on rotating per-agent signals).
  Fitted to the raw pooled eq. (9) measurement (unbiased; omega_hat's low-pass would bias it). In
  Algorithm 1 it runs over the J stage only, where f_i = k_z s(t) z_i^perp and tau_i = 0 (Result 5), so
  sum_i f_i = 0 and T = s(t) sum_i g_i, g_i = k_z q_i . (q_i - z_C), averaged from the m stage on (no
  consensus transient when the stage starts or s flips); in Algorithm 2 with exponential forgetting
  under any control law.
* **Flow-updating average consensus** (:class:`FlowAverage`) for every network quantity: the mean force
  fbar, the mean extra torque, the J stage's mean g_i, z_C (in the agents' shared body frame), and the averages of the local
  m and J over the agents that have one (numerator and weight channels). Flows keep the network sum
  exact under loss and delay; common inputs (a common force) are tracked without lag.
* **Stage agreement** (:class:`StageBarrier`): agents move through the stages together with no clock
  but the tick count and no coordinator. Each agent floods a bitmask of the agents known to be ready
  and the latest ready tick; once the mask is full the switch tick is that latest ready tick plus a
  horizon, the same number at every agent (the mask and the max are exact once complete). A lost
  message only delays the flood (states are re-sent every tick); an agent that learns of a switch late
  switches at once (counted); an agent that finds a neighbour two stages ahead (it restarted) jumps there
  and takes the network's estimates (its own weight is 0).
"""

from __future__ import annotations

import copy
import functools
import math
import statistics
from collections.abc import Callable, Sequence
from math import cos, isfinite, sin
from operator import itemgetter

import numpy as np

from agents.laws import ControlLawError, LawInput, checked_wrench
from config.agent_params import DynamicsSpec
from net.vocabulary import (  # the stage machine speaks in these; re-exported for readers of D.*
    BACKGROUND,
    DONE,
    J_AVERAGE,
    J_EXCITE,
    KINEMATIC,
    M_AVERAGE,
    M_EXCITE,
    SPINUP,
    STAGE_NAMES,  # noqa: F401
)

# Flow-average channels
# mean force (FX, FY): world-fixed, so a common force passes through at once. In the J stage the forces turn
# with the load (f_i = k_z s z_i^perp, agent-specific and rotating in the world frame, which no consensus
# tracks; pitfalls note) but they sum to zero by construction (z_C is the mean of the q_i), and their torque
# about the CoM is sum_i q_i x f_i = s sum_i g_i with g_i = k_z q_i . (q_i - z_C) rotation-invariant: JG
# carries g_i from the m stage on, so it has converged when the J stage starts and s(t) flips (a channel
# fed s g_i was off by up to 25 N m per agent for ~0.5 s after each flip, measured, and biased J by %).
CH_FX, CH_FY, CH_JG, CH_DT, CH_ZX, CH_ZY, CH_MN, CH_MW, CH_JN, CH_JW = range(10)
N_CH = 10
# augmented model (DynamicsSpec.estimate_effects): the local b and c numerators; their weights are the m
# and J weight channels (b is offered exactly when m is, c when J is), so two channels, not four
CH_BN, CH_CN = 10, 11
N_CH_AUG = 12
_CH_KEYS = tuple(f"c{c}" for c in range(N_CH_AUG))  # their names in StateMsg.shared (built once, not per message)
NO_FLOWS = (0.0,) * N_CH_AUG  # a neighbour that sent no pair entry for us (it has not heard from us yet)

_MASK_BITS = 50  # agents per float in the flooded ready mask (exact in a double)
_U_BIAS_SD0 = 0.05  # prior std of the eq. (9) rate's error b at a filter start (rad/s): fresh circle fits


class FlowAverage:
    """Flow-updating average consensus of ``N_CH`` real channels (one agent's side).

    x_i = u_i - sum_j F_ij with F_ij = (F_ij - F_ji)/2 + eps_ij (x_i - x_j) each tick (F_ji the latest
    received), eps_ij the Metropolis weight 1 / (1 + max(d_i, d_j)). While messages flow the flows are
    antisymmetric, so the network mean of x equals the mean of the inputs u at every tick (common input
    changes pass through at once); a lost message makes a pair asymmetric until its next exchange, after
    which the mean is exact again, and x converges to it.
    """

    __slots__ = ("u", "x", "flow", "nx", "nf", "ndeg", "deg", "nch", "_eps", "_rows", "get_x", "no_flows", "deg_f", "_upd")

    def __init__(self, nbr_ids: Sequence[int], nch: int = N_CH) -> None:
        self.nch = nch
        self.u = [0.0] * nch
        self.x = [0.0] * nch
        self.deg = len(nbr_ids)
        self.flow = {j: [0.0] * nch for j in nbr_ids}  # F_ij (each list updated in place)
        self.nx: dict[int, list[float]] = {}  # x_j, latest received
        self.nf = {j: [0.0] * nch for j in nbr_ids}  # F_ji, latest received
        self.ndeg = {j: 1 for j in nbr_ids}
        self._eps: dict[int, float] = {}  # eps_ij of the neighbours heard from (set on receive)
        self._rows = tuple(self.flow.items())  # (j, F_ij), in neighbour order: no dict walk per tick
        # for DynamicPhase's message handling: the channels' StateMsg.shared values in one call, the
        # flows of a neighbour that sent none, the degree as sent
        self.get_x = itemgetter("ps", "dg", *_CH_KEYS[:nch])  # (psi, degree, x_j) as sent
        self.no_flows = NO_FLOWS[:nch]
        self.deg_f = float(self.deg)
        self._upd = _flow_update(nch)

    def receive(self, j: int, xj: list[float], fji: Sequence[float], degj: int) -> None:
        self.nx[j] = xj
        self.nf[j] = list(map(float, fji))
        if self.ndeg[j] != degj or j not in self._eps:  # the Metropolis weight only when the degree is new
            self.ndeg[j] = degj
            self._eps[j] = 1.0 / (1.0 + max(self.deg, degj))

    def update(self) -> None:
        # x_i = u_i - sum_j F_ij, F_ij = (F_ij - F_ji)/2 + eps_ij (x_i - x_j): (F_ij - F_ji)/2 rather than
        # -F_ji because both ends update at once from each other's previous flows, and with -F_ji an
        # asymmetry (from one lost message) would flip sign every tick for ever; the mean of the two kills
        # it at the next exchange. The arithmetic is in ``_flow_update`` (unrolled over the channels).
        self.x = self._upd(self.x, self.u, self._rows, self.nx, self.nf, self._eps)


@functools.cache
def _flow_update(nch: int):  # type: ignore[no-untyped-def]
    """FlowAverage.update's arithmetic for ``nch`` channels, unrolled into straight-line code on locals.

    The plain form (a loop over neighbours, an inner loop over channels indexing lists) was the
    dominant cost of FlowAverage; unrolled it is ~1.6x faster on CPython 3.11 (measured). The same
    expressions in the same order (per neighbour in ``_rows`` order: F_ij, then the running sum from
    0.0), so the result is bit-identical to the loop (tests/test_agent_speed.py checks it). Neighbours
    not heard from yet keep their flows. Returns the new x (a new list: snapshots of x stay valid); the
    flow lists are updated in place.
    """
    ch = range(nch)

    def names(p: str) -> str:
        return ", ".join(f"{p}{c}" for c in ch) + ("," if nch == 1 else "")

    lines = [
        "def update(x, u, rows, nx, nf, eps_of):",
        f"    {names('x')} = x",
        "".join(f"    t{c} = 0.0\n" for c in ch).rstrip("\n"),
        "    for j, fl in rows:",
        "        xj = nx.get(j)",
        "        if xj is not None:",
        "            e = eps_of[j]",
        f"            {names('f')} = fl",
        f"            {names('g')} = nf[j]",
        f"            {names('a')} = xj",
        *(f"            f{c} = 0.5 * (f{c} - g{c}) + e * (x{c} - a{c})" for c in ch),
        f"            fl[:] = ({names('f')})",
        "        else:",
        f"            {names('f')} = fl",
        *(f"        t{c} += f{c}" for c in ch),
        f"    {names('u')} = u",
        "    return [" + ", ".join(f"u{c} - t{c}" for c in ch) + "]",
    ]
    env: dict = {}
    exec("\n".join(lines), env)  # noqa: S102 - generated from the channel count only
    return env["update"]


class StageBarrier:
    """Agreement on the tick at which the whole team leaves the current stage (see module docstring)."""

    __slots__ = ("me", "n", "full", "horizon", "mask", "tmax", "switch", "mask_keys", "_get", "_dec", "_enc")

    def __init__(self, me: int, n: int, horizon_ticks: int) -> None:
        self.me = me
        self.n = n
        self.full = (1 << n) - 1
        self.mask_keys = tuple(f"B{c}" for c in range((n + _MASK_BITS - 1) // _MASK_BITS))
        self._get = itemgetter(*self.mask_keys, "Bt", "Bs")  # the wire fields, in one call
        # the flooded values change a few times per stage: decoded and encoded forms are cached
        self._dec: dict[tuple, tuple[int, int, int]] = {}  # wire values -> (mask, tmax, switch)
        self._enc: tuple = (None, ())  # ((mask, tmax, switch), wire items) of the last encode
        self.horizon = horizon_ticks
        self.reset()

    def reset(self) -> None:
        self.mask = 0
        self.tmax = -1
        self.switch = -1

    def set_ready(self, tick: int) -> None:
        if not (self.mask >> self.me) & 1:
            self.mask |= 1 << self.me
            self.tmax = max(self.tmax, tick)
            self._check()

    def merge(self, mask: int, tmax: int, switch: int) -> None:
        if switch >= 0 and self.switch < 0:
            self.switch = switch
        if mask & ~self.mask:
            self.mask |= mask & self.full
            self.tmax = max(self.tmax, tmax)
            self._check()

    def _check(self) -> None:
        if self.switch < 0 and self.mask == self.full:
            self.switch = self.tmax + self.horizon

    def encode(self, out: dict[str, float]) -> None:
        state = (self.mask, self.tmax, self.switch)
        key, items = self._enc
        if key != state:
            m = self.mask
            items = tuple(
                (key, float((m >> (c * _MASK_BITS)) & ((1 << _MASK_BITS) - 1))) for c, key in enumerate(self.mask_keys)
            ) + (("Bt", float(self.tmax)), ("Bs", float(self.switch)))
            self._enc = (state, items)
        out.update(items)

    def decode(self, sh: dict[str, float]) -> tuple[int, int, int]:
        raw = self._get(sh)
        dec = self._dec.get(raw)  # equal wire values decode alike (NaN never gets in: it raises below)
        if dec is not None:
            return dec
        m = 0
        for c in range(len(self.mask_keys)):
            v = raw[c]
            if not (0.0 <= v < 2.0**_MASK_BITS) or v != int(v):
                raise ValueError("bad mask chunk")
            m |= int(v) << (c * _MASK_BITS)
        dec = (m, int(raw[-2]), int(raw[-1]))
        if len(self._dec) >= 64:
            self._dec.clear()
        self._dec[raw] = dec
        return dec


class RigidEKF:
    """Extended Kalman filter on s = (v_Cx, v_Cy, q_x, q_y, mu = 1/m, omega, iota = 1/J, [beta, gamma,] b),
    world frame; b (always the last state, index ``ib``) is the pooled rate's own error, u = omega + b, a
    random walk of ``spec.u_bias_walk`` (pinned at 0 when that is 0).

    Model (the plant's own discrete step, semi-implicit Euler): v_C(k+1) = v_C + dt mu F(k),
    q(k+1) = R(omega dt) q, omega(k+1) = omega + dt iota T(k); F, T the total force and torque about the
    CoM, from the consensus. Measurements: the own contact velocity v_Ci = v_C + omega q^perp and the pooled
    eq. (9) rate u = omega (variance 2 sigma^2 / sum_j |z_ij|^2). Estimating omega here, with the torque
    model, removes the lag of the kinematic omega_hat filter (which rotated q and the J-stage forces
    away from the body while omega ramped).

    Augmented model (``spec.estimate_effects``): two more states, beta = b/m (1/s) and gamma = c/J (1/s),
    with v_C(k+1) = v_C + dt (mu F - beta v_C) and omega(k+1) = omega + dt (iota T - gamma omega), the
    plant's step with viscous friction -b v_C and rotational damping -c omega (simulator/effects.py: forces
    of the state at tick k act over k -> k+1). The rates rather than b and c keep the model linear in the
    parameters given the (well-measured) velocities, whatever the current mu; b = beta/mu, c = gamma/iota.
    An effect not estimated keeps its state at exactly 0 (zero variance, no walk).
    """

    __slots__ = ("s", "P", "Qd", "r", "ready", "_I", "aug", "ib", "qb", "b0", "nis")

    def __init__(self, sigma_v: float, spec: DynamicsSpec, background: bool) -> None:
        self.r = max(sigma_v, 1e-3) ** 2
        self.ready = False
        self.nis = 2.0  # the last update's normalised innovation squared of the own velocity (2 dof)
        walk_mu = spec.mu_walk if background else 0.0
        walk_iota = spec.iota_walk if background else 0.0
        # per-second process noise intensities; q's angle walk is scaled by |q|^2 at each step
        self.Qd = (spec.kf_v_walk**2, spec.kf_angle_walk**2, walk_mu**2, spec.omega_walk**2, walk_iota**2)
        # augmented model: prior variances and per-second walk intensities of (beta, gamma); 0 and 0 for
        # an effect not estimated (its state stays exactly 0)
        self.aug: tuple[float, float, float, float] | None = None
        if spec.estimate_effects:
            on_b = 1.0 if "viscous_friction" in spec.estimate_effects else 0.0
            on_c = 1.0 if "rotational_damping" in spec.estimate_effects else 0.0
            w2 = spec.effect_walk**2
            self.aug = (on_b, on_c, on_b * w2, on_c * w2)
        # the pooled eq. (9) rate's own slowly varying error b (u = omega + b), the last state; pinned at 0
        # (zero variance, no walk) with u_bias_walk = 0
        self.ib = 7 if self.aug is None else 9
        self.qb = spec.u_bias_walk**2
        self.b0 = _U_BIAS_SD0**2 if self.qb > 0.0 else 0.0
        self.s = np.zeros(self.ib + 1)
        self.P = np.eye(self.ib + 1)
        self._I = np.eye(self.ib + 1)

    def start(self, v: complex, q0: complex, omega: float) -> None:
        vc = v - omega * 1j * q0
        self.s = np.array([vc.real, vc.imag, q0.real, q0.imag, 0.0, omega, 0.0])
        self.P = np.diag([1.0, 1.0, 1.0, 1.0, 1.0, 0.1, 1e-2])
        if self.aug is not None:  # beta, gamma pinned at 0 until release_effects()
            self.s = np.append(self.s, (0.0, 0.0))
            P = np.zeros((9, 9))
            P[:7, :7] = self.P
            self.P = P
        ib = self.ib
        self.s = np.append(self.s, 0.0)
        P = np.zeros((ib + 1, ib + 1))
        P[:ib, :ib] = self.P
        P[ib, ib] = self.b0
        self.P = P
        self.ready = True

    def release_effects(self) -> None:
        """Augmented model: let beta and gamma move (from 0, prior std 0.3 1/s) and restart mu and iota from
        their current values with the start's priors (their cross-covariances dropped).

        Called when the excitation starts (the m stage, or Algorithm 2's background stage). Free from the
        start, beta explained the decay of the filter's own initial v_C error (q_i still unknown) as
        friction (measured: beta ~ 1.4 1/s, a 0.7 s time constant, for a true 0.1) and that wrong start
        outlived the m stage in some agents (m off by up to 26 %); and what mu and iota learnt before,
        under the nominal model, had absorbed the friction (iota ~ 0: the regulation torque that holds
        omega against the damping looked like a torque that does not accelerate the load).
        """
        if self.aug is None or not self.ready:
            return
        P = self.P.copy()
        s = self.s.copy()  # replaced, never changed in place (snapshots hold it)
        for k, var in ((4, 1.0), (6, 1e-2), (7, 0.1 * self.aug[0]), (8, 0.1 * self.aug[1])):
            if k >= 7:
                s[k] = 0.0
            P[k, :] = 0.0
            P[:, k] = 0.0
            P[k, k] = var
        self.s = s
        self.P = P

    def forget_iota(self, var: float = 1e-2) -> None:
        """Drops what the filter believes about 1/J (variance ``var``, no correlations): before the J stage
        the torque is the agents' regulation torque, whose consensus is off by several N m per tick, and the
        1/J learnt from it was off by up to 50 % yet confident enough to hold the J-stage estimate there."""
        P = self.P.copy()
        P[6, :] = 0.0
        P[:, 6] = 0.0
        P[6, 6] = var
        self.P = P

    def hold_shape(self) -> None:
        """From here on q is known (held: it only turns with omega) and the pooled rate u measures omega
        without an error of its own (b = 0, pinned). For a load that may stop turning (done under a law or
        braking): at rest q is not observable from v_Ci = v_C + omega q^perp, the q random walk inflated its
        variance until the updates moved it (|q| 1.39 -> 1.05 m in 25 s), and b swallowed the slow part of
        u, which at rest is the only measurement of omega's drift (u = omega cos(delta): no pair-angle bias
        at omega = 0); measured: omega_hat off by 0.015 rad/s, the load turning unseen."""
        ib = self.ib
        P = self.P.copy()
        for k in (2, 3, ib):
            P[k, :] = 0.0
            P[:, k] = 0.0
        s = self.s.copy()
        s[ib] = 0.0
        self.s = s
        self.P = P
        self.qb = 0.0
        qv, _, qm, qo, qi = self.Qd
        self.Qd = (qv, 0.0, qm, qo, qi)

    def set_omega_walk(self, walk: float) -> None:
        """Process noise of omega (rad/s/sqrt(s)): small where the torque is known exactly (the J stage)."""
        qv, qa, qm, _, qi = self.Qd
        self.Qd = (qv, qa, qm, walk**2, qi)

    def update(self, v: complex, u: float, u_var: float, u_dc: float = 0.0, u_dw: float = 0.0) -> None:
        """Measurement update; H is sparse, so P H^T is three column combinations of P.

        ``u`` may be older than the state (a delayed measurement): it measured omega ``a`` ticks ago,
        omega - dt iota sum T + dt gamma sum omega over those ticks. ``u_dc`` is that dt sum T (the
        torques this filter predicted with), ``u_dw`` the dt sum omega (augmented model), both 0 for a
        current sample; the u row of H gets -u_dc on iota and u_dw on gamma. Taken as current, a sample
        100 ms old during the J stage's ramp conflicts with the own velocity by dt iota T per tick of age,
        which reverses with s(t) (measured: J 0.47 % instead of 0.02 %, issue 5)."""
        s, P = self.s, self.P
        qx, qy, om = s[2], s[3], s[5]
        r = self.r
        c0 = P[:, 0] - om * P[:, 3] - qy * P[:, 5]  # P H^T, column for v_x
        c1 = P[:, 1] + om * P[:, 2] + qx * P[:, 5]  # ... v_y
        e0 = v.real - (s[0] - om * qy)
        e1 = v.imag - (s[1] + om * qx)
        s00 = c0[0] - om * c0[3] - qy * c0[5] + r
        s01 = c1[0] - om * c1[3] - qy * c1[5]
        s11 = c1[1] + om * c1[2] + qx * c1[5] + r
        d2 = s00 * s11 - s01 * s01
        if d2 > 0.0:  # the lock check's statistic (DynamicPhase): ~2 while the filter explains v_Ci
            self.nis = (s11 * e0 * e0 - 2.0 * s01 * e0 * e1 + s00 * e1 * e1) / d2
        if u == u and u_var > 0.0:
            ib = self.ib
            c2 = P[:, 5] + P[:, ib]  # ... u = omega + b
            e2 = u - om - s[ib]
            if u_dc or u_dw:  # delayed: omega of a ticks ago, d/d iota = -u_dc, d/d gamma = u_dw
                c2 = c2 - u_dc * P[:, 6]
                e2 += u_dc * s[6]
                if self.aug is not None:
                    c2 = c2 + u_dw * P[:, 8]
                    e2 -= u_dw * s[8]
                s22 = c2[5] + c2[ib] - u_dc * c2[6] + (u_dw * c2[8] if self.aug is not None else 0.0) + u_var
            else:
                s22 = c2[5] + c2[ib] + u_var
            s02 = c2[0] - om * c2[3] - qy * c2[5]
            s12 = c2[1] + om * c2[2] + qx * c2[5]
            # explicit inverse of the symmetric 3x3 innovation covariance
            a00 = s11 * s22 - s12 * s12
            a01 = s02 * s12 - s01 * s22
            a02 = s01 * s12 - s02 * s11
            a11 = s00 * s22 - s02 * s02
            a12 = s01 * s02 - s00 * s12
            a22 = s00 * s11 - s01 * s01
            det = s00 * a00 + s01 * a01 + s02 * a02
            if det <= 0.0:
                return
            C = np.column_stack((c0, c1, c2))
            Sinv = np.array(((a00, a01, a02), (a01, a11, a12), (a02, a12, a22))) / det
            K = C @ Sinv
            self.s = s + K @ np.array((e0, e1, e2))
        else:
            det = s00 * s11 - s01 * s01
            if det <= 0.0:
                return
            C = np.column_stack((c0, c1))
            Sinv = np.array(((s11, -s01), (-s01, s00))) / det
            K = C @ Sinv
            self.s = s + K @ np.array((e0, e1))
        P = P - K @ C.T
        self.P = 0.5 * (P + P.T)

    def predict(self, force: complex, torque: float, dt: float) -> None:
        s = self.s
        qx, qy, mu, om, iota = s[2], s[3], s[4], s[5], s[6]
        c, sn = cos(om * dt), sin(om * dt)
        nq = np.array([
            s[0] + dt * mu * force.real,
            s[1] + dt * mu * force.imag,
            c * qx - sn * qy,
            sn * qx + c * qy,
            mu,
            om + dt * iota * torque,
            iota,
        ])
        A = self._I.copy()
        A[0, 4] = dt * force.real
        A[1, 4] = dt * force.imag
        A[2, 2] = c
        A[2, 3] = -sn
        A[3, 2] = sn
        A[3, 3] = c
        A[2, 5] = dt * (-sn * qx - c * qy)
        A[3, 5] = dt * (c * qx - sn * qy)
        A[5, 6] = dt * torque
        if self.aug is not None:  # augmented model: - dt beta v_C, - dt gamma omega
            beta, gamma = s[7], s[8]
            nq[0] -= dt * beta * s[0]
            nq[1] -= dt * beta * s[1]
            nq[5] -= dt * gamma * om
            A[0, 0] -= dt * beta
            A[1, 1] -= dt * beta
            A[0, 7] = -dt * s[0]
            A[1, 7] = -dt * s[1]
            A[5, 5] -= dt * gamma
            A[5, 8] = -dt * om
            nq = np.append(nq, (beta, gamma))
        nq = np.append(nq, s[self.ib])
        P = A @ self.P @ A.T
        qv, qa, qm, qo, qi = self.Qd
        P[0, 0] += qv * dt
        P[1, 1] += qv * dt
        qq = qa * dt * (qx * qx + qy * qy)
        P[2, 2] += qq
        P[3, 3] += qq
        P[4, 4] += qm * dt
        P[5, 5] += qo * dt
        P[6, 6] += qi * dt
        if self.aug is not None:
            P[7, 7] += self.aug[2] * dt
            P[8, 8] += self.aug[3] * dt
        P[self.ib, self.ib] += self.qb * dt
        self.s = nq
        self.P = P

    @property
    def q(self) -> complex:
        return complex(self.s[2], self.s[3])

    @property
    def vc(self) -> complex:
        return complex(self.s[0], self.s[1])

    @property
    def mu(self) -> float:
        return float(self.s[4])

    @property
    def mu_var(self) -> float:
        return float(self.P[4, 4])

    @property
    def omega(self) -> float:
        return float(self.s[5])

    @property
    def iota(self) -> float:
        return float(self.s[6])

    @property
    def iota_var(self) -> float:
        return float(self.P[6, 6])

    @property
    def beta(self) -> float:
        """b/m (1/s), augmented model only."""
        return float(self.s[7])

    @property
    def gamma(self) -> float:
        """c/J (1/s), augmented model only."""
        return float(self.s[8])


def fit_rotation(v: np.ndarray, f: np.ndarray, dt: float, omega_max: float) -> tuple[float, complex, float]:
    """Global fit of the own contact velocity over a window: v(k) = a + mu f(k) + i omega e^{i omega k dt} q0
    (v_C = a + mu f, f = dt sum of the total force so far; q turning at a constant omega), for the omega in
    [-omega_max, omega_max] with the least squared residual. Linear in (a, mu, q0) for a given omega, so
    omega is scanned on a grid (step well inside the residual's dip, whose width is ~2 pi / window) and
    refined. Returns (omega, q at the window's last sample, residual RMS per component): a restart point for
    a filter that locked onto a wrong (q_i, omega), from the agent's own data alone."""
    n = len(v)
    t = np.arange(n) * dt
    y = np.concatenate((v.real, v.imag))
    fc = f - f.mean()  # (a absorbs the mean: better conditioned)

    def scan(om: np.ndarray) -> np.ndarray:
        e = 1j * om[:, None] * np.exp(1j * om[:, None] * t[None, :])  # (K, n)
        k = len(om)
        A = np.empty((k, 2 * n, 5))
        A[:, :n, 0], A[:, n:, 0] = 1.0, 0.0
        A[:, :n, 1], A[:, n:, 1] = 0.0, 1.0
        A[:, :n, 2], A[:, n:, 2] = fc.real, fc.imag
        A[:, :n, 3], A[:, n:, 3] = e.real, e.imag
        A[:, :n, 4], A[:, n:, 4] = -e.imag, e.real
        G = np.einsum("kri,krj->kij", A, A)
        b = np.einsum("kri,r->ki", A, y)
        G += np.eye(5) * (1e-9 * np.trace(G, axis1=1, axis2=2))[:, None, None]
        x = np.linalg.solve(G, b[..., None])[..., 0]
        return y @ y - np.einsum("ki,ki->k", b, x), x

    step = min(0.25, 0.5 / (n * dt))
    grid = np.arange(-omega_max, omega_max + step, step)
    res, _ = scan(grid)
    best = grid[int(np.argmin(res))]
    fine = best + np.linspace(-step, step, 41)
    res, x = scan(fine)
    i = int(np.argmin(res))
    om = float(fine[i])
    if 0 < i < len(fine) - 1:
        # the residual is a parabola near its minimum: its vertex, not the fine grid's step, sets omega
        # (a grid point can be step/80 off, which at |q| = 3 m put q 0.026 m off on noise-free data)
        r0, r1, r2 = res[i - 1], res[i], res[i + 1]
        den = r0 - 2.0 * r1 + r2
        if den > 0.0:
            om_v = om + 0.5 * (fine[1] - fine[0]) * (r0 - r2) / den
            res_v, x_v = scan(np.array([om_v]))
            if res_v[0] <= r1:
                om, res, x, i = om_v, res_v, x_v, 0
    q0 = complex(x[i, 3], x[i, 4])
    return om, q0 * complex(cos(om * t[-1]), sin(om * t[-1])), float(np.sqrt(max(res[i], 0.0) / (2 * n)))


class DynamicPhase:
    """One agent's dynamical phase (see module docstring). Driven by AgentCore.step."""

    def __init__(self, agent_id: int, nbr_ids: Sequence[int], n: int, dt: float, sigma_v: float,
                 spec: DynamicsSpec, hist: int = 64, law: Callable[[LawInput], Sequence[float]] | None = None,
                 law_ref: str = "") -> None:
        self.id = agent_id
        self.law = law  # the user's control law (agents/laws.py): done stage of Algorithm 1, Algorithm 2
        self.law_ref = law_ref
        self.q_held: complex | None = None  # q_i in the shared body frame, held from done on (see step)
        # delayed eq. (9) samples (RigidEKF.update): cumulative dt T and dt omega of the filter's
        # predictions up to each of the last ``hist`` state ticks, and this tick's |z|^2-weighted sums
        # over the late samples (note_late)
        self.hist = hist
        self.cum_c = [0.0] * hist
        self.cum_w = [0.0] * hist
        self.cum_t = [-1] * hist
        self.cc = 0.0  # dt sum T up to the current state tick
        self.cw = 0.0  # dt sum omega
        self.late_z = self.late_c = self.late_w = 0.0
        self.n = n
        self.dt = dt
        self.spec = spec
        self.background = spec.algorithm == "background"
        self.avg = FlowAverage(nbr_ids, N_CH_AUG if spec.estimate_effects else N_CH)
        self.ch_keys = _CH_KEYS[:self.avg.nch]
        self.b_local = math.nan  # augmented model: own b = beta m and c = gamma J, before the averaging
        self.c_local = math.nan
        self.released = False
        ticks = lambda s: max(1, int(round(s / dt)))  # noqa: E731
        self.barrier = StageBarrier(agent_id, n, ticks(spec.horizon_s))
        self.kf = RigidEKF(sigma_v, spec, self.background)
        self.sigma_v = sigma_v
        self.stage = SPINUP
        self.stage_tick = 0
        self.late_switches = 0
        self.kin_since = -1
        self.settle = ticks(spec.kin_settle_s)
        self.m_ticks = ticks(spec.m_excite_s)
        self.m_switch = ticks(spec.m_switch_s)
        self.j_ticks = ticks(spec.j_excite_s)
        self.avg_window = ticks(spec.avg_window_s)
        self.dither_ticks = ticks(spec.dither_period_s)
        self.conv_since = -1
        self.m_local = math.nan
        self.j_local = math.nan
        self.nbr_stage: dict[int, int] = {}
        self.nbr_stage_tick: dict[int, int] = {}
        self.alpha = 0.0  # modelled angular acceleration for the next tick (rad/s^2)
        self.nbr_psi: dict[int, tuple[float, int]] = {}  # (psi_j predicted for t + 1, t)
        # psi: the body-frame angle of the consensus on body-fixed vectors (z_C). Integral of the
        # filter's omega, which follows omega ramps without lag (the kinematic phi = integral of
        # omega_hat fell ~1.6 rad behind during the J stage), kept common by phase consensus.
        self.psi = math.nan
        self.nbr_barrier: dict[int, tuple[int, int, int]] = {}
        self.frozen_m = False
        self.frozen_j = False
        self.restarted = False  # the filter's restart at kinematic readiness is done
        # lock check (DynamicsSpec.lock_nis): running mean of the filter's velocity NIS from the restart on;
        # a filter that locked onto a wrong (q_i, omega) is restarted on trial (_reseed, _judge)
        self.lock_thr = spec.lock_nis
        self.lock_alpha = min(1.0, dt / spec.lock_tau_s)
        self.lock_hold = ticks(spec.lock_hold_s)
        self.nis_avg = 2.0
        self.lock_from = 0  # no judgement before this tick (a fresh start's transient)
        self.reseeds = 0  # restarts by the lock check
        self.kf_tick = -1  # tick of the last such restart: excitation before it is not in the weights
        self.shadow: RigidEKF | None = None  # the filter a restart on trial replaced (see _reseed)
        self.shadow_nis = 2.0
        self.trial_tick = -1
        self.lock_fails = 0  # restarts in a row that did no better than the filter they replaced
        self.m_start = self.j_start = -1  # first ticks of the m and J excitation stages
        self.nbr_om: dict[int, float] = {}  # neighbours' omega_hat (their kinematic shared state)
        # the own contact velocities of the last lock_window_s and v_C's change per unit 1/m up to each
        # (dt sum of the total force): the restart point of a lost filter is fitted to them (fit_rotation)
        self.win_n = ticks(spec.lock_window_s)
        self.win_v = np.zeros(self.win_n, complex)
        self.win_f = np.zeros(self.win_n, complex)
        self.win_k = 0
        self.f_int = 0j
        # omega_hat's measurement for the next tick (AgentCore): the filter's predicted omega once it has
        # restarted at kinematic readiness (``DynamicsSpec.filter_omega``), NaN before (the eq. (9) rate)
        self.om_meas = math.nan

    # ------------------------------------------------------------------ messages
    def receive(self, j: int, t: int, msg_phase: int, sh: dict[str, float], flows: Sequence[float]) -> None:
        """A neighbour's state of tick ``t``; raises (KeyError, ValueError, TypeError) if malformed."""
        avg = self.avg
        psi, degj, *xj = avg.get_x(sh)
        xj = list(map(float, xj))
        psi = float(psi)
        if psi - psi != 0.0:
            raise ValueError("non-finite")
        # its omega_hat (the agent's kinematic key in the same dict; the lock check's fallback seed)
        om = float(sh.get("om", math.nan))
        degj = int(degj)
        if flows is NO_FLOWS:
            flows = avg.no_flows
        if degj < 1 or len(flows) != avg.nch:
            raise ValueError("bad dynamic state")
        bar = self.barrier.decode(sh)
        if not all(map(isfinite, xj)):
            raise ValueError("non-finite")
        avg.receive(j, xj, flows, degj)
        self.nbr_stage[j] = int(msg_phase)
        self.nbr_stage_tick[j] = int(sh["Sk"])
        self.nbr_barrier[j] = bar
        if msg_phase >= KINEMATIC:  # its filter (and psi) runs from the kinematic stage on
            self.nbr_psi[j] = (psi, t)
            if om - om == 0.0:
                self.nbr_om[j] = om

    def note_late(self, t: int, zz: float) -> None:
        """An eq. (9) sample of tick t with pooling weight zz went into this tick's u (AgentCore, only for
        samples older than the state tick on entry: fault-free ones are not reported, they are 1 tick old)."""
        i = t % self.hist
        if self.cum_t[i] == t:
            self.late_z += zz
            self.late_c += zz * self.cum_c[i]
            self.late_w += zz * self.cum_w[i]

    def _u_age(self, tick: int, u_den: float) -> tuple[float, float]:
        """(dt sum T, dt sum omega) from the pooled u's samples to the state tick: the pooled value is
        the |z|^2-weighted mean of per-sample omegas, so its prediction is the weighted mean of theirs."""
        i = (tick - 1) % self.hist
        c1, w1 = (self.cum_c[i], self.cum_w[i]) if self.cum_t[i] == tick - 1 else (self.cc, self.cw)
        w0 = u_den - self.late_z  # the samples of tick - 1 (and any older than the buffer)
        cbar = (self.late_c + w0 * c1) / u_den
        wbar = (self.late_w + w0 * w1) / u_den
        return self.cc - cbar, self.cw - wbar

    # ------------------------------------------------------------------ helpers
    def _enter(self, stage: int, tick: int) -> None:
        filters = (self.kf,) if self.shadow is None else (self.kf, self.shadow)  # a restart on trial: both
        if stage >= M_EXCITE and self.kf.aug is not None and not self.released:
            self.released = True  # the excitation starts (or we jumped past it): see release_effects
            for kf in filters:
                kf.release_effects()
        self.stage = stage
        self.stage_tick = tick
        if stage == M_EXCITE:
            self.m_start = tick
        elif stage == J_EXCITE:
            self.j_start = tick
        self.barrier.reset()
        self.conv_since = -1
        for kf in filters:
            if kf.ready and stage == J_EXCITE:
                kf.forget_iota()  # J from the J stage's exactly known torque alone (Result 5)
                kf.set_omega_walk(self.spec.j_omega_walk)
            elif stage != J_EXCITE:
                kf.set_omega_walk(self.spec.omega_walk)

    def _advance(self, tick: int) -> None:
        """Stage agreement: neighbours ahead, barrier merges, own readiness, due switches."""
        st = self.stage
        # a neighbour two or more stages ahead (we restarted / joined late): jump there
        if not self.background and st >= KINEMATIC:
            ahead, j_ahead = max(((s, j) for j, s in self.nbr_stage.items()), default=(-1, -1))
            if st + 1 < ahead <= DONE:
                self._enter(ahead, self.nbr_stage_tick[j_ahead])
                self.late_switches += 1
                return
        for j, s in self.nbr_stage.items():
            if s == st:
                mask, tmax, sw = self.nbr_barrier[j]
                self.barrier.merge(mask, tmax, sw)
            elif s == st + 1 and st in (KINEMATIC, M_AVERAGE, J_AVERAGE):
                # the neighbour has switched already: its stage start is the agreed tick
                self.barrier.merge(0, -1, self.nbr_stage_tick[j])
        sw = self.barrier.switch
        if sw >= 0 and tick >= sw and st in (KINEMATIC, M_AVERAGE, J_AVERAGE):
            if tick > sw:
                self.late_switches += 1
            nxt = {KINEMATIC: BACKGROUND if self.background else M_EXCITE, M_AVERAGE: J_EXCITE,
                   J_AVERAGE: DONE}[st]
            self._enter(nxt, tick)
        elif st == M_EXCITE and tick >= self.stage_tick + self.m_ticks:
            self._enter(M_AVERAGE, tick)
        elif st == J_EXCITE and tick >= self.stage_tick + self.j_ticks:
            self._enter(J_AVERAGE, tick)

    def _offer(self, inv: float, var: float, num: int, wch: int, w: float = 1.0, sure: bool = False) -> float | None:
        """Hands the local estimate 1/inv (the filter's 1/m or 1/J) to its average channels with weight w;
        None if the filter has no usable value yet (with ``sure``, also while its sd is not below the value:
        a restarted filter's 1/m starts at 0 with sd 1). Weight 1 (a plain average over the agents that have one)
        unless the lock check restarted the filter during the excitation (:meth:`_clean_share`): the
        filters' variances proved overconfident as inverse-variance weights."""
        if not (inv > 0.0 and var > 0.0) or (sure and var >= inv * inv):
            return None
        au = self.avg.u
        au[num] = w / inv
        au[wch] = w
        return 1.0 / inv

    def _clean_share(self, start: int, ticks: int) -> float:
        """The weight of an estimate learnt over the excitation ticks [start, start + ticks): the share of
        them since the filter's last restart by the lock check (1 without one), near 0 if the filter is
        lost now (not 0: a team whose filters are all lost must still reach an average)."""
        w = 1.0
        if start >= 0 and self.kf_tick > start:
            w = max(0.0, (start + ticks - self.kf_tick) / ticks)
        if self.nis_avg > self.lock_thr > 0.0:  # lost
            w = 0.0
        return w if w > 1e-3 else 1e-3

    def _reseed(self, tick: int, v: complex, zi: complex, omega_hat: float, zc: complex) -> None:
        """Restart, on trial, the filter that seems to have lost lock: (omega, q_i) fitted to the own contact
        velocities of the last window (:func:`fit_rotation`; before it is full, the neighbours' omega_hat and
        the kinematic z_i + z_C), 1/m and 1/J forgotten. Measured on grid run n20-s0.8-r20: the neighbours'
        omega_hat was no seed there (-1.2..+0.8 rad/s with the load at 2.5: half the line had lost lock).
        The old filter runs beside it until :meth:`_judge` keeps the one whose velocity innovations are the
        more consistent: a wrong lock is fixed by a restart, an effect the model lacks (sensor lag, friction)
        raises every filter's NIS and is not, so there the old filter and what it learnt are kept."""
        oms = list(self.nbr_om.values())
        om0 = statistics.median(oms) if oms else omega_hat
        q0 = zi + zc if zc == zc else zi
        if self.win_k >= self.win_n:
            k = self.win_k % self.win_n  # the oldest sample
            lim = self.spec.lock_omega_max
            # not the lost filter's own omega (it may be anything); capped, so that the scan stays small
            om_max = min(max(lim, 2.0 * abs(omega_hat), *(2.0 * abs(o) for o in oms)), 5.0 * lim)
            om_fit, q_fit, _ = fit_rotation(np.roll(self.win_v, -k), np.roll(self.win_f, -k), self.dt, om_max)
            if abs(om_fit) * self.win_n * self.dt >= 2.0:
                # the load turned by 2 rad or more in the window: the fit is determined (slower, q is not,
                # measured: omega 0.3 rad/s fitted as -0.1 with |q| 8.5 m), else the fallback above
                om0, q0 = om_fit, q_fit
        kf = self.kf
        self.shadow = copy.copy(kf)  # its arrays are replaced on every step, never changed in place
        self.shadow_nis = self.nis_avg
        kf.start(v, q0, om0)
        if self.released:
            kf.release_effects()
        # the trial's running mean starts at the threshold, not at the consistent 2: what is left of the
        # start after the trial (13 % at 4 s over 2 s) then leans towards keeping the old filter
        self.nis_avg = self.lock_thr
        self.trial_tick = tick
        self.lock_from = tick + self.lock_hold

    def _judge(self, tick: int) -> None:
        """End of a restart's trial (see :meth:`_reseed`)."""
        if self.nis_avg < min(self.lock_thr, 0.5 * self.shadow_nis):
            # consistent, and clearly better: a fresh filter's wide covariance lowers its NIS for a while,
            # so a small gain (or one that is still inconsistent) is not evidence of a wrong lock
            self.kf_tick = self.trial_tick
            self.reseeds += 1
            self.lock_fails = 0
            self.lock_from = tick
        else:  # the restart did no better: back to the old filter, and wait longer before the next try
            self.kf = self.shadow
            self.nis_avg = self.shadow_nis
            self.lock_fails += 1
            self.lock_from = tick + (self.lock_hold << min(self.lock_fails, 5))
        self.shadow = None

    def _converged(self, num: int, wch: int, tick: int) -> bool:
        """Local convergence of a weighted average: own value and every neighbour's within tolerance."""
        x = self.avg.x
        if x[wch] <= 0.0:
            return False
        mine = x[num] / x[wch]
        tol = self.spec.avg_tol * abs(mine)
        ok = True
        for xj in self.avg.nx.values():
            if xj[wch] <= 0.0 or abs(xj[num] / xj[wch] - mine) > tol:
                ok = False
                break
        if not ok:
            self.conv_since = -1
            return False
        if self.conv_since < 0:
            self.conv_since = tick
        return tick - self.conv_since >= self.avg_window

    # ------------------------------------------------------------------ the tick
    def step(
        self, tick: int, v: complex, u: float, u_den: float, omega_hat: float, phi: float, zi: complex,
        trusted: bool, om_init: bool, wrench: tuple[float, float, float],
    ) -> tuple[float, float, float]:
        """Advance one tick; returns the wrench to apply (``wrench`` is the kinematic-phase law's)."""
        dt = self.dt
        n = self.n
        spec = self.spec
        kf = self.kf
        if self.stage == SPINUP and om_init:
            self._enter(KINEMATIC, tick)
        if self.stage >= KINEMATIC:
            if not kf.ready:
                kf.start(v, zi, omega_hat)
                self.psi = phi
            if self.stage == KINEMATIC:
                if trusted:
                    if self.kin_since < 0:
                        self.kin_since = tick
                    if tick - self.kin_since >= self.settle:
                        if not self.restarted:
                            # restart the filter from the settled kinematic z_i and omega_hat: started at
                            # spin-up from z_i = 0 it could lock onto a wrong (q, omega) and take most of
                            # the m stage to recover (seed 3: one agent's m off by 5 %, measured)
                            self.restarted = True
                            kf.start(v, zi, omega_hat)
                            self.lock_from = tick + self.lock_hold
                        self.barrier.set_ready(tick)
                else:
                    self.kin_since = -1
            self._advance(tick)
        stage = self.stage
        x = self.avg.x
        if kf.ready:
            # phase consensus: psi_i += sum_j eps_ij (psi_j - psi_i), neighbours' values predicted to now
            psi = self.psi
            acc = 0.0
            om = kf.omega
            deg = self.avg.deg
            for j, (pj, tj) in self.nbr_psi.items():
                eps = 1.0 / (1.0 + max(deg, self.avg.ndeg[j]))
                acc += eps * (pj + om * dt * (tick - 1 - tj) - psi)
            self.psi = psi = psi + acc
        else:
            psi = phi
        rot = complex(cos(psi), sin(psi))

        # --- estimator update with this tick's data ----------------------------------------------
        i = tick % self.hist
        if self.cum_t[i] != tick:  # the first tick
            self.cum_t[i], self.cum_c[i], self.cum_w[i] = tick, self.cc, self.cw
        if kf.ready:
            u_var = spec.u_var_scale * 2.0 * self.sigma_v**2 / u_den if u_den > 0.0 and spec.u_var_scale > 0 else 0.0
            u_dc = u_dw = 0.0
            if spec.u_delayed and u_var > 0.0:
                u_dc, u_dw = self._u_age(tick, u_den)
            kf.update(v, u, u_var, u_dc, u_dw)
            q = kf.q
        else:
            q = zi
        zc = complex(x[CH_ZX], x[CH_ZY]) * rot  # z_C, world (the consensus runs in the shared body frame)
        held = self.q_held
        if self.restarted and held is None and self.lock_thr > 0.0:
            w = self.win_k % self.win_n
            self.win_v[w] = v
            self.win_f[w] = self.f_int
            self.win_k += 1
            a = self.lock_alpha
            self.nis_avg = na = self.nis_avg + a * (kf.nis - self.nis_avg)
            old = self.shadow
            if old is not None:  # a restart on trial: the filter it replaced runs beside it
                old.update(v, u, u_var, u_dc, u_dw)
                self.shadow_nis += a * (old.nis - self.shadow_nis)
                if tick >= self.lock_from:
                    self._judge(tick)
                    kf = self.kf
                    q = kf.q
            elif na > self.lock_thr and tick >= self.lock_from:
                self._reseed(tick, v, zi, omega_hat, zc)
                q = kf.q
        if held is None and stage == DONE and kf.ready and (self.law is not None or spec.brake > 0.0):
            # the user's law or Prop. 7 braking may stop the rotation, and q_i (so z_C) is observable only
            # while the load turns (v_Ci = v_C + omega q_i^perp): from done on, q_i is held in the shared
            # body frame (measured without: |q_i| 1.39 -> 1.05 m in 25 s of a load stopped by a law)
            if self.shadow is not None:  # a restart on trial: judged now, no more lock checks from here on
                self._judge(tick)
                kf = self.kf
                q = kf.q
            held = self.q_held = q * rot.conjugate()
            kf.hold_shape()
            kf.set_omega_walk(spec.j_omega_walk)
        if held is not None:
            q = held * rot

        # --- control -------------------------------------------------------------------------------
        fx, fy, tau = wrench
        jstage = False  # the J stage's forces (torque from the JG channel, net force zero)
        if stage == M_EXCITE or stage == BACKGROUND:
            k = tick - self.stage_tick
            sgn = -1.0 if (k // self.m_switch) & 1 else 1.0
            fx = sgn * spec.m_force * cos(spec.m_force_angle)
            fy = sgn * spec.m_force * sin(spec.m_force_angle)
        elif stage == J_EXCITE:
            k = tick - self.stage_tick
            half = max(1, self.j_ticks // (2 * spec.j_cycles))
            sgn = 1.0 if (k // half) % 2 == 0 else -1.0
            if spec.omega_sign < 0:
                sgn = -sgn
            # Result 5: f_i = k_z z_i^perp with the refined z_i = q_i - z_C, so sum_i f_i = 0 and
            # z_C drops out of the rotation; tau_i = 0
            f = spec.k_z * sgn * 1j * (q - zc)
            fx, fy, tau = f.real, f.imag, 0.0
            jstage = True
        elif stage == DONE and spec.brake > 0.0:
            fx, fy, tau = -spec.brake * v.real, -spec.brake * v.imag, 0.0
        if self.law is not None and (stage == DONE or stage == BACKGROUND):
            fx, fy, tau = self._law_wrench(tick, stage, v, q, zc, (fx, fy, tau))
        if stage == BACKGROUND:  # Prop. 6 (above; or the user's law) + the regulation torque + a dither for J
            k = tick - self.stage_tick
            tau += spec.dither_torque * sin(2.0 * math.pi * k / self.dither_ticks)

        # --- consensus inputs for this tick ---------------------------------------------------------
        au = self.avg.u
        if jstage:
            # sum_i f_i = 0 and the torque is s sum_i g_i (JG); DT gets 0 so that it has no J-stage
            # values to forget when the kinematic control resumes
            au[CH_FX] = au[CH_FY] = au[CH_DT] = 0.0
        else:
            au[CH_FX] = fx
            au[CH_FY] = fy
            df = complex(fx, fy) - complex(x[CH_FX], x[CH_FY])
            au[CH_DT] = (q.real * df.imag - q.imag * df.real) + tau  # q_i x (f_i - fbar) + tau_i
        if kf.ready and M_EXCITE <= stage <= J_EXCITE:
            # g_i = q_i x (J-stage f_i / s) with this tick's q_i and z_C, exactly as the force is built
            au[CH_JG] = spec.k_z * (q.real * (q.real - zc.real) + q.imag * (q.imag - zc.imag))
        if kf.ready:
            qp = q * rot.conjugate() if held is None else held  # q_i in the shared body frame; their mean is z_C
            au[CH_ZX] = qp.real
            au[CH_ZY] = qp.imag
        # not while a restart is on trial (its 1/m and 1/J start from nothing; the offer waits for the
        # judgement, at most lock_hold_s): the old filter's last offer stays in the background average
        take_m = self.shadow is None and (stage == BACKGROUND or (stage == M_AVERAGE and not self.frozen_m))
        take_j = self.shadow is None and (stage == BACKGROUND or (stage == J_AVERAGE and not self.frozen_j))
        # after a kept restart, only a determined value (sd below the value) is offered
        sure = self.kf_tick >= 0
        if kf.ready and take_m:
            w = 1.0 if stage == BACKGROUND else self._clean_share(self.m_start, self.m_ticks)
            m_local = self._offer(kf.mu, kf.mu_var, CH_MN, CH_MW, w, sure)
            if m_local is not None:
                self.m_local = m_local
                self.frozen_m = stage == M_AVERAGE
                if kf.aug is not None:  # b = beta m, averaged with m's weights
                    self.b_local = kf.beta * m_local
                    au[CH_BN] = w * self.b_local
        if kf.ready and take_j:
            w = 1.0 if stage == BACKGROUND else self._clean_share(self.j_start, self.j_ticks)
            j_local = self._offer(kf.iota, kf.iota_var, CH_JN, CH_JW, w, sure)
            if j_local is not None:
                self.j_local = j_local
                self.frozen_j = stage == J_AVERAGE
                if kf.aug is not None:  # c = gamma J, averaged with J's weights
                    self.c_local = kf.gamma * j_local
                    au[CH_CN] = w * self.c_local
        self.avg.update()
        x = self.avg.x

        # readiness of the averaging stages
        if stage == M_AVERAGE and self._converged(CH_MN, CH_MW, tick):
            self.barrier.set_ready(tick)
        elif stage == J_AVERAGE and self._converged(CH_JN, CH_JW, tick):
            self.barrier.set_ready(tick)

        # --- prediction to tick + 1 with the total force and torque (decomposition (12)-(14)) ---------
        if kf.ready:
            fbar = complex(x[CH_FX], x[CH_FY])
            if jstage:
                torque = n * sgn * x[CH_JG]
            else:
                zc = complex(x[CH_ZX], x[CH_ZY]) * rot
                torque = n * ((zc.real * fbar.imag - zc.imag * fbar.real) + x[CH_DT])
            self.psi += dt * kf.omega  # the body turns by the pre-update omega (semi-implicit Euler)
            self.cc += dt * torque
            self.cw += dt * kf.omega
            self.f_int += dt * n * fbar
            kf.predict(n * fbar, torque, dt)
            if self.shadow is not None:
                self.shadow.predict(n * fbar, torque, dt)
            iota = kf.iota
            # only once 1/J is known to 10 % (or, with j_feedforward, through the whole J stage: its torque
            # is exact and 1/J keeps its pre-stage value when it is forgotten)
            if iota > 0.0 and (kf.iota_var < (0.1 * iota) ** 2 or (jstage and spec.j_feedforward)):
                self.alpha = iota * torque
                if kf.aug is not None:
                    self.alpha -= kf.gamma * kf.omega
            else:
                self.alpha = 0.0  # not a stale acceleration from before 1/J was forgotten
            if self.restarted and spec.filter_omega:
                om = kf.omega
                self.om_meas = om if om - om == 0.0 else math.nan  # a diverged filter: back to eq. (9)
        i = (tick + 1) % self.hist
        self.cum_t[i], self.cum_c[i], self.cum_w[i] = tick + 1, self.cc, self.cw
        self.late_z = self.late_c = self.late_w = 0.0
        return fx, fy, tau

    def _law_wrench(self, tick: int, stage: int, v: complex, q: complex, zc: complex,
                    default: tuple[float, float, float]) -> tuple[float, float, float]:
        """The user's law with this tick's estimates (agents/laws.py); its output is checked here, at the edge."""
        x = self.avg.x
        kf = self.kf
        li = LawInput()
        li.tick = tick
        li.t = tick * self.dt
        li.stage = "done" if stage == DONE else "background"
        li.m = x[CH_MN] / x[CH_MW] if x[CH_MW] > 0.0 else math.nan
        li.J = x[CH_JN] / x[CH_JW] if x[CH_JW] > 0.0 else math.nan
        if kf.ready:
            vc = kf.vc
            li.omega = kf.omega
            li.vc = (vc.real, vc.imag)
            li.q = (q.real, q.imag)
        else:
            li.omega = math.nan
            li.vc = li.q = (math.nan, math.nan)
        li.zc = (zc.real, zc.imag)
        li.v = (v.real, v.imag)
        li.default = default
        try:
            out = self.law(li)
        except Exception as exc:  # the user's code: one line naming it, where and when, not a bare traceback
            raise ControlLawError(f"control.law {self.law_ref!r} raised {type(exc).__name__}: {exc} at tick {tick} "
                                  f"(agent {self.id})") from exc
        return checked_wrench(out, self.law_ref, tick, self.id)

    # ------------------------------------------------------------------ outputs
    def shared(self, out: dict[str, float]) -> None:
        avg = self.avg
        out.update(zip(_CH_KEYS, avg.x))
        out["dg"] = avg.deg_f
        out["Sk"] = float(self.stage_tick)
        out["ps"] = self.psi if self.psi == self.psi else 0.0
        self.barrier.encode(out)

    def flows_to(self, j: int) -> list[float]:
        return self.avg.flow[j]

    def snapshot(self) -> tuple:
        """What :func:`estimates` needs, taken every tick and turned into the estimate only on the ticks
        that are recorded or published (the consensus state ``avg.x`` and the filter state ``kf.s`` are
        replaced each tick, never changed in place, so holding them is enough)."""
        return (self.avg.x, self.psi, self.kf.s, self.stage, self.j_local, self.m_local, self.late_switches,
                self.b_local, self.c_local, self.reseeds)


def estimates(snap: tuple) -> dict[str, float]:
    """The dynamical phase's estimate values (``net.vocabulary.ESTIMATE_NAMES``) from a :meth:`DynamicPhase.snapshot`."""
    x, psi, s, stage, j_local, m_local, late, b_local, c_local, reseeds = snap
    nan = math.nan
    m = x[CH_MN] / x[CH_MW] if x[CH_MW] > 0.0 else nan
    J = x[CH_JN] / x[CH_JW] if x[CH_JW] > 0.0 else nan
    if stage >= M_AVERAGE:
        zc = complex(x[CH_ZX], x[CH_ZY]) * complex(cos(psi), sin(psi))
        vc = complex(s[0], s[1])
    else:
        zc = vc = complex(nan, nan)
    return {
        "J": J,
        "m": m,
        "zc_x": zc.real,
        "zc_y": zc.imag,
        "vc_x": vc.real,
        "vc_y": vc.imag,
        "J_local": j_local,
        "m_local": m_local,
        "late_switches": float(late),
        # augmented model (estimate_effects): b with m's weights, c with J's
        "b": x[CH_BN] / x[CH_MW] if len(x) > CH_BN and x[CH_MW] > 0.0 else nan,
        "c": x[CH_CN] / x[CH_JW] if len(x) > CH_CN and x[CH_JW] > 0.0 else nan,
        "b_local": b_local,
        "c_local": c_local,
        "filter_restarts": float(reseeds),
    }
