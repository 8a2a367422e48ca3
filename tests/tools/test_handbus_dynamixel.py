"""handbus decode --dynamixel on an arm-bus capture (golden packets written by hand)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tools.cli import handbus

# WRITE id 5, goal position (address 30) = 0x0200: FF FF 05 05 03 1E 00 02 CHK
# CHK = ~(05 + 05 + 03 + 1E + 00 + 02) = ~0x2D = 0xD2
WRITE_GOAL = bytes.fromhex("FFFF0505031E0002D2")
# status of id 5, no error, no params: ~(05 + 02 + 00) = ~0x07 = 0xF8
STATUS_OK = bytes.fromhex("FFFF050200F8")
# READ id 2, step_count (address 40 = 0x28), 4 bytes: ~(02 + 04 + 02 + 28 + 04) = ~0x34 = 0xCB
READ_STEPS = bytes.fromhex("FFFF0204022804CB")
# status of id 2 with OVERLOAD (0x20) and 01 02 03 04: ~(02+06+20+01+02+03+04) = ~0x32 = 0xCD
STATUS_OVERLOAD = bytes.fromhex("FFFF02062001020304CD")


def run(tmp_path: Path, data: bytes, capsys: pytest.CaptureFixture[str]) -> list[dict]:
    path = tmp_path / "arm.bin"
    path.write_bytes(data)
    assert handbus.main(["decode", "--dynamixel", str(path)]) == 0
    return [json.loads(line) for line in capsys.readouterr().out.splitlines()]


def test_arm_capture_names_registers_and_errors(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    noise = b"\x13\x37"
    records = run(tmp_path, WRITE_GOAL + noise + STATUS_OK + READ_STEPS + STATUS_OVERLOAD,
                  capsys)
    *packets, summary = records
    assert [p["kind"] for p in packets] == ["instruction", "status", "instruction", "status"]
    assert packets[0]["fields"] == {"address": 30, "register": "goal_position", "data": "0002"}
    assert packets[1]["offset"] == len(WRITE_GOAL) + len(noise)
    assert packets[2]["fields"]["register"] == "step_count"
    assert packets[3]["name"] == "READ"
    assert packets[3]["fields"]["errors"] == ["OVERLOAD"]
    assert summary["summary"]["packets"] == 4
    assert summary["summary"]["bytes_discarded"] == len(noise)


def test_corrupted_packet_is_printed_as_a_checksum_failure(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = bytearray(READ_STEPS)
    bad[5] ^= 0x01  # 28 -> 29: FF FF 02 04 02 29 04 CB, checksum no longer matches
    records = run(tmp_path, STATUS_OK + bytes(bad) + WRITE_GOAL, capsys)
    *packets, summary = records
    assert [(p["offset"], p["id"], p["checksum_ok"]) for p in packets] == [
        (0, 5, True), (len(STATUS_OK), 2, False), (len(STATUS_OK) + len(bad), 5, True)]
    failed = packets[1]
    assert failed == {"offset": 6, "id": 2, "length": 8, "checksum_ok": False, "kind": None,
                      "name": None, "fields": None, "raw": "ffff0204022904cb"}
    assert summary["summary"]["checksum_failures"] == 1
    assert summary["summary"]["packets"] == 2


def test_checksum_failures_are_kept_only_when_asked() -> None:
    from protocol.dynamixel import DynamixelStreamDecoder

    bad = READ_STEPS[:-1] + bytes([READ_STEPS[-1] ^ 0xFF])
    quiet = DynamixelStreamDecoder()
    quiet.feed(bad)
    assert (quiet.checksum_failures, quiet.bad_checksums) == (1, [])
    loud = DynamixelStreamDecoder(report_bad_checksums=True)
    assert loud.feed(b"\x00" + bad[:4]) == []
    loud.feed(bad[4:] + WRITE_GOAL, t=1.5)
    assert [(b.offset, b.raw, b.t) for b in loud.bad_checksums] == [(1, bad, 1.5)]
