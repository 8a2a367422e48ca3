"""Draw the robot's messages in a rerun recording: one function for live and replayed data.

The messages are the JSON-ready dicts the MCAP recorders write (:mod:`host.hand_recording`,
:mod:`host.arm_recording`), by topic:

======================  ==============================================================
topic                   payload
======================  ==============================================================
``/arm/state``          :meth:`host.arm_state.ArmState.as_dict`
``/hand/state``         :meth:`host.hand_state.HandState.to_dict`
``/hand/events``        a :class:`host.hand_session.FingerEvent` as a dict
``/arm/bus/stats``      :class:`host.dynamixel_bus.BusStats` as a dict (counts)
``/hand/link/stats``    :class:`host.hand_session.SessionCounters` as a dict (counts)
======================  ==============================================================

so a recording replays (:func:`tools.robot_view`) exactly as it was drawn live.  The time
line ``time`` is each message's ``t`` (s on the link's clock: the simulation's on an
in-process emulator).  Entities: ``world/arm`` and ``world/hand/*`` (3D, metres, the arm's
base frame, or the palm frame for a hand on its own), ``arm/*`` and ``hand/finger{k}/*``
time series, ``alarms`` (a text log of alarm bits, finger problems and events as they
appear and clear).  This module imports rerun; :mod:`host.view` imports it only when a view
is asked for.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Final

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from host.robot_geometry import (
    IDENTITY,
    Pose,
    arm_skeleton,
    finger_skeleton,
    palm_on_flange,
    palm_outline,
)
from host.view import ARM_BUS_STATS, ARM_STATE, HAND_EVENTS, HAND_LINK_STATS, HAND_STATE
from protocol.robot import ARM_JOINT_NAMES, FINGER_JOINT_NAMES, motor_to_joint

#: Every topic :meth:`Renderer.message` draws.
TOPICS: Final = (ARM_STATE, HAND_STATE, HAND_EVENTS, ARM_BUS_STATS, HAND_LINK_STATS)
TIMELINE: Final = "time"
FINGERS: Final = 4
#: Colours (RGB): the arm, the fingers, the palm, alarms raised and cleared.
ARM_RGB: Final = (255, 140, 0)
FINGER_RGB: Final = (40, 160, 255)
PALM_RGB: Final = (120, 220, 120)
_STEPPERS: Final = ARM_JOINT_NAMES[:4]
_SERVOS: Final = ARM_JOINT_NAMES[4:]
_STATS: Final = ("requests", "retries", "timeouts")

#: Time-series entities and their series' names (logged once, static).
SERIES: Final[dict[str, Sequence[str]]] = {
    "arm/joints/angle": ARM_JOINT_NAMES,
    "arm/joints/goal": _STEPPERS,
    "arm/steppers/motor_angle": _STEPPERS,
    "arm/steppers/deflection_counts": _STEPPERS,
    "arm/steppers/torque_nm": _STEPPERS,
    "arm/servos/load": _SERVOS,
    "arm/servos/temperature_c": _SERVOS,
    "arm/bus": _STATS,
    "hand/link": _STATS,
    **{f"hand/finger{k}/{what}": names for k in range(FINGERS) for what, names in (
        ("joints", FINGER_JOINT_NAMES), ("targets", FINGER_JOINT_NAMES),
        ("temperature_c", ("motor0", "motor1", "motor2")),
        ("current_ma", ("supply", "phalange_bus")),
        ("tactile", ("proximal", "distal")))},
}


def blueprint() -> rrb.Blueprint:
    """The page's layout: the robot in 3D beside its time series and the alarms."""
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(rrb.Spatial3DView(name="robot", origin="world"),
                         rrb.TextLogView(name="alarms", origin="alarms"), row_shares=[3, 1]),
            rrb.Vertical(
                rrb.TimeSeriesView(name="arm joints (rad)", origin="arm/joints"),
                rrb.TimeSeriesView(name="arm torques (N·m)", origin="arm/steppers/torque_nm"),
                rrb.TimeSeriesView(name="hand joints (rad)", origin="hand",
                                   contents=[f"hand/finger{k}/joints" for k in range(FINGERS)]),
                rrb.TimeSeriesView(name="tactile (ADC counts)", origin="hand",
                                   contents=[f"hand/finger{k}/tactile" for k in range(FINGERS)]),
                rrb.TimeSeriesView(name="bus (counts)", origin="/",
                                   contents=["arm/bus", "hand/link"]),
            ),
            column_shares=[3, 2]),
        collapse_panels=True)


class Renderer:
    """Logs messages to ``recording``; ``layout`` is the hand's
    (:data:`protocol.robot.HAND_LAYOUTS`).  Keeps what it needs between messages: the
    flange's last pose (a hand on the arm is drawn on it) and the alarms standing."""

    def __init__(self, recording: rr.RecordingStream, layout: str) -> None:
        self.rec = recording
        self.layout = layout
        self._flange: Pose | None = None
        self._alarms: dict[str, str] = {}
        for path, names in SERIES.items():
            recording.log(path, rr.SeriesLines(names=list(names)), static=True)
        recording.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)

    def message(self, topic: str, t: float, payload: Mapping[str, Any]) -> None:
        """Draw one message at time ``t`` (s); an unknown topic is ignored."""
        self.rec.set_time(TIMELINE, duration=max(0.0, float(t)))
        if topic == ARM_STATE:
            self._arm(payload)
        elif topic == HAND_STATE:
            self._hand(payload)
        elif topic == HAND_EVENTS:
            self.rec.log("alarms", rr.TextLog(
                f"finger {payload['finger']}: {payload['event']}",
                level=rr.TextLogLevel.WARN if payload["event"] in ("lost", "breaker_trip")
                else rr.TextLogLevel.INFO))
        elif topic in (ARM_BUS_STATS, HAND_LINK_STATS):
            path = "arm/bus" if topic == ARM_BUS_STATS else "hand/link"
            self._scalars(path, [payload.get(k, 0) for k in _STATS])

    def _scalars(self, path: str, values: Sequence[Any]) -> None:
        self.rec.log(path, rr.Scalars(np.array([np.nan if v is None else float(v)
                                                for v in values])))

    def _alarm(self, source: str, text: str | None) -> None:
        """Log ``source``'s alarm when it appears, changes or clears."""
        if self._alarms.get(source) == text:
            return
        if text is None:
            self._alarms.pop(source, None)
            self.rec.log("alarms", rr.TextLog(f"{source}: cleared", level=rr.TextLogLevel.INFO))
        else:
            self._alarms[source] = text
            self.rec.log("alarms", rr.TextLog(f"{source}: {text}",
                                              level=rr.TextLogLevel.ERROR))

    def _arm(self, p: Mapping[str, Any]) -> None:
        joints = p["joints"]
        points, flange = arm_skeleton(joints)
        self._flange = flange
        self.rec.log("world/arm", rr.LineStrips3D([points], colors=[ARM_RGB], radii=0.012),
                     rr.Points3D(points[1:-1], colors=[ARM_RGB], radii=0.02))
        self._scalars("arm/joints/angle", joints)
        if "goals" in p:
            self._scalars("arm/joints/goal", p["goals"])
        self._scalars("arm/steppers/motor_angle", p["motor_joints"])
        self._scalars("arm/steppers/deflection_counts", p["deflection_counts"])
        self._scalars("arm/steppers/torque_nm", p["torques"])
        self._scalars("arm/servos/load", p["servo_load"])
        self._scalars("arm/servos/temperature_c", p["servo_temperature_c"])
        errors: Mapping[str, Sequence[str]] = p.get("errors") or {}
        flags = {name: ["SLIP"] for name, slip in zip(_STEPPERS, p.get("slip", ()),
                                                       strict=False) if slip}
        for name in ARM_JOINT_NAMES:
            bits = [*errors.get(name, ()), *flags.get(name, ())]
            self._alarm(name, ", ".join(bits) if bits else None)

    def _hand(self, p: Mapping[str, Any]) -> None:
        palm = IDENTITY if self._flange is None else palm_on_flange(self._flange)
        strips = []
        for f in p["fingers"]:
            k = int(f["index"])
            strips.append(finger_skeleton(self.layout, k, f["joints"], palm))
            base = f"hand/finger{k}"
            self._scalars(f"{base}/joints", f["joints"])
            targets = f.get("targets_hall")
            if targets is not None:
                self._scalars(f"{base}/targets", motor_to_joint(targets))
            if f.get("temperatures_c") is not None:
                self._scalars(f"{base}/temperature_c", f["temperatures_c"])
            currents = f.get("currents") or {}
            self._scalars(f"{base}/current_ma", [currents.get("supply"),
                                                 currents.get("phalange_bus")])
            tactile = f.get("tactile") or {}
            if tactile:
                self._scalars(f"{base}/tactile", [sum(tactile.get("proximal", ())),
                                                  sum(tactile.get("distal", ()))])
            problem = "breaker tripped" if f.get("breaker_tripped") else f.get("problem")
            self._alarm(f"finger {k}", problem if f.get("power") != "off" else None)
        self.rec.log("world/hand/fingers",
                     rr.LineStrips3D(strips, colors=[FINGER_RGB], radii=0.005))
        self.rec.log("world/hand/palm",
                     rr.LineStrips3D([palm_outline(palm)], colors=[PALM_RGB], radii=0.004))
