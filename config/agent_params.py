"""Parameters of the agents' estimator and control law (what a robot is configured with).

Owned by the agent core (``agents``); kept here so that scenarios can carry them without the
config package importing the algorithms. Defaults are tuned for the reference scenario of paper 000
(n = 10 on a 4.0 m x 2.2 m, 50 kg, J = 86.89 kg m^2 load, line graph, dt = 0.01 s, sigma = 0.3 m/s).
"""

from __future__ import annotations

import math
import re
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

# control.law: "package.module:factory" or "some/file.py:factory" (the attribute may be dotted; a file
# path may hold colons: the attribute follows the last one)
LAW_REF = re.compile(r"(?P<target>.+\.py|[A-Za-z_]\w*(?:\.[A-Za-z_]\w*)*):(?P<attr>[A-Za-z_]\w*(?:\.[A-Za-z_]\w*)*)")
_BARE_KEY = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def _check_law_param(value: Any, where: str = "") -> None:
    """law_params are written back to run.toml for the daemons: plain TOML values under bare keys only."""
    at = f"{where}: " if where else ""
    if isinstance(value, dict):
        for k, v in value.items():
            if not isinstance(k, str) or not _BARE_KEY.fullmatch(k):
                raise ValueError(f"{at}key {k!r} is not a plain name (letters, digits, _)")
            _check_law_param(v, f"{where}.{k}" if where else k)
    elif isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            _check_law_param(v, f"{where}[{i}]")
    elif isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f"{at}{value!r} is not a finite number")
    elif not isinstance(value, (bool, int, str)):
        raise ValueError(f"{at}{type(value).__name__} values are not supported (numbers, strings, booleans, "
                         f"lists and tables are)")


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class EstimatorSpec(_Strict):
    """Tuning of the kinematic-phase estimators (z_ij, z_i, omega; see ``agents/kernels/kinematic.py`` and
    ``agents/kernels/pair.py``)."""

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
        0.02,
        gt=0,
        description=(
            "process noise of the z_ij angle tracker, i.e. omega_hat error (rad/sqrt(s)); sets the angle "
            "loop's bandwidth: 0.05 keeps lock in more runs at sigma 1 but is noisier (docs/spinup.md)"
        ),
    )
    gate_snr: float = Field(
        2.5,
        ge=0,
        description="with angle_meas = 'axis': z_ij angle corrections only when |omega_hat| |z_ij| >= gate_snr * sigma_v * sqrt(2) (-)",
    )
    angle_meas: Literal["linear", "axis"] = Field(
        "linear",
        description=(
            "z_ij angle correction per sample: 'linear' = the radial part of (v_Ci - v_Cj) / z_ij, "
            "omega sin(angle error), weighted by omega_hat, no gate; 'axis' = the normalised axis "
            "perp(v_Ci - v_Cj), gated by gate_snr (the form before docs/spinup.md)"
        ),
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
    """The kinematic-phase control schedule (see ``kin_wrench`` in ``agents/kernels/kinematic.py``). Per-agent
    magnitudes."""

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
    omega_boost: float = Field(
        2.5, ge=0,
        description="with the dynamical phase: |omega| held instead of omega_target while the team is still in "
                    "the kinematic stage boost_after_s after the start (some pair has no circle fit yet: at high "
                    "noise a short pair's tangential speed |omega| |z_ij| is too small for it); back to "
                    "omega_target once every agent is ready; never below omega_target. 0: off (rad/s)",
    )
    boost_after_s: float = Field(
        30.0, ge=0, description="when omega_boost starts if the team is not ready yet (simulated s)"
    )
    law: str = Field(
        "", description="a control law of yours where the algorithm allows one (Algorithm 1 once done, Algorithm "
                        "2 from its background stage on; agents/laws.py, docs/control-laws.md): "
                        "'package.module:factory' or 'path/to/file.py:factory' (a relative path from the "
                        "scenario file's directory, or from the working directory when given with --set); "
                        "empty: the built-in schedule",
    )
    law_params: dict[str, Any] = Field(
        default_factory=dict, description="keyword arguments of the law's factory (a TOML table)"
    )

    @field_validator("law")
    @classmethod
    def _law_ref(cls, v: str) -> str:
        if v and not LAW_REF.fullmatch(v):
            raise ValueError("expected 'package.module:factory' or 'path/to/file.py:factory'")
        return v

    @field_validator("law_params")
    @classmethod
    def _law_params(cls, v: dict[str, Any]) -> dict[str, Any]:
        _check_law_param(v)
        return v


class DynamicsSpec(_Strict):
    """The dynamical phase (paper 000 Sec. V-VI; see ``agents/dynamic_phase.py`` and docs/dynamics.md)."""

    algorithm: Literal["none", "sequential", "background"] = Field(
        "none",
        description="none: kinematic phase only; sequential: Algorithm 1 (stages m, z_C, v_C then J, then "
                    "done); background: Algorithm 2 (observers with forgetting under Prop. 6 + a torque dither)",
    )
    kin_settle_s: float = Field(
        10.0, ge=0, description="an agent is ready to leave the kinematic phase after all its z_ij have been "
                                "estimated for this long (s)",
    )
    horizon_s: float = Field(
        1.0, gt=0, description="agreement margin: the team switches stage this long after the last agent "
                               "became ready (s); must exceed the flood time (diameter x (1 + link delay))",
    )
    m_excite_s: float = Field(40.0, gt=0, description="length of the mass/geometry excitation stage (s)")
    m_force: float = Field(3.0, ge=0, description="Prop. 6 common force per agent during that stage (N)")
    m_force_angle: float = Field(0.5, description="its direction, world frame, from +x (rad)")
    m_switch_s: float = Field(5.0, gt=0, description="the common force flips sign every this long (s)")
    j_excite_s: float = Field(20.0, gt=0, description="length of the J stage: f_i = k_z s(t) z_i^perp, tau_i = 0 (s)")
    k_z: float = Field(1.0, gt=0, description="gain of the J-stage force f_i = k_z s(t) z_i^perp (N/m)")
    j_cycles: int = Field(1, ge=1, description="up/down cycles of s(t) in the J stage (omega ramps up, then back)")
    omega_sign: int = Field(1, description="+1: the first J-stage half-cycle speeds the spin up (sign of the spin)")
    avg_tol: float = Field(
        1e-4, gt=0, description="an averaging consensus has converged at an agent when its value and every "
                                "neighbour's agree within this relative tolerance (-)",
    )
    avg_window_s: float = Field(0.5, ge=0, description="... and have done so for this long (s)")
    brake: float = Field(
        0.0, ge=0, description="Prop. 7 braking gain once done, f_i = -brake v_Ci (N s/m); 0 keeps the "
                               "kinematic control running, so the shape stays observable (a braked load's "
                               "heading is dead-reckoned: docs/control-laws.md)",
    )
    kf_angle_walk: float = Field(
        0.02, ge=0, description="Kalman filter: angle random walk of q_i, i.e. omega_hat error (rad/sqrt(s))"
    )
    kf_v_walk: float = Field(
        0.01, ge=0, description="Kalman filter: random walk of v_C, unmodelled forces (m/s/sqrt(s))"
    )
    mu_walk: float = Field(
        1e-4, ge=0, description="background: random walk of 1/m, lets the mass estimate follow a changing "
                                "load (1/kg/sqrt(s))",
    )
    iota_walk: float = Field(
        3e-4, ge=0, description="background: random walk of 1/J, lets the inertia estimate follow a "
                                "changing load (1/(kg m^2)/sqrt(s))",
    )
    u_var_scale: float = Field(
        1.0, ge=0, description="Kalman filter: weight of the pooled eq. (9) rate as an omega measurement, as a "
                               "factor on its variance; 0 leaves it out (-)",
    )
    u_delayed: bool = Field(
        True, description="Kalman filter: take the pooled eq. (9) rate as a delayed measurement of omega at "
                          "its samples' ticks (predicted back through the filter's own torque model); false: "
                          "as a measurement of the current tick",
    )
    j_feedforward: bool = Field(
        False, description="J stage: feed the filter's modelled angular acceleration (current 1/J times the "
                           "exactly known torque) forward into omega_hat from the stage's first tick, before "
                           "1/J is known to 10 %; false: only once it is (true keeps EERD < 1 % through the "
                           "J-stage start under 100 ms delay but cost ~0.05 points of J error, docs/faults.md)",
    )
    omega_walk: float = Field(
        0.05, ge=0, description="Kalman filter: random walk of omega beyond the torque model (rad/s/sqrt(s))"
    )
    u_bias_walk: float = Field(
        0.05, ge=0, description="Kalman filter: random walk of the pooled eq. (9) rate's own slowly varying error "
                                "b (u = omega + b; the pair trackers' angle error, which no circle fit corrects "
                                "for short pairs at high noise), so that omega's slow part rests on the rotation "
                                "of the own contact velocity; 0 takes u as unbiased (rad/s/sqrt(s))",
    )
    filter_omega: bool = Field(
        True, description="from the filter's restart at kinematic readiness on, omega_hat's measurement is the "
                          "filter's omega instead of the pooled eq. (9) rate (whose pair angles, dead-reckoned "
                          "with omega_hat at high noise, fed a lagging omega_hat back to itself until it lost "
                          "lock); false: the eq. (9) rate throughout",
    )
    lock_nis: float = Field(
        6.0, ge=0, description="Kalman filter lock check, from its restart at kinematic readiness on: when the "
                               "running mean of the own velocity's normalised innovation squared (2 for a "
                               "consistent filter) exceeds this, the filter has locked onto a wrong (q_i, "
                               "omega) and is restarted, on trial, from a fit of its own contact velocities "
                               "(at sigma 0.8-0.9, n = 20 a lost filter's mean runs at 11-300, a consistent one's "
                               "at 2.0-2.9: docs/high-noise.md); 0: never",
    )
    lock_tau_s: float = Field(2.0, gt=0, description="time constant of that running mean (s)")
    trust_min_fresh: float = Field(
        0.9, gt=0, le=1,
        description="estimate trust (agents/estimate_trust.py, docs/estimate-trust.md): an m or J estimate is "
                    "flagged untrusted when, in one of the stages it rests on, the newest state the agent had from "
                    "a neighbour was fresh (not older than estimator.max_age_ticks) in fewer than this fraction of "
                    "the stage's ticks x neighbours, by a one-sided test at level trust_alpha (-)",
    )
    monitor_window_s: float = Field(
        5.0, ge=0,
        description="innovation monitor (agents/innovation_monitor.py, docs/innovation-monitor.md): each agent "
                    "tests its filter's own-velocity innovations over consecutive windows this long for "
                    "whiteness and for correlation with v_C, sign(v_C), omega q_i^perp and its own force; "
                    "report-only (s; 0: off)",
    )
    monitor_lags: int = Field(10, ge=1, description="lags of the monitor's whiteness test (ticks)")
    monitor_alpha: float = Field(
        0.01, gt=0, lt=1,
        description="the monitor's false-alarm rate per window under a right model (Bonferroni over its five "
                    "tests) (-)",
    )
    trust_alpha: float = Field(
        0.01, gt=0, lt=0.5,
        description="that test's level: the probability of flagging a stage whose true fresh fraction is "
                    "trust_min_fresh (independent slots assumed) (-)",
    )
    lock_window_s: float = Field(
        2.0, gt=0, description="the restart point (omega, q_i) is fitted to the own contact velocities of this "
                               "last window (agents.rigid_filter.fit_rotation; the neighbours' median omega_hat and the "
                               "kinematic z_i + z_C before the window is full, or when the load turned by less "
                               "than 2 rad in it) (s)",
    )
    lock_omega_max: float = Field(
        6.0, gt=0, description="that fit searches omega within +-max(this, twice the largest omega_hat around), "
                               "at most +-5 times this (rad/s)",
    )
    lock_hold_s: float = Field(
        4.0, ge=0, description="after a (re)start, how long the lock check waits before it judges again (s)"
    )
    j_omega_walk: float = Field(
        0.005, ge=0, description="Kalman filter: the same during the J stage, where the torque is known exactly "
                                 "(sum of the agents' own forces' moments); small, so that J rests on the whole "
                                 "stage's omega ramp and not on the last second of it (rad/s/sqrt(s))",
    )
    dither_torque: float = Field(
        2.0, ge=0, description="background: amplitude of the sinusoidal torque dither per agent that makes J "
                               "observable beside z_C (N m)",
    )
    dither_period_s: float = Field(6.0, gt=0, description="background: period of that dither (s)")
    estimate_effects: tuple[Literal["viscous_friction", "rotational_damping", "coulomb_friction", "force_bias"],
                            ...] = Field(
        (),
        description="plant effects the agents estimate online with m and J (names of coload diagnose): "
                    "viscous_friction, b (N s/m) in dv_C = (F - b v_C) dt/m; rotational_damping, c (N m s) in "
                    "domega = (T - c omega) dt/J; coulomb_friction, F_c (N) in dv_C = (F - F_c tanh(|v_C|/v_s) "
                    "v_C/|v_C|) dt/m (v_s: coulomb_speed); force_bias, a constant force f (N, 2-vector, world "
                    "frame) in dv_C = (F + f) dt/m; each an extra filter state (two for force_bias) averaged by "
                    "consensus like m and J; empty: the nominal model",
    )
    coulomb_speed: float = Field(
        0.05, gt=0, description="Kalman filter: the smoothing speed v_s of the Coulomb friction model (m/s); the "
                                "plant's is unknown: a few times the filter's sd of v_C, so that the model's "
                                "slope F_c/v_s at rest does not swing the prediction on v_C's noise "
                                "(docs/online-detection.md measures a mismatch)",
    )
    online_detection: bool = Field(
        False, description="the team decides online which effect is missing (agents/effect_decision.py, "
                           "docs/online-detection.md): every filter carries beta = b/m, gamma = c/J, kappa = F_c/m "
                           "(and a slope's a = f/m) pinned at 0, the agents pool the score of each over windows of "
                           "monitor_window_s by consensus and switch on, on an agreed tick, the one significant "
                           "at monitor_alpha / 5 (one-sided; / 4 without online_force_bias) whose own score is the "
                           "largest; false: only estimate_effects, decided beforehand",
    )
    online_force_bias: bool = Field(
        True, description="online detection: a constant external force (force_bias, a slope) is a candidate too "
                          "(level monitor_alpha / 5; judged on windows that start after the m stage's push first "
                          "reverses; beside a significant scalar candidate it needs its score beyond that one's "
                          "significant too; ruled out or withdrawn where the window before read along its force "
                          "is significantly negative); every agent runs a twin filter with the slope free from the "
                          "m stage's start, its filter if the slope is switched on (docs/online-detection.md); "
                          "false: the three scalar candidates at monitor_alpha / 4, no twin",
    )
    effect_walk: float = Field(
        3e-3, ge=0, description="Kalman filter: random walk of the estimated effects' rates b/m, c/J "
                                "(1/s/sqrt(s)) and F_c/m (m/s^2/sqrt(s)); lets a filter forget a wrong start "
                                "(1e-3 left one agent's b at 5 % of the truth on one seed in five)",
    )
