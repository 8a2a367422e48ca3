"""Hand-frame decoding speed: the product's StreamDecoder against two reference decoders.

Each path decodes one byte string of N concatenated frames and checks every CRC:

- ``stream-decoder``: :class:`protocol.stream.StreamDecoder` (the product path, one ``feed``);
- ``construct-interpreted`` (the baseline): a naive, interpreted construct ``Struct`` of the
  same frame (sync ``Const``, address, length, type, ``Bytes(this.length)``, CRC), parsed
  one frame at a time from a ``BytesIO`` with a crcmod check;
- ``struct-crcmod-floor``: a hand-written ``struct.unpack_from`` + crcmod loop with no
  resynchronisation logic at all, the floor a pure-Python decoder can hope to reach.

Small frames are pings (7 B), large ones fmcb.status replies (155 B).  Run with
``python -m benchmarks.bench_framing [--quick]``.
"""

from __future__ import annotations

import io
import struct
import sys
from functools import partial

import construct as c
import crcmod.predefined

from benchmarks.harness import Result, best_rate
from protocol.messages import CATALOGUE
from protocol.stream import StreamDecoder
from protocol.topology import ADDR_FMCB

_crc = crcmod.predefined.mkCrcFun("xmodem")

#: The frame as someone would first declare it with construct (interpreted, not compiled).
NAIVE_FRAME = c.Struct(
    "sync" / c.Const(b"\x42"),
    "address" / c.Int8ul,
    "length" / c.Int16ul,
    "type" / c.Int8ul,
    "payload" / c.Bytes(c.this.length),
    "crc" / c.Int16ul,
)

_HEADER = struct.Struct("<BBHB")
_CRC = struct.Struct("<H")

BASELINE = "construct-interpreted"


def decode_stream_decoder(data: bytes) -> int:
    """Frames decoded by the product path."""
    return len(StreamDecoder().feed(data))


def decode_construct(data: bytes) -> int:
    """Frames decoded by the naive construct declaration, one at a time, CRC by crcmod."""
    stream = io.BytesIO(data)
    end = len(data)
    count = 0
    while stream.tell() < end:
        start = stream.tell()
        frame = NAIVE_FRAME.parse_stream(stream)
        stop = stream.tell()
        if _crc(data[start : stop - 2]) != frame.crc:
            raise ValueError(f"CRC mismatch at {start}")
        count += 1
    return count


def decode_struct_floor(data: bytes) -> int:
    """Frames decoded by a bare struct.unpack_from loop with a crcmod check."""
    unpack_header = _HEADER.unpack_from
    unpack_crc = _CRC.unpack_from
    crc = _crc
    pos = 0
    end = len(data)
    frames = []
    while pos < end:
        sync, address, length, msg_type = unpack_header(data, pos)
        if sync != 0x42:
            raise ValueError(f"no sync at {pos}")
        body_end = pos + 5 + length
        if crc(data[pos:body_end]) != unpack_crc(data, body_end)[0]:
            raise ValueError(f"CRC mismatch at {pos}")
        frames.append((address, msg_type, data[pos + 5 : body_end]))
        pos = body_end + 2
    return len(frames)


def _frames() -> dict[str, bytes]:
    status = CATALOGUE["fmcb.status"]
    values = {
        "pp_time": 1, "dp_time": 2, "fmcb_time": 3, "pp_tactile": [4] * 6,
        "dp_tactile": [5] * 12, "pp_imu": [6] * 6, "dp_imu": [7] * 6, "fmcb_imu": [8] * 6,
        "pp_temp": [9] * 4, "dp_temp": [10] * 4, "fmcb_temp": [11] * 3, "voltage": 12,
        "pb_current": 13, "pp_strain": 14, "hall_tgt": [15] * 3, "hall_pos": [16] * 3,
        "effort": [17] * 3,
    }
    return {
        "framing-small": CATALOGUE["ping"].request_frame(ADDR_FMCB),
        "framing-large": status.reply_frame(values),
    }


def run(quick: bool = False) -> list[Result]:
    """Frames per second of the three decoders, for small and large frames."""
    n = 2_000 if quick else 20_000
    repeat, min_time = (2, 0.05) if quick else (5, 0.2)
    results: list[Result] = []
    for group, frame in _frames().items():
        data = frame * n
        paths = [
            ("stream-decoder", decode_stream_decoder,
             300_000.0 if group == "framing-small" else None),
            (BASELINE, decode_construct, None),
            ("struct-crcmod-floor", decode_struct_floor, None),
        ]
        for name, func, target in paths:
            if func(data) != n:  # every path must decode every frame
                raise AssertionError(f"{name} decoded {func(data)} of {n} frames")
            rate = best_rate(partial(func, data), repeat=repeat, min_time=min_time)
            results.append(Result(
                group=group, name=name, rate=rate, unit="frames",
                baseline=None if name == BASELINE else BASELINE, target=target,
                note=f"{n} frames of {len(frame)} B in one stream",
            ))
    return results


def format_results(results: list[Result]) -> str:
    """A plain-text table with each rate's ratio to its baseline."""
    rates = {(r.group, r.name): r.rate for r in results}
    unit = results[0].unit if results else "frames"
    lines = [f"{'group':14s} {'name':22s} {unit + '/s':>11s} {'× baseline':>11s} {'target':>10s}"]
    for r in results:
        ratio = f"{r.rate / rates[(r.group, r.baseline)]:.1f}×" if r.baseline else "-"
        target = f"{r.target:,.0f}" if r.target else "-"
        mark = "" if not r.target else ("  ok" if r.rate >= r.target else "  BELOW TARGET")
        lines.append(
            f"{r.group:14s} {r.name:22s} {r.rate:>9,.0f}/s {ratio:>11s} {target:>10s}{mark}"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    print(format_results(run(quick="--quick" in args)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
