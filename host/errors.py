"""The host library's one exception tree.

Every error also inherits the matching built-in, so ``except TimeoutError`` or ``except
ConnectionError`` catches it where a caller does not know this library::

    HostError
    ├── TransportError(ConnectionError)   the link itself: no such port, unplugged, closed
    ├── ReplyTimeout(TimeoutError)        a request got no (matching) reply in time
    ├── RouteError                        the palm could not deliver to a finger node
    ├── NodeError                         a node answered, but with a refusal or a bad reply
    │   └── DynamixelNodeError            an arm node's status error byte (host.arm.bus)
    ├── UsageError(ValueError)            the caller asked for something impossible
    │   ├── NotHomedError                 a motion command for a finger not yet homed
    │   ├── LimitError                    an arm motion the gate refuses before it starts
    │   ├── FingerMovingError             the finger moved while read for homing
    │   ├── AmbiguousPoseError            two poses fit the accelerometers
    │   ├── UnobservableJointError        a joint axis too near vertical (host.estimation.closed_form)
    │   └── CalibrationFileError          a calibration file unreadable, malformed, newer, another robot's
    ├── NoAccelerationError               accelerometers unpowered or silent (host.estimation.closed_form)
    ├── HomingError                       an arm joint's index mark was not found
    ├── StallError                        a stepper joint kept latching STALLED
    ├── JointAlarmError                   an arm joint's node latched an alarm mid-motion
    ├── ViewUnavailable                   the live view cannot start
    ├── RecordingError(OSError)           a recording's file could not be written
    ├── CalibrationError                  a calibration's fit does not explain its readings
    └── TouchMissed                       a guarded touch felt nothing (host.arm.touches)
        └── NotSeated                     ... or its ball did not seat in the dimple

Defined here unless their constructor needs their module's data (the module is named).
"""

from __future__ import annotations

from typing import Any


class HostError(Exception):
    """Base of every error raised by the host library."""


class TransportError(HostError, ConnectionError):
    """The link failed: the port does not exist, was unplugged, or is closed."""


class ReplyTimeout(HostError, TimeoutError):
    """No reply matching the request arrived within its deadline."""


class RouteError(HostError):
    """The palm answered ``palm.route`` with a status other than ok.

    ``status`` is the route status code (an IntEnum member where the catalogue declares
    one), ``finger`` and ``hop`` say where the frame was going.
    """

    def __init__(self, message: str, *, status: Any, finger: int, hop: int) -> None:
        super().__init__(message)
        self.status = status
        self.finger = finger
        self.hop = hop


class NodeError(HostError):
    """A node answered but refused the request or sent a reply that does not parse.

    ``status`` is the ``txn`` status code of a refusal (None for an unparsable reply).
    """

    def __init__(self, message: str, *, status: Any = None) -> None:
        super().__init__(message)
        self.status = status


class UsageError(HostError, ValueError):
    """A request the library refuses before sending anything (bad URL, joint limit …)."""


class HomingError(HostError):
    """A joint's index mark was not found (or the homing search could not run).

    ``joint`` names the joint (``"J1"`` … ``"J4"``) when one is to blame, else None.
    """

    def __init__(self, message: str, *, joint: str | None = None) -> None:
        super().__init__(message)
        self.joint = joint


class RecordingError(HostError, OSError):
    """A recording's file could not be created or written (no such directory, no
    permission, a full disk); what was written before stays in the file."""


class CalibrationFileError(UsageError):
    """A calibration file (:mod:`host.estimation.calibration_file`) that cannot be read, is
    not one, is of a newer version than this library reads, or (when writing) belongs to
    another robot.  ``path`` is the file."""

    def __init__(self, message: str, *, path: Any) -> None:
        super().__init__(message)
        self.path = path


class CalibrationError(HostError):
    """A calibration's fit leaves residuals far above the sensors' noise: the robot did not
    do what the poses assumed (a finger met something, its halls lost counts); nothing was
    written.  ``finger`` names the finger (None: not a finger's)."""

    def __init__(self, message: str, *, finger: int | None = None) -> None:
        super().__init__(message)
        self.finger = finger


class TouchMissed(HostError):
    """A guarded move of the arm's touch calibration reached its end without feeling
    anything (:mod:`host.arm.touches`: the surface or dimple not where it was looked for)."""


class NotSeated(TouchMissed):
    """A touch of the arm's touch calibration felt its dimple, but the ball did not come to
    rest at the bottom (:mod:`host.arm.touches`: each push along the dimple's axis still
    moved it): on a wall, on the rim, outside the dimple.  ``springs``: what the springs
    carried before the pushes (:class:`host.arm.touches.Springs`), to take the push off by."""

    def __init__(self, message: str, *, springs: object = None) -> None:
        super().__init__(message)
        self.springs = springs


class StallError(HostError):
    """A stepper joint kept latching STALLED however often the controller re-enabled it:
    something holds it, or its load is more than its stepper holds.  The node holds it where
    it stopped (torque on, latched).  ``joint`` names it (``"J1"`` … ``"J4"``)."""

    def __init__(self, message: str, *, joint: str) -> None:
        super().__init__(message)
        self.joint = joint


class NotHomedError(UsageError):
    """A motion command for a finger whose hall offsets were never set (``Hand.home``);
    ``unhomed=True`` overrides.  ``fingers`` lists the fingers concerned."""

    def __init__(self, message: str, *, fingers: list[int]) -> None:
        super().__init__(message)
        self.fingers = fingers


class LimitError(UsageError):
    """An arm motion refused before anything moved (:mod:`host.arm.gate`): a goal outside a
    joint's range, a path faster than a joint can follow, a joint's torque off, a number
    that is not finite.  ``joint`` names the joint (``"J1"`` … ``"J7"``) when one is to
    blame, else None."""

    def __init__(self, message: str, *, joint: str | None = None) -> None:
        super().__init__(message)
        self.joint = joint


class FingerMovingError(UsageError):
    """The finger moved while its accelerometers were read for homing."""


class AmbiguousPoseError(UsageError):
    """Two poses within the joint stops fit the accelerometers; homing cannot choose."""


class ViewUnavailable(HostError):
    """The view cannot start: rerun-sdk is not installed, or a port is taken."""


class JointAlarmError(HostError):
    """A joint's node latched an alarm during a motion (a stepper's STALLED or SLIP, an
    RX-64's OVERLOAD …) and turned its torque off; the motion stopped and the rest of the
    arm holds where it is.  ``joint`` names it, ``latches`` the latches and alarm bits."""

    def __init__(self, message: str, *, joint: str, latches: tuple[str, ...]) -> None:
        super().__init__(message)
        self.joint = joint
        self.latches = latches


def why_no_answer(exc: HostError) -> str:
    """Why a node did not answer, in a word or two: a :class:`RouteError`'s status name
    (``no_reply``, ``unpowered``, ``link_down`` …), ``no reply`` for a :class:`ReplyTimeout`,
    ``refused: …`` for a :class:`NodeError`, else the error's type and message."""
    if isinstance(exc, RouteError):
        from host.code_names import code_name
        from protocol.messages.palm import RouteStatus

        return code_name(RouteStatus, exc.status, "status")
    if isinstance(exc, ReplyTimeout):
        return "no reply"
    if isinstance(exc, NodeError):
        return f"refused: {exc}"
    return f"{type(exc).__name__}: {exc}"
