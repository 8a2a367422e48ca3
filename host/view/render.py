"""Draw the robot's messages in a rerun recording: one function for live and replayed data.

The messages are the JSON-ready dicts the MCAP recorders write (:mod:`host.hand.recording`,
:mod:`host.arm.recording`), by topic:

======================  ==============================================================
topic                   payload
======================  ==============================================================
``/arm/state``          :meth:`host.arm.state.ArmState.as_dict`
``/hand/state``         :meth:`host.hand.state.HandState.to_dict`
``/hand/events``        a :class:`host.hand.session.FingerEvent` as a dict
``/arm/bus/stats``      :class:`host.arm.bus.BusStats` as a dict (counts)
``/hand/link/stats``    :class:`host.hand.session.SessionCounters` as a dict (counts)
======================  ==============================================================

so a recording replays (:func:`tools.cli.robot_view`) exactly as it was drawn live.  The time
line ``time`` is each message's ``t`` (s on the link's clock: the simulation's on an
in-process emulator).  Entities: ``world/arm`` and ``world/hand/*`` (3D, metres, the arm's
base frame, or the palm frame for a hand on its own), ``arm/*`` and ``hand/finger{k}/*``
time series, ``alarms`` (a text log of alarm bits, finger problems and events as they
appear and clear).  This module imports rerun; :mod:`host.view.live` imports it only when a view
is asked for.

Cheap per state: a state becomes one row per entity (:class:`host.view.columns.Columns`),
sent as columns when the owner calls :meth:`Renderer.flush` (the live view: a few times a
second; a replay: at the end), never one rerun call per value.  Colours and sizes are logged
once as static data, the palm outline once, the fingers' geometry in a few array operations.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Final

import rerun as rr
import rerun.blueprint as rrb

from host.recording.topics import ARM_BUS_STATS, ARM_STATE, HAND_EVENTS, HAND_LINK_STATS, HAND_STATE
from host.view.columns import (
    LEVEL,
    MAT3X3,
    POSITIONS,
    SCALARS,
    STRIPS,
    TEXT,
    TRANSLATION,
    Columns,
)
from host.view.geometry import (
    Pose,
    arm_skeleton,
    hand_skeleton,
    palm_on_flange,
    palm_outline,
)
from protocol.robot import ARM_JOINT_NAMES, FINGER_JOINT_NAMES, motor_to_joint

#: Every topic :meth:`Renderer.message` draws.
TOPICS: Final = (ARM_STATE, HAND_STATE, HAND_EVENTS, ARM_BUS_STATS, HAND_LINK_STATS)
FINGERS: Final = 4
#: Colours (RGB): the arm, the fingers, the palm, alarms raised and cleared.
ARM_RGB: Final = (255, 140, 0)
FINGER_RGB: Final = (40, 160, 255)
PALM_RGB: Final = (120, 220, 120)
#: Colours of the arm's seven joint-angle series (RGB), J1..J7.
JOINT_RGB: Final = ((230, 25, 75), (60, 180, 75), (255, 225, 25), (0, 130, 200),
                    (145, 30, 180), (70, 240, 240), (240, 50, 230))
_STEPPERS: Final = ARM_JOINT_NAMES[:4]
_SERVOS: Final = ARM_JOINT_NAMES[4:]
_STATS: Final = ("requests", "retries", "timeouts")

_HAND_JOINTS: Final = tuple(f"f{k} {name}" for k in range(FINGERS)
                             for name in FINGER_JOINT_NAMES)
#: Time-series entities and their series' names (logged once, static).  Few entities with
#: several series each: every entity costs a column per batch, whatever it carries.
SERIES: Final[dict[str, Sequence[str]]] = {
    "arm/joints": (*ARM_JOINT_NAMES, *(f"{j} goal" for j in _STEPPERS),
                   *(f"{j} motor" for j in _STEPPERS)),
    "arm/torque_nm": _STEPPERS,
    "arm/deflection_counts": _STEPPERS,
    "arm/servo_load": _SERVOS,
    "arm/servo_temperature_c": _SERVOS,
    "arm/bus": _STATS,
    "hand/link": _STATS,
    "hand/joints": (*_HAND_JOINTS, *(f"{name} target" for name in _HAND_JOINTS)),
    "hand/tactile": tuple(f"f{k} {pad}" for k in range(FINGERS)
                          for pad in ("proximal", "distal")),
    "hand/current_ma": tuple(f"f{k} {what}" for k in range(FINGERS)
                             for what in ("supply", "phalange_bus")),
    "hand/temperature_c": tuple(f"f{k} motor{m}" for k in range(FINGERS) for m in range(3)),
}


#: Series the page's layout does not show (a user can add them): sent with the rest only
#: every few sends (:meth:`Renderer.flush`), their rows complete but later.
BACKGROUND: Final = frozenset({"arm/deflection_counts", "arm/servo_load",
                               "arm/servo_temperature_c", "hand/current_ma",
                               "hand/temperature_c"})


def blueprint() -> rrb.Blueprint:
    """The page's layout: the robot in 3D beside its time series and the alarms."""
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(rrb.Spatial3DView(name="robot", origin="world"),
                         rrb.TextLogView(name="alarms", origin="alarms"), row_shares=[3, 1]),
            rrb.Vertical(
                rrb.TimeSeriesView(name="arm joints (rad)", origin="arm/joints"),
                rrb.TimeSeriesView(name="arm torques (N·m)", origin="arm/torque_nm"),
                rrb.TimeSeriesView(name="hand joints (rad)", origin="hand/joints"),
                rrb.TimeSeriesView(name="tactile (ADC counts)", origin="hand/tactile"),
                rrb.TimeSeriesView(name="bus (counts)", origin="/",
                                   contents=["arm/bus", "hand/link"]),
            ),
            column_shares=[3, 2]),
        collapse_panels=True)


class Renderer:
    """Draws messages in ``recording``; ``layout`` is the hand's
    (:data:`protocol.robot.HAND_LAYOUTS`).  Keeps what it needs between messages: the
    flange's last pose (a hand on the arm is drawn on it) and the alarms standing.  What
    :meth:`message` draws is sent by :meth:`flush` (or once an entity has gathered
    :data:`host.view.columns.MAX_ROWS` rows)."""

    def __init__(self, recording: rr.RecordingStream, layout: str) -> None:
        self.rec = recording
        self.layout = layout
        self.columns = Columns(recording, background=BACKGROUND)
        self._flange: Pose | None = None
        self._hand_seen = False
        self._last_values: dict[str, list[Any]] = {}
        self._alarms: dict[str, str] = {}
        for path, names in SERIES.items():
            colors = (*JOINT_RGB, *JOINT_RGB[:4], *JOINT_RGB[:4]) if path == "arm/joints" else None
            recording.log(path, rr.SeriesLines(names=list(names), colors=colors, widths=2.0),
                          static=True)
        recording.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        # Colours and sizes once, static: converting them costs more than the geometry.
        recording.log("world/arm", rr.LineStrips3D.from_fields(colors=[ARM_RGB], radii=0.012),
                      rr.Points3D.from_fields(colors=[ARM_RGB], radii=0.02), static=True)
        recording.log("world/hand/fingers",
                      rr.LineStrips3D.from_fields(colors=[FINGER_RGB], radii=0.005),
                      static=True)
        recording.log("world/hand/palm",
                      rr.LineStrips3D.from_fields(colors=[PALM_RGB], radii=0.004), static=True)

    def message(self, topic: str, t: float, payload: Mapping[str, Any]) -> None:
        """Draw one message at time ``t`` (s); an unknown topic is ignored."""
        if topic == ARM_STATE:
            self._arm(t, payload)
        elif topic == HAND_STATE:
            self._hand(t, payload)
        elif topic == HAND_EVENTS:
            level = "WARN" if payload["event"] in ("lost", "breaker_trip") else "INFO"
            self.columns.row("alarms", t, (TEXT, f"finger {payload['finger']}: "
                                                 f"{payload['event']}"), (LEVEL, level))
        elif topic in (ARM_BUS_STATS, HAND_LINK_STATS):
            path = "arm/bus" if topic == ARM_BUS_STATS else "hand/link"
            self._scalars(path, t, [payload.get(k, 0) for k in _STATS])

    def flush(self, everything: bool = True) -> None:
        """Send what was drawn since the last flush (``everything`` False: not the
        :data:`BACKGROUND` series)."""
        self.columns.flush(everything)

    def _scalars(self, path: str, t: float, values: Sequence[Any],
                 changes_only: bool = False) -> None:
        """Draw ``values`` on ``path`` (``changes_only``: unless they are the last ones:
        temperatures, read one cycle in ten, change over seconds)."""
        if changes_only:
            if self._last_values.get(path) == list(values):
                return
            self._last_values[path] = list(values)
        self.columns.row(path, t, (SCALARS, values))

    def _alarm(self, source: str, t: float, text: str | None) -> None:
        """Draw ``source``'s alarm when it appears, changes or clears."""
        if self._alarms.get(source) == text:
            return
        if text is None:
            self._alarms.pop(source, None)
            self.columns.row("alarms", t, (TEXT, f"{source}: cleared"), (LEVEL, "INFO"))
        else:
            self._alarms[source] = text
            self.columns.row("alarms", t, (TEXT, f"{source}: {text}"), (LEVEL, "ERROR"))

    def _arm(self, t: float, p: Mapping[str, Any]) -> None:
        joints = p["joints"]
        points, flange = arm_skeleton(joints)
        self._flange = flange
        if self._hand_seen:
            self._place_hand(t)
        self.columns.row("world/arm", t, (STRIPS, points[None]), (POSITIONS, points[1:-1]))
        goals = p.get("goals") or [None] * len(_STEPPERS)
        self._scalars("arm/joints", t, [*joints, *goals, *p["motor_joints"]])
        self._scalars("arm/torque_nm", t, p["torques"])
        self._scalars("arm/deflection_counts", t, p["deflection_counts"])
        self._scalars("arm/servo_load", t, p["servo_load"])
        self._scalars("arm/servo_temperature_c", t, p["servo_temperature_c"],
                      changes_only=True)
        errors: Mapping[str, Sequence[str]] = p.get("errors") or {}
        flags = {name: ["SLIP"] for name, slip in zip(_STEPPERS, p.get("slip", ()),
                                                       strict=False) if slip}
        for name in ARM_JOINT_NAMES:
            bits = [*errors.get(name, ()), *flags.get(name, ())]
            self._alarm(name, t, ", ".join(bits) if bits else None)

    def _place_hand(self, t: float) -> None:
        """The palm frame (entity ``world/hand``) on the flange's last pose."""
        assert self._flange is not None
        position, rotation = palm_on_flange(self._flange)
        self.columns.row("world/hand", t, (TRANSLATION, position), (MAT3X3, rotation))

    def _hand(self, t: float, p: Mapping[str, Any]) -> None:
        if not self._hand_seen:
            if self._flange is not None:
                self._place_hand(t)
            # drawn in the palm frame (world/hand is placed on the flange): it never moves
            self.rec.log("world/hand/palm",
                         rr.LineStrips3D.from_fields(strips=[palm_outline()]), static=True)
        self._hand_seen = True
        fingers = sorted(p["fingers"], key=lambda f: int(f["index"]))
        joints: list[Any] = []
        targets: list[Any] = []
        tactile: list[Any] = []
        currents: list[Any] = []
        temperatures: list[Any] = []
        for f in fingers:
            joints += f["joints"]
            hall = f.get("targets_hall")
            targets += [None] * 3 if hall is None else motor_to_joint(hall)
            pads = f.get("tactile") or {}
            tactile += ([sum(pads.get("proximal", ())), sum(pads.get("distal", ()))] if pads
                        else [None, None])
            amps = f.get("currents") or {}
            currents += [amps.get("supply"), amps.get("phalange_bus")]
            temperatures += f.get("temperatures_c") or [None] * 3
            problem = "breaker tripped" if f.get("breaker_tripped") else f.get("problem")
            self._alarm(f"finger {f['index']}", t,
                        problem if f.get("power") != "off" else None)
        self._scalars("hand/joints", t, [*joints, *targets])
        self._scalars("hand/tactile", t, tactile)
        self._scalars("hand/current_ma", t, currents)
        self._scalars("hand/temperature_c", t, temperatures, changes_only=True)
        skeleton = hand_skeleton(self.layout, [int(f["index"]) for f in fingers],
                                 [f["joints"] for f in fingers])
        self.columns.row("world/hand/fingers", t, (STRIPS, skeleton))
