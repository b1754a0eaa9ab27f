"""Parameters of the agents' estimator and control law (what a robot is configured with).

Owned by the agent core (``agents``); kept here so that scenarios can carry them without the
config package importing the algorithms. Defaults are tuned for the reference scenario of paper 000
(n = 10 on a 4.0 m x 2.2 m, 50 kg, J = 86.89 kg m^2 load, line graph, dt = 0.01 s, sigma = 0.3 m/s).
"""

from __future__ import annotations

import math

from pydantic import BaseModel, ConfigDict, Field


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class EstimatorSpec(_Strict):
    """Tuning of the kinematic-phase estimators (z_ij, z_i, omega; see ``agents/kinematic.py``)."""

    sigma_v: float | None = Field(
        None, ge=0, description="velocity-sensor noise the agents assume (m/s); default: the scenario's noise"
    )
    history_ticks: int = Field(
        64, ge=2, le=4096, description="own measurements kept to pair with late neighbour messages (ticks)"
    )
    max_age_ticks: int = Field(
        50, ge=1, description="a neighbour's consensus state older than this is not used (ticks)"
    )
    fit_arc: float = Field(
        1.5 * math.pi, gt=0, description="rotation a circle-fit window must cover before it is accepted (rad)"
    )
    fit_min_ticks: int = Field(50, ge=3, description="minimum samples in a circle-fit window (ticks)")
    fit_max_ticks: int = Field(
        1500, ge=10, description="a window that has not covered fit_arc by then is dropped and restarted (ticks)"
    )
    fit_check_ticks: int = Field(
        10, ge=1, description="the window is checked (fit solved, arc measured) every this many samples (ticks)"
    )
    max_gap_ticks: int = Field(
        25, ge=1, description="a longer run of missing samples restarts the circle-fit window (ticks)"
    )
    angle_walk: float = Field(
        0.02, gt=0, description="process noise of the z_ij angle tracker, i.e. omega_hat error (rad/sqrt(s))"
    )
    gate_snr: float = Field(
        2.5,
        ge=0,
        description="z_ij angle corrections only when |omega_hat| |z_ij| >= gate_snr * sigma_v * sqrt(2) (-)",
    )
    omega_tau: float = Field(
        0.5, gt=0, description="time constant of the omega low-pass consensus filter (s)"
    )
    omega_eps: float = Field(
        0.3, gt=0, lt=1, description="consensus gain of the omega filter per tick (-); eps * degree < 1"
    )
    centroid_eps: float = Field(
        0.3, gt=0, lt=1, description="gain of the centroid (z_i) iteration per tick (-); eps * degree < 1"
    )


class ControlSpec(_Strict):
    """The kinematic-phase control schedule (see ``agents/control.py``). Per-agent magnitudes."""

    force: float = Field(1.0, ge=0, description="Prop. 6 common force magnitude per agent (N)")
    force_angle: float = Field(
        0.5, description="direction of the common force, world frame, from +x (rad)"
    )
    switch_period: float = Field(
        4.0, gt=0, description="the common force flips sign every switch_period (s)"
    )
    spin_torque: float = Field(
        3.0, description="torque each agent applies until its omega estimate is trusted (N m); its sign sets the spin"
    )
    omega_target: float = Field(
        1.5, ge=0, description="|omega| held by the torque regulation once omega_hat is trusted (rad/s)"
    )
    k_omega: float = Field(
        3.0, ge=0,
        description="regulation gain per agent: tau = k_omega (omega_target - omega_hat) (N m s/rad); low on "
                    "purpose: the loop only has to keep omega away from zero, and with 10 it diverged under "
                    "200 ms link delay (omega_hat lags by the delay plus the consensus filter)",
    )
    torque_max: float = Field(5.0, ge=0, description="saturation of the regulation torque per agent (N m)")
