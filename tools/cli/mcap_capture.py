"""Raw-frame channels of an MCAP recording, for ``handbus decode FILE.mcap``, read up to a cut.

:mod:`host.hand.recording` writes every hand frame the host sent or decoded on
``/hand/frames/tx`` and ``/hand/frames/rx`` (message encoding ``hand-frame``, one whole
frame per message); :mod:`host.arm.recording` writes the arm bus's bytes on
``/arm/bus/tx`` (whole instruction packets) and ``/arm/bus/rx`` (bytes as they arrived;
``application/octet-stream``).

:func:`read_recording` walks the file record by record from its start (the way a
streaming reader does, not through the summary at its end), so a recording cut short (a
killed recorder, a full disk, a partial copy) gives every message in the chunks before the
cut, and says where and why it stopped (:attr:`Contents.stopped`); chunk CRCs are checked.
:func:`decode_mcap` concatenates each channel's bytes in the order they were written,
decodes them as ``handbus decode`` decodes a raw capture, and prints the same JSON lines with
``channel`` (the topic), ``t`` (log time of the message holding the frame's first byte: the
wall clock, s since 1970) and ``t_link`` (its publish time: the link's clock, s; the
simulation's with the in-process emulator) added; ``offset`` counts within that channel's
bytes.  A file is an MCAP file if it starts with :data:`MCAP_MAGIC`.
"""

from __future__ import annotations

import bisect
import io
import json
import struct
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

from tools.errors import McapCaptureError

#: The first bytes of every MCAP file.
MCAP_MAGIC: Final = b"\x89MCAP0\r\n"
#: Message encodings of the raw-frame channels (:mod:`host.hand.recording`,
#: :mod:`host.arm.recording`).
HAND_FRAME_ENCODING: Final = "hand-frame"
ARM_BYTES_ENCODING: Final = "application/octet-stream"
#: What decodes each raw encoding (the hint when the other one was asked for).
ENCODING_HINT: Final = {HAND_FRAME_ENCODING: "hand frames: decode without --dynamixel",
                        ARM_BYTES_ENCODING: "arm bus bytes: decode with --dynamixel"}

_OP_HEADER, _OP_FOOTER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK = 1, 2, 3, 4, 5, 6
_OP_METADATA, _OP_DATA_END, _OP_LAST = 0x0C, 0x0F, 0x0F
_RECORD_HEAD = 9  # opcode (1 byte) and length (8)

#: ``(data, out) -> summary counters``: one of ``handbus``'s raw-capture decoders.
Decoder = Callable[[bytes, Any], dict[str, int]]


@dataclass(frozen=True)
class RawChunk:
    """One message: ``channel`` (topic), ``log_time_ns`` (ns, wall clock),
    ``publish_time_ns`` (ns, the link's clock), ``data`` (a whole hand frame, arm bus
    bytes, or JSON)."""

    channel: str
    log_time_ns: int
    data: bytes
    publish_time_ns: int = 0


@dataclass
class Contents:
    """What :func:`read_recording` found: ``encodings`` (topic → message encoding), the
    ``messages`` in file order, the file's ``size``, ``end`` (the offset after the last
    record read whole) and, if it stopped before the footer, ``stopped`` (why)."""

    size: int
    encodings: dict[str, str] = field(default_factory=dict)
    messages: list[RawChunk] = field(default_factory=list)
    end: int = 0
    stopped: str | None = None
    #: Messages read from the start of a chunk cut short (its CRC unchecked).
    salvaged: int = 0
    #: The file's metadata records by name (``source``: :mod:`host.recording.writer`).
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)

    @property
    def unread(self) -> int:
        """Bytes at the end that could not be read (0 for a whole file)."""
        return self.size - self.end if self.stopped else 0


def is_mcap(path: str | Path) -> bool:
    """True if ``path`` starts with the MCAP magic bytes (False if unreadable)."""
    try:
        with open(path, "rb") as fh:
            return fh.read(len(MCAP_MAGIC)) == MCAP_MAGIC
    except OSError:
        return False


def _string(data: bytes, at: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", data, at)
    return data[at + 4: at + 4 + n].decode("utf-8"), at + 4 + n


class _Walker:
    """Reads the records of one MCAP byte string (the data section or a chunk's records)."""

    def __init__(self, contents: Contents) -> None:
        self.contents = contents
        self.channels: dict[int, tuple[str, str]] = {}

    def record(self, opcode: int, body: bytes) -> None:
        if opcode == _OP_CHANNEL:
            (channel_id,) = struct.unpack_from("<H", body, 0)
            at = 4  # id, schema id
            topic, at = _string(body, at)
            encoding, at = _string(body, at)
            self.channels[channel_id] = (topic, encoding)
            self.contents.encodings[topic] = encoding
        elif opcode == _OP_METADATA:
            name, at = _string(body, 0)
            (size,) = struct.unpack_from("<I", body, at)
            at += 4
            end = at + size
            record: dict[str, str] = {}
            while at < end:
                key, at = _string(body, at)
                record[key], at = _string(body, at)
            self.contents.metadata[name] = record
        elif opcode == _OP_MESSAGE:
            channel_id, _seq, log_time, publish_time = struct.unpack_from("<HIQQ", body, 0)
            topic, _ = self.channels.get(channel_id, (f"channel {channel_id}", ""))
            self.contents.messages.append(RawChunk(topic, log_time, bytes(body[22:]),
                                                   publish_time))

    def chunk(self, body: bytes) -> None:
        _start, _end, size, crc = struct.unpack_from("<QQQI", body, 0)
        compression, at = _string(body, 28)
        (length,) = struct.unpack_from("<Q", body, at)
        data = body[at + 8: at + 8 + length]
        self._records(self._decompress(compression, data, size), crc)

    def partial_chunk(self, body: bytes) -> int:
        """The whole records at the start of a chunk cut short (as far as its compressed
        blocks before the cut go); returns how many messages they held."""
        before = len(self.contents.messages)
        try:
            compression, at = _string(body, 28)
            (length,) = struct.unpack_from("<Q", body, at)
            data = body[at + 8: at + 8 + length]
            if compression == "zstd":
                import zstandard

                records = zstandard.ZstdDecompressor().decompressobj().decompress(data)
            elif compression == "":
                records = data
            else:
                return 0
            self._records(records, 0, whole=False)
        except (ValueError, struct.error, ImportError):
            pass  # nothing more comes out of it
        return len(self.contents.messages) - before

    @staticmethod
    def _decompress(compression: str, data: bytes, size: int) -> bytes:
        if compression == "zstd":
            import zstandard

            records = zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
        elif compression == "lz4":
            import lz4.frame  # type: ignore[import-not-found,import-untyped,unused-ignore]

            records = lz4.frame.decompress(data)
        elif compression == "":
            records = data
        else:
            raise ValueError(f"a chunk compressed with {compression!r}, which this reader "
                             "does not know")
        return records

    def _records(self, records: bytes, crc: int, whole: bool = True) -> None:
        if crc and zlib.crc32(records) != crc:
            raise ValueError("a chunk whose CRC does not match its contents (the file is "
                             "damaged)")
        at = 0
        while at + _RECORD_HEAD <= len(records):
            opcode, n = struct.unpack_from("<BQ", records, at)
            if not whole and at + _RECORD_HEAD + n > len(records):
                break
            self.record(opcode, records[at + _RECORD_HEAD: at + _RECORD_HEAD + n])
            at += _RECORD_HEAD + n


def read_recording(path: str | Path) -> Contents:
    """Every message of the MCAP file ``path`` in file order, up to its end or up to where
    it cannot be read (a cut, a damaged chunk: :attr:`Contents.stopped` says which and
    where).  :class:`McapCaptureError` if the file cannot be opened, is empty, or is not an
    MCAP file (naming what it starts with)."""
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise McapCaptureError(f"{path}: cannot read it ({exc.strerror or exc})") from exc
    if not data:
        raise McapCaptureError(f"{path} is empty (0 bytes): not a recording")
    if not data.startswith(MCAP_MAGIC):
        raise McapCaptureError(f"{path} is not an MCAP file: {describe_start(data)}")
    contents = Contents(size=len(data), end=len(MCAP_MAGIC))
    walker = _Walker(contents)
    at = len(MCAP_MAGIC)
    while True:
        if at + _RECORD_HEAD > len(data):
            contents.stopped = "cut short" + ("" if at < len(data) else " (no footer)")
            break
        opcode, n = struct.unpack_from("<BQ", data, at)
        if opcode == 0 or _OP_LAST < opcode < 0x80:  # 0x80.. are private records
            contents.stopped = f"damaged: no MCAP record at offset {at} (opcode {opcode:#04x})"
            break
        if at + _RECORD_HEAD + n > len(data):
            contents.stopped = "cut short"
            if opcode == _OP_CHUNK:
                contents.salvaged = walker.partial_chunk(data[at + _RECORD_HEAD:])
            break
        body = data[at + _RECORD_HEAD: at + _RECORD_HEAD + n]
        try:
            if opcode == _OP_CHUNK:
                walker.chunk(body)
            else:
                walker.record(opcode, body)
        except (ValueError, struct.error, ImportError) as exc:
            contents.stopped = f"damaged at offset {at}: {exc}"
            break
        at += _RECORD_HEAD + n
        contents.end = at
        if opcode == _OP_FOOTER:
            break
    return contents


def describe_start(data: bytes) -> str:
    """What a file starting with ``data`` looks like, for a message."""
    kinds = ((b"\x89PNG", "a PNG image"), (b"\x7fELF", "an ELF program"),
             (b"PK\x03\x04", "a zip archive"), (b"\x1f\x8b", "gzip data"),
             (b"\x28\xb5\x2f\xfd", "zstd data"), (b"%PDF", "a PDF document"),
             (MCAP_MAGIC[:5], "an MCAP file cut inside its magic bytes"))
    for magic, kind in kinds:
        if data.startswith(magic):
            return f"it is {kind}"
    head = data[:16]
    try:
        text = data[:4096].decode("utf-8")
    except UnicodeDecodeError:
        return f"it starts with {head.hex(' ')}"
    if text.lstrip().startswith(("{", "[")):
        return "it is JSON text"
    if all(c.isprintable() or c in "\r\n\t" for c in text):
        return f"it is text ({text.strip().splitlines()[0][:40]!r}…)" if text.strip() \
            else "it holds only white space"
    return f"it starts with {head.hex(' ')}"


def raw_chunks(path: str | Path, encoding: str) -> list[RawChunk]:
    """The messages of ``path``'s channels with message encoding ``encoding``, in file
    order, up to a cut."""
    contents = read_recording(path)
    return [m for m in contents.messages if contents.encodings.get(m.channel) == encoding]


def raw_topics(contents: Contents) -> dict[str, list[str]]:
    """Raw encoding → the topics of ``contents`` with it."""
    out: dict[str, list[str]] = {}
    for topic, encoding in sorted(contents.encodings.items()):
        if encoding in ENCODING_HINT:
            out.setdefault(encoding, []).append(topic)
    return out


def decode_mcap(path: str | Path, encoding: str, decoders: Callable[[str], Decoder],
                out: Any, contents: Contents | None = None) -> dict[str, int]:
    """Decode every channel of ``encoding`` in ``path`` (or its :func:`read_recording`
    ``contents``) with ``decoders(topic)`` and print its JSON lines to ``out`` with
    ``channel``, ``t`` and ``t_link`` (s) added; return the summed counters.
    :class:`McapCaptureError` if there is no such channel (saying which channels there
    are, and how they decode)."""
    if contents is None:
        contents = read_recording(path)
    streams: dict[str, tuple[bytearray, list[int], list[RawChunk]]] = {}
    for topic in sorted(t for t, e in contents.encodings.items() if e == encoding):
        streams[topic] = (bytearray(), [], [])
    for chunk in contents.messages:
        if chunk.channel in streams:
            data, starts, chunks = streams[chunk.channel]
            starts.append(len(data))
            chunks.append(chunk)
            data += chunk.data
    if not streams:
        raise McapCaptureError(_no_channel(path, encoding, contents))
    total: dict[str, int] = {}
    for topic in sorted(streams):
        data, starts, chunks = streams[topic]
        lines = io.StringIO()
        counters = decoders(topic)(bytes(data), lines)
        for line in lines.getvalue().splitlines():
            record = json.loads(line)
            at = max(bisect.bisect_right(starts, int(record.get("offset", 0))) - 1, 0)
            record["channel"] = topic
            if chunks:
                record["t"] = chunks[at].log_time_ns / 1e9
                record["t_link"] = chunks[at].publish_time_ns / 1e9
            print(json.dumps(record, ensure_ascii=False), file=out)
        for key, value in counters.items():
            total[key] = total.get(key, 0) + value
    return total


def _no_channel(path: str | Path, encoding: str, contents: Contents) -> str:
    kind = "hand frames" if encoding == HAND_FRAME_ENCODING else "arm bus bytes"
    others = raw_topics(contents)
    if others:
        hints = "; ".join(f"{', '.join(topics)} hold {ENCODING_HINT[enc]}"
                          for enc, topics in others.items())
        return f"{path} has no {kind} ({encoding!r} channels): {hints}"
    if contents.encodings:
        return (f"{path} has no {kind} ({encoding!r} channels); its channels are "
                f"{', '.join(sorted(contents.encodings))}")
    where = f" before its cut at byte {contents.end}" if contents.stopped else ""
    return f"{path} is an MCAP file with no channel{where}: nothing to decode"
