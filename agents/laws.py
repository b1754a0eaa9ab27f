"""Control laws of your own, plugged in where the algorithm allows one; docs/control-laws.md.

Where: Algorithm 1 (``dynamics.algorithm = "sequential"``) once the team is done, instead of the
kinematic control (or Prop. 7 braking); Algorithm 2 (``"background"``) from its background stage on,
instead of Prop. 6 and the omega regulation (the torque dither that keeps J observable is added on
top; ``dynamics.dither_torque = 0`` leaves it out). Not before: the kinematic phase needs the load
turning, and the m and J stages of Algorithm 1 rest on the forces they prescribe (Result 5 needs
f_i = k_z z_i^perp and no torques).

A law is named in the scenario, ``control.law = "package.module:factory"`` or
``"path/to/file.py:factory"``, with ``control.law_params`` (a TOML table) as the factory's keyword
arguments. Each agent builds its law with ``factory(setup, **params)`` (``setup`` a :class:`LawSetup`;
the command line also builds them once beforehand to check them, so a factory should only build)
and calls ``law(x)`` every tick where it applies (``x`` a :class:`LawInput`), which returns the
agent's wrench ``(fx, fy, tau)``: force on its contact point, world frame (N), torque (N m). Return
``x.default`` to keep the algorithm's own. Like the rest of the core a law gets time and data as
arguments: no clock, socket, global random state or module-level state (agents share a module in
one process, not across daemons), so runs stay reproducible and both engines agree.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

Wrench = tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class LawSetup:
    """What an agent knows before the run: who it is and its team."""

    agent: int  # this agent's id, 0..n-1
    n: int  # team size
    dt: float  # tick length (s)
    neighbours: tuple[int, ...]  # one-hop neighbours' ids


class LawInput:
    """One tick's estimates, as this agent holds them (world frame; NaN where not known yet).

    Symbols of paper 000: C the load's centre of mass, C_i the agent's contact point.
    """

    __slots__ = ("tick", "t", "stage", "m", "J", "omega", "vc", "zc", "q", "v", "default")

    tick: int  # the tick this wrench is for
    t: float  # tick * dt (s)
    stage: str  # "done" (Algorithm 1) or "background" (Algorithm 2)
    m: float  # mass (kg), the team's average
    J: float  # inertia about C (kg m^2), the team's average
    omega: float  # angular rate (rad/s)
    vc: tuple[float, float]  # velocity of C (m/s)
    zc: tuple[float, float]  # z_C: contact centroid minus C (m)
    q: tuple[float, float]  # q_i = p_Ci - p_C: own contact point relative to C, the torque arm (m)
    v: tuple[float, float]  # own measured contact velocity v_Ci (m/s, with the sensor's noise)
    default: Wrench  # the wrench the algorithm would apply without a law


LawFactory = Callable[..., Callable[[LawInput], Sequence[float]]]


class ControlLawError(ValueError):
    """A law that cannot be loaded or built, or a wrench that is not three finite numbers."""


def checked_wrench(out: object, ref: str, tick: int, agent: int = -1) -> Wrench:
    """The law's output as (fx, fy, tau) floats; a clear error naming the law, the agent and the tick otherwise."""
    who = f" (agent {agent})" if agent >= 0 else ""
    try:
        fx, fy, tau = out  # type: ignore[misc]
        w = (float(fx), float(fy), float(tau))
    except (TypeError, ValueError, OverflowError):
        raise ControlLawError(f"control.law {ref!r} returned {out!r} at tick {tick}{who}: "
                              f"expected (fx, fy, tau), three numbers") from None
    if not (math.isfinite(w[0]) and math.isfinite(w[1]) and math.isfinite(w[2])):
        raise ControlLawError(f"control.law {ref!r} returned {w!r} at tick {tick}{who}: not finite")
    return w


# ------------------------------------------------------------------------------------- example law
class TrackVelocity:
    """Carry the load at a reference velocity and rate with what the team learnt (m, J, z_C, v_C).

    Each agent pushes its share of the force that brings v_C to ``v_ref`` with time constant 1/k_v,
    f_i = (m/n) k_v (v_ref - v_C), and of the torque that brings omega to ``omega_ref``,
    tau_i = (J/n) k_w (omega_ref - omega) - q_i x f_i: the second term cancels the torque of its own
    force about C, so the load's rotation and translation are commanded separately (equal forces on
    contacts whose centroid is not C would otherwise turn it). Saturated at ``f_max`` / ``tau_max`` per
    agent. Keeps the algorithm's wrench while m or J is not known.
    """

    __slots__ = ("n", "vx", "vy", "w", "kv", "kw", "fmax", "tmax")

    def __init__(self, setup: LawSetup, v_ref: Sequence[float] = (0.2, 0.0), omega_ref: float = 0.0,
                 k_v: float = 0.5, k_w: float = 0.5, f_max: float = 5.0, tau_max: float = 5.0) -> None:
        if len(v_ref) != 2:
            raise ControlLawError(f"TrackVelocity: v_ref must be [vx, vy] (got {v_ref!r})")
        for name, val in (("k_v", k_v), ("k_w", k_w), ("f_max", f_max), ("tau_max", tau_max)):
            if not val >= 0.0:
                raise ControlLawError(f"TrackVelocity: {name} must be >= 0 (got {val!r})")
        self.n = setup.n
        self.vx, self.vy = float(v_ref[0]), float(v_ref[1])
        self.w = float(omega_ref)
        self.kv, self.kw = float(k_v), float(k_w)
        self.fmax, self.tmax = float(f_max), float(tau_max)

    def __call__(self, x: LawInput) -> Wrench:
        m, J = x.m, x.J
        if not (m > 0.0 and J > 0.0) or x.vc[0] != x.vc[0] or x.q[0] != x.q[0]:
            return x.default
        g = m / self.n * self.kv
        fx = g * (self.vx - x.vc[0])
        fy = g * (self.vy - x.vc[1])
        f = math.hypot(fx, fy)
        if f > self.fmax:
            fx *= self.fmax / f
            fy *= self.fmax / f
        qx, qy = x.q
        tau = J / self.n * self.kw * (self.w - x.omega) - (qx * fy - qy * fx)
        tau = min(self.tmax, max(-self.tmax, tau))
        return fx, fy, tau
