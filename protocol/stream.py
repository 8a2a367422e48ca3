"""The hand-frame stream decoder: bytes in (with arrival times), frames out, never a crash.

Built on :func:`protocol.framing.check_frame`.  It survives anything a bus can produce:

- a payload length above ``max_payload`` drops the sync byte and rescans;
- a CRC failure rescans from the byte after the failed sync byte, so a good frame hidden
  behind a corrupted one is still found (optionally the rejected candidate is reported);
- an inter-frame gap longer than ``gap_s`` discards a partial frame (the dissertation's
  "slightly spaced in time" re-synchronisation);
- :meth:`StreamDecoder.flush` at the end of a capture rescans what is left, so frames behind
  a false sync byte that promised more bytes are recovered too.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, TypeAlias

from protocol.crc import crc16_xmodem_fast
from protocol.framing import (
    BAD_LENGTH,
    CRC_SIZE,
    DEFAULT_MAX_PAYLOAD,
    HEADER_SIZE,
    SKIP,
    SYNC,
    Frame,
)

#: A frame as a plain tuple: (address, type, payload, offset, crc_ok); see
#: :meth:`StreamDecoder.feed_tuples`.
FrameTuple: TypeAlias = tuple[int, int, bytes, int, bool]


@dataclass
class DecoderCounters:
    """What a decoder has seen since it was made (all counts, bytes in bytes)."""

    frames: int = 0
    crc_failures: int = 0
    length_errors: int = 0
    resyncs: int = 0
    bytes_in: int = 0
    bytes_discarded: int = 0
    gap_discards: int = 0
    truncated: int = 0

    def as_dict(self) -> dict[str, int]:
        """The counters as a plain dict (JSON-ready)."""
        return asdict(self)


class StreamDecoder:
    """Incremental hand-frame decoder.

    ``max_payload`` bounds the length field (bytes); ``gap_s`` is the inter-frame gap
    (seconds, in the clock of the ``t`` passed to :meth:`feed`) after which a partial frame
    is dropped, or None for no gap rule; with ``report_rejected`` the decoder also returns
    CRC-failed candidates as frames with ``crc_ok=False`` (for capture tools), still
    rescanning from the byte after their sync.
    """

    __slots__ = ("_buf", "_base", "_last_t", "counters", "max_payload", "gap_s", "report_rejected")

    def __init__(
        self,
        max_payload: int = DEFAULT_MAX_PAYLOAD,
        gap_s: float | None = 0.010,
        report_rejected: bool = False,
    ) -> None:
        self._buf = bytearray()
        self._base = 0  # stream offset of _buf[0]
        self._last_t: float | None = None
        self.counters = DecoderCounters()
        self.max_payload = max_payload
        self.gap_s = gap_s
        self.report_rejected = report_rejected

    @property
    def pending(self) -> int:
        """Bytes held, waiting for the rest of a frame."""
        return len(self._buf)

    def reset(self) -> None:
        """Drop any partial frame (counted as discarded bytes)."""
        self.counters.bytes_discarded += len(self._buf)
        self._base += len(self._buf)
        self._buf.clear()

    def feed(self, data: bytes | bytearray, t: float | None = None) -> list[Frame]:
        """Add ``data`` that arrived at time ``t`` (seconds) and return the frames completed.

        If ``t`` is later than the previous arrival by more than ``gap_s`` while a partial
        frame is held, that partial frame is discarded first.
        """
        if t is not None:
            if (
                self.gap_s is not None
                and self._buf
                and self._last_t is not None
                and t - self._last_t > self.gap_s
            ):
                self.counters.gap_discards += 1
                self.reset()
            self._last_t = t
        self.counters.bytes_in += len(data)
        if self._buf:
            self._buf += data
            return self._scan(self._buf, t, final=False)
        # Nothing held: scan the caller's bytes in place (no copy into the buffer; payloads
        # are sliced straight out of them) and keep only an unfinished tail.
        return self._scan(data if type(data) is bytes else bytes(data), t, final=False)

    def pass_frame(self, data: bytes | bytearray | memoryview, t: float | None = None) -> bool:
        """Account for ``data`` without building its frame, if it is exactly one whole
        good frame and nothing is held: the decoder ends as :meth:`feed` would leave it
        (counters, stream offset, arrival time) and the frame is not returned.  Returns
        False, having done nothing, in every other case (then call :meth:`feed`).

        For a listener that knows from the address byte (``data[1]``) that the frame is not
        for it: what it would do with the frame is count it, so building it is wasted.
        """
        if type(data) is not bytes:  # a bytearray or a view: the caller feeds it
            return False
        n = len(data)
        if self._buf or n < HEADER_SIZE + CRC_SIZE or data[0] != SYNC:
            return False
        length = data[2] | (data[3] << 8)
        body_end = HEADER_SIZE + length
        if (length > self.max_payload or body_end + CRC_SIZE != n
                or crc16_xmodem_fast(data[:body_end]) != data[body_end] | (data[body_end + 1] << 8)):
            return False
        if t is not None:
            self._last_t = t  # nothing is held: no gap can discard anything
        counters = self.counters
        counters.bytes_in += n
        counters.frames += 1
        self._base += n
        return True

    def flush(self, t: float | None = None) -> list[Frame]:
        """End of stream: recover frames behind false syncs and drop the rest."""
        frames = self._scan(self._buf, t, final=True)
        if self._buf:
            self.counters.truncated += 1
            self.reset()
        return frames

    def feed_tuples(self, data: bytes | bytearray | memoryview) -> list[FrameTuple]:
        """Like :meth:`feed` without arrival times, each frame as a plain :data:`FrameTuple`.

        For capture tools that decode millions of frames: making a :class:`Frame` costs
        more than finding and checking a small one.  Same frames, same counters.
        """
        self.counters.bytes_in += len(data)
        if self._buf:
            self._buf += data
            return self._scan(self._buf, None, final=False, tuples=True)
        data = data if type(data) is bytes else bytes(data)
        return self._scan(data, None, final=False, tuples=True)

    def flush_tuples(self) -> list[FrameTuple]:
        """Like :meth:`flush`, each frame as a plain :data:`FrameTuple`."""
        frames = self._scan(self._buf, None, final=True, tuples=True)
        if self._buf:
            self.counters.truncated += 1
            self.reset()
        return frames

    def _scan(self, buf: bytes | bytearray, t: float | None, final: bool,
              tuples: bool = False) -> list[Any]:
        """Decode ``buf`` (``self._buf`` itself, or new bytes when nothing was held).

        This is :func:`~protocol.framing.check_frame` inlined, outcome by outcome, so the
        common case (a good frame at the scan position) costs no function call besides the
        CRC; the tests check that both agree on every input.
        """
        maxp = self.max_payload
        counters = self.counters
        base = self._base
        copy = type(buf) is not bytes  # a bytearray's slices must become bytes
        out: list[Any] = []
        append = out.append
        frames = 0
        pos = 0
        end = len(buf)
        while pos < end:
            if buf[pos] != SYNC:  # SKIP up to the next sync candidate
                nxt = buf.find(b"\x42", pos + 1)
                n = (end if nxt < 0 else nxt) - pos
                counters.bytes_discarded += n
                pos += n
                continue
            if end - pos >= HEADER_SIZE:
                length = buf[pos + 2] | (buf[pos + 3] << 8)
                if length > maxp:  # BAD_LENGTH
                    counters.length_errors += 1
                    counters.resyncs += 1
                    counters.bytes_discarded += 1
                    pos += 1
                    continue
                body_end = pos + HEADER_SIZE + length
                if body_end + CRC_SIZE <= end:
                    # Called by name: compiled, a local alias is a Python-level call.
                    if (crc16_xmodem_fast(buf[pos:body_end])
                            == buf[body_end] | (buf[body_end + 1] << 8)):
                        payload = buf[pos + HEADER_SIZE : body_end]
                        if copy:
                            payload = bytes(payload)
                        if tuples:
                            append((buf[pos + 1], buf[pos + 4], payload, base + pos, True))
                        else:
                            append(Frame(buf[pos + 1], buf[pos + 4], payload,  # type: ignore[arg-type]
                                         base + pos, True, t))
                        frames += 1
                        pos = body_end + CRC_SIZE
                        continue
                    # BAD_CRC: rescan from the byte after the sync byte
                    counters.crc_failures += 1
                    if self.report_rejected:
                        rejected = bytes(buf[pos + HEADER_SIZE : body_end])
                        if tuples:
                            append((buf[pos + 1], buf[pos + 4], rejected, base + pos, False))
                        else:
                            append(Frame(buf[pos + 1], buf[pos + 4], rejected, base + pos, False, t))
                    counters.resyncs += 1
                    counters.bytes_discarded += 1
                    pos += 1
                    continue
            # NEED_MORE
            if not final:
                break
            # At end of stream a frame that needs more bytes never completes: treat its
            # sync byte as false and keep scanning behind it.
            counters.truncated += 1
            counters.resyncs += 1
            counters.bytes_discarded += 1
            pos += 1
        counters.frames += frames
        if buf is self._buf:
            if pos:
                del self._buf[:pos]
        else:
            self._buf[:] = buf[pos:]
        self._base += pos
        return out


def decode_all(data: bytes | bytearray, max_payload: int = DEFAULT_MAX_PAYLOAD) -> list[Frame]:
    """Decode a whole capture at once (feed + flush); convenience for tools and tests."""
    dec = StreamDecoder(max_payload=max_payload, gap_s=None)
    return dec.feed(data) + dec.flush()


__all__ = ["DecoderCounters", "FrameTuple", "StreamDecoder", "decode_all", "SKIP", "BAD_LENGTH"]
