"""Tests of protocol.canlink: hand frames cut into CAN 2.0A frames and put back together."""

from __future__ import annotations

import random

import pytest
from hypothesis import given
from hypothesis import strategies as st

from protocol.canlink import (
    CAN_MAX_DATA,
    DEFAULT_PALM_NODE,
    MAX_NODE,
    TO_HOST_BASE,
    TO_NODE_BASE,
    CanId,
    CanReassembler,
    can_id,
    parse_can_id,
    segment,
)
from protocol.errors import FrameError
from protocol.framing import encode_frame
from protocol.stream import StreamDecoder

PING = bytes([0x42, 0x0A, 0x00, 0x00, 0x01, 0x61, 0x2D])
#: fmcb.status reply (148 zero bytes) to the host: 155 bytes, 20 CAN frames.
STATUS = encode_frame(0, 0x21, bytes(148))


def test_identifiers() -> None:
    assert (TO_NODE_BASE, TO_HOST_BASE, MAX_NODE, CAN_MAX_DATA) == (0x100, 0x180, 0x7F, 8)
    assert can_id(DEFAULT_PALM_NODE, to_host=False) == 0x10A
    assert can_id(DEFAULT_PALM_NODE, to_host=True) == 0x18A
    assert can_id(0, False) == 0x100
    assert can_id(0x7F, True) == 0x1FF
    for bad in (-1, 0x80, 0x100):
        with pytest.raises(FrameError):
            can_id(bad, False)


def test_parse_identifiers() -> None:
    assert parse_can_id(0x10A) == CanId(to_host=False, node=0x0A)
    assert parse_can_id(0x18A) == CanId(to_host=True, node=0x0A)
    assert parse_can_id(0x100) == CanId(False, 0)
    assert parse_can_id(0x1FF) == CanId(True, 0x7F)
    for other in (0x0FF, 0x200, 0x7FF, 0):
        assert parse_can_id(other) is None


@given(st.integers(0, MAX_NODE), st.booleans())
def test_identifier_round_trip(node: int, to_host: bool) -> None:
    assert parse_can_id(can_id(node, to_host)) == CanId(to_host, node)
    assert can_id(node, to_host) < 0x800  # 11 bits


def test_segment() -> None:
    assert segment(PING) == [PING]
    parts = segment(STATUS)
    assert len(parts) == 20
    assert all(len(p) == 8 for p in parts[:-1])
    assert len(parts[-1]) == 155 - 19 * 8
    assert b"".join(parts) == STATUS
    assert segment(b"") == []
    assert segment(bytes(16)) == [bytes(8), bytes(8)]


def test_reassemble_one_frame() -> None:
    rx = CanReassembler()
    ident = can_id(DEFAULT_PALM_NODE, to_host=True)
    frames = []
    for i, part in enumerate(segment(STATUS)):
        got = rx.feed(ident, part, t=i * 1e-4)
        if i < 19:
            assert got == []
        frames += got
    assert len(frames) == 1
    assert (frames[0].address, frames[0].type, frames[0].payload) == (0, 0x21, bytes(148))
    assert frames[0].to_bytes() == STATUS


def test_more_than_8_bytes_is_rejected() -> None:
    rx = CanReassembler()
    with pytest.raises(FrameError):
        rx.feed(0x10A, bytes(9))
    assert rx.feed(0x10A, bytes(8)) == []  # 8 is fine


def test_lost_can_frame_is_recovered_by_the_gap_rule() -> None:
    rx = CanReassembler(gap_s=0.010)
    ident = can_id(3, to_host=True)
    parts = segment(STATUS)
    t = 0.0
    for i, part in enumerate(parts):
        if i == 5:
            continue  # lost on the bus
        assert rx.feed(ident, part, t=t) == []
        t += 1e-4
    # the next frame arrives after a quiet gap: the partial one is dropped, this one decodes
    t += 0.02
    frames = []
    for part in segment(PING):
        frames += rx.feed(ident, part, t=t)
    assert [f.to_bytes() for f in frames] == [PING]
    assert rx.decoder(ident).counters.gap_discards == 1


def test_lost_can_frame_without_the_gap_rule_swallows_the_next_frame() -> None:
    rx = CanReassembler(gap_s=None)
    ident = can_id(3, to_host=True)
    for i, part in enumerate(segment(STATUS)):
        if i != 5:
            rx.feed(ident, part, t=i * 1e-4)
    assert rx.feed(ident, PING, t=1.0) == []


def test_interleaved_identifiers_reassemble_independently() -> None:
    rx = CanReassembler()
    to_host = {n: encode_frame(0, 0x21, bytes([n]) * 148) for n in (1, 2, 3)}
    to_node = encode_frame(10, 0x1F, bytes(range(40)))
    streams = {can_id(n, True): segment(w) for n, w in to_host.items()}
    streams[can_id(1, False)] = segment(to_node)
    got: dict[int, list[bytes]] = {ident: [] for ident in streams}
    t = 0.0
    # round-robin: one CAN frame of each identifier in turn
    for i in range(max(len(p) for p in streams.values())):
        for ident, parts in streams.items():
            if i < len(parts):
                got[ident] += [f.to_bytes() for f in rx.feed(ident, parts[i], t=t)]
                t += 1e-5
    for n, wire in to_host.items():
        assert got[can_id(n, True)] == [wire]
    assert got[can_id(1, False)] == [to_node]
    assert isinstance(rx.decoder(can_id(2, True)), StreamDecoder)
    assert rx.decoder(can_id(2, True)) is rx.decoder(can_id(2, True))


@given(
    st.lists(
        st.tuples(st.sampled_from([0x10A, 0x18A, 0x181]),
                  st.builds(encode_frame, st.integers(0, 255), st.integers(0, 255),
                            st.binary(max_size=60))),
        max_size=8,
    ),
    st.randoms(use_true_random=False),
)
def test_any_interleaving_reassembles(
    frames: list[tuple[int, bytes]], rnd: random.Random
) -> None:
    # each identifier's CAN frames stay in order; identifiers interleave at random
    queues: dict[int, list[bytes]] = {}
    for ident, wire in frames:
        queues.setdefault(ident, []).extend(segment(wire))
    rx = CanReassembler()
    got: dict[int, list[bytes]] = {ident: [] for ident in queues}
    pending = [ident for ident, q in queues.items() for _ in q]
    rnd.shuffle(pending)
    positions = dict.fromkeys(queues, 0)
    for ident in pending:
        part = queues[ident][positions[ident]]
        positions[ident] += 1
        got[ident] += [f.to_bytes() for f in rx.feed(ident, part)]
    for ident in queues:
        assert got[ident] == [w for i, w in frames if i == ident]
