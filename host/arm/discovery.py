"""Finding the arm on its bus: opening the bus's transport and discovering the seven joints.

:func:`discover` pings J1..J7 at their bus IDs (:data:`host.arm.state.JOINT_IDS`) and reads
what each node is (model, firmware and, for a stepper node, its reduction, steps per rev,
microstepping, encoder resolution and the arm's serial number), refusing a node of the wrong model or a stepper node
whose firmware predates the cycle block :class:`~host.arm.facade.Arm` reads.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Final

from host.arm.bus import ARM_BUS_BAUD, DEFAULT_RETRIES, DynamixelBus
from host.arm.state import (
    DEFAULT_STIFFNESS_NM_PER_RAD,
    JOINT_IDS,
    JOINT_NAMES,
    N_STEPPERS,
    JointInfo,
)
from host.errors import NodeError, ReplyTimeout
from host.transports.base import Transport, open_transport, url_options, url_scheme
from protocol.control_tables import (
    RX64_TABLE,
    STEPPER_CYCLE_BLOCK_FIRMWARE,
    STEPPER_TABLE,
    TABLES_BY_MODEL,
)

_S = STEPPER_TABLE
#: The head of every node's table that discovery reads: model, firmware, id, baud, return
#: delay (the same addresses in both tables).
_HEAD_END: Final = _S["return_delay_time"].end
assert RX64_TABLE["return_delay_time"].end == _HEAD_END


def open_arm_transport(url: str) -> Transport:
    """Open the arm bus's transport: a serial path at 1 Mbaud unless ``?baud=N``, or any
    transport URL."""
    options: dict[str, Any] = {}
    if url_scheme(url) == "serial" and "baud" not in url_options(url) and "?" not in url:
        options["baud"] = ARM_BUS_BAUD
    return open_transport(url, **options)


def open_bus(url: str, *, latency_s: float | None = None,
             retries: int = DEFAULT_RETRIES) -> DynamixelBus:
    """The arm's Dynamixel bus on ``url`` (:func:`open_arm_transport`) without discovering
    the joints (to scan it, or reach a node at an unexpected ID); close its transport."""
    transport = open_arm_transport(url)
    return DynamixelBus(transport, getattr(transport, "baud", ARM_BUS_BAUD), retries=retries,
                        latency_s=latency_s)


def discover(bus: DynamixelBus,
             stiffness: Sequence[float] = DEFAULT_STIFFNESS_NM_PER_RAD) -> list[JointInfo]:
    """Ping the seven joints and read what each node is: model, firmware and, for a stepper
    node, its reduction, steps per rev, microstepping and encoder resolution.

    Raises :class:`~host.errors.ReplyTimeout` naming a joint that does not answer and
    :class:`~host.errors.NodeError` for a node of the wrong model."""
    joints = []
    for joint, dxl_id in enumerate(JOINT_IDS):
        want = STEPPER_TABLE if joint < N_STEPPERS else RX64_TABLE
        try:
            bus.ping(dxl_id)
        except ReplyTimeout as exc:
            raise ReplyTimeout(f"{JOINT_NAMES[joint]} (bus ID {dxl_id}) does not answer: {exc}"
                               f"; a scan lists the IDs that do (armctl scan)") from exc
        # model, firmware, and the id, baud and return delay it holds: a recording of
        # this session then shows what an earlier program left in register 5
        head = bus.read(dxl_id, 0, _HEAD_END)
        model, firmware = int.from_bytes(head[:2], "little"), head[2]
        table = TABLES_BY_MODEL.get(model)
        if table is not want:
            raise NodeError(f"bus ID {dxl_id} ({JOINT_NAMES[joint]}) is model {model} "
                            f"({table.name if table else 'unknown'}), the arm has "
                            f"{want.name} there; check the node's ID")
        if table is STEPPER_TABLE and firmware < STEPPER_CYCLE_BLOCK_FIRMWARE:
            raise NodeError(f"bus ID {dxl_id} ({JOINT_NAMES[joint]}) runs stepper firmware "
                            f"{firmware}, without the cycle block (from version "
                            f"{STEPPER_CYCLE_BLOCK_FIRMWARE}); update the node")
        if table is RX64_TABLE:
            joints.append(JointInfo(joint, dxl_id, "servo", model, firmware))
            continue
        at = _S["gear_reduction_x100"].address
        end = _S["arm_serial"].end
        eeprom = bus.read(dxl_id, at, end - at)

        def value(name: str, eeprom: bytes = eeprom, at: int = at) -> int:
            reg = _S[name]
            return reg.decode(eeprom[reg.address - at : reg.end - at])

        joints.append(JointInfo(
            joint, dxl_id, "stepper", model, firmware,
            reduction=value("gear_reduction_x100") / 100,
            steps_per_rev=value("steps_per_rev"), microstepping=value("microstepping"),
            encoder_counts_per_rev=value("encoder_resolution"),
            stiffness=float(stiffness[joint]), arm_serial=value("arm_serial")))
    return joints
