"""The vocabulary every process shares: stage numbers and the names of an agent's estimates.

The stage travels in every state message (``phase``) and in the ``phase`` estimate; the estimate
names are the columns of estimates.csv and the fields of an ``estimate`` message (docs/wire.md,
docs/run-directory.md).
"""

from __future__ import annotations

# Stages (the StateMsg ``phase`` field and the ``phase`` estimate)
SPINUP = 0  # no omega_hat yet: common spin-up torque
KINEMATIC = 1  # z_ij, omega, z_i (Sec. IV); omega regulated by torques
M_EXCITE = 2  # Prop. 6 common force, stronger, switched: mass, q_i (hence z_C) by the Kalman filter
M_AVERAGE = 3  # averaging consensus of m and z_C until converged
J_EXCITE = 4  # f_i = k_z s(t) z_i^perp, tau_i = 0: J by the rotation regression (Result 5)
J_AVERAGE = 5  # averaging consensus of J until converged
DONE = 6  # every estimate final; Prop. 7 braking (optional)
BACKGROUND = 7  # Algorithm 2: Prop. 6 + torque dither, background observers with forgetting

STAGE_NAMES = ("spinup", "kinematic", "m_excite", "m_average", "j_excite", "j_average", "done", "background")

ESTIMATE_NAMES: tuple[str, ...] = (
    "phase",  # stage: 0 spinning up (no omega_hat yet), 1 kinematic (omega regulated); 2.. the
    # dynamical phase (STAGE_NAMES)
    "omega",  # omega_hat (rad/s), consensus-filtered
    "omega_local",  # this tick's local pooled eq. (9) value (rad/s; NaN when no sample)
    "zi_x",  # z_i = p_Ci - p_G estimate, world frame (m)
    "zi_y",
    "pairs_ready",  # neighbours whose z_ij is estimated
    "dropped_unknown",  # messages from senders not in neighbours (count)
    "dropped_stale",  # duplicates / not newer than already used / from the future / malformed (count)
    # dynamical phase (agents/dynamic_phase.py; NaN while not estimated, or without it)
    "J",  # moment of inertia about the CoM after the averaging consensus (kg m^2)
    "m",  # mass after the averaging consensus (kg)
    "zc_x",  # z_C = p_G - p_C, world frame (m)
    "zc_y",
    "vc_x",  # CoM velocity v_C, world frame (m/s)
    "vc_y",
    "J_local",  # this agent's own J estimate, before the averaging consensus (kg m^2)
    "m_local",  # this agent's own m estimate, before the averaging consensus (kg)
    "late_switches",  # stage switches this agent learnt of after the agreed tick (count)
    # augmented model (DynamicsSpec.estimate_effects; NaN without it)
    "b",  # viscous floor friction on v_C after the averaging consensus (N s/m)
    "c",  # rotational damping on omega after the averaging consensus (N m s)
    "fc",  # Coulomb friction on v_C after the averaging consensus (N; its smoothing speed DynamicsSpec.coulomb_speed)
    "fb_x",  # constant external force (force_bias, a slope) on the CoM after the averaging consensus, world frame (N)
    "fb_y",
    "b_local",  # this agent's own b, before the averaging consensus (N s/m)
    "c_local",  # this agent's own c, before the averaging consensus (N m s)
    "filter_restarts",  # restarts of the dynamical phase's filter by its lock check (count; DynamicsSpec.lock_nis)
    # estimate trust (agents/estimate_trust.py, docs/estimate-trust.md; NaN before the estimate's stages)
    "m_trusted",  # 1: the m stages' data sufficed; 0: untrusted (too few fresh neighbour states in a stage)
    "m_fresh",  # fresh fraction of the neighbour states of the poorest m stage so far (-)
    "m_sd",  # one standard deviation of m: own filter's sd and the consensus spread (kg)
    "J_trusted",  # the same for J (J excitation and averaging stages)
    "J_fresh",
    "J_sd",  # (kg m^2)
    # innovation monitor (agents/innovation_monitor.py, docs/innovation-monitor.md; report-only; NaN before
    # its first complete window or without it): the last window's p-values and alarm, and counts
    "mon_p_white",  # whiteness (against positive autocorrelation) of the own filter's whitened velocity innovations
    "mon_p_vc",  # correlation with v_C (viscous friction)
    "mon_p_sgn",  # with v_C / |v_C| (Coulomb friction)
    "mon_p_om",  # with omega q_i^perp (rotational damping)
    "mon_p_f",  # with the own applied force (actuator gain)
    "mon_alarm",  # 1: some p-value below monitor_alpha / 5 in the last window, else 0
    "mon_windows",  # windows tested so far (count)
    "mon_alarms",  # windows with an alarm so far (count)
    # online detection (agents/effect_decision.py, docs/online-detection.md; NaN without it)
    "eff_on",  # effects in the filters: bit 0 viscous friction, bit 1 rotational damping, bit 2 Coulomb friction,
    # bit 3 a constant external force (force_bias) (declared or switched on)
    "eff_out",  # effects ruled out or withdrawn (bits as eff_on): never proposed again
    "eff_tick",  # tick of the last switch, withdrawal or ruling-out the team agreed (-1: none)
    "eff_z",  # its pooled statistic (z, one-sided; a withdrawal's is the rate's Wald z, negative)
    "eff_unexplained",  # windows the team judged structured with no candidate significant (count)
    "eff_zp",  # the last judged window's pooled persistence z (this agent's view of the team means)
    "eff_zb",  # ... pooled score z of viscous friction
    "eff_zc",  # ... of rotational damping
    "eff_zf",  # ... of Coulomb friction
    "eff_zs",  # ... of the constant external force: its chi2 (2 dof) as the normal-equivalent z
)
