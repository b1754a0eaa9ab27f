"""The wrench each stage of the dynamical phase applies (paper 000 Sec. V-VI; docs/dynamics.md).

M stage and Algorithm 2: Prop. 6's common force, switched in sign. J stage: Result 5's
f_i = k_z s(t) z_i^perp with tau_i = 0 (sum_i f_i = 0, so z_C drops out of the rotation). Done: Prop. 7
braking if asked. Algorithm 2 adds a torque dither for J. Pure functions of the stage's tick count ``k``.
"""

from __future__ import annotations

import math
from math import cos, sin

from config.agent_params import DynamicsSpec
from net.vocabulary import BACKGROUND, DONE, J_EXCITE, M_EXCITE


def j_sign(k: int, j_ticks: int, spec: DynamicsSpec) -> float:
    """s(t) of the J stage at its tick ``k``: +-1, ``spec.j_cycles`` cycles over the stage, starting
    in the direction of ``spec.omega_sign``."""
    half = max(1, j_ticks // (2 * spec.j_cycles))
    sgn = 1.0 if (k // half) % 2 == 0 else -1.0
    if spec.omega_sign < 0:
        sgn = -sgn
    return sgn


def stage_wrench(stage: int, k: int, spec: DynamicsSpec, m_switch: int, j_ticks: int, v: complex, q: complex,
                 zc: complex, wrench: tuple[float, float, float]) -> tuple[float, float, float]:
    """(fx, fy, tau) at the stage's tick ``k``; ``wrench`` (the kinematic law's) where the stage has none.
    ``v`` own contact velocity, ``q`` = q_i, ``zc`` = z_C (world)."""
    fx, fy, tau = wrench
    if stage == M_EXCITE or stage == BACKGROUND:
        sgn = -1.0 if (k // m_switch) & 1 else 1.0
        fx = sgn * spec.m_force * cos(spec.m_force_angle)
        fy = sgn * spec.m_force * sin(spec.m_force_angle)
    elif stage == J_EXCITE:
        # with the refined z_i = q_i - z_C
        f = spec.k_z * j_sign(k, j_ticks, spec) * 1j * (q - zc)
        fx, fy, tau = f.real, f.imag, 0.0
    elif stage == DONE and spec.brake > 0.0:
        fx, fy, tau = -spec.brake * v.real, -spec.brake * v.imag, 0.0
    return fx, fy, tau


def dither(k: int, spec: DynamicsSpec, dither_ticks: int) -> float:
    """Algorithm 2's torque dither for J at the stage's tick ``k``."""
    return spec.dither_torque * sin(2.0 * math.pi * k / dither_ticks)
