"""Pure-numpy rigid-body truth for the agent-core tests, and a closed loop of AgentCores around it.

The load is a rigid body with CoM C: omega_dot = (sum_i (p_Ci - p_C) x f_i + tau_i) / J,
v_C_dot = sum_i f_i / m; each agent measures its contact-point velocity plus N(0, sigma^2 I).
Wrenches are held over [k, k+1) (semi-implicit Euler with the rotation integrated exactly per tick).
Messages of tick k reach the neighbours at tick k+1 (no faults) or go through a caller-supplied
``deliver`` hook. Only explicit ``numpy.random.Generator`` objects are used.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from agents.agent import AgentCore
from config.agent_params import ControlSpec, EstimatorSpec
from net.messages import StateMsg


def rectangle_perimeter_points(width: float, height: float, n: int, start: float = 0.0) -> np.ndarray:
    """n points evenly spaced along the rectangle outline (counter-clockwise from the lower-left corner),
    body frame with origin at the rectangle's centroid; ``start`` is the first point's fraction of the outline."""
    per = 2.0 * (width + height)
    corners = np.array([[-width / 2, -height / 2], [width / 2, -height / 2], [width / 2, height / 2], [-width / 2, height / 2]])
    lengths = [width, height, width, height]
    pts = []
    for k in range(n):
        s = ((start + k / n) % 1.0) * per
        e = 0
        while s > lengths[e] and e < 3:
            s -= lengths[e]
            e += 1
        a, b = corners[e], corners[(e + 1) % 4]
        pts.append(a + (b - a) * (s / lengths[e]))
    return np.array(pts)


def line_neighbours(n: int) -> list[list[int]]:
    return [[j for j in (i - 1, i + 1) if 0 <= j < n] for i in range(n)]


@dataclass
class RigidLoad:
    """Planar rigid body; ``body_pts`` are the contact points relative to the CoM, body frame (m)."""

    body_pts: np.ndarray
    mass: float
    inertia: float
    pc: complex = 0j
    vc: complex = 0j
    theta: float = 0.0
    omega: float = 0.0
    _b: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._b = self.body_pts[:, 0] + 1j * self.body_pts[:, 1]

    def arms(self) -> np.ndarray:
        """p_Ci - p_C, world frame (complex)."""
        return np.exp(1j * self.theta) * self._b

    def contact_positions(self) -> np.ndarray:
        return self.pc + self.arms()

    def contact_velocities(self) -> np.ndarray:
        return self.vc + 1j * self.omega * self.arms()

    def step(self, forces: np.ndarray, taus: np.ndarray, dt: float) -> None:
        arms = self.arms()
        torque = float(np.sum(arms.real * forces.imag - arms.imag * forces.real) + np.sum(taus))
        self.omega += torque / self.inertia * dt
        self.vc += complex(np.sum(forces)) / self.mass * dt
        self.theta += self.omega * dt
        self.pc += self.vc * dt


@dataclass
class LoopResult:
    t: np.ndarray  # recorded times (s)
    omega: np.ndarray  # true omega at those times
    omega_hat: np.ndarray  # (T, n)
    eerd_ratio: np.ndarray  # (T,) network EERD (every directed estimate) / initial EERD
    eerd_agent_max: np.ndarray  # (T,) max over agents of its own pairs' EERD ratio
    zi_rms: np.ndarray  # (T,) RMS over agents of |z_i_hat - z_i| (m)
    pair_err_rms: np.ndarray  # (T,) RMS over directed pairs of |z_ij_hat - z_ij| (m)
    radius_rel_err: np.ndarray  # (n_pairs,) final | |z_ij|_hat / |z_ij| - 1 |
    step_us: float  # mean wall time of one AgentCore.step (microseconds)
    agents: list[AgentCore]

    def omega_rms(self, t0: float, t1: float) -> float:
        sel = (self.t >= t0) & (self.t <= t1)
        return float(np.sqrt(np.mean((self.omega_hat[sel] - self.omega[sel, None]) ** 2)))

    def at(self, arr: np.ndarray, t: float, window: float = 1.0) -> float:
        """Mean of a recorded series over [t - window, t]."""
        sel = (self.t >= t - window) & (self.t <= t + 1e-9)
        return float(np.mean(arr[sel]))


def reference_load(n: int = 10, scale: float = 1.0, com_offset: tuple[float, float] = (0.3, -0.2)) -> RigidLoad:
    """Paper 000's reference load (4.0 m x 2.2 m, 50 kg, J = 86.89) scaled by ``scale`` in length with
    m = 5 n (the paper's Monte Carlo rule) and J of a uniform rectangle for scale != 1."""
    w, h = 4.0 * scale, 2.2 * scale
    pts = rectangle_perimeter_points(w, h, n, 0.0) - np.asarray(com_offset) * scale
    if scale == 1.0 and n == 10:
        m, J = 50.0, 86.89
    else:
        m = 5.0 * n
        J = m * (w * w + h * h) / 12.0
    return RigidLoad(pts, m, J)


def run_closed_loop(
    load: RigidLoad,
    neighbours: Sequence[Sequence[int]],
    *,
    sigma: float,
    seconds: float,
    seed: int,
    dt: float = 0.01,
    estimator: EstimatorSpec | None = None,
    control: ControlSpec | None = None,
    record_every: int = 10,
    deliver: Callable[[int, int, list[StateMsg]], list[StateMsg]] | None = None,
    time_steps: bool = False,
) -> LoopResult:
    """Run n AgentCores around ``load`` for ``seconds``.

    ``deliver(tick, receiver, msgs)`` may filter / reorder / delay the list of neighbours' messages
    of tick-1 (default: pass through)."""
    rng = np.random.default_rng(seed)
    n = len(neighbours)
    est = estimator or EstimatorSpec()
    ctl = control or ControlSpec()
    agents = [AgentCore(i, neighbours[i], n, dt, sigma, est, ctl) for i in range(n)]
    edges = sorted({(min(i, j), max(i, j)) for i in range(n) for j in neighbours[i]})
    directed = [(i, j) for i, j in edges] + [(j, i) for i, j in edges]
    ticks = int(round(seconds / dt))
    prev: list[StateMsg | None] = [None] * n
    rec_t, rec_om, rec_omh, rec_eerd, rec_emax, rec_zi, rec_pair = [], [], [], [], [], [], []
    p0 = load.contact_positions()
    init_eerd = sum(abs(p0[i] - p0[j]) ** 2 for i, j in directed)
    per_agent_init = [sum(abs(p0[i] - p0[j]) ** 2 for j in neighbours[i]) for i in range(n)]
    spent = 0.0
    for k in range(ticks):
        vel = load.contact_velocities()
        noise = rng.normal(0.0, sigma, size=(n, 2)) if sigma > 0 else np.zeros((n, 2))
        meas = vel + noise[:, 0] + 1j * noise[:, 1]
        forces = np.zeros(n, dtype=complex)
        taus = np.zeros(n)
        results = []
        for i in range(n):
            inbox = [prev[j] for j in neighbours[i] if prev[j] is not None]
            if deliver is not None:
                inbox = deliver(k, i, inbox)
            if time_steps:
                t0 = time.perf_counter()
                r = agents[i].step(k, float(meas[i].real), float(meas[i].imag), inbox)
                spent += time.perf_counter() - t0
            else:
                r = agents[i].step(k, float(meas[i].real), float(meas[i].imag), inbox)
            results.append(r)
            forces[i] = complex(r.wrench.fx, r.wrench.fy)
            taus[i] = r.wrench.tau
        prev = [r.state for r in results]
        if k % record_every == 0 or k == ticks - 1:
            p = load.contact_positions()
            pg = p.mean()
            zi_true = p - pg
            zi_hat = np.array([complex(r.estimate.values["zi_x"], r.estimate.values["zi_y"]) for r in results])
            zhat = {(i, j): complex(*results[i].estimate.pairs[j]) for i, j in directed}
            errs = {(i, j): abs(zhat[(i, j)] - (p[i] - p[j])) ** 2 for i, j in directed}
            rec_t.append(k * dt)
            rec_om.append(load.omega)
            rec_omh.append([r.estimate.values["omega"] for r in results])
            rec_eerd.append(sum(errs.values()) / init_eerd)
            rec_emax.append(max(sum(errs[(i, j)] for j in neighbours[i]) / per_agent_init[i] for i in range(n)))
            rec_zi.append(math.sqrt(float(np.mean(np.abs(zi_hat - zi_true) ** 2))))
            rec_pair.append(math.sqrt(sum(errs.values()) / len(directed)))
        load.step(forces, taus, dt)
    p = load.contact_positions()
    rad = np.array(
        [abs(agents[i].pairs[j].r / abs(p[i] - p[j]) - 1.0) for i, j in directed]
    )
    return LoopResult(
        np.array(rec_t), np.array(rec_om), np.array(rec_omh), np.array(rec_eerd), np.array(rec_emax),
        np.array(rec_zi), np.array(rec_pair), rad, spent / (ticks * n) * 1e6 if time_steps else 0.0, agents,
    )
