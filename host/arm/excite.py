"""An excitation for identifying the arm: a chirp on each joint in turn, slow ramps through
zero speed, holds under gravity, as one timed joint path through the arm's gate; then, in a
loaded pose, a probe of each named stepper's holding torque.

What makes the emulator's parameters observable from a recording (``hil-bench replay``):
a chirp (a sine whose frequency sweeps from ``f0_hz`` to ``f1_hz``) on one joint at a time
shows that joint's elastic element over a band of frequencies, with the other joints still;
holds with the upper arm and forearm raised show the elements' deflection under gravity
(their stiffness).  A slow ramp (``ramp_speed_rad_s``) out to ``+ramp_rad``, back through
the start to ``−ramp_rad`` and back, pausing at each turn, shows the bearings' Coulomb
friction: moving slowly each way the element carries the load plus or minus the friction, so
its deflection differs between the two ways by twice the friction over the stiffness (at the
turns the joint sticks until the element has wound that far).  The holding probes
(:mod:`host.arm.holding_probe`, in the pose ``probe_pose``) lower each named stepper's
holding current until its rotor slips under the load, and stop there.

Safety: the whole path is one list of waypoints that :func:`host.arm.waypoints.play_waypoints`
checks through the gate (:func:`host.arm.gate.check_path`: every point within its joint's
range, no segment faster or corner sharper than the joint's limits) before a single goal is
sent, and nothing is clamped.  Each chirp's amplitude is the smallest of the one asked, what
keeps its peak speed within :data:`SPEED_SHARE` of the joint's move speed limit
(:data:`host.arm.gate.MOVE_SPEED_LIMITS`), its peak acceleration within
:data:`SPEED_SHARE` of the joint's acceleration limit
(:data:`protocol.robot.ARM_JOINT_ACCEL_LIMITS`) and, for a joint whose range is known (the
servos; the steppers once homed), its excursion :data:`RANGE_MARGIN_RAD` inside the range.
A chirp fades in and out (a sine² taper over :data:`TAPER_SHARE` of it at each end), so it
starts and ends at rest where the joint was.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

from host.arm.gate import MOVE_SPEED_LIMITS
from host.arm.holding_probe import ProbeResult, probe_holding
from host.arm.interface import DrivenArm
from host.arm.state import JOINT_NAMES, N_JOINTS, N_STEPPERS, ArmState
from host.arm.trajectory import Waypoint, timed_path
from host.arm.waypoints import play_waypoints
from host.errors import UsageError
from protocol.robot import ARM_JOINT_ACCEL_LIMITS, ARM_JOINT_LIMITS

#: Share of a joint's speed and acceleration limits a chirp may use at its peak.
SPEED_SHARE: Final = 0.5
#: A chirp stays this far inside a known joint range (rad).
RANGE_MARGIN_RAD: Final = 0.05
#: Share of a chirp's time spent fading in, and again fading out.
TAPER_SHARE: Final = 0.15
#: Speed of the moves between holds (rad/s).
HOLD_MOVE_SPEED_RAD_S: Final = 0.3
#: Holds under gravity: offsets (rad) of J2 (shoulder) and J4 (elbow) from the start pose.
HOLD_OFFSETS: Final = ((0.3, 0.0), (0.3, 0.4), (0.0, 0.4))
#: The pose of the holding probes: offsets (rad) of J2 and J4 from the start pose, loading
#: both under gravity (about 4 and 2 N·m).
PROBE_POSE: Final = (0.3, 0.8)
#: What ``armctl excite`` ramps and probes unless told: every stepper ramped; J4 and J2, the
#: ones the probe pose loads, probed (the elbow first: a shoulder's slip moves it).
DEFAULT_RAMPS: Final = (0, 1, 2, 3)
DEFAULT_PROBES: Final = (3, 1)
#: Pause at each turn of a friction ramp (s), the joint at rest.
RAMP_PAUSE_S: Final = 0.3


@dataclass(frozen=True)
class Excitation:
    """The excitation: ``joints`` (indices 0..6) chirped in turn, each for ``chirp_s`` s
    sweeping ``f0_hz`` → ``f1_hz`` with amplitude at most ``amplitude_rad``; then each joint
    of ``ramps`` moved ±``ramp_rad`` about the start at ``ramp_speed_rad_s`` (none: no
    ramps); then each pose of ``holds`` (J2, J4 offsets, rad) held for ``hold_s`` s;
    waypoints every 1/``rate_hz`` s.  Then, in ``probe_pose`` (J2, J4 offsets), each
    stepper of ``probes`` in turn has its holding torque probed over ``probe_s`` s (none:
    no probes)."""

    joints: tuple[int, ...] = tuple(range(N_JOINTS))
    amplitude_rad: float = 0.2
    chirp_s: float = 4.0
    f0_hz: float = 0.2
    f1_hz: float = 1.0
    holds: tuple[tuple[float, float], ...] = HOLD_OFFSETS
    hold_s: float = 1.5
    rate_hz: float = 50.0
    ramps: tuple[int, ...] = ()
    ramp_rad: float = 0.1
    ramp_speed_rad_s: float = 0.05
    probes: tuple[int, ...] = ()
    probe_pose: tuple[float, float] = PROBE_POSE
    probe_s: float = 3.0

    def __post_init__(self) -> None:
        for name in ("amplitude_rad", "chirp_s", "f0_hz", "f1_hz", "rate_hz", "ramp_rad",
                     "ramp_speed_rad_s", "probe_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise UsageError(f"excitation {name} {value} must be a finite number > 0")
        if not (math.isfinite(self.hold_s) and self.hold_s >= 0):
            raise UsageError(f"excitation hold_s {self.hold_s} must be a finite number >= 0")
        if self.f1_hz < self.f0_hz:
            raise UsageError(f"the chirp sweeps up: f1 {self.f1_hz} Hz below f0 {self.f0_hz}")
        bad = [j for j in self.joints if not 0 <= j < N_JOINTS]
        if bad or not self.joints:
            raise UsageError(f"excitation joints must be among 0..{N_JOINTS - 1}, got "
                             f"{list(self.joints)}")
        if any(not 0 <= j < N_JOINTS for j in self.ramps):
            raise UsageError(f"excitation ramps must be among 0..{N_JOINTS - 1}, got "
                             f"{list(self.ramps)}")
        if any(not 0 <= j < N_STEPPERS for j in self.probes):
            raise UsageError(f"holding probes are of steppers (0..{N_STEPPERS - 1}), got "
                             f"{list(self.probes)}")


def amplitude(plan: Excitation, joint: int, at: float, homed: bool) -> float:
    """The chirp amplitude (rad) of ``joint`` starting at angle ``at`` (module doc).  The
    bounds hold for the tapered chirp: its speed is at most A·(Ω + π/2R) and its
    acceleration at most A·((Ω + π/R)² + 2π·(f1 − f0)/T), Ω = 2π·f1, R the taper's time."""
    omega = 2 * math.pi * plan.f1_hz
    ramp = TAPER_SHARE * plan.chirp_s
    speed = omega + math.pi / (2 * ramp)
    accel = (omega + math.pi / ramp) ** 2 + 2 * math.pi * (plan.f1_hz - plan.f0_hz) / plan.chirp_s
    peak = min(plan.amplitude_rad, SPEED_SHARE * MOVE_SPEED_LIMITS[joint] / speed,
               SPEED_SHARE * ARM_JOINT_ACCEL_LIMITS[joint] / accel)
    if homed or joint >= N_STEPPERS:
        lo, hi = ARM_JOINT_LIMITS[joint]
        peak = min(peak, at - lo - RANGE_MARGIN_RAD, hi - at - RANGE_MARGIN_RAD)
    if peak <= 0:
        raise UsageError(f"{JOINT_NAMES[joint]} is at {at:+.3f} rad, at its range's edge: "
                         "move it inward before exciting it")
    return peak


def _taper(t: float, length: float) -> float:
    ramp = TAPER_SHARE * length
    if t < ramp:
        return math.sin(math.pi * t / (2 * ramp)) ** 2
    if t > length - ramp:
        return math.sin(math.pi * (length - t) / (2 * ramp)) ** 2
    return 1.0


def chirp(plan: Excitation, joint: int, start: Sequence[float], t0: float, homed: bool
          ) -> list[Waypoint]:
    """One joint's chirp about ``start`` (7 rad) from time ``t0`` (s), the others still."""
    a = amplitude(plan, joint, start[joint], homed)
    n = max(2, int(round(plan.chirp_s * plan.rate_hz)))
    sweep = (plan.f1_hz - plan.f0_hz) / (2 * plan.chirp_s)
    out = []
    for k in range(1, n + 1):
        t = plan.chirp_s * k / n
        q = list(start)
        q[joint] = start[joint] + a * _taper(t, plan.chirp_s) * math.sin(
            2 * math.pi * (plan.f0_hz * t + sweep * t * t))
        out.append(Waypoint(t0 + t, tuple(q)))
    return out


def ramp(plan: Excitation, joint: int, start: Sequence[float], t0: float, homed: bool
         ) -> list[Waypoint]:
    """One joint's friction ramp about ``start`` (7 rad) from time ``t0`` (s): out to
    ``+ramp_rad``, back through the start to ``−ramp_rad``, back to the start, at
    ``ramp_speed_rad_s``, pausing :data:`RAMP_PAUSE_S` at each turn."""
    here = tuple(float(v) for v in start)
    if homed or joint >= N_STEPPERS:
        lo, hi = ARM_JOINT_LIMITS[joint]
        if not lo + RANGE_MARGIN_RAD <= here[joint] - plan.ramp_rad <= \
                here[joint] + plan.ramp_rad <= hi - RANGE_MARGIN_RAD:
            raise UsageError(f"{JOINT_NAMES[joint]} at {here[joint]:+.3f} rad cannot ramp "
                             f"±{plan.ramp_rad} rad within its range {lo}..{hi}")
    out: list[Waypoint] = []
    at = Waypoint(t0, here)
    for offset in (plan.ramp_rad, -plan.ramp_rad, 0.0):
        q = list(here)
        q[joint] += offset
        move = timed_path([at.joints, tuple(q)], plan.ramp_speed_rad_s, at.t)[1:]
        out += move
        at = move[-1]
        if offset:
            at = Waypoint(at.t + RAMP_PAUSE_S, at.joints)
            out.append(at)
    return out


def _offset(here: Sequence[float], shoulder: float, elbow: float) -> tuple[float, ...]:
    q = list(here)
    q[1] += shoulder
    q[3] += elbow
    return tuple(q)


def _move(path: list[Waypoint], pose: tuple[float, ...]) -> None:
    path += timed_path([path[-1].joints, pose], HOLD_MOVE_SPEED_RAD_S, path[-1].t)[1:]


def excitation_path(plan: Excitation, start: Sequence[float], homed: bool) -> list[Waypoint]:
    """The whole path from ``start`` (7 rad, where the arm is): each chirp, each ramp, then
    each hold (moved to at :data:`HOLD_MOVE_SPEED_RAD_S`, held ``hold_s``), then back to
    ``start`` (with ``probes``: to the probe pose instead, :func:`excite` probes there and
    returns)."""
    here = tuple(float(v) for v in start)
    path = [Waypoint(0.0, here)]
    for joint in plan.joints:
        path += chirp(plan, joint, here, path[-1].t, homed)
    for joint in plan.ramps:
        path += ramp(plan, joint, here, path[-1].t, homed)
    for shoulder, elbow in plan.holds:
        _move(path, _offset(here, shoulder, elbow))
        path.append(Waypoint(path[-1].t + plan.hold_s, path[-1].joints))
    _move(path, _offset(here, *plan.probe_pose) if plan.probes else here)
    return path


def excite(arm: DrivenArm, plan: Excitation) -> tuple[ArmState, float, list[ProbeResult]]:
    """Run ``plan`` from where ``arm`` is (through the gate: a
    :class:`~host.errors.LimitError` before anything moves for a path it refuses); returns
    the last state, the path's duration (s, the probes' time not counted) and what each
    holding probe found."""
    start = arm.state().joints
    path = excitation_path(plan, start, arm.homed)
    state = play_waypoints(arm, path, settle_s=0.5)
    probes = [probe_holding(arm, joint, plan.probe_s) for joint in plan.probes]
    if plan.probes:
        back = timed_path([arm.state().joints, tuple(start)], HOLD_MOVE_SPEED_RAD_S)
        state = play_waypoints(arm, back, settle_s=0.5)
    return state, path[-1].t, probes
