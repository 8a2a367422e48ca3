"""What the host tells the stepper nodes, with every goal, about the arm at rest: the
deflection that will hold each link still where a watchdog stop would leave it.

A node whose host vanished mid-move brakes, holds its motor and settles its link's swing
(:mod:`firmware_py.stepper_settle`): at the link's turns it moves its motor so the elastic
element carries just the deflection that holds the link still there.  On its own it has to
identify that deflection from the swing, and it knows only its own joint: the elbow's (J4)
depends on the shoulder's angle too (the routes turn its capstan with 0.18·Δq2, the
forearm's weight about it changes with J2), and its estimate was off by up to 30 counts in
some poses.  The host knows the whole arm while it is alive, so with every cycle that sends
stepper goals it writes each node's ``rest_deflection`` (counts, the node's frame as its
``deflection`` register reads):

    d_i = δ_i(τ_i(q_r))  +  offset_i  −  Σ_j C[i][j] · (q_r,j − q_j)

``τ(q_r)`` the springs' torques holding the arm still (:func:`host.arm.gravity.spring_torques`,
the hand counted unless told otherwise) at ``q_r``, the pose the host expects a stop to leave
the arm in: the stepper joints carried on at their present speeds for the watchdog's timeout
and :data:`REST_AHEAD_S` more (braking and the links' overshoot); ``δ_i`` the joint's
element's deflection at that torque (:func:`protocol.robot.series_elastic_deflection`: its
stiffness within the tubes' soft travel of ±4°, ten times it beyond, where a linear model
put the outstretched shoulder's 20-40 counts too far), ``offset_i`` the coupling offset sent with the goal (``−C·Δq`` now) and the last
term its change by ``q_r`` (counts throughout).  Only for an arm that is homed (the model
needs the joints' absolute angles) and nodes whose firmware takes it
(:data:`~protocol.control_tables.STEPPER_REST_DEFLECTION_FIRMWARE`).  The node uses it only
once its link's swing has gone through it, so a model that is wrong (a hand that is not
there) costs only what the node's own identification would.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Final

import numpy as np

from host.arm.gravity import spring_torques
from host.arm.state import N_STEPPERS, ArmState, JointInfo
from protocol.control_tables import STEPPER_REST_DEFLECTION_FIRMWARE, STEPPER_TABLE
from protocol.dynamixel import InstructionPacket, make_sync_write
from protocol.robot import arm_route_coupling_matrix, series_elastic_deflection

_REG = STEPPER_TABLE["rest_deflection"]
#: Beyond the watchdog's timeout, how far ahead (s, at the joints' present speeds) the pose
#: lies that the model is evaluated at: the motors' braking and the links' overshoot (measured
#: in process: 0.1 s settled the 20 stop moments soonest of 0, 0.1 and 0.2 s).
REST_AHEAD_S: Final = 0.1
_ROUTES = arm_route_coupling_matrix()


def rest_deflections(steppers: Sequence[JointInfo], state: ArmState, offsets: Sequence[int],
                     *, hand: bool, ahead_s: float) -> list[int]:
    """Each stepper node's deflection (counts, its frame) holding its link still at the pose
    ``ahead_s`` (s) on from ``state`` (absolute angles, rad) at the stepper joints' present
    speeds; ``offsets`` the coupling offsets (counts) sent now; ``hand`` on the flange."""
    q = np.array(state.joints, dtype=float)
    moved = np.array([s.velocity * ahead_s for s in state.steppers[:N_STEPPERS]])
    rest = q.copy()
    rest[:N_STEPPERS] += moved
    torques = spring_torques(rest, hand)
    out = []
    for i, j in enumerate(steppers[:N_STEPPERS]):
        per_rad = j.encoder_counts_per_rev / (2.0 * math.pi)
        element = series_elastic_deflection(float(torques[i]), j.stiffness) * per_rad
        shift = float(_ROUTES[i] @ moved) * per_rad
        value = round(element + offsets[i] - shift)
        out.append(max(-32767, min(32767, value)))  # -32768 says "not given"
    return out


def rest_deflection_packet(steppers: Sequence[JointInfo], values: Sequence[int],
                           unpowered: frozenset[int] | set[int]) -> InstructionPacket | None:
    """The SYNC_WRITE of ``values`` (counts, J1..J4) to the nodes that take it (torque on),
    or None."""
    data = {j.dxl_id: _REG.encode(v) for i, (j, v) in enumerate(zip(steppers, values,
                                                                    strict=False))
            if j.firmware_version >= STEPPER_REST_DEFLECTION_FIRMWARE and i not in unpowered}
    return make_sync_write(_REG.address, _REG.size, data) if data else None

