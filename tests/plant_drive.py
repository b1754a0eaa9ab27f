"""Drive the project's pymunk plant with a scripted team control law and record truth, measurements, wrenches.

For the paper-observer tests and bench (agents/paper_observers.py): the observers are checked against
the real integrator (simulator/plant.py), not against a copy of their own model. The control laws
see the plant's truth (omega, z_i): they only have to excite the load, they are not under test.
Only explicit numpy Generators are used.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from config.loader import load_scenario
from simulator.plant import Plant, Truth, sensor_rng

ROOT = Path(__file__).resolve().parents[1]
FIG4 = ROOT / "config" / "scenarios" / "paper-fig4.toml"

# controller(k, t, truth) -> (forces (n, 2) world frame, taus (n,))
Controller = Callable[[int, float, Truth], tuple[np.ndarray, np.ndarray]]


@dataclass
class Recording:
    """Per tick k (before the wrench of tick k is applied): truth and measurements; then that wrench."""

    n: int
    dt: float
    t: np.ndarray  # (T,)
    omega: np.ndarray  # (T,)
    zc: np.ndarray  # (T, 2)
    zi: np.ndarray  # (T, n, 2)
    vc: np.ndarray  # (T, 2)
    vci: np.ndarray  # (T, n, 2) measured contact velocities (noise-free when sigma = 0)
    mass: np.ndarray  # (T,)
    inertia: np.ndarray  # (T,)
    forces: np.ndarray  # (T, n, 2)
    taus: np.ndarray  # (T, n)


def drive(seconds: float, controller: Controller, overrides: Sequence[str] = (), sigma: float = 0.0, seed: int = 1) -> Recording:
    """Run paper-fig4's plant (n = 10, 4.0 m x 2.2 m, m = 50, J = 86.89) under ``controller``."""
    sc = load_scenario(FIG4, [f"noise.sigma_v={sigma}", f"seed={seed}", *overrides])
    plant = Plant(sc)
    rng = sensor_rng(seed)
    n, dt = sc.n, sc.dt
    T = round(seconds / dt)
    rec = Recording(
        n, dt, np.arange(T) * dt, np.empty(T), np.empty((T, 2)), np.empty((T, n, 2)), np.empty((T, 2)),
        np.empty((T, n, 2)), np.empty(T), np.empty(T), np.empty((T, n, 2)), np.empty((T, n)),
    )  # fmt: skip
    for k in range(T):
        tr = plant.truth()
        rec.omega[k], rec.zc[k], rec.zi[k], rec.vc[k] = tr.omega, tr.zc, tr.zi, tr.vc
        rec.mass[k], rec.inertia[k] = tr.mass, tr.inertia
        rec.vci[k] = plant.measure(rng) if sigma > 0 else plant.velocities()
        f, tau = controller(k, k * dt, tr)
        rec.forces[k], rec.taus[k] = f, tau
        plant.apply_and_step([(float(a), float(b), float(c)) for (a, b), c in zip(f, tau)])
    return rec


def push_and_spin(
    n: int,
    force: float = 5.0,
    switch_s: float = 4.0,
    direction: float = 0.5,
    turn: float = 0.0,
    spread: float = 0.0,
    omega_ref: float = 1.5,
    k_omega: float = 20.0,
    dither: float = 15.0,
    dither_s: float = 3.0,
) -> Controller:
    """A common force of ``force`` N per agent along ``direction`` (rad; turning at ``turn`` rad/s) whose
    sign flips every ``switch_s`` s, plus per-agent offsets of ``spread`` N (world-fixed, summing to a
    non-zero net force); the team torque k_omega (omega_ref - omega) + dither sin(2 pi t / dither_s)
    (N m, split evenly) keeps the load turning and makes the torque about the contact centroid vary."""
    offs = spread * np.stack([np.cos(np.arange(n) * 2.1), np.sin(np.arange(n) * 1.3)], axis=1)

    def ctl(k: int, t: float, tr: Truth) -> tuple[np.ndarray, np.ndarray]:
        sgn = 1.0 if (t % (2 * switch_s)) < switch_s else -1.0
        a = direction + turn * t
        f = np.tile(sgn * force * np.array([math.cos(a), math.sin(a)]), (n, 1)) + offs
        total = k_omega * (omega_ref - tr.omega) + dither * math.sin(2 * math.pi * t / dither_s)
        return f, np.full(n, total / n)

    return ctl


def j_stage(n: int, kz: float = 4.0, flip_s: float = 5.0) -> Controller:
    """Result 5: f_i = k_z s(t) z_i^perp, tau_i = 0, with s = +1 then -1 (omega ramps up and back)."""

    def ctl(k: int, t: float, tr: Truth) -> tuple[np.ndarray, np.ndarray]:
        s = kz if (t % (2 * flip_s)) < flip_s else -kz
        zi = np.asarray(tr.zi)
        return s * np.stack([-zi[:, 1], zi[:, 0]], axis=1), np.zeros(n)

    return ctl


def line_neighbours(n: int) -> list[list[int]]:
    """The paper's worst-case graph: agent i talks to i - 1 and i + 1."""
    return [[j for j in (i - 1, i + 1) if 0 <= j < n] for i in range(n)]


def team_averages(rec: Recording, zi: np.ndarray | None = None, eps: float = 0.3) -> np.ndarray:
    """(T, n, 4): each agent's dynamic-consensus estimate of the averages of the four channels of
    ``paper_observers.local_channels`` (f_x, f_y, z_i x (f_i - f_mean_i), tau_i), as the team computes
    them with one exchange per tick on the line graph (first-order input dynamic consensus, ref. [23]).

    Agent i first updates its force channels, then forms z_i x (f_i - f_mean_i) with its new f_mean
    estimate (so a common force step leaves that channel at 0). ``zi`` defaults to the true z_i.
    """
    from agents.paper_observers import fodac_step, local_channels

    n, T = rec.n, len(rec.t)
    zi = rec.zi if zi is None else zi
    nb = line_neighbours(n)
    out = np.empty((T, n, 4))
    x = np.empty((n, 4))
    prev = np.empty((n, 4))
    for k in range(T):
        f, tau = rec.forces[k], rec.taus[k]
        if k == 0:
            x[:, :2], x[:, 3] = f, tau
        else:
            old = x.copy()
            for c in (0, 1, 3):
                u = f[:, c] if c < 2 else tau
                for i in range(n):
                    x[i, c] = fodac_step(old[i, c], (old[j, c] for j in nb[i]), eps, u[i] - prev[i, c])
        cur = np.array([local_channels(tuple(f[i]), float(tau[i]), tuple(zi[k, i]), (x[i, 0], x[i, 1])) for i in range(n)])
        if k == 0:
            x[:, 2] = cur[:, 2]
        else:
            for i in range(n):
                x[i, 2] = fodac_step(old[i, 2], (old[j, 2] for j in nb[i]), eps, cur[i, 2] - prev[i, 2])
        prev = cur
        out[k] = x
    return out
