"""Kinematic-phase control law (pure): keep the load turning briskly, keep v_C bounded.

Choice: *spin up, then regulate*. The load starts at rest, and the kinematic estimators need
|omega| |z_ij| well above sigma*sqrt(2). Each agent applies a common torque ``spin_torque`` until its
own omega estimate exists (its first accepted circle fit, or a neighbour's estimate); torques add directly,
omega_dot = sum tau_i / J, whatever the unknown CoM. Then a torque-only proportional regulation
tau_i = sat(k_omega (omega_target - omega_hat_i)) holds omega near the target: torque only, because
a force-based regulation would need z_C, and the torque keeps Prop. 6's random walk of omega^2
(the common force switched in sign) from stopping the rotation. On top, the Prop. 6 common force,
small and flipped every ``switch_period`` so v_C oscillates around zero instead of growing.
The spin direction is the sign of ``spin_torque``.
"""

from __future__ import annotations

import math

from config.agent_params import ControlSpec


class KinematicControl:
    """Precomputed constants of the control law; :meth:`wrench` is O(1) and allocation-free."""

    __slots__ = ("_fx", "_fy", "_switch", "spin", "_target", "_k", "_tmax")

    def __init__(self, spec: ControlSpec, dt: float) -> None:
        self._fx = spec.force * math.cos(spec.force_angle)
        self._fy = spec.force * math.sin(spec.force_angle)
        self._switch = max(1, int(round(spec.switch_period / dt)))
        self.spin = spec.spin_torque
        sgn = 1.0 if spec.spin_torque >= 0.0 else -1.0
        self._target = sgn * spec.omega_target
        self._k = spec.k_omega
        self._tmax = spec.torque_max

    def wrench(self, tick: int, omega_hat: float, regulate: bool, target: float | None = None) -> tuple[float, float, float]:
        """(fx, fy, tau) for [tick, tick+1); ``target`` replaces omega_target (the team's omega boost)."""
        if (tick // self._switch) & 1:
            fx, fy = -self._fx, -self._fy
        else:
            fx, fy = self._fx, self._fy
        if regulate:
            tau = self._k * ((self._target if target is None else target) - omega_hat)
            if tau > self._tmax:
                tau = self._tmax
            elif tau < -self._tmax:
                tau = -self._tmax
        else:
            tau = self.spin
        return fx, fy, tau
