"""Waypoints of the arm: recorded by moving it by hand, played back on the joint loop,
kept in files.

**Waypoint files** are JSON lines (UTF-8, one JSON object per line)::

    {"kind": "arm-waypoints", "version": 1, "joints": ["J1", …, "J7"], "units": "rad, s"}
    {"t": 0.0, "joints": [0.0, 0.1, 0.0, 0.2, 0.0, 0.0, 0.0]}
    {"t": 1.25, "joints": [0.05, 0.15, 0.0, 0.3, 0.0, -0.1, 0.0]}

The first line is the header (optional on reading; a line with ``"kind"`` is a header); every
other line is one waypoint: ``t`` (s since the recording started, non-decreasing) and
``joints`` (seven absolute joint angles, rad, J1..J7).  Playback interpolates linearly in
joint space between waypoints at their times (reaching the first from wherever the arm is at
a joint speed of ``approach_speed``).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Final

import numpy as np

from host.arm.gate import check_goals, check_path
from host.arm.interface import DrivenArm
from host.arm.joint_loop import JointController, TrackingLog
from host.arm.state import JOINT_NAMES, N_JOINTS, ArmState
from host.arm.trajectory import Trajectory, Waypoint, timed_path
from host.errors import LimitError, UsageError

#: Waypoint file header.
WAYPOINTS_KIND: Final = "arm-waypoints"
WAYPOINTS_VERSION: Final = 1


def record_waypoints(arm: DrivenArm, seconds: float, *, rate_hz: float = 50.0,
                     min_change: float = 0.01,
                     on_sample: Callable[[ArmState], None] | None = None,
                     kept: list[Waypoint] | None = None) -> list[Waypoint]:
    """Turn every joint's torque off and sample the joints at ``rate_hz`` for ``seconds``
    while someone moves the arm by hand; keep a waypoint whenever some joint moved more than
    ``min_change`` (rad) since the last one kept, and the last sample.  ``on_sample`` sees
    every state.  The torque stays off.  The waypoints go into ``kept`` (a new list if
    None) as they come, so a caller keeps those recorded before an error or Ctrl-C."""
    if not seconds > 0 or not rate_hz > 0:
        raise UsageError("record for > 0 s at > 0 Hz")
    clock = arm.transport
    state = arm.torque(False)
    t0 = state.t
    if kept is None:
        kept = []
    kept.append(Waypoint(0.0, tuple(state.joints)))
    last = state
    period = 1.0 / rate_hz
    tick = 0
    while clock.now() - t0 < seconds:
        tick += 1
        wait = t0 + tick * period - clock.now()
        if wait > 0:
            clock.sleep(wait)
        last = arm.cycle()
        if on_sample is not None:
            on_sample(last)
        if max(abs(a - b) for a, b in zip(last.joints, kept[-1].joints, strict=True)) \
                > min_change:
            kept.append(Waypoint(last.t - t0, tuple(last.joints)))
    if kept[-1].t != last.t - t0:
        kept.append(Waypoint(last.t - t0, tuple(last.joints)))
    return kept


def play_waypoints(arm: DrivenArm, waypoints: Sequence[Waypoint], *, approach_speed: float = 0.3,
                   time_scale: float = 1.0, settle_s: float = 1.0,
                   controller: JointController | None = None,
                   log: TrackingLog | None = None) -> ArmState:
    """Play recorded waypoints: from where the arm is to the first at ``approach_speed``
    (rad/s), then through the rest at their recorded times (× ``time_scale``), then hold
    the last for ``settle_s`` seconds.

    The whole path passes the gate before anything moves (:func:`host.arm.gate.check_path`):
    a waypoint outside its joint's range, or steps needing more speed or acceleration than
    a joint has, raise :class:`~host.errors.LimitError` naming the joint and the waypoint
    (and how much larger a ``time_scale`` would do); nothing is clamped."""
    if not waypoints:
        raise UsageError("no waypoints to play")
    for value, what in ((approach_speed, "approach speed (rad/s)"),
                        (time_scale, "time scale")):
        if not (math.isfinite(value) and value > 0):
            raise LimitError(f"{what} {value} must be a finite number > 0")
    if not (math.isfinite(settle_s) and settle_s >= 0):
        raise LimitError(f"settle time {settle_s} must be a finite number >= 0 s")
    control = controller or JointController(arm)
    state = control.state or control.start()
    first = np.asarray(waypoints[0].joints, dtype=float)
    check_goals(first, state.joints, homed=arm.homed, what="goal (waypoint 1)")
    approach = timed_path([state.joints, first], approach_speed)
    lead = approach[-1].t
    t_first = waypoints[0].t
    path = approach + [Waypoint(lead + (w.t - t_first) * time_scale, w.joints)
                       for w in waypoints[1:]]
    extra = len(approach) - 1

    def label(k: int) -> str:
        return "where the arm is" if k < extra else f"waypoint {k - extra + 1}"

    check_path([w.t for w in path], np.array([w.joints for w in path]), state.joints,
               homed=arm.homed, label=label,
               slower="a time scale (time_scale=, armctl waypoints play --time-scale) of")
    trajectory = Trajectory(path)
    return control.run(trajectory, trajectory.duration + settle_s, log)


def save_waypoints(path: str | Path, waypoints: Iterable[Waypoint]) -> None:
    """Write a waypoint file (JSON lines, see the module docs)."""
    with open(path, "w", encoding="utf-8") as f:
        f.write(json.dumps({"kind": WAYPOINTS_KIND, "version": WAYPOINTS_VERSION,
                            "joints": list(JOINT_NAMES), "units": "rad, s"}) + "\n")
        for w in waypoints:
            f.write(json.dumps({"t": w.t, "joints": list(w.joints)}) + "\n")


def load_waypoints(path: str | Path) -> list[Waypoint]:
    """Read a waypoint file; :class:`~host.errors.UsageError` names the bad line."""
    out: list[Waypoint] = []
    with open(path, encoding="utf-8") as f:
        for number, line in enumerate(f, 1):
            if not line.strip():
                continue
            try:
                record = json.loads(line)
                if "kind" in record:
                    if record["kind"] != WAYPOINTS_KIND or record.get("version") != 1:
                        raise ValueError(f"not an {WAYPOINTS_KIND} v1 header")
                    continue
                t = float(record["t"])
                joints = tuple(float(v) for v in record["joints"])
                if len(joints) != N_JOINTS or not all(map(math.isfinite, (t, *joints))):
                    raise ValueError(f"needs t and {N_JOINTS} finite joint angles")
                if out and t < out[-1].t:
                    raise ValueError("time goes backwards")
            except (ValueError, KeyError, TypeError) as exc:
                raise UsageError(f"{path}:{number}: bad waypoint line: {exc}") from exc
            out.append(Waypoint(t, joints))
    if not out:
        raise UsageError(f"{path} holds no waypoints")
    return out
