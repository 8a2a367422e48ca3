"""The robot as a recording made over a port found it, rebuilt before the replay.

A recording made on a serial port (a real robot, or ``hil-emulator`` behind a pty) starts on
a robot other programs used before: ``armctl torque on`` left the joints' torque on and the
nodes' return delay at 0, and nothing in the file says so (its ``earlier`` is unknown).
Replayed on a fresh emulator, the first PING's reply then came 0.5 ms late and collided with
the next request, and the arm hung unpowered until the recorded program's own torque write:
even against the very robot that made it, the replay parted at once.

What the recording's own replies show of each arm node's writable registers before the
recorded program wrote them is what those registers held when it started
(:func:`start_values`; the host's discovery reads the return delay for this).  Before the
first host message the replay writes those that differ from the emulator's power-up values
(:func:`writes`, EEPROM first, torque last) and lets the emulator run
:data:`SETTLE_S`: the recorded robot had been running for a while too (its phalanges
sampling, a goal reached).  A register no reply showed, or one the program wrote before any
reply showed it, is left at power-up.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Final

from hil_emulator.arm.rig import ArmRig
from hil_emulator.emulator import Emulator
from protocol.control_tables import TABLES_BY_MODEL, Register
from protocol.dynamixel import (
    DynamixelStreamDecoder,
    Instruction,
    InstructionPacket,
    make_write,
    parse_sync_write,
    parse_write,
)
from protocol.errors import DynamixelError
from protocol.topology import ARM_JOINTS, ARM_MODEL_BY_ID
from tools.hil_bench.replay.exchanges import Exchange
from tools.hil_bench.replay.source import Timed

#: Simulated time the emulator runs before a port recording's first message (s), after the
#: writes: the robot it was made on had been on for a while.
SETTLE_S: Final = 1.0
#: Between two of the writes (s): each node's answer has passed by then.
WRITE_GAP_S: Final = 0.002
#: Writable registers never written back: the node's address on the bus and its bit rate
#: (the replay talks to it at the recorded ones), and commands that read 0.
NOT_RESTORED: Final = frozenset({"id", "baud_rate", "clear_flags", "keep_alive"})
_ID_BY_JOINT: Final = {j.name: j.dxl_id for j in ARM_JOINTS}


def first_writes(tx: Iterable[Timed]) -> dict[tuple[int, int], float]:
    """When (s) the host first wrote each (bus ID, address) byte in ``tx`` (WRITE, REG_WRITE,
    SYNC_WRITE)."""
    decoder = DynamixelStreamDecoder("instruction")
    out: dict[tuple[int, int], float] = {}
    for message in tx:
        for decoded in decoder.feed(message.data):
            packet = decoded.packet
            assert isinstance(packet, InstructionPacket)
            for dxl_id, address, size in _written(packet):
                for a in range(address, address + size):
                    out.setdefault((dxl_id, a), message.t)
    return out


def _written(packet: InstructionPacket) -> list[tuple[int, int, int]]:
    """(bus ID, address, bytes) that ``packet`` writes (none for a packet that does not
    parse)."""
    try:
        if packet.instruction in (Instruction.WRITE, Instruction.REG_WRITE):
            address, data = parse_write(packet.params)
            return [(packet.id, address, len(data))]
        if packet.instruction == Instruction.SYNC_WRITE:
            address, size, entries = parse_sync_write(packet.params)
            return [(dxl_id, address, size) for dxl_id in entries]
    except DynamixelError:
        pass
    return []


def start_values(recorded: Sequence[Exchange], tx: Iterable[Timed]
                 ) -> dict[int, dict[str, int]]:
    """Per arm node (bus ID), each writable register's value as the first of ``recorded``'s
    replies to show it gave it, where the host (``tx``) had not written it before."""
    written = first_writes(tx)
    out: dict[int, dict[str, int]] = {}
    for ex in sorted(recorded, key=lambda e: e.t):
        joint = ex.prefix.removeprefix("arm.")
        dxl_id = _ID_BY_JOINT.get(joint)
        if ex.fields is None or dxl_id is None or not ex.prefix.startswith("arm."):
            continue
        table = TABLES_BY_MODEL[ARM_MODEL_BY_ID[dxl_id]]
        seen = out.setdefault(dxl_id, {})
        for name, value in ex.fields.items():
            if name in seen or name in NOT_RESTORED or name not in table:
                continue
            reg = table[name]
            if reg.writable and all(written.get((dxl_id, a), float("inf")) > ex.t
                                    for a in range(reg.address, reg.end)):
                seen[name] = int(value)
    return {k: v for k, v in out.items() if v}


def writes(values: Mapping[int, Mapping[str, int]], holds: Callable[[int, str], int]
           ) -> list[tuple[str, InstructionPacket]]:
    """The WRITEs that set ``values`` (:func:`start_values`) where they differ from what the
    node holds (``holds(bus ID, register)``, the emulator's): per node its EEPROM, then its
    RAM by address, its torque last (a goal first, then the torque that holds it); each
    with a description (``J2 torque_enable=1``)."""
    out: list[tuple[str, InstructionPacket]] = []
    names = {j.dxl_id: j.name for j in ARM_JOINTS}
    for dxl_id in sorted(values):
        table = TABLES_BY_MODEL[ARM_MODEL_BY_ID[dxl_id]]
        changed: list[Register] = [table[n] for n, v in values[dxl_id].items()
                                   if v != holds(dxl_id, n)]
        changed.sort(key=lambda r: (r.name == "torque_enable", r.area != "EEPROM", r.address))
        for reg in changed:
            value = values[dxl_id][reg.name]
            out.append((f"{names[dxl_id]} {reg.name}={value}",
                        make_write(dxl_id, reg.address, reg.encode(value))))
    return out


def held_by(emulator: Emulator, link: str) -> Callable[[int, str], int]:
    """What the emulator's arm node holds in a register: ``(bus ID, name) -> value``."""
    rig = emulator.rig(link)
    if not isinstance(rig, ArmRig):
        raise TypeError(f"link {link!r} is not the arm's")
    return lambda dxl_id, name: rig.app(dxl_id).get(name)


def rebuild(emulator: Emulator, link: str,
            packets: Sequence[tuple[str, InstructionPacket]]) -> None:
    """Send ``packets`` (:func:`writes`) on ``emulator``'s ``link`` :data:`WRITE_GAP_S` apart,
    their answers dropped, then run it :data:`SETTLE_S`."""
    rig = emulator.rig(link)
    displaced = rig.on_host_bytes
    rig.on_host_bytes = lambda data, t_us: None
    try:
        for _what, packet in packets:
            rig.send_from_host(packet.encode())
            emulator.step(int(WRITE_GAP_S * 1e6))
    finally:
        rig.on_host_bytes = displaced
    emulator.step(int(SETTLE_S * 1e6))
