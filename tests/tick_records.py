"""The records one agent tick passed between its kinematic and dynamical phases before the team's dynamical phase
was compiled: what tests/dynamic_reference.py (the frozen Python phase) reads and returns.

:class:`KinematicTick` goes from the kinematic phase to the dynamical phase, :class:`DynamicOut` back
to the agent (the phase's states go into the agent's OUT row), and its :class:`DynamicFeedback` into the
kinematic phase of the next tick. Nothing else crosses: neither phase reads the other's fields.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np


class DynamicFeedback(NamedTuple):
    """What the dynamical phase tells the kinematic phase of the next tick (the defaults: before it runs)."""

    om_meas: float = math.nan  # omega_hat's measurement: the filter's omega (NaN: the pooled eq. (9) rate)
    alpha: float = 0.0  # modelled angular acceleration, fed forward into omega_hat (rad/s^2)
    hold_shape: bool = False  # z_i is held: the load may stop turning, and z_i is observable only while it turns
    team_waiting: bool = False  # kinematic stage and some agent not ready yet (the omega boost applies)


class KinematicTick(NamedTuple):
    """The kinematic phase's results of one tick (Sec. IV of paper 000)."""

    tick: int
    v: complex  # own measured contact velocity (m/s, world)
    u: float  # pooled eq. (9) rate of this tick's pair samples (rad/s; NaN: none)
    u_den: float  # its pooling weight sum_j |z_ij|^2 (0.0: none)
    late: tuple[tuple[int, float], ...]  # (tick, weight) of the samples in u older than the state tick
    omega: float  # omega_hat after the tick (rad/s)
    om_init: bool  # omega_hat exists (own circle fit or adopted from a neighbour)
    phi: float  # body-frame angle (rad)
    y: complex  # z_i in the body frame
    zi: complex  # z_i in the world frame
    pairs: tuple[tuple[int, complex, complex], ...]  # (j, z_ij as sent, centroid flow F_ij), neighbour order
    ready: int  # neighbours whose z_ij is estimated
    trusted: bool  # every pair estimated
    wrench: tuple[float, float, float]  # the kinematic control law's (fx, fy, tau)
    inbox: np.ndarray  # the neighbours' IN rows (net/rows.py) whose dynamical states are taken, in taking order
    dropped_unknown: int  # counters so far (see ESTIMATE_NAMES)
    dropped_stale: int


class DynamicOut(NamedTuple):
    """The dynamical phase's results of one tick."""

    wrench: tuple[float, float, float]  # to apply (fx, fy, tau)
    stage: int
    estimates: dict[str, Any]  # its estimate values, ESTIMATE_NAMES from "J" on
    feedback: DynamicFeedback  # for the kinematic phase of the next tick
