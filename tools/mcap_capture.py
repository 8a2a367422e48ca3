"""Raw-frame channels of an MCAP recording, for ``handbus decode FILE.mcap``.

:mod:`host.hand_recording` writes every hand frame the host sent or decoded on
``/hand/frames/tx`` and ``/hand/frames/rx`` (message encoding ``hand-frame``, one whole
frame per message); :mod:`host.arm_recording` writes the arm bus's bytes on
``/arm/bus/tx`` (whole instruction packets) and ``/arm/bus/rx`` (bytes as they arrived;
``application/octet-stream``).  :func:`raw_chunks` yields those messages as
:class:`RawChunk` (channel, log time, bytes); :func:`decode_mcap` concatenates each channel's
bytes in log-time order, decodes them as ``handbus decode`` decodes a raw capture, and prints
the same JSON lines with ``channel`` (the topic) and ``t`` (log time of the message holding
the frame's first byte, s) added; ``offset`` counts within that channel's bytes.  A file
is an MCAP file if it starts with :data:`MCAP_MAGIC`.
"""

from __future__ import annotations

import bisect
import io
import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

#: The first bytes of every MCAP file.
MCAP_MAGIC: Final = b"\x89MCAP0\r\n"
#: Message encodings of the raw-frame channels (:mod:`host.hand_recording`,
#: :mod:`host.arm_recording`).
HAND_FRAME_ENCODING: Final = "hand-frame"
ARM_BYTES_ENCODING: Final = "application/octet-stream"

#: ``(data, out) -> summary counters``: one of ``handbus``'s raw-capture decoders.
Decoder = Callable[[bytes, Any], dict[str, int]]


class McapCaptureError(Exception):
    """The file is not a readable MCAP recording or holds no raw channel of that kind."""


@dataclass(frozen=True)
class RawChunk:
    """One raw-frame message: ``channel`` (topic), ``log_time_ns`` (ns, the recording's
    clock), ``data`` (a whole hand frame, or arm bus bytes)."""

    channel: str
    log_time_ns: int
    data: bytes


def is_mcap(path: str | Path) -> bool:
    """True if ``path`` starts with the MCAP magic bytes (False if unreadable)."""
    try:
        with open(path, "rb") as fh:
            return fh.read(len(MCAP_MAGIC)) == MCAP_MAGIC
    except OSError:
        return False


def raw_chunks(path: str | Path, encoding: str) -> Iterator[RawChunk]:
    """The messages of ``path``'s channels whose message encoding is ``encoding``, in log
    time order.  Raises :class:`McapCaptureError` for a file the reader rejects."""
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as fh:
            reader = make_reader(fh)
            for _, channel, message in reader.iter_messages(log_time_order=True):
                if channel.message_encoding == encoding:
                    yield RawChunk(channel.topic, message.log_time, bytes(message.data))
    except (McapError, ValueError, EOFError, OSError) as exc:  # OSError: a seek before the
        # start of a file too short for the footer
        raise McapCaptureError(f"{path}: not a readable MCAP file ({exc})") from exc


def decode_mcap(path: str | Path, encoding: str, decoders: Callable[[str], Decoder],
                out: Any) -> dict[str, int]:
    """Decode every channel of ``encoding`` in ``path`` with ``decoders(topic)`` and print
    its JSON lines to ``out`` with ``channel`` and ``t`` (s) added; return the summed
    counters.  Raises :class:`McapCaptureError` if there is no such channel."""
    streams: dict[str, tuple[bytearray, list[int], list[int]]] = {}
    for chunk in raw_chunks(path, encoding):
        data, starts, times = streams.setdefault(chunk.channel, (bytearray(), [], []))
        starts.append(len(data))
        times.append(chunk.log_time_ns)
        data += chunk.data
    if not streams:
        raise McapCaptureError(f"{path}: no channel with message encoding {encoding!r}")
    total: dict[str, int] = {}
    for topic in sorted(streams):
        data, starts, times = streams[topic]
        lines = io.StringIO()
        counters = decoders(topic)(bytes(data), lines)
        for line in lines.getvalue().splitlines():
            record = json.loads(line)
            at = bisect.bisect_right(starts, int(record.get("offset", 0))) - 1
            record["channel"] = topic
            record["t"] = times[max(at, 0)] / 1e9
            print(json.dumps(record, ensure_ascii=False), file=out)
        for key, value in counters.items():
            total[key] = total.get(key, 0) + value
    return total
