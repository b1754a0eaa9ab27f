"""Plant effects the agents' model lacks: friction, sensor delay and bias, actuator gain, a slope, a periodic
force, a load change.

Configured per scenario in ``[plant]`` (:class:`config.scenario.PlantSpec`) and never told to the
agents. :class:`simulator.plant.Plant` builds an :class:`Effects` only when some effect is set, so
a nominal run takes exactly the nominal code path (same cost, bit-identical outputs). Pure: no clock,
no RNG of its own (the sensor noise stays the plant's one draw per tick).

Conventions (paper 000's discrete plant, see ``simulator/plant.py``): the wrench of tick k and the
effect forces computed from the state at tick k act during the step k -> k + 1 (semi-implicit
Euler, like pymunk's own integration).

- viscous friction: F = -c_v v_C (N s/m) at the CoM;
- Coulomb friction: F = -F_c tanh(|v_C|/v_s) v_C/|v_C| (N; smoothing speed v_s in m/s);
- rotational damping: torque = -c_r omega (N m s);
- external force: constant, world frame (N), e.g. a slope;
- periodic force: F(k) = A sin(2 pi k dt / T) u at the CoM, u = (cos theta, sin theta) fixed in the
  world frame (N), evaluated at tick k like the other forces of tick k;
- actuator gain: the plant receives gain x the commanded wrench (what the agents record);
- measurement delay: whole ticks d = round(delay/dt); the measurement at tick k is the true contact
  velocity at tick k - d (tick 0 before that), plus noise;
- velocity bias: a constant world-frame vector added to every agent's measurement (m/s);
- load change: at the first tick k with k dt >= t, mass, J (about the new CoM) and the CoM position in
  the body step; the contact points stay on the body and every body point keeps its velocity.
"""

from __future__ import annotations

import math
from collections import deque
from typing import TYPE_CHECKING

import numpy as np

from config.scenario import LoadChangeSpec, Scenario
from simulator import geometry

if TYPE_CHECKING:
    from simulator.plant import Plant


class Effects:
    """The configured effects of one plant; holds the little state they need (sensor history, CoM offset)."""

    __slots__ = (
        "dt", "gain", "viscous", "coulomb", "coulomb_speed", "rotational", "fext", "periodic", "bias", "delay_ticks",
        "_hist", "_changes", "_offset", "_outline",
    )  # fmt: skip

    def __init__(self, scenario: Scenario, outline_about_centroid: np.ndarray) -> None:
        p = scenario.plant
        self.dt = scenario.dt
        self.gain = p.actuator_gain
        self.viscous = p.friction.viscous
        self.coulomb = p.friction.coulomb
        self.coulomb_speed = p.friction.coulomb_speed
        self.rotational = p.friction.rotational
        self.fext = tuple(p.external_force)
        pf = p.periodic_force
        theta = math.radians(pf.direction_deg)
        # (A cos theta, A sin theta, 2 pi dt / T): the force of tick k is sin(k w) times the first two.
        self.periodic = (
            (pf.amplitude * math.cos(theta), pf.amplitude * math.sin(theta), 2.0 * math.pi * scenario.dt / pf.period_s)
            if pf.amplitude else None
        )
        self.bias = np.asarray(p.sensor.velocity_bias, dtype=float)
        self.delay_ticks = int(round(p.sensor.delay / scenario.dt))
        self._hist: deque[np.ndarray] = deque(maxlen=self.delay_ticks + 1)
        self._changes = list(p.load_changes)
        self._offset = np.asarray(scenario.load.com_offset, dtype=float)
        self._outline = outline_about_centroid

    @classmethod
    def build(cls, scenario: Scenario, outline_about_centroid: np.ndarray) -> Effects | None:
        """None when no effect is configured: the plant then runs its nominal path unchanged."""
        return cls(scenario, outline_about_centroid) if scenario.plant.active else None

    # --- hooks called by Plant -----------------------------------------------------------------
    def start(self, plant: Plant) -> None:
        """After construction: apply changes due at t = 0 and seed the sensor history."""
        self._apply_due_changes(plant)
        self._hist.append(plant.contact_velocities())

    def after_step(self, plant: Plant) -> None:
        """After each step (plant.tick advanced): load changes now due, then this tick's true velocities."""
        self._apply_due_changes(plant)
        self._hist.append(plant.contact_velocities())

    def wrench(self, plant: Plant, fx: float, fy: float, torque: float) -> tuple[float, float, float]:
        """Resultant (force, torque about the CoM) the body gets for the agents' commanded resultant."""
        g = self.gain
        fx, fy, torque = g * fx + self.fext[0], g * fy + self.fext[1], g * torque
        if self.periodic is not None:
            fx, fy = self._add_periodic(plant.tick, fx, fy)
        vx, vy = plant.com_velocity
        if self.viscous:
            fx -= self.viscous * vx
            fy -= self.viscous * vy
        if self.coulomb:
            speed = math.hypot(vx, vy)
            if speed > 0.0:
                k = self.coulomb * math.tanh(speed / self.coulomb_speed) / speed
                fx -= k * vx
                fy -= k * vy
        if self.rotational:
            torque -= self.rotational * plant.angular_velocity
        return fx, fy, torque

    def periodic_force(self, tick: int) -> tuple[float, float]:
        """The periodic force acting during the step tick -> tick + 1 (world frame, N); (0, 0) when off."""
        return self._add_periodic(tick, 0.0, 0.0) if self.periodic is not None else (0.0, 0.0)

    def _add_periodic(self, tick: int, fx: float, fy: float) -> tuple[float, float]:
        ax, ay, w = self.periodic
        # The phase from the integer tick (not an accumulated angle): no drift over a long run.
        s = math.sin(w * tick)
        return fx + s * ax, fy + s * ay

    def measure(self, plant: Plant, rng: np.random.Generator) -> np.ndarray:
        """Delayed true velocities plus bias plus the plant's usual N(0, sigma^2) draw (same stream as nominal)."""
        return self._hist[0] + self.bias + rng.normal(0.0, plant.sigma_v, size=(plant.n, 2))

    # --- load change ---------------------------------------------------------------------------
    def _apply_due_changes(self, plant: Plant) -> None:
        t = plant.tick * self.dt
        while self._changes and self._changes[0].t <= t + 1e-9 * self.dt:
            self._change_load(plant, self._changes.pop(0))

    def _change_load(self, plant: Plant, change: LoadChangeSpec) -> None:
        new_off = self._offset if change.com_offset is None else np.asarray(change.com_offset, dtype=float)
        d = new_off - self._offset  # CoM displacement, body frame
        inertia = change.inertia
        if inertia is None:
            j_centroid = change.mass * geometry.polar_moment_per_mass(self._outline)
            inertia = j_centroid + change.mass * float(new_off @ new_off)
        plant.change_load(change.mass, inertia, d)
        self._offset = new_off


__all__ = ["Effects"]
