"""Tests of protocol.stream.StreamDecoder: chunking, counters, resync, gap rule, flush."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.framing import (
    BAD_CRC,
    BAD_LENGTH,
    DEFAULT_MAX_PAYLOAD,
    FRAME,
    NEED_MORE,
    OVERHEAD,
    SKIP,
    Frame,
    check_frame,
    encode_frame,
)
from protocol.stream import DecoderCounters, StreamDecoder, decode_all

# Golden frames written by hand (see test_framing.py for their CRCs).
PING = bytes([0x42, 0x0A, 0x00, 0x00, 0x01, 0x61, 0x2D])
POWER_ON = bytes([0x42, 0x0A, 0x01, 0x00, 0x1E, 0x01, 0x17, 0xE1])
HW_REPLY = bytes([0x42, 0x00, 0x04, 0x00, 0xFA, 0x41, 0x00, 0xEF, 0xBE, 0x31, 0x7F])

#: POWER_ON with the last CRC byte flipped: no 0x42 anywhere but the sync byte.
POWER_ON_BAD_CRC = POWER_ON[:-1] + bytes([POWER_ON[-1] ^ 0x01])
#: A header promising 0x40 payload bytes (a false sync, or a frame whose tail was lost).
LONG_PROMISE = bytes([0x42, 0x0A, 0x40, 0x00, 0x01])


def split_at(data: bytes, cuts: list[int]) -> list[bytes]:
    points = sorted({min(max(cut, 0), len(data)) for cut in cuts})
    out, prev = [], 0
    for point in points:
        out.append(data[prev:point])
        prev = point
    out.append(data[prev:])
    return out


def triple(frame: Frame) -> tuple[int, int, bytes]:
    return frame.address, frame.type, frame.payload


def feed_all(dec: StreamDecoder, chunks: list[bytes], t: float | None = None) -> list[Frame]:
    out: list[Frame] = []
    for chunk in chunks:
        out += dec.feed(chunk, t)
    return out


# --- chunking ---------------------------------------------------------------------------------

STREAM = PING + HW_REPLY + POWER_ON
EXPECTED = [(10, 1, b""), (0, 0xFA, bytes([0x41, 0x00, 0xEF, 0xBE])), (10, 0x1E, b"\x01")]


def test_one_chunk() -> None:
    dec = StreamDecoder()
    frames = dec.feed(STREAM)
    assert [triple(f) for f in frames] == EXPECTED
    assert [f.offset for f in frames] == [0, 7, 18]
    assert all(f.crc_ok for f in frames)
    assert dec.pending == 0


def test_every_single_split_point() -> None:
    for i in range(len(STREAM) + 1):
        dec = StreamDecoder()
        frames = feed_all(dec, [STREAM[:i], STREAM[i:]])
        assert [triple(f) for f in frames] == EXPECTED, i
        assert [f.offset for f in frames] == [0, 7, 18]
        assert dec.counters.frames == 3
        assert dec.counters.bytes_discarded == 0


def test_every_pair_of_split_points() -> None:
    n = len(STREAM)
    for i in range(n + 1):
        for j in range(i, n + 1):
            dec = StreamDecoder()
            frames = feed_all(dec, [STREAM[:i], STREAM[i:j], STREAM[j:]])
            assert [triple(f) for f in frames] == EXPECTED, (i, j)


def test_byte_at_a_time_frames_complete_on_their_last_byte() -> None:
    dec = StreamDecoder()
    completed_at = []
    for i, byte in enumerate(STREAM):
        frames = dec.feed(bytes([byte]), t=i * 1e-4)
        if frames:
            assert len(frames) == 1
            assert frames[0].t == pytest.approx(i * 1e-4)
            completed_at.append(i)
    assert completed_at == [6, 17, 25]


def test_pending_and_reset() -> None:
    dec = StreamDecoder()
    assert dec.feed(PING[:4]) == []
    assert dec.pending == 4
    dec.reset()
    assert dec.pending == 0
    assert dec.counters.bytes_discarded == 4
    frames = dec.feed(PING)
    assert [f.offset for f in frames] == [4]  # offsets keep counting across a reset


# --- counters -------------------------------------------------------------------------------


def test_counters_of_a_mixed_stream() -> None:
    bad_length = bytes([0x42, 0x0A, 0xFF, 0xFF, 0x01])
    tail = bytes([0x42, 0x0A, 0x05])
    stream = b"\x00\x01" + PING + POWER_ON_BAD_CRC + bad_length + PING + tail
    dec = StreamDecoder()
    frames = dec.feed(stream)
    assert [triple(f) for f in frames] == [(10, 1, b""), (10, 1, b"")]
    assert [f.offset for f in frames] == [2, 2 + 7 + 8 + 5]
    assert dec.pending == 3
    assert dec.flush() == []
    assert dec.counters == DecoderCounters(
        frames=2,
        crc_failures=1,
        length_errors=1,
        resyncs=3,  # bad CRC, bad length, the truncated tail's sync at flush
        bytes_in=len(stream),
        bytes_discarded=2 + 8 + 5 + 3,
        gap_discards=0,
        truncated=1,
    )
    assert dec.counters.as_dict()["bytes_in"] == 32
    assert set(dec.counters.as_dict()) == {
        "frames", "crc_failures", "length_errors", "resyncs", "bytes_in", "bytes_discarded",
        "gap_discards", "truncated",
    }


def test_counters_start_at_zero() -> None:
    assert all(v == 0 for v in StreamDecoder().counters.as_dict().values())


# --- CRC failure and resync -----------------------------------------------------------------


def test_good_frame_inside_a_corrupted_frame_is_recovered() -> None:
    # An outer frame whose payload is a complete good frame, with a wrong CRC.
    outer = encode_frame(10, 0x1F, PING)
    outer = outer[:-2] + bytes([outer[-2] ^ 0xFF, outer[-1]])
    dec = StreamDecoder()
    frames = dec.feed(outer)
    assert [triple(f) for f in frames] == [(10, 1, b"")]
    assert frames[0].offset == 5
    assert dec.counters.crc_failures == 1


def test_frame_after_a_frame_that_lost_its_tail() -> None:
    # A header promising 16 bytes, 3 of them arrived, then three good frames.
    lost = bytes([0x42, 0x0A, 0x10, 0x00, 0x01, 0x11, 0x12, 0x13])
    stream = lost + PING + PING + PING
    dec = StreamDecoder()
    frames = dec.feed(stream)
    assert [f.offset for f in frames] == [8, 15, 22]
    assert dec.counters.crc_failures == 1
    assert dec.counters.bytes_discarded == len(lost)


def test_report_rejected_yields_crc_failed_candidates() -> None:
    dec = StreamDecoder(report_rejected=True)
    frames = dec.feed(PING + POWER_ON_BAD_CRC + HW_REPLY)
    assert [(f.crc_ok, f.offset) for f in frames] == [(True, 0), (False, 7), (True, 15)]
    rejected = frames[1]
    assert triple(rejected) == (10, 0x1E, b"\x01")
    assert dec.counters.crc_failures == 1
    assert dec.counters.frames == 2  # rejected candidates are not counted as frames


def test_report_rejected_still_rescans_inside() -> None:
    outer = encode_frame(0, 0x1F, HW_REPLY)
    outer = outer[:-1] + bytes([outer[-1] ^ 0x01])
    dec = StreamDecoder(report_rejected=True)
    frames = dec.feed(outer, t=1.5)
    assert [(f.crc_ok, f.offset, f.type) for f in frames] == [(False, 0, 0x1F), (True, 5, 0xFA)]
    assert frames[0].payload == HW_REPLY
    assert all(f.t == 1.5 for f in frames)


def test_without_report_rejected_nothing_is_returned_for_a_bad_frame() -> None:
    dec = StreamDecoder()
    assert dec.feed(POWER_ON_BAD_CRC) == []
    assert dec.counters.crc_failures == 1


# --- the length bound -----------------------------------------------------------------------


def test_length_bound() -> None:
    at_bound = encode_frame(10, 0x1F, bytes(range(20)))
    over = encode_frame(10, 0x1F, bytes(range(21)))
    dec = StreamDecoder(max_payload=20)
    frames = dec.feed(at_bound + over + PING)
    assert [len(f.payload) for f in frames] == [20, 0]
    assert dec.counters.length_errors == 1
    assert dec.counters.resyncs == 1


def test_default_length_bound() -> None:
    ok = encode_frame(10, 0x1F, bytes(DEFAULT_MAX_PAYLOAD))
    too_long = encode_frame(10, 0x1F, bytes(DEFAULT_MAX_PAYLOAD + 1))
    dec = StreamDecoder()
    frames = dec.feed(ok + too_long)
    assert [len(f.payload) for f in frames] == [DEFAULT_MAX_PAYLOAD]
    assert dec.counters.length_errors == 1
    assert dec.pending == 0  # nothing waits for the over-long frame


def test_a_false_length_does_not_stall_the_decoder_forever() -> None:
    # Without a bound a garbled 0xFFFF length would swallow 64 KiB of good frames.
    dec = StreamDecoder()
    frames = dec.feed(bytes([0x42, 0x0A, 0xFF, 0xFF, 0x01]) + PING)
    assert len(frames) == 1


# --- the gap rule ---------------------------------------------------------------------------


def test_gap_drops_a_partial_frame() -> None:
    dec = StreamDecoder(gap_s=0.010)
    assert dec.feed(LONG_PROMISE + b"\x01\x02", t=0.0) == []
    frames = dec.feed(PING, t=0.020)
    assert [triple(f) for f in frames] == [(10, 1, b"")]
    assert frames[0].offset == len(LONG_PROMISE) + 2
    assert frames[0].t == 0.020
    assert dec.counters.gap_discards == 1
    assert dec.counters.bytes_discarded == len(LONG_PROMISE) + 2


def test_no_gap_keeps_the_partial_frame() -> None:
    dec = StreamDecoder(gap_s=0.010)
    assert dec.feed(LONG_PROMISE + b"\x01\x02", t=0.0) == []
    assert dec.feed(PING, t=0.005) == []  # swallowed by the promised length, for now
    assert dec.counters.gap_discards == 0
    assert [triple(f) for f in dec.flush()] == [(10, 1, b"")]


def test_gap_rule_disabled_and_without_times() -> None:
    for dec, times in ((StreamDecoder(gap_s=None), (0.0, 5.0)), (StreamDecoder(), (None, None))):
        assert dec.feed(LONG_PROMISE, t=times[0]) == []
        assert dec.feed(PING, t=times[1]) == []
        assert dec.counters.gap_discards == 0


def test_gap_is_measured_from_the_last_arrival() -> None:
    dec = StreamDecoder(gap_s=0.010)
    dec.feed(LONG_PROMISE, t=0.0)
    dec.feed(b"\x00", t=0.008)
    assert dec.feed(PING, t=0.016) == []  # 8 ms after the previous chunk
    assert dec.counters.gap_discards == 0


def test_gap_without_a_partial_frame_is_not_a_discard() -> None:
    dec = StreamDecoder(gap_s=0.010)
    assert len(dec.feed(PING, t=0.0)) == 1
    assert len(dec.feed(PING, t=1.0)) == 1
    assert dec.counters.gap_discards == 0


# --- flush ----------------------------------------------------------------------------------


def test_flush_recovers_frames_behind_a_false_sync() -> None:
    dec = StreamDecoder()
    assert dec.feed(LONG_PROMISE + PING + HW_REPLY, t=2.0) == []
    frames = dec.flush(t=3.0)
    assert [triple(f) for f in frames] == [(10, 1, b""), EXPECTED[1]]
    assert [f.offset for f in frames] == [5, 12]
    assert all(f.t == 3.0 for f in frames)
    assert dec.counters.truncated == 1
    assert dec.pending == 0
    assert dec.counters.bytes_discarded == len(LONG_PROMISE)


def test_flush_of_an_empty_decoder() -> None:
    dec = StreamDecoder()
    assert dec.flush() == []
    assert dec.counters.truncated == 0


def test_flush_of_a_lone_partial_frame() -> None:
    dec = StreamDecoder()
    dec.feed(PING[:-1])
    assert dec.flush() == []
    assert dec.counters.truncated == 1
    assert dec.counters.bytes_discarded == len(PING) - 1


def test_decode_all() -> None:
    frames = decode_all(b"\x00" + LONG_PROMISE + PING + POWER_ON_BAD_CRC + HW_REPLY)
    assert [triple(f) for f in frames] == [(10, 1, b""), EXPECTED[1]]
    assert decode_all(b"") == []
    assert decode_all(POWER_ON, max_payload=0) == []


# --- properties -----------------------------------------------------------------------------

frames_st = st.builds(
    encode_frame, st.integers(0, 255), st.integers(0, 255), st.binary(max_size=40)
)
cuts_st = st.lists(st.integers(0, 400), max_size=8)


def check_invariants(dec: StreamDecoder, stream: bytes, frames: list[Frame]) -> None:
    good = [f for f in frames if f.crc_ok]
    counters = dec.counters
    assert counters.bytes_in == len(stream)
    assert counters.frames == len(good)
    assert counters.bytes_discarded + sum(f.size for f in good) + dec.pending == len(stream)
    for frame in frames:
        if frame.crc_ok:
            assert stream[frame.offset : frame.offset + frame.size] == frame.to_bytes()
        else:
            assert stream[frame.offset] == 0x42
    offsets = [f.offset for f in frames]
    assert offsets == sorted(offsets)


@given(st.lists(st.binary(max_size=60), max_size=10), st.booleans(), st.booleans())
def test_arbitrary_chunks_never_raise(
    chunks: list[bytes], report_rejected: bool, small_bound: bool
) -> None:
    dec = StreamDecoder(max_payload=8 if small_bound else DEFAULT_MAX_PAYLOAD,
                        report_rejected=report_rejected)
    frames: list[Frame] = []
    for i, chunk in enumerate(chunks):
        frames += dec.feed(chunk, t=i * 0.004)
    stream = b"".join(chunks)
    check_invariants(dec, stream, frames)
    frames += dec.flush()
    check_invariants(dec, stream, frames)
    assert dec.pending == 0


@given(st.lists(frames_st, max_size=6), cuts_st)
def test_concatenated_frames_in_arbitrary_chunks(wires: list[bytes], cuts: list[int]) -> None:
    stream = b"".join(wires)
    dec = StreamDecoder()
    frames = feed_all(dec, split_at(stream, cuts)) + dec.flush()
    assert [f.to_bytes() for f in frames] == wires
    offsets, pos = [], 0
    for wire in wires:
        offsets.append(pos)
        pos += len(wire)
    assert [f.offset for f in frames] == offsets
    assert dec.counters.bytes_discarded == 0
    check_invariants(dec, stream, frames)


garbage_no_sync = st.binary(max_size=30).map(lambda b: b.replace(b"\x42", b"\x43"))


@given(st.lists(st.tuples(garbage_no_sync, frames_st), max_size=6), garbage_no_sync, cuts_st)
def test_frames_among_sync_free_garbage_are_all_found(
    parts: list[tuple[bytes, bytes]], tail: bytes, cuts: list[int]
) -> None:
    stream = b"".join(g + w for g, w in parts) + tail
    dec = StreamDecoder()
    frames = feed_all(dec, split_at(stream, cuts)) + dec.flush()
    assert [f.to_bytes() for f in frames] == [w for _, w in parts]
    check_invariants(dec, stream, frames)


def is_subsequence(needles: list[bytes], haystack: list[bytes]) -> bool:
    it = iter(haystack)
    return all(any(n == h for h in it) for n in needles)


@settings(max_examples=150)
@given(
    st.lists(st.tuples(st.binary(max_size=40), frames_st, st.binary(max_size=40)), max_size=6),
    st.binary(max_size=40),
    st.floats(0.0105, 1.0),
    st.lists(st.integers(0, 100), max_size=3),
)
def test_frames_in_garbage_recovered_after_a_gap(
    parts: list[tuple[bytes, bytes, bytes]], lead: bytes, gap: float, cuts: list[int]
) -> None:
    dec = StreamDecoder(gap_s=0.010)
    frames = dec.feed(lead, t=0.0)
    stream = lead
    t = 0.0
    expected_offsets = []
    for before, wire, after in parts:
        frames += dec.feed(before, t=t)  # garbage right behind the previous frame's bytes
        stream += before
        t += gap
        expected_offsets.append(len(stream))
        # the frame and trailing garbage arrive after a quiet gap, possibly in pieces
        for chunk in split_at(wire + after, cuts):
            frames += dec.feed(chunk, t=t)
        stream += wire + after
    frames += dec.flush()
    wires = [w for _, w, _ in parts]
    found = [f.to_bytes() for f in frames if f.crc_ok]
    assert is_subsequence(wires, found)
    by_offset = {f.offset: f.to_bytes() for f in frames}
    for offset, wire in zip(expected_offsets, wires, strict=True):
        assert by_offset.get(offset) == wire
    check_invariants(dec, stream, frames)


@given(st.binary(max_size=200), cuts_st)
def test_bytes_in_counts_everything_fed(data: bytes, cuts: list[int]) -> None:
    dec = StreamDecoder()
    chunks = split_at(data, cuts)
    for chunk in chunks:
        dec.feed(bytearray(chunk))
    assert dec.counters.bytes_in == len(data)
    dec.flush()
    assert dec.counters.bytes_in == len(data)


@given(st.binary(max_size=120), st.lists(st.integers(0, 120), max_size=6))
def test_chunking_does_not_change_the_result_without_times(data: bytes, cuts: list[int]) -> None:
    whole = StreamDecoder(report_rejected=True)
    ref = whole.feed(data) + whole.flush()
    pieces = StreamDecoder(report_rejected=True)
    got = feed_all(pieces, split_at(data, cuts)) + pieces.flush()
    assert [(f.offset, f.crc_ok, triple(f)) for f in got] == [
        (f.offset, f.crc_ok, triple(f)) for f in ref
    ]
    assert pieces.counters.frames == whole.counters.frames
    assert pieces.counters.bytes_discarded == whole.counters.bytes_discarded


def reference_decode(
    chunks: list[bytes], max_payload: int, report_rejected: bool
) -> tuple[list[tuple[int, bool, tuple[int, int, bytes]]], dict[str, int]]:
    """The decoder spelled out with check_frame, outcome by outcome (no gap rule)."""
    counters = dict.fromkeys(DecoderCounters().as_dict(), 0)
    out: list[tuple[int, bool, tuple[int, int, bytes]]] = []
    buf = b""
    base = 0

    def scan(final: bool) -> None:
        nonlocal buf, base
        pos = 0
        while pos < len(buf):
            outcome, n = check_frame(buf, pos, max_payload)
            if outcome == FRAME:
                out.append((base + pos, True, (buf[pos + 1], buf[pos + 4], buf[pos + 5:pos + n - 2])))
                counters["frames"] += 1
                pos += n
            elif outcome == SKIP:
                counters["bytes_discarded"] += n
                pos += n
            elif outcome == NEED_MORE and not final:
                break
            else:  # a sync byte that starts no frame: drop it, rescan behind it
                assert n == 1 or outcome == NEED_MORE
                if outcome == BAD_CRC:
                    counters["crc_failures"] += 1
                    if report_rejected:
                        length = buf[pos + 2] | (buf[pos + 3] << 8)
                        out.append((base + pos, False,
                                    (buf[pos + 1], buf[pos + 4], buf[pos + 5:pos + 5 + length])))
                elif outcome == BAD_LENGTH:
                    counters["length_errors"] += 1
                else:
                    assert outcome == NEED_MORE
                    counters["truncated"] += 1
                counters["resyncs"] += 1
                counters["bytes_discarded"] += 1
                pos += 1
        buf = buf[pos:]
        base += pos

    for chunk in chunks:
        counters["bytes_in"] += len(chunk)
        buf += chunk
        scan(final=False)
    scan(final=True)
    return out, counters


near_frame_bytes = st.one_of(
    frames_st,
    frames_st.map(lambda w: w[: len(w) // 2]),
    frames_st.map(lambda w: w[:-1] + bytes([w[-1] ^ 0x10])),
    st.binary(max_size=12).map(lambda b: b"\x42" + b),
    st.binary(max_size=12),
)


@pytest.mark.slow
@settings(max_examples=300)
@given(st.lists(near_frame_bytes, max_size=8), cuts_st, st.booleans(),
       st.sampled_from([DEFAULT_MAX_PAYLOAD, 20, 0]), st.booleans())
def test_decoder_agrees_with_check_frame(
    pieces: list[bytes], cuts: list[int], report_rejected: bool, max_payload: int,
    as_bytearray: bool,
) -> None:
    stream = b"".join(pieces)
    chunks = split_at(stream, cuts)
    ref_frames, ref_counters = reference_decode(chunks, max_payload, report_rejected)
    dec = StreamDecoder(max_payload=max_payload, report_rejected=report_rejected)
    got: list[Frame] = []
    for chunk in chunks:
        got += dec.feed(bytearray(chunk) if as_bytearray else chunk)
    got += dec.flush()
    assert [(f.offset, f.crc_ok, triple(f)) for f in got] == ref_frames
    assert all(type(f.payload) is bytes for f in got)
    assert dec.counters.as_dict() == ref_counters


def test_decoder_does_not_keep_the_callers_buffer() -> None:
    data = bytearray(PING + PING[:3])
    dec = StreamDecoder()
    frames = dec.feed(data)
    data[:] = b"\x00" * len(data)  # the caller reuses its buffer
    assert [triple(f) for f in frames] == [(10, 1, b"")]
    assert [triple(f) for f in dec.feed(PING[3:])] == [(10, 1, b"")]


def test_frame_size_property() -> None:
    frames = decode_all(HW_REPLY)
    assert frames[0].size == len(HW_REPLY) == 4 + OVERHEAD


@pytest.mark.slow
@settings(max_examples=150, deadline=None)
@given(st.lists(st.one_of(st.binary(max_size=30), st.sampled_from(
    [PING, POWER_ON, HW_REPLY, POWER_ON_BAD_CRC, LONG_PROMISE])), max_size=12),
    st.lists(st.integers(0, 200), max_size=4), st.booleans())
def test_tuples_are_the_frames_feed_returns(parts: list[bytes], cuts: list[int],
                                            rejected: bool) -> None:
    data = b"".join(parts)
    framed = StreamDecoder(gap_s=None, report_rejected=rejected)
    plain = StreamDecoder(gap_s=None, report_rejected=rejected)
    frames: list[Frame] = []
    tuples = []
    for chunk in split_at(data, cuts):
        frames += framed.feed(chunk)
        tuples += plain.feed_tuples(memoryview(chunk))
    frames += framed.flush()
    tuples += plain.flush_tuples()
    assert tuples == [(f.address, f.type, f.payload, f.offset, f.crc_ok) for f in frames]
    assert all(type(payload) is bytes for _, _, payload, _, _ in tuples)
    assert plain.counters == framed.counters


# --- pass_frame -------------------------------------------------------------------------------


def _state(dec: StreamDecoder) -> tuple[object, ...]:
    return (dec.counters, dec.pending, dec._base, dec._last_t)


@pytest.mark.parametrize("frame", [PING, POWER_ON, HW_REPLY])
def test_pass_frame_leaves_the_decoder_as_feed_does(frame: bytes) -> None:
    fed, passed = StreamDecoder(), StreamDecoder()
    for dec in (fed, passed):  # some history first
        assert len(dec.feed(PING, 0.001)) == 1
    assert len(fed.feed(frame, 0.002)) == 1
    assert passed.pass_frame(frame, 0.002)
    assert _state(passed) == _state(fed)
    # and the next frame decodes at the same stream offset
    assert fed.feed(POWER_ON, 0.003)[0].offset == passed.feed(POWER_ON, 0.003)[0].offset


@pytest.mark.parametrize("data", [
    POWER_ON_BAD_CRC,            # bad CRC: feed counts a failure and rescans
    POWER_ON[:-1],               # not whole
    POWER_ON + PING,             # more than one frame
    b"\x00" + POWER_ON,          # junk before the sync
    LONG_PROMISE,                # a promise of more bytes
    b"",
])
def test_pass_frame_refuses_anything_but_one_good_frame(data: bytes) -> None:
    dec = StreamDecoder()
    before = (DecoderCounters(**dec.counters.as_dict()), dec.pending, dec._base, dec._last_t)
    assert not dec.pass_frame(data, 0.001)
    assert (dec.counters, dec.pending, dec._base, dec._last_t) == before


def test_pass_frame_refuses_while_a_partial_frame_is_held() -> None:
    dec = StreamDecoder()
    assert dec.feed(PING[:3], 0.001) == []
    assert not dec.pass_frame(POWER_ON, 0.002)
    assert dec.pending == 3


def test_pass_frame_respects_the_length_bound() -> None:
    dec = StreamDecoder(max_payload=0)
    assert dec.pass_frame(PING, 0.001)
    assert not dec.pass_frame(POWER_ON, 0.002)


@pytest.mark.parametrize("kind", [bytearray, memoryview])
def test_pass_frame_leaves_a_bytes_like_frame_to_feed(kind: type) -> None:
    """A good frame given as a bytearray or a view: refused (the caller feeds it), not a
    TypeError (as a compiled signature of ``bytes`` would raise)."""
    dec = StreamDecoder()
    assert not dec.pass_frame(kind(PING), 0.001)
    assert dec.counters.frames == 0
    assert [f.type for f in dec.feed(bytearray(PING), 0.001)] == [PING[4]]
