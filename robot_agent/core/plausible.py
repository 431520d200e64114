"""The plausible range of every numeric parameter of a robot's config file (:data:`PLAUSIBLE`,
section.field -> (low, high)): a value outside it is refused by ``--check-config`` and by the
agent, so a typo such as ``stale_pose_s = 1e6`` never reaches the wheels.

Split out of robot_config.py (issue 12) so the table can be reviewed on its own; still
importable from ``robot_agent.core.robot_config``.
"""

from __future__ import annotations

import math

PLAUSIBLE: dict[str, tuple[float, float]] = {
    # geometry (m, rad/s): a table-top robot to a small wheelchair
    "geometry.wheel_radius_m": (0.005, 0.5),
    "geometry.half_track_m": (0.01, 1.0),
    "geometry.max_wheel_radps": (0.1, 200.0),
    "geometry.body_radius_m": (0.01, 1.5),
    "geometry.ref_offset_m": (0.001, 1.0),
    # gains (paper eqs 21-22; the paper uses kp 0.21, Ti 105 s, Td 0.01 s)
    "gains.kp": (0.0, 50.0),
    "gains.ti_s": (0.001, 10000.0),
    "gains.td_s": (0.0, 10.0),
    "gains.d_filter_tau_s": (0.0, 10.0),
    "gains.integral_limit_ms": (0.0, 10.0),
    "gains.max_ref_speed_mps": (0.001, 5.0),
    # repulsion
    "repulsion.k_rep": (0.0, 1.0),
    "repulsion.d0_m": (0.01, 5.0),
    "repulsion.max_speed_mps": (0.0, 5.0),
    # safety (s): a stale input must stop the robot within seconds, not days
    "safety.stale_pose_s": (0.01, 5.0),
    "safety.stale_setpoint_s": (0.01, 5.0),
    "safety.max_dt_s": (0.001, 5.0),
    # safety filter
    "safety_filter.margin_m": (0.0, 1.0),
    "safety_filter.noise_budget_m": (0.0, 0.5),
    "safety_filter.gamma_per_s": (0.01, 1000.0),
    "safety_filter.neighbour_speed_mps": (0.0, 5.0),
    "safety_filter.max_age_s": (0.01, 10.0),
    "safety_filter.stuck_time_s": (0.01, 60.0),
    "safety_filter.stuck_speed_mps": (0.0, 5.0),
    "safety_filter.stuck_error_m": (0.0, 5.0),
    "safety_filter.tiebreak_time_s": (0.0, 60.0),
    "safety_filter.tiebreak_angle_rad": (0.0, math.pi),
    "safety_filter.tiebreak_speed_mps": (0.0, 5.0),
    "safety_filter.convoy_share": (0.0, 0.5),
    "safety_filter.convoy_angle_rad": (0.01, math.pi / 2),
    "safety_filter.convoy_gain": (1.0, 10.0),
    "safety_filter.convoy_gap_m": (0.0, 0.5),
    # the shared-frame plane's proof pays the motion since the frame from the margin
    "safety_filter.frame_max_age_s": (0.0, 0.5),
    # estimator
    "estimator.history_s": (0.01, 60.0),
    "estimator.max_dropout_odom_s": (0.0, 60.0),
    "estimator.max_dropout_cmd_s": (0.0, 60.0),
    "estimator.odom_timeout_s": (0.001, 10.0),
    "estimator.max_latency_s": (0.0, 10.0),
    "estimator.future_tolerance_s": (0.0, 1.0),
    "estimator.actuation_delay_s": (0.0, 1.0),
    "estimator.setpoint_lead_s": (0.0, 1.0),
    "estimator.meas_pos_std_m": (0.0, 1.0),
    "estimator.meas_theta_std_rad": (0.0, math.pi),
    "estimator.odom_pos_var_per_m": (0.0, 1.0),
    "estimator.cmd_pos_var_per_m": (0.0, 1.0),
    "estimator.odom_pos_var_per_s": (0.0, 1.0),
    "estimator.cmd_pos_var_per_s": (0.0, 1.0),
    "estimator.theta_var_per_rad": (0.0, 1.0),
    "estimator.theta_var_per_m": (0.0, 1.0),
    "estimator.theta_var_per_s": (0.0, 1.0),
    "estimator.gate_m": (0.0, 10.0),
    "estimator.reset_after": (1, 1000),
    "estimator.n_sigma": (0.1, 100.0),
    "estimator.max_uncertainty_m": (0.0, 10.0),
    # [motor] with backend = "roboclaw" (RoboClawConfig)
    "motor.baud": (2400, 460800),
    "motor.address": (0x80, 0x87),
    "motor.encoder_counts_per_rev": (0.0, 1.0e6),
    "motor.gear_ratio": (0.01, 10000.0),
    "motor.serial_timeout_s": (0.1, 5.0),
    "motor.ack_timeout_s": (0.001, 1.0),
    "motor.write_timeout_s": (0.001, 5.0),
    "motor.reopen_backoff_s": (0.01, 60.0),
    "motor.reopen_backoff_max_s": (0.01, 600.0),
    "motor.max_consecutive_failures": (1, 1000),
}
