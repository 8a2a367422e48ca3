"""What the host knows of the hand at one moment, as plain data.

:class:`FingerState` and :class:`HandState` are built from the palm's ``palm.hand_status``
summaries and, where a finger answered, its ``fmcb.status`` snapshot.  Joint angles (rad)
come from the motor hall counts through the gear ratios and the tendon coupling
(:func:`protocol.robot.motor_to_joint`); ``to_dict`` gives JSON-ready dicts (``handctl --json``).

The outcomes of the hand's procedures are data too, shared by the facade
(:class:`host.hand.facade.Hand`) and its helpers: a command as data (:class:`FingerCommand`), how a
move ended (:class:`MoveResult`), how the boards came up (:class:`NodeUp`,
:class:`FingerUp`) and how a grasp ended (:class:`GraspResult`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Final

from host.code_names import code_name
from protocol.messages.palm import FingerPower
from protocol.robot import motor_to_joint
from protocol.sensor_counts import pb_current_amps, supply_volts, temperature_c

#: ``pb_current`` value meaning the phalange-bus breaker has tripped.
BREAKER_TRIPPED: Final = 0xFFFF

Vec3 = tuple[float, float, float]


def joints_from_hall(hall: list[int] | tuple[int, ...]) -> Vec3:
    """Joint angles (rad) of motor positions ``hall`` (hall counts, homing-relative)."""
    return motor_to_joint(hall)


@dataclass
class FingerState:
    """One finger: ``present`` if its fmcb answered now; ``power`` ``"off"|"low"|"full"``;
    ``joints_hall`` motor positions (hall counts), ``joints`` the joint angles they mean
    (rad, J0 J1 J2), ``targets_hall`` the fmcb's motor targets (hall counts), ``effort``
    (1/255 of full PWM), ``tactile`` taxels (ADC counts) of ``proximal`` (6) and ``distal``
    (12), ``currents`` in mA (``supply`` from the palm, ``phalange_bus`` from the fmcb;
    None when unknown), ``breaker_tripped`` for the phalange bus, ``supply_v`` the fmcb's
    logic supply (V) and ``temperatures_c`` its motor temperatures (°C), converted from the
    status's raw ADC counts (:mod:`protocol.sensor_counts`)."""

    index: int
    present: bool = False
    power: str = "off"
    joints_hall: list[int] = field(default_factory=lambda: [0, 0, 0])
    targets_hall: list[int] | None = None
    effort: list[int] = field(default_factory=lambda: [0, 0, 0])
    tactile: dict[str, list[int]] = field(default_factory=dict)
    currents: dict[str, int | None] = field(
        default_factory=lambda: {"supply": None, "phalange_bus": None})
    breaker_tripped: bool = False
    supply_v: float | None = None
    temperatures_c: list[float] | None = None
    fmcb_time_us: int | None = None
    #: Accelerometers (counts, mg; board axes) ``fmcb``, ``f2``, ``f3`` from the status.
    accels: dict[str, list[int]] = field(default_factory=dict)
    #: Why the fmcb's status did not come (:func:`host.errors.why_no_answer`: ``unpowered``,
    #: ``link_down``, ``no_reply``, ``no reply`` …), None when it did.
    problem: str | None = None

    @property
    def joints(self) -> Vec3:
        """Joint angles (rad) from :attr:`joints_hall`."""
        return joints_from_hall(self.joints_hall)

    @property
    def joint_targets(self) -> Vec3 | None:
        """Joint angles (rad) the fmcb is driving toward, when known."""
        return None if self.targets_hall is None else joints_from_hall(self.targets_hall)

    def update_from_summary(self, summary: dict[str, Any]) -> None:
        """Take the palm's per-finger summary (``palm.hand_status``)."""
        self.power = code_name(FingerPower, summary["power"], "power")
        self.present = bool(summary["present"])
        self.currents["supply"] = int(summary["current"])
        self.joints_hall = [int(v) for v in summary["hall_pos"]]
        self.effort = [int(v) for v in summary["effort"]]

    def update_from_status(self, status: dict[str, Any]) -> None:
        """Take the fmcb's ``fmcb.status`` (it answered: the finger is present)."""
        self.present = True
        self.joints_hall = [int(v) for v in status["hall_pos"]]
        self.targets_hall = [int(v) for v in status["hall_tgt"]]
        self.effort = [int(v) for v in status["effort"]]
        self.tactile = {"proximal": [int(v) for v in status["pp_tactile"]],
                        "distal": [int(v) for v in status["dp_tactile"]]}
        pb = int(status["pb_current"])
        self.breaker_tripped = pb == BREAKER_TRIPPED
        self.currents["phalange_bus"] = (None if self.breaker_tripped
                                         else round(pb_current_amps(pb) * 1000))
        self.supply_v = supply_volts(int(status["voltage"]))
        self.temperatures_c = [temperature_c(int(v)) for v in status["fmcb_temp"]]
        self.fmcb_time_us = int(status["fmcb_time"])
        self.accels = {"fmcb": [int(v) for v in status["fmcb_imu"][:3]],
                       "f2": [int(v) for v in status["pp_imu"][:3]],
                       "f3": [int(v) for v in status["dp_imu"][:3]]}

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: joints (rad), joints_hall, tactile, currents (mA), present, power …"""
        return {
            "index": self.index,
            "present": self.present,
            "power": self.power,
            "joints": [round(q, 6) for q in self.joints],
            "joints_hall": list(self.joints_hall),
            "targets_hall": None if self.targets_hall is None else list(self.targets_hall),
            "effort": list(self.effort),
            "tactile": {k: list(v) for k, v in self.tactile.items()},
            "currents": dict(self.currents),
            "breaker_tripped": self.breaker_tripped,
            "supply_v": None if self.supply_v is None else round(self.supply_v, 3),
            "temperatures_c": (None if self.temperatures_c is None
                               else [round(t, 1) for t in self.temperatures_c]),
            "problem": self.problem,
        }


@dataclass
class HandState:
    """The hand at time ``t`` (s, the link's clock): four fingers and the palm's summary
    (``effort_cap`` 1/255 of full PWM, ``poll_hz``, ``bus_voltage_mv``, ``palm_time_us``)."""

    t: float
    fingers: list[FingerState]
    effort_cap: int | None = None
    poll_hz: int | None = None
    bus_voltage_mv: int | None = None
    palm_time_us: int | None = None

    @property
    def joints(self) -> list[float]:
        """All 12 joint angles (rad), finger by finger."""
        return [q for f in self.fingers for q in f.joints]

    def update_from_hand_status(self, status: dict[str, Any]) -> None:
        """Take ``palm.hand_status``."""
        self.effort_cap = int(status["effort_cap"])
        self.poll_hz = int(status["poll_hz"])
        self.bus_voltage_mv = int(status["bus_voltage"])
        self.palm_time_us = int(status["time"])
        for finger, summary in zip(self.fingers, status["fingers"], strict=False):
            finger.update_from_summary(summary)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready, with ``fingers`` a list of four :meth:`FingerState.to_dict`."""
        return {
            "t": round(self.t, 6),
            "palm_time_us": self.palm_time_us,
            "effort_cap": self.effort_cap,
            "poll_hz": self.poll_hz,
            "bus_voltage_mv": self.bus_voltage_mv,
            "fingers": [f.to_dict() for f in self.fingers],
        }


@dataclass(frozen=True)
class NodeInfo:
    """What discovery found at one place: ``where`` (``"palm"``, ``"finger 1 f2"``),
    ``answered``; if it did, ``running`` (``"bootloader"`` / ``"application"``), board
    type, address, versions (``fw_version`` ``"major.minor.patch"``, ``hw_version``),
    ``uid`` and whether its message catalogue matches the host's; else ``problem``."""

    where: str
    finger: int | None
    hop: int | None
    answered: bool
    running: str | None = None
    board: int | None = None
    address: int | None = None
    fw_version: str | None = None
    hw_version: int | None = None
    uid: int | None = None
    catalogue_matches: bool | None = None
    problem: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


@dataclass(frozen=True)
class FingerCommand:
    """An ``fmcb.control`` request for finger ``finger`` as data: ``mode`` and ``args``."""

    finger: int
    mode: int
    args: dict[str, Any] = field(default_factory=dict)

    @property
    def fields(self) -> dict[str, Any]:
        """The ``fmcb.control`` request fields."""
        return {"mode": self.mode, "args": self.args}


@dataclass
class MoveResult:
    """How a move ended: ``settled`` when every finger's motors are within the deadband
    tolerance of their targets; ``stalled`` fingers stopped short (blocked, effort too
    low); ``errors`` joint errors (rad, target − actual) per finger moved.  ``robot_rate``
    is how fast the robot's clock (the fmcbs' status timestamps) ran against the link's
    while waiting: 1.0 on hardware and in process, less for an emulator a busy machine
    slows below real time (then ``elapsed_s`` on the wall meant less robot time); None
    when unknown."""

    settled: bool
    stalled: list[int]
    errors: dict[int, tuple[float, float, float]]
    states: dict[int, FingerState]
    elapsed_s: float
    robot_rate: float | None = None


@dataclass
class NodeUp:
    """How one board came up: ``up`` once it answered running its application,
    ``after_s`` (s on the link's clock since the bring-up began) when it was first seen so;
    otherwise ``problem`` says what was last seen and what to check.  ``running`` is the
    program that last answered (``"application"``, ``"bootloader"``) or None."""

    where: str
    up: bool = False
    running: str | None = None
    after_s: float | None = None
    problem: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"where": self.where, "up": self.up, "running": self.running,
                "after_s": None if self.after_s is None else round(self.after_s, 3),
                "problem": self.problem}


@dataclass
class FingerUp:
    """One finger's bring-up: its ``power`` state after, its three boards (fmcb, f2, f3)
    and whether the fmcb's ``autopoll`` of its phalanges is on (``autopoll_problem`` if
    switching it on failed)."""

    finger: int
    power: str
    nodes: list[NodeUp] = field(default_factory=list)
    autopoll: bool = False
    autopoll_problem: str | None = None

    @property
    def up(self) -> bool:
        """Every board runs its application and the fmcb polls its phalanges."""
        return self.autopoll and all(n.up for n in self.nodes)

    @property
    def down(self) -> list[str]:
        """The boards that did not come up (``"finger 2 f3"`` …)."""
        return [n.where for n in self.nodes if not n.up]

    def to_dict(self) -> dict[str, Any]:
        return {"finger": self.finger, "up": self.up, "power": self.power,
                "nodes": [n.to_dict() for n in self.nodes], "autopoll": self.autopoll,
                "autopoll_problem": self.autopoll_problem}


@dataclass
class GraspResult:
    """How a grasp ended: the ``targets`` (rad) per finger, ``contacts`` (finger → why it
    stopped closing), the final settle (:class:`MoveResult`), ``elapsed_s`` on
    the link's clock."""

    name: str
    amount: float
    targets: dict[int, Vec3]
    contacts: dict[int, str] = field(default_factory=dict)
    move: MoveResult | None = None
    elapsed_s: float = 0.0
