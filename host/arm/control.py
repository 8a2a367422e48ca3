"""The arm's joint-space control in one import, as it was before it was split by what each
part does; new code imports the module that declares each name:

* :mod:`host.arm.joint_loop` - the PID loop with the coupling feed-forward and braking lead;
* :mod:`host.arm.motor_goals` - the coupling feed-forward and the springs' sag;
* :mod:`host.arm.trajectory` - waypoints, their interpolation, timing a path to the limits;
* :mod:`host.arm.cartesian` - IK chosen for the stepper joints' loads, and ``moveto``;
* :mod:`host.arm.waypoints` - record, play, save and load waypoints.

Nothing in :mod:`host` imports this module.
"""

from __future__ import annotations

from host.arm.cartesian import IK_SEEDS, MOVETO_LOAD_LIMIT, CartesianMove, choose_ik, moveto
from host.arm.joint_loop import (
    DEFAULT_RATE_HZ,
    ENCODER_COUNT_RAD,
    STALL_RETRIES,
    STALL_WINDOW_S,
    STEPPER_ACCEL_RAD_S2,
    JointController,
    JointPid,
    PidGains,
    TrackingLog,
    braking_lead,
    elastic_deflections,
)
from host.arm.motor_goals import coupling_feedforward
from host.arm.trajectory import MIN_JERK_PEAK, Trajectory, Vector, Waypoint, timed_path
from host.arm.waypoints import (
    WAYPOINTS_KIND,
    WAYPOINTS_VERSION,
    load_waypoints,
    play_waypoints,
    record_waypoints,
    save_waypoints,
)

__all__ = [
    "IK_SEEDS", "MOVETO_LOAD_LIMIT", "CartesianMove", "choose_ik", "moveto",
    "DEFAULT_RATE_HZ", "ENCODER_COUNT_RAD", "STALL_RETRIES", "STALL_WINDOW_S",
    "STEPPER_ACCEL_RAD_S2", "JointController", "JointPid", "PidGains", "TrackingLog",
    "braking_lead", "coupling_feedforward", "elastic_deflections",
    "MIN_JERK_PEAK", "Trajectory", "Vector", "Waypoint", "timed_path",
    "WAYPOINTS_KIND", "WAYPOINTS_VERSION", "load_waypoints", "play_waypoints",
    "record_waypoints", "save_waypoints",
]
