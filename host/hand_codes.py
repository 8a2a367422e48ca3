"""The hand protocol's coded fields and addresses as the host names them, in one place.

Route status, transaction status, finger power, finger events, control modes and hops are
plain integers on the wire; the catalogue declares their names (``protocol.messages``).
Everything in :mod:`host` that needs a code or a name takes it from here, so turning the
catalogue's tables into IntEnums changes this module only.
"""

from __future__ import annotations

from enum import IntEnum
from typing import Final

from protocol.messages.common import Running, TxnStatus
from protocol.messages.fmcb import ControlMode
from protocol.messages.palm import FingerEvent, FingerPower, RouteStatus
from protocol.topology import ADDR_HOST, ADDR_PALM, FINGERS
from protocol.topology import HOP_ADDRESS as _HOP_ADDRESS
from protocol.topology import HOP_NODE as _HOP_NODE

__all__ = [
    "ADDR_HOST", "ADDR_PALM", "FINGERS", "HOP_ADDRESS", "HOP_NODE", "ROUTE_OK",
    "ROUTE_NO_REPLY", "ROUTE_UNPOWERED", "ROUTE_BAD_DESTINATION", "ROUTE_LINK_DOWN",
    "ROUTE_BUSY", "TXN_OK", "TXN_BUSY", "POWER_OFF", "POWER_LOW", "POWER_FULL",
    "ALL_FINGERS", "MODE_IDLE", "MODE_MOTOR", "MODE_JOINT", "MODE_JOINT_FIXED",
    "MODE_JOINT_EFFORT", "MODE_RELATIVE", "route_status_name", "txn_status_name",
    "power_code", "power_name", "event_name", "mode_code", "running_name",
]


def _names(codes: type[IntEnum]) -> dict[int, str]:
    """code → lower-case name of the catalogue's IntEnum ``codes``."""
    return {int(member): member.name.lower() for member in codes}


ROUTE_STATUS: Final = _names(RouteStatus)
TXN_STATUS: Final = _names(TxnStatus)
FINGER_POWER: Final = _names(FingerPower)
FINGER_EVENTS: Final = _names(FingerEvent)
CONTROL_MODES: Final = _names(ControlMode)
RUNNING: Final = _names(Running)


def _code(table: dict[int, str], name: str) -> int:
    for code, text in table.items():
        if text == name:
            return code
    raise KeyError(f"{name!r} is not one of {sorted(table.values())}")


#: Hop behind a finger's pogo link → catalogue node kind, and → bus address.
HOP_NODE: Final[dict[int, str]] = {int(hop): str(kind.value) for hop, kind in _HOP_NODE.items()}
HOP_ADDRESS: Final[dict[int, int]] = {int(hop): address for hop, address in _HOP_ADDRESS.items()}

ROUTE_OK: Final = _code(ROUTE_STATUS, "ok")
ROUTE_NO_REPLY: Final = _code(ROUTE_STATUS, "no_reply")
ROUTE_UNPOWERED: Final = _code(ROUTE_STATUS, "unpowered")
ROUTE_BAD_DESTINATION: Final = _code(ROUTE_STATUS, "bad_destination")
ROUTE_LINK_DOWN: Final = _code(ROUTE_STATUS, "link_down")
ROUTE_BUSY: Final = _code(ROUTE_STATUS, "busy")
#: Route statuses worth trying again (the finger may answer next time).
ROUTE_RETRYABLE: Final = frozenset({ROUTE_NO_REPLY, ROUTE_BUSY})

TXN_OK: Final = _code(TXN_STATUS, "ok")
TXN_BUSY: Final = _code(TXN_STATUS, "busy")

POWER_OFF: Final = _code(FINGER_POWER, "off")
POWER_LOW: Final = _code(FINGER_POWER, "low")
POWER_FULL: Final = _code(FINGER_POWER, "full")
#: ``palm.finger_power`` finger index meaning every finger.
ALL_FINGERS: Final = 0xFF

MODE_IDLE: Final = _code(CONTROL_MODES, "idle")
MODE_MOTOR: Final = _code(CONTROL_MODES, "motor")
MODE_JOINT: Final = _code(CONTROL_MODES, "joint")
MODE_JOINT_FIXED: Final = _code(CONTROL_MODES, "joint_fixed")
MODE_JOINT_EFFORT: Final = _code(CONTROL_MODES, "joint_effort")
MODE_RELATIVE: Final = _code(CONTROL_MODES, "relative")


def route_status_name(code: int) -> str:
    """``palm.route`` status code → name (``"unpowered"``); unknown codes as ``"status 9"``."""
    return ROUTE_STATUS.get(code, f"status {code}")


def txn_status_name(code: int) -> str:
    """``txn`` reply status code → name (``"refused"``)."""
    return TXN_STATUS.get(code, f"status {code}")


def power_code(state: int | str) -> int:
    """A finger power state given by name (``"off"``, ``"low"``, ``"full"``) or code."""
    if isinstance(state, str):
        return _code(FINGER_POWER, state.lower())
    if state not in FINGER_POWER:
        raise KeyError(f"finger power {state} is not one of {sorted(FINGER_POWER)}")
    return int(state)


def power_name(code: int) -> str:
    """Finger power code → ``"off"`` / ``"low"`` / ``"full"``."""
    return FINGER_POWER.get(code, f"power {code}")


def event_name(code: int) -> str:
    """``palm.finger_event`` code → ``"lost"``, ``"returned"``, ``"breaker_trip"`` …"""
    return FINGER_EVENTS.get(code, f"event {code}")


def mode_code(mode: int | str) -> int:
    """An fmcb control mode by name (``"joint_effort"``) or code."""
    if isinstance(mode, str):
        return _code(CONTROL_MODES, mode)
    if mode not in CONTROL_MODES:
        raise KeyError(f"control mode {mode} is not one of {sorted(CONTROL_MODES)}")
    return int(mode)


def running_name(code: int) -> str:
    """identify's running code → ``"bootloader"`` / ``"application"``."""
    return RUNNING.get(code, f"running {code}")
