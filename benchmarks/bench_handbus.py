"""``handbus decode`` throughput: capture bytes to JSON lines, against the former writer.

Each path turns one synthetic capture (:func:`benchmarks.capture.make_capture`: requests
and replies of every catalogue message, the sample session first) into the JSON lines
``handbus decode`` prints, written to an in-memory text stream:

- ``handbus-decode``: :func:`tools.cli.handbus.decode_hand`, the product path;
- ``per-frame-dumps`` (the baseline): the writer the tool had before it was made fast, and
  what anyone writes first: decode everything into ``Frame`` objects, interpret each frame
  from scratch, copy the fields with ``jsonable`` and ``json.dumps`` a dict per frame.  It
  parses payloads with today's catalogue (struct fast paths included), so the ratio is
  what the writer, the interpretation plans and the tuple decoding gain on top of those.

Three captures: ``mixed`` (every message alike), ``small`` (pings, polls and one-byte
commands, the frames a real session is mostly made of) and ``large`` (148-byte status
replies).  Rates are in MB/s of capture; the note gives seconds per 10 MB.  Run with
``python -m benchmarks.bench_handbus [--quick]``.
"""

from __future__ import annotations

import io
import json
import sys
import time
from collections.abc import Callable
from typing import Any

from benchmarks.capture import make_capture
from benchmarks.harness import Result
from protocol.catalogue import REQUEST
from protocol.errors import ProtocolError
from protocol.framing import DEFAULT_MAX_PAYLOAD, Frame, encode_frame
from protocol.interpret import Interpretation, candidate_nodes, unwrap_envelopes
from protocol.messages import CATALOGUE
from protocol.stream import StreamDecoder
from protocol.topology import ADDR_HOST
from tools.cli.handbus import decode_hand, jsonable

BASELINE = "per-frame-dumps"
#: Goal of the product path: 10 MB in at most 15 s.
TARGET_MB_S = 10 / 15


def interpret_from_scratch(frame: Any, hint: str | None) -> Interpretation:
    """How ``handbus`` named a frame before its plans were cached: every candidate declaration
    tried in turn (the baseline of this benchmark and the oracle of the handbus tests)."""
    direction = "reply" if frame.address == ADDR_HOST else REQUEST
    first: tuple[Any, str | None] = (None, None)
    seen: set[str] = set()
    for node in candidate_nodes(frame.address, hint):
        msg = CATALOGUE.lookup(node, frame.type)
        if msg is None or msg.name in seen:
            continue
        seen.add(msg.name)
        if (msg.request if direction == REQUEST else msg.reply) is None:
            continue
        try:
            return Interpretation(msg, direction, msg.parse(direction, frame.payload))
        except ProtocolError as exc:
            if first[1] is None:
                first = (msg, str(exc))
    return Interpretation(first[0], direction, None, first[1])


def decode_per_frame_dumps(data: bytes, out: io.StringIO, node: str | None = None) -> None:
    """The former writer: a dict per frame, ``jsonable`` copy, ``print(json.dumps(…))``
    (``node``: as ``handbus decode --node``); the benchmark's baseline and the oracle of the
    handbus tests."""
    decoder = StreamDecoder(gap_s=None, report_rejected=True)
    last: dict[int, str] = {}
    for frame in decoder.feed(data) + decoder.flush():
        record: dict[str, Any] = {"offset": frame.offset, "addr": frame.address,
                                  "type": frame.type, "name": None,
                                  "length": len(frame.payload), "crc_ok": frame.crc_ok,
                                  "fields": None}
        if frame.crc_ok:
            hint = node or (last.get(frame.type) if frame.address == ADDR_HOST else None)
            meaning = interpret_from_scratch(frame, hint)
            record["name"] = meaning.name
            record["direction"] = meaning.direction
            record["fields"] = jsonable(meaning.fields)
            if meaning.error:
                record["error"] = meaning.error
            if meaning.message and meaning.direction == REQUEST:
                last[frame.type] = meaning.message.node
            if meaning.message is None:
                record["payload"] = frame.payload.hex()
            layers = unwrap_envelopes(meaning, Frame(frame.address, frame.type, frame.payload))
            if layers:
                record["wrapped"] = [
                    {"name": layer.name, "fields": jsonable(layer.fields),
                     **({"error": layer.error} if layer.error else {})} for layer in layers]
        else:
            record["payload"] = frame.payload.hex()
        print(json.dumps(record, ensure_ascii=False), file=out)


def decode_product(data: bytes, out: io.StringIO) -> None:
    """The product path."""
    decode_hand(data, None, DEFAULT_MAX_PAYLOAD, out)


def _repeat(message: str, payload: bytes, address: int, size: int) -> bytes:
    frame = encode_frame(address, CATALOGUE[message].type_id, payload)
    return frame * (size // len(frame) + 1)


def captures(size: int) -> dict[str, bytes]:
    """The three captures, each about ``size`` bytes."""
    small = b"".join([
        encode_frame(10, 0x01), encode_frame(0, 0x01),                        # ping
        encode_frame(10, 0x65, bytes([50])), encode_frame(0, 0x65, bytes([50])),  # palm.poll
        encode_frame(10, 0x1E, b"\x01"), encode_frame(0, 0x1E, b"\x01"),    # phalange_power
        encode_frame(10, 0x21), encode_frame(1, 0x12),                        # status, imu
    ])
    status = bytes(range(148))
    return {
        "mixed": make_capture(size, seed=2),
        "small": small * (size // len(small) + 1),
        "large": _repeat("fmcb.status", status, ADDR_HOST, size),
    }


def _seconds(func: Callable[[bytes, io.StringIO], None], data: bytes, repeat: int) -> float:
    """Best-of-``repeat`` wall time (s) of one decode of ``data``."""
    best = float("inf")
    for _ in range(repeat):
        out = io.StringIO()
        start = time.perf_counter()
        func(data, out)
        best = min(best, time.perf_counter() - start)
    return best


def run(quick: bool = False) -> list[Result]:
    """MB/s of capture decoded to JSON lines by both paths, for each capture."""
    size = 200_000 if quick else 1_000_000
    repeat = 1 if quick else 2
    results: list[Result] = []
    for group, data in captures(size).items():
        check_product, check_baseline = io.StringIO(), io.StringIO()
        decode_product(data, check_product)
        decode_per_frame_dumps(data, check_baseline)
        if check_product.getvalue() != check_baseline.getvalue():
            raise AssertionError(f"{group}: the paths print different lines")
        frames = check_product.getvalue().count("\n")
        for name, func in (("handbus-decode", decode_product), (BASELINE, decode_per_frame_dumps)):
            seconds = _seconds(func, data, repeat)
            rate = len(data) / seconds / 1e6
            results.append(Result(
                group=f"handbus-{group}", name=name, rate=rate, unit="MB",
                baseline=None if name == BASELINE else BASELINE,
                target=TARGET_MB_S if name != BASELINE else None,
                note=f"{10 / rate:.1f} s per 10 MB; {len(data) / 1e6:.1f} MB, {frames} frames",
            ))
    return results


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    for r in run(quick="--quick" in args):
        print(f"{r.group:16s} {r.name:16s} {r.rate:6.2f} MB/s  {r.note}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
