"""Generate docs/PROTOCOL.md from the declarations (``python -m protocol.docgen``).

A test regenerates the text and fails when the committed file differs, so the reference
never drifts from the code.
"""

from __future__ import annotations

import construct as c

from protocol import control_tables
from protocol.catalogue import REPLY, REQUEST, Message, iter_fields, static_size
from protocol.enum_field import EnumField
from protocol.image import FLASH, MAX_PAYLOAD, SLOT_MAX_PAYLOAD
from protocol.messages import CATALOGUE, CATALOGUE_HASH
from protocol.messages.slots import TRIAL_TIMEOUT_US, SlotEvent, SlotState
from protocol.topology import HAND_BOARDS

_NODE_TITLES = {
    "common": "Every node (application and bootloader)",
    **{b.app: b.title for b in HAND_BOARDS},
    "bootloader": "Bootloader (every microcontroller)",
}


def _type_name(con: c.Construct) -> str:
    names = {
        c.Int8ul: "u8", c.Int16ul: "u16", c.Int32ul: "u32", c.Int8sl: "i8", c.Int16sl: "i16",
        c.Int32sl: "i32", c.Float32l: "f32",
    }
    for prim, label in names.items():
        if con is prim:
            return label
    if isinstance(con, EnumField):
        return _type_name(con.subcon)
    if isinstance(con, c.Array):
        return f"{_type_name(con.subcon)}[{con.count}]"
    if isinstance(con, c.Rebuild):
        return _type_name(con.subcon)
    if isinstance(con, c.Struct):
        return "struct{" + ", ".join(f"{n}: {_type_name(s)}" for n, s, _ in iter_fields(con)) + "}"
    if isinstance(con, c.Bytes):
        return "bytes" + (f"[{con.length}]" if isinstance(con.length, int) else "[length]")
    if con is c.GreedyBytes:
        return "bytes…"
    if isinstance(con, c.Padded):
        return "pad"
    if isinstance(con, c.StringEncoded):
        return "u8 len + ascii"
    if isinstance(con, c.Switch):
        return "by mode"
    if isinstance(con, c.Check):
        return "check"
    return type(con).__name__


def _codes(con: c.Construct, label: str = "") -> list[str]:
    """The codes of every EnumField in ``con`` (arrays and nested structs included), as
    ``"Enum (0 NAME, 1 NAME)"``, prefixed by ``"field: "`` for a field of a nested struct."""
    while isinstance(con, c.Renamed):
        con = con.subcon
    if isinstance(con, EnumField):
        codes = ", ".join(f"{int(m)} {m.name}" for m in con.enum_type)
        return [f"{label}{con.enum_type.__name__} ({codes})"]
    if isinstance(con, c.Array):
        return _codes(con.subcon, label)
    if isinstance(con, c.Struct):
        return [text for name, sub, _ in iter_fields(con) for text in _codes(sub, f"{name}: ")]
    return []


def _unit_and_doc(docs: str) -> tuple[str, str]:
    if docs.startswith("[") and "]" in docs:
        unit, rest = docs[1:].split("]", 1)
        return unit, rest.strip()
    return "", docs


def _payload_table(con: c.Construct | None) -> list[str]:
    if con is None:
        return ["(none)"]
    rows = list(iter_fields(con))
    if not rows:
        return ["empty"]
    out = ["| offset | field | type | size | unit | meaning |", "|---|---|---|---|---|---|"]
    offset: int | None = 0
    for name, sub, docs in rows:
        if isinstance(sub, c.Check):
            continue
        size = static_size(sub)
        unit, doc = _unit_and_doc(docs)
        doc = "; ".join([doc, *_codes(sub)]) if doc else "; ".join(_codes(sub))
        where = "" if offset is None else str(offset)
        out.append(
            f"| {where} | {name} | {_type_name(sub)} | {'var' if size is None else size} "
            f"| {unit} | {doc} |"
        )
        offset = None if offset is None or size is None else offset + size
    if (total := static_size(con)) is not None:
        out.append(f"\nTotal: {total} bytes.")
    return out


def _message_section(msg: Message) -> list[str]:
    tag = "" if msg.original else " (new)"
    out = [f"### `{msg.name}` — type 0x{msg.type_id:02X}{tag}", "", msg.summary, ""]
    for direction in (REQUEST, REPLY):
        con = msg.request if direction == REQUEST else msg.reply
        label = "Request (host → node)" if direction == REQUEST else "Reply (node → host, address 0)"
        out += [f"**{label}**", "", *_payload_table(con), ""]
    return out


def _control_table_section(table: control_tables.ControlTable) -> list[str]:
    out = [
        f"### {table.name} (model number {table.model_number})",
        "",
        "| address | size | access | area | name | default | unit / meaning |",
        "|---|---|---|---|---|---|---|",
    ]
    for reg in table.registers:
        out.append(
            f"| {reg.address} | {reg.size} | {reg.access} | {reg.area} | {reg.name} "
            f"| {reg.default} | {reg.unit} |"
        )
    return out + [""]


def _pages(r: range) -> str:
    return f"{r.start}–{r.stop - 1}"


_STATE_MEANING = {
    SlotState.CONFIRMED: "the primary image is the one that boots; nothing pending (also "
    "what a node flashed the one-slot way reads as)",
    SlotState.PENDING: "`slot.swap` accepted a verified secondary image; the next reset swaps",
    SlotState.SWAPPING: "the bootloader exchanges the slots; a reset or power cut at any "
    "instant resumes it",
    SlotState.TRIAL: "the new image runs once on trial; unconfirmed at the next reset or "
    "when the trial watchdog fires, it is swapped back",
    SlotState.REVERTING: "the exchange back to the previous image, resumable like SWAPPING",
}
_EVENT_MEANING = {
    SlotEvent.NONE: "nothing since the last update began",
    SlotEvent.INSTALLED: "a swap finished; the new image runs on trial",
    SlotEvent.CONFIRMED: "the trial image was confirmed (host or application)",
    SlotEvent.REVERTED: "the trial image was not confirmed (reset, crash, trial watchdog, "
    "or it did not verify after the swap): the previous image is back",
    SlotEvent.REFUSED: "the pending image no longer verified at the reset: nothing swapped",
}


def _slots_section() -> list[str]:
    """The two-slot flash layout and how an update proceeds."""
    status = ", ".join(str(p) for p in FLASH.swap_status_pages)
    out = [
        "## Firmware update with two image slots",
        "",
        f"Flash of every finger MCU: {FLASH.page_count} pages of {FLASH.page_size} B.",
        "",
        "| pages | what |",
        "|---|---|",
        f"| {_pages(FLASH.bootloader_pages)} | bootloader, key record (page {FLASH.key_page}), "
        "identity (end of page 31); locked |",
        f"| {_pages(FLASH.primary_slot)} | primary slot: the image that runs (header on page "
        f"{FLASH.header_page}) |",
        f"| {_pages(FLASH.secondary_slot)} | secondary slot: where a new image is written |",
        f"| {_pages(FLASH.scratch)} | scratch: one chunk of the primary during a swap |",
        f"| {FLASH.param_page} | parameters (kept across updates) |",
        f"| {FLASH.boot_control_page} | activation record of the primary image |",
        f"| {status} | swap status: two records written alternately (sequence number, "
        "CRC-32) |",
        "",
        f"An image of at most {SLOT_MAX_PAYLOAD} payload bytes fits a slot.  The one-slot way "
        f"(`bl.write_page` from page {FLASH.header_page}, then `bl.activate` or `bl.boot`) "
        f"still burns the primary slot with images of up to {MAX_PAYLOAD} bytes; it forgets "
        "any update in progress first, and a node whose running image runs on into the "
        "secondary slot refuses `slot.write` (PAGE_PROTECTED).  A node with an older, "
        "one-slot bootloader answers no `slot.*` message.",
        "",
        "An update, while the application keeps running:",
        "",
        "1. `slot.write` each page of the new image into the secondary slot (through "
        "`palm.route` and the fmcb tunnel for f2/f3, like any request); the header page is "
        "refused first if the image is for another board, too large for a slot, or not "
        "signed with the node's key.",
        "2. `slot.hash` the written pages on the node and compare with the file's hash; its "
        "`image_status` is the verdict the swap will apply.",
        "3. `slot.swap` with the payload SHA-256 and who confirms: the node verifies the image "
        "(header, board, size, payload hash, signature where provisioned), records PENDING, "
        "acknowledges and resets.  The bootloader verifies it again, exchanges the slots "
        "(only the pages either image occupies, a chunk of scratch pages at a time) and "
        "boots the new image at once, on trial, with no autoboot window: the node is down "
        "for that one reboot.",
        f"4. Within {TRIAL_TIMEOUT_US / 1e6:g} s (the trial watchdog), `slot.confirm` from the "
        "host after its checks, or the application itself after its health check when the "
        "swap asked for APPLICATION, makes the new image the confirmed one.  Otherwise (a "
        "reset, a crash, the watchdog) the next boot swaps the previous image back and "
        "`slot.info` reports REVERTED.  After a confirmed update the secondary slot holds "
        "the previous image: `slot.swap` of it is a rollback.",
        "",
        "| state | meaning |",
        "|---|---|",
        *(f"| {int(k)} {k.name} | {v} |" for k, v in _STATE_MEANING.items()),
        "",
        "| event | meaning |",
        "|---|---|",
        *(f"| {int(k)} {k.name} | {v} |" for k, v in _EVENT_MEANING.items()),
        "",
    ]
    return out


def render() -> str:
    """The whole of docs/PROTOCOL.md as text."""
    out = [
        "# Protocol reference",
        "",
        "Generated by `python -m protocol.docgen` from the declarations in `protocol/`; "
        "do not edit by hand (`make docs` regenerates it, and a test fails when it is stale).",
        "",
        "## Hand frames",
        "",
        "`42 | address | length u16 LE | type | payload | CRC-16/XMODEM u16 LE` — the CRC covers "
        "sync through payload. Addresses: host 0, f2 1, f3 2, fmcb and palm 10, broadcast 0xFF. "
        "Replies go to address 0 with the request's type. All multi-byte fields are "
        "little-endian.",
        "",
        f"Catalogue fingerprint (identify reply): `{CATALOGUE_HASH.hex()}`; "
        f"{len(CATALOGUE)} messages.",
        "",
        "On CAN (palm host link): each hand frame is cut into CAN 2.0A frames of ≤ 8 data bytes "
        "with identifier 0x100 + node (to the node) or 0x180 + node (to the host), and "
        "reassembled with the serial stream decoder.",
        "",
    ]
    for node, title in _NODE_TITLES.items():
        msgs = [m for m in CATALOGUE if m.node == node]
        out += [f"## {title}", ""]
        for msg in msgs:
            out += _message_section(msg)
    out += _slots_section()
    out += ["## Arm bus: Dynamixel 1.0 control tables", ""]
    for table in (control_tables.RX64_TABLE, control_tables.STEPPER_TABLE):
        out += _control_table_section(table)
    return "\n".join(out).rstrip() + "\n"


def main() -> None:
    """Print the reference to standard output."""
    print(render(), end="")


if __name__ == "__main__":
    main()
