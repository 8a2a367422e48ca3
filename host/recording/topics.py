"""The names of the robot's data streams, shared by the recorders (MCAP topics:
:mod:`host.arm.recording`, :mod:`host.hand.recording`) and the live view (:mod:`host.view.live`,
drawn by :mod:`host.view.render`), declared once here so that neither imports the other."""

from __future__ import annotations

from typing import Final

ARM_STATE: Final = "/arm/state"
HAND_STATE: Final = "/hand/state"
HAND_EVENTS: Final = "/hand/events"
ARM_BUS_STATS: Final = "/arm/bus/stats"
HAND_LINK_STATS: Final = "/hand/link/stats"
