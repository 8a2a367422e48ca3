"""When the arm has come to rest: what a move waits for before it says "settled".

A compliant, gravity-loaded arm whose motors reached their goals still swings on its
springs for a few seconds, and a single reading cannot tell a joint at rest from one at the
end of a swing (a stepper node measures its joint's velocity over 10 ms, in steps of 100
counts/s = 0.063 rad/s: a slow swing reads 0).  :class:`RestWatch` therefore looks at a
window of readings, :data:`REST_WINDOW_S` of the link's clock: the arm is at rest when,
throughout it, every stepper joint's angle and spring deflection each stayed within
:data:`REST_SPREAD_COUNTS` encoder counts (a speed below 2 counts in 1 s, 1.3 mrad/s, and
a spring torque steady to 2 counts' worth: 0.17 N·m at the elbow), and every servo's angle
within :data:`REST_SERVO_SPREAD_RAD`.  At that the hand on the wrist reads its
accelerometers steadily enough to be homed from them (``handctl home``).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from math import copysign
from typing import Final

from host.arm.state import JOINT_NAMES, ArmState, ServoState
from protocol.control_tables import RX64_TABLE
from protocol.robot import ARM_ENCODER_COUNTS_PER_REV, RX64_RAD_PER_UNIT

#: How long (s, the link's clock) the arm must have stayed still to count as at rest.
REST_WINDOW_S: Final = 1.0
#: How far (joint encoder counts) a stepper joint's angle, and its spring's deflection, may
#: wander within the window.
REST_SPREAD_COUNTS: Final = 2
#: How far (rad) a servo's angle may wander within the window: a position unit either way
#: (an RX-64 at rest hunts across its compliance margin by a unit).
REST_SERVO_SPREAD_RAD: Final = 2.05 * RX64_RAD_PER_UNIT
_COUNT_RAD: Final = 2 * math.pi / ARM_ENCODER_COUNTS_PER_REV
_R = RX64_TABLE


def servo_setpoint(servo: ServoState) -> float:
    """Where the RX-64 of ``servo`` drives to (rad): its angle plus the error (setpoint −
    present) its compliance needs for the torque it applies, ``load`` (counter-clockwise
    > 0, the way the angle grows): torque = punch + (limit − punch)·(|e| − margin)/slope,
    the registers at their defaults.  Its angle when it applies no more than ``punch``."""
    torque = abs(servo.load) * 1023  # present_load: 1/1023 of the maximum torque
    punch, limit = float(_R["punch"].default), float(_R["torque_limit"].default)
    if torque <= punch or limit <= punch:
        return servo.angle
    side = "cw" if servo.load > 0 else "ccw"  # e > 0 (CCW torque) uses the CW margin
    margin = float(_R[f"{side}_compliance_margin"].default)
    slope = float(_R[f"{side}_compliance_slope"].default)
    error = margin + slope * min(torque - punch, limit - punch) / (limit - punch)
    return servo.angle + copysign(error * RX64_RAD_PER_UNIT, servo.load)


class RestWatch:
    """Fed every state of a move (:meth:`update`), says whether the arm has been still for
    ``window_s`` (s): every stepper joint's angle and deflection within ``spread_counts``
    (joint encoder counts), every servo's angle within ``servo_spread`` (rad).
    :meth:`why_not` names the joint that is not, and how."""

    def __init__(self, window_s: float = REST_WINDOW_S, spread_counts: int = REST_SPREAD_COUNTS,
                 servo_spread: float = REST_SERVO_SPREAD_RAD) -> None:
        self.window_s = window_s
        self.spread = spread_counts * _COUNT_RAD * (1 + 1e-9)
        self.servo_spread = servo_spread
        self._states: deque[ArmState] = deque()

    def reset(self) -> None:
        """Forget the states seen (a new goal)."""
        self._states.clear()

    def update(self, state: ArmState) -> bool:
        """Take ``state`` in; True if the arm has been at rest for the whole window."""
        states = self._states
        states.append(state)
        while len(states) > 2 and state.t - states[1].t >= self.window_s:
            states.popleft()
        return self.why_not() is None

    def why_not(self) -> str | None:
        """None at rest, else what still moves (``J2 moved 0.004 rad in the last 1.00 s``)."""
        states = self._states
        if not states or states[-1].t - states[0].t < self.window_s:
            return f"not yet {self.window_s:g} s of readings"
        span = states[-1].t - states[0].t
        for k in range(len(states[0].steppers)):
            angles = [s.steppers[k].angle for s in states]
            springs = [s.steppers[k].deflection_rad for s in states]
            if max(angles) - min(angles) > self.spread:
                return (f"{JOINT_NAMES[k]} moved {max(angles) - min(angles):.4f} rad in the "
                        f"last {span:.2f} s")
            if max(springs) - min(springs) > self.spread:
                return (f"{JOINT_NAMES[k]}'s spring deflection changed by "
                        f"{max(springs) - min(springs):.4f} rad in the last {span:.2f} s")
        for k, servo in enumerate(states[0].servos):
            angles = [s.servos[k].angle for s in states]
            if max(angles) - min(angles) > self.servo_spread:
                return (f"{JOINT_NAMES[servo.joint]} moved {max(angles) - min(angles):.4f} "
                        f"rad in the last {span:.2f} s")
        return None


def off_goal(state: ArmState, goals: Sequence[float], tolerance: float) -> str | None:
    """Which joint of ``state`` is not yet at its goal (``goals``, rad) within ``tolerance``
    (rad): a stepper whose motor is further or still moving, a servo whose joint is
    further; None when every joint is there."""
    for s in state.steppers:
        if s.moving:
            return f"{JOINT_NAMES[s.joint]}'s motor is still on its way"
        if abs(s.motor_angle - goals[s.joint]) > tolerance:
            return (f"{JOINT_NAMES[s.joint]}'s motor is {s.motor_angle - goals[s.joint]:+.3f} "
                    "rad off its goal")
    for v in state.servos:
        if abs(servo_setpoint(v) - goals[v.joint]) > tolerance:
            return (f"{JOINT_NAMES[v.joint]} is {v.angle - goals[v.joint]:+.3f} rad off its goal "
                    f"(its setpoint {servo_setpoint(v) - goals[v.joint]:+.3f})")
    return None


def settled(state: ArmState, goals: Sequence[float], tolerance: float,
            settle_speed: float = math.inf) -> bool:
    """True if every stepper node stopped with its motor within ``tolerance`` (rad) of
    ``goals`` and its joint slower than ``settle_speed`` (rad/s), and every servo drives to
    within ``tolerance`` of its goal (:func:`servo_setpoint`: its joint sits off the goal by
    what its compliance needs for the load it holds, 0.026 rad for J6 holding the hand in an
    extended pose)."""
    for s in state.steppers:
        if (s.moving or abs(s.motor_angle - goals[s.joint]) > tolerance
                or abs(s.velocity) > settle_speed):
            return False
    return all(abs(servo_setpoint(s) - goals[s.joint]) <= tolerance for s in state.servos)
