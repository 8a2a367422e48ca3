"""HandNode, the base of every hand-protocol program: addressing, dispatch, common messages."""

from __future__ import annotations

from typing import Any

import pytest

from firmware_py.hal import Hal
from firmware_py.hand_node import (
    DEFERRED,
    FRAME_GAP_US,
    HandNode,
    Request,
)
from firmware_py.identity import default_identity
from firmware_py.scheduler import Scheduler
from firmware_py.sim.boards import make_hal
from firmware_py.sim.virtual_hal import VirtualHal
from protocol.framing import Frame, encode_frame
from protocol.image import BoardType
from protocol.messages import CATALOGUE, CATALOGUE_HASH
from protocol.messages.common import TxnStatus
from protocol.stream import decode_all
from protocol.topology import ADDR_BROADCAST

ADDR = 10  # every fmcb
UID = 0x12345678
TXN = CATALOGUE["txn"]


class TinyNode(HandNode):
    """A minimal program: two fmcb messages handled, one answered later, one without reply."""

    node_kind = "fmcb"
    FW_VERSION = (2, 7, 300)

    def __init__(self, hal: Hal) -> None:
        super().__init__(hal)
        self.caps: list[int] = []
        self.handle("fmcb.temperatures", lambda req: {"temp": [250, 251, 252]})
        self.handle("fmcb.effort_cap", self._on_cap)
        self.handle("fmcb.phalange_power", self._on_power_later)

    def _on_cap(self, req: Request) -> None:
        self.caps.append(req.fields["cap"])
        return None

    def _on_power_later(self, req: Request) -> Any:
        self.hal.clock.call_later(1_000, lambda: req.respond({}))
        return DEFERRED


@pytest.fixture
def rig() -> tuple[Scheduler, VirtualHal, TinyNode]:
    scheduler = Scheduler()
    hal = make_hal(scheduler, BoardType.FMCB, default_identity(BoardType.FMCB, UID))
    node = TinyNode(hal)
    node.listen(hal.uart("pogo"))
    return scheduler, hal, node


def deliver(hal: VirtualHal, address: int, msg_type: int, payload: bytes = b"") -> None:
    hal.uart("pogo").deliver(encode_frame(address, msg_type, payload))


def replies(scheduler: Scheduler, hal: VirtualHal, run_us: int = 500) -> list[Frame]:
    scheduler.run_for(run_us)
    return decode_all(b"".join(hal.uart("pogo").take_sent()))


def txn(scheduler: Scheduler, hal: VirtualHal, seq: int, inner_type: int, inner: bytes = b"",
        address: int = ADDR) -> dict[str, Any]:
    deliver(hal, address, TXN.type_id, TXN.build_request(seq=seq, inner_type=inner_type,
                                                          inner=inner))
    (frame,) = replies(scheduler, hal)
    assert frame.type == TXN.type_id and frame.address == 0
    return TXN.parse_reply(frame.payload)


# --- common messages ----------------------------------------------------------------------
def test_ping_gets_an_empty_reply_to_the_host(rig: Any) -> None:
    scheduler, hal, node = rig
    deliver(hal, ADDR, 0x01)
    frames = replies(scheduler, hal)
    assert [(f.address, f.type, f.payload) for f in frames] == [(0, 0x01, b"")]
    assert node.counters.replies == 1 and node.counters.frames == 1


def test_hw_version_golden_bytes(rig: Any) -> None:
    scheduler, hal, _node = rig
    deliver(hal, ADDR, 0xFA)
    scheduler.run_for(500)
    raw = b"".join(hal.uart("pogo").take_sent())
    # sync, host address, length 4, type 0xFA, 0xBEEF0041 LE, then the CRC
    assert raw[:9] == bytes.fromhex("42 00 0400 fa 4100efbe")
    assert len(raw) == 11
    assert decode_all(raw)[0].payload == bytes.fromhex("4100efbe")


def test_identify_reports_who_and_the_catalogue_fingerprint(rig: Any) -> None:
    scheduler, hal, _node = rig
    scheduler.run_until(7_000)
    deliver(hal, ADDR, CATALOGUE["identify"].type_id)
    (frame,) = replies(scheduler, hal)
    ident = CATALOGUE["identify"].parse_reply(frame.payload)
    assert ident == {
        "board": int(BoardType.FMCB),
        "address": ADDR,
        "running": 1,
        "hw_version": 0xBEEF0041,
        "fw_version": {"major": 2, "minor": 7, "patch": 300},
        "catalogue": CATALOGUE_HASH,
        "uid": UID,
        "uptime_us": 7_000,
    }


def test_reset_acknowledges_then_resets(rig: Any) -> None:
    scheduler, hal, _node = rig
    reset_at: list[int] = []
    hal.on_reset = lambda: reset_at.append(scheduler.now_us())
    deliver(hal, ADDR, 0x09)
    assert hal.resets == 0  # not before the acknowledgement has gone
    scheduler.run_for(1_000)
    (ack,) = hal.uart("pogo").sent
    assert decode_all(ack.data)[0].type == 0x09
    assert hal.resets == 1 and len(reset_at) == 1
    assert ack.end_us <= reset_at[0]


# --- addressing -------------------------------------------------------------------------
def test_frames_for_other_addresses_are_ignored(rig: Any) -> None:
    scheduler, hal, node = rig
    for address in (0, 1, 2, 11):
        deliver(hal, address, 0x01)
        deliver(hal, address, 0x23, b"\x80")
    assert replies(scheduler, hal) == []
    assert node.counters.not_for_me == 8 and node.counters.frames == 0
    assert node.caps == []


def test_broadcast_is_handled_but_not_answered(rig: Any) -> None:
    scheduler, hal, node = rig
    deliver(hal, ADDR_BROADCAST, 0x23, b"\x40")
    deliver(hal, ADDR_BROADCAST, 0x01)
    deliver(hal, ADDR_BROADCAST, TXN.type_id, TXN.build_request(seq=1, inner_type=1, inner=b""))
    assert replies(scheduler, hal) == []
    assert node.caps == [0x40]
    assert node.counters.frames == 3 and node.counters.replies == 0


def test_unknown_type_and_bad_payload_are_dropped_and_counted(rig: Any) -> None:
    scheduler, hal, node = rig
    deliver(hal, ADDR, 0x77)  # means nothing on an fmcb
    deliver(hal, ADDR, CATALOGUE["fmcb.status"].type_id)  # known, but no handler here
    deliver(hal, ADDR, 0x22, b"\x00")  # temperatures take no payload
    deliver(hal, ADDR, 0x23, b"")  # effort cap needs one byte
    assert replies(scheduler, hal) == []
    assert node.counters.unknown_type == 2 and node.counters.bad_payload == 2
    assert node.caps == []


def test_deferred_reply_comes_when_the_handler_responds(rig: Any) -> None:
    scheduler, hal, _node = rig
    deliver(hal, ADDR, 0x1E, b"\x01")
    assert replies(scheduler, hal, 900) == []
    (frame,) = replies(scheduler, hal, 200)
    assert (frame.type, frame.payload) == (0x1E, b"")


def test_partial_frame_dropped_after_the_gap(rig: Any) -> None:
    scheduler, hal, _node = rig
    frame = encode_frame(ADDR, 0x01)
    uart = hal.uart("pogo")
    uart.deliver(frame[:4])
    scheduler.run_for(FRAME_GAP_US + 1_000)
    uart.deliver(frame[4:])
    assert replies(scheduler, hal) == []
    uart.deliver(frame[:3])  # split within the gap: reassembled
    scheduler.run_for(100)
    uart.deliver(frame[3:])
    assert [f.type for f in replies(scheduler, hal)] == [0x01]


def test_corrupted_frame_is_ignored(rig: Any) -> None:
    scheduler, hal, node = rig
    bad = bytearray(encode_frame(ADDR, 0x01))
    bad[-1] ^= 0x55
    hal.uart("pogo").deliver(bytes(bad))
    assert replies(scheduler, hal) == []
    assert node.counters.frames == 0


# --- transaction envelope ---------------------------------------------------------------
def test_txn_wraps_a_reply_and_echoes_the_sequence(rig: Any) -> None:
    scheduler, hal, _node = rig
    for seq in (0, 7, 255):
        reply = txn(scheduler, hal, seq, 0x22)
        assert reply == {"seq": seq, "board": int(BoardType.FMCB), "address": ADDR,
                         "inner_type": 0x22, "status": TxnStatus.OK,
                         "inner": bytes.fromhex("fa00 fb00 fc00")}
    assert txn(scheduler, hal, 3, 0x01) == {"seq": 3, "board": int(BoardType.FMCB),
                                            "address": ADDR, "inner_type": 0x01,
                                            "status": TxnStatus.OK, "inner": b""}


def test_txn_golden_bytes(rig: Any) -> None:
    scheduler, hal, _node = rig
    # Request by hand: seq 0x2A, inner type 0xFA, no inner payload.
    deliver(hal, ADDR, 0x61, bytes.fromhex("2a fa"))
    scheduler.run_for(500)
    (frame,) = decode_all(b"".join(hal.uart("pogo").take_sent()))
    # seq, board 2 (fmcb), address 10, inner type, status 0, then hw_version 0xBEEF0041 LE
    assert frame.payload == bytes.fromhex("2a 02 0a fa 00 4100efbe")


def test_txn_error_statuses(rig: Any) -> None:
    scheduler, hal, node = rig
    unknown = txn(scheduler, hal, 1, 0x77)
    assert (unknown["status"], unknown["inner"]) == (TxnStatus.UNKNOWN_TYPE, b"")
    no_handler = txn(scheduler, hal, 2, CATALOGUE["fmcb.status"].type_id)
    assert no_handler["status"] == TxnStatus.UNKNOWN_TYPE
    bad = txn(scheduler, hal, 3, 0x22, b"\x01\x02")
    assert (bad["seq"], bad["status"], bad["inner"]) == (3, TxnStatus.BAD_PAYLOAD, b"")
    nested = txn(scheduler, hal, 4, TXN.type_id, TXN.build_request(seq=5, inner_type=1, inner=b""))
    assert (nested["seq"], nested["status"]) == (4, TxnStatus.REFUSED)
    assert node.counters.unknown_type == 2 and node.counters.bad_payload == 1


def test_txn_acknowledges_a_message_without_reply(rig: Any) -> None:
    scheduler, hal, node = rig
    reply = txn(scheduler, hal, 9, 0x23, b"\x99")
    assert (reply["seq"], reply["inner_type"], reply["status"], reply["inner"]) == (
        9, 0x23, TxnStatus.OK, b"")
    assert node.caps == [0x99]


def test_txn_carries_a_deferred_reply(rig: Any) -> None:
    scheduler, hal, _node = rig
    deliver(hal, ADDR, TXN.type_id, TXN.build_request(seq=17, inner_type=0x1E, inner=b"\x01"))
    assert replies(scheduler, hal, 900) == []
    (frame,) = replies(scheduler, hal, 200)
    reply = TXN.parse_reply(frame.payload)
    assert (reply["seq"], reply["inner_type"], reply["status"]) == (17, 0x1E, TxnStatus.OK)


def test_txn_to_another_address_is_ignored(rig: Any) -> None:
    scheduler, hal, node = rig
    deliver(hal, 1, TXN.type_id, TXN.build_request(seq=1, inner_type=1, inner=b""))
    assert replies(scheduler, hal) == []
    assert node.counters.not_for_me == 1
