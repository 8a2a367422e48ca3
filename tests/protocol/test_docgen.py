"""docs/PROTOCOL.md is generated from the declarations and must not drift from them."""

from __future__ import annotations

from pathlib import Path

from protocol import docgen
from protocol.messages import CATALOGUE, CATALOGUE_HASH

DOC = Path(__file__).resolve().parents[2] / "docs" / "PROTOCOL.md"


def test_committed_reference_matches_the_declarations() -> None:
    assert DOC.read_text(encoding="utf-8") == docgen.render(), (
        "docs/PROTOCOL.md is stale: run `make docs` and commit it"
    )


def test_reference_names_every_message_and_the_fingerprint() -> None:
    text = docgen.render()
    for msg in CATALOGUE:
        assert f"`{msg.name}` — type 0x{msg.type_id:02X}" in text
    assert CATALOGUE_HASH.hex() in text


def test_status_table_gives_offsets_and_units() -> None:
    text = docgen.render()
    section = text.split("### `fmcb.status`")[1].split("### ")[0]
    assert "| 128 | hall_pos | i32[3] | 12 | hall counts |" in section
    assert "| 110 | <pad> | pad | 2 |" in section
    assert "Total: 148 bytes." in section


def test_coded_fields_list_their_enum_members() -> None:
    text = docgen.render()
    route = text.split("### `palm.route`")[1].split("### ")[0]
    assert ("| 2 | status | u8 | 1 | - | outcome of the route; RouteStatus (0 OK, 1 NO_REPLY, "
            "2 UNPOWERED, 3 BAD_DESTINATION, 4 LINK_DOWN, 5 BUSY) |") in route
    status = text.split("### `palm.hand_status`")[1].split("### ")[0]
    assert "power: FingerPower (0 OFF, 1 LOW, 2 FULL)" in status  # a field of a nested struct
