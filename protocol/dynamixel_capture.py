"""Describe a Dynamixel 1.0 capture of the arm bus in plain dicts (for ``handbus``).

Register names come from this arm's control tables, by the model each id has
(:data:`protocol.topology.ARM_JOINTS`: ids 1–4 stepper nodes, 5–7 RX-64 servos).  Status packets
(replies) are named by the instruction they most likely answer: the last instruction seen
for that id.
"""

from __future__ import annotations

from typing import Any

from protocol.control_tables import TABLES_BY_MODEL, ControlTable
from protocol.dynamixel import (
    BROADCAST_ID,
    DynamixelStreamDecoder,
    ErrorBit,
    Instruction,
    InstructionPacket,
    StatusPacket,
    parse_read,
    parse_sync_write,
    parse_write,
)
from protocol.errors import DynamixelError
from protocol.topology import ARM_MODEL_BY_ID


def table_for_id(dxl_id: int) -> ControlTable | None:
    """The control table of an arm bus id (None for ids this arm does not use)."""
    model = ARM_MODEL_BY_ID.get(dxl_id)
    return None if model is None else TABLES_BY_MODEL[model]


def _register_name(dxl_id: int, address: int) -> str | None:
    table = table_for_id(dxl_id)
    if table is None:
        return None
    reg = table.covering(address)
    return reg.name if reg is not None else None


def _instruction_fields(pkt: InstructionPacket) -> dict[str, Any]:
    params = bytes(pkt.params)
    try:
        if pkt.instruction == Instruction.READ:
            address, length = parse_read(params)
            return {"address": address, "register": _register_name(pkt.id, address),
                    "length": length}
        if pkt.instruction in (Instruction.WRITE, Instruction.REG_WRITE):
            address, data = parse_write(params)
            return {"address": address, "register": _register_name(pkt.id, address),
                    "data": data}
        if pkt.instruction == Instruction.SYNC_WRITE:
            address, length, per_id = parse_sync_write(params)
            return {"address": address, "length": length,
                    "data": {str(k): v for k, v in per_id.items()}}
    except DynamixelError as exc:
        return {"error": str(exc), "params": params}
    return {"params": params} if params else {}


def decode_dynamixel_capture(data: bytes, direction: str = "auto"
                             ) -> tuple[list[dict[str, Any]], dict[str, int]]:
    """One record per packet found in ``data``, and the decoder's counters.

    A candidate whose checksum failed is a record too, in stream order, with
    ``checksum_ok: false``, no kind, name or fields, and its ``raw`` bytes.
    """
    decoder = DynamixelStreamDecoder(direction=direction,  # type: ignore[arg-type]
                                     report_bad_checksums=True)
    records: list[dict[str, Any]] = []
    last_instruction: dict[int, str] = {}
    for found in decoder.feed(data):
        pkt = found.packet
        record: dict[str, Any] = {"offset": found.offset, "id": pkt.id, "length": len(found.raw),
                                  "checksum_ok": True}
        if isinstance(pkt, InstructionPacket):
            try:
                name = Instruction(pkt.instruction).name
            except ValueError:
                name = None
            record.update(kind="instruction", name=name, fields=_instruction_fields(pkt))
            if name and pkt.id != BROADCAST_ID:
                last_instruction[pkt.id] = name
        elif isinstance(pkt, StatusPacket):
            errors = [bit.name for bit in ErrorBit if pkt.error & bit]
            record.update(kind="status", name=last_instruction.get(pkt.id),
                          fields={"error": pkt.error, "errors": errors, "params": pkt.params})
        records.append(record)
    if decoder.bad_checksums:
        records.extend({"offset": bad.offset, "id": bad.raw[2], "length": len(bad.raw),
                        "checksum_ok": False, "kind": None, "name": None, "fields": None,
                        "raw": bad.raw} for bad in decoder.bad_checksums)
        records.sort(key=lambda record: record["offset"])
    counters = {
        "packets": decoder.packets,
        "checksum_failures": decoder.checksum_failures,
        "resyncs": decoder.resyncs,
        "bytes_discarded": decoder.bytes_discarded,
        "rejected": decoder.rejected,
        "pending": decoder.pending,
    }
    return records, counters
