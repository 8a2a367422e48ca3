"""``handbus``: decode and encode hand-bus and arm-bus captures at the bench.

    handbus decode [FILE|-] [--hex] [--dynamixel] [--node NODE]   one JSON object per frame,
                                                                  then a summary line
    handbus decode RUN.mcap [--dynamixel]                         the raw-frame channels of a
                                                                  recording, with channel, t
    handbus encode NAME [field=value …] --addr A [--reply]        the frame as hex
    handbus list                                                  the message catalogue

Like a logic-analyser decoder: it never crashes on garbage; bad input files or bad
arguments give a clear message on standard error and exit status 2.

A coded field (an ``EnumField`` of the catalogue) decodes to its member's name, e.g.
``"status": "NO_REPLY"``, and an unknown code to its number; ``encode`` accepts either
(``mode=joint``, ``mode=2``).
"""

from __future__ import annotations

import argparse
import difflib
import enum
import json
import re
import sys
from collections.abc import Sequence
from typing import Any, BinaryIO

from protocol.catalogue import REPLY, REQUEST
from protocol.errors import ProtocolError
from protocol.framing import DEFAULT_MAX_PAYLOAD
from protocol.interpret import interpret
from protocol.messages import CATALOGUE
from protocol.stream import StreamDecoder
from protocol.topology import ADDR_F2, ADDR_F3, ADDR_FMCB, ADDR_HOST
from tools.cli_values import FieldValueError, build_fields


class UsageError(Exception):
    """Bad arguments or input: printed, exit status 2."""


def jsonable(value: Any) -> Any:
    """Bytes → hex strings and code members → their names, recursively, so any decoded
    payload prints as JSON that ``encode`` takes back."""
    if isinstance(value, bytes | bytearray):
        return value.hex()
    if isinstance(value, enum.IntEnum):
        return value.name
    if isinstance(value, dict):
        return {k: jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    return value


_HEX_TOKEN = re.compile(r"^(?:0x)?([0-9a-fA-F]*)$")


def parse_hex_text(text: str) -> bytes:
    """Hex text → bytes: whitespace, commas and colons separate; '#' starts a comment."""
    out = bytearray()
    for lineno, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0]
        for token in re.split(r"[\s,:]+", line.strip()):
            if not token:
                continue
            m = _HEX_TOKEN.match(token)
            if not m or len(m.group(1)) % 2:
                raise UsageError(f"line {lineno}: {token!r} is not hex bytes")
            out += bytes.fromhex(m.group(1))
    return bytes(out)


def read_input(path: str, as_hex: bool, stdin: BinaryIO) -> bytes:
    """The capture's bytes from a file or standard input ('-')."""
    try:
        if path == "-":
            raw = stdin.read()
        else:
            with open(path, "rb") as fh:
                raw = fh.read()
    except OSError as exc:
        raise UsageError(f"cannot read {path}: {exc.strerror}") from exc
    if not as_hex:
        return raw
    try:
        return parse_hex_text(raw.decode("ascii"))
    except UnicodeDecodeError as exc:
        raise UsageError(f"{path} is not hex text (byte {exc.start} is not ASCII)") from exc


def decode_hand(data: bytes, node: str | None, max_payload: int, out: Any) -> dict[str, int]:
    """Print one JSON line per frame found in ``data`` (rejected ones with crc_ok false)."""
    decoder = StreamDecoder(max_payload=max_payload, gap_s=None, report_rejected=True)
    last_node_for_type: dict[int, str] = {}
    for frame in decoder.feed(data) + decoder.flush():
        record: dict[str, Any] = {
            "offset": frame.offset,
            "addr": frame.address,
            "type": frame.type,
            "name": None,
            "length": len(frame.payload),
            "crc_ok": frame.crc_ok,
            "fields": None,
        }
        if frame.crc_ok:
            hint = node or (last_node_for_type.get(frame.type) if frame.address == ADDR_HOST
                            else None)
            meaning = interpret(frame, hint)
            record["name"] = meaning.name
            record["direction"] = meaning.direction
            record["fields"] = jsonable(meaning.fields)
            if meaning.error:
                record["error"] = meaning.error
            if meaning.message and meaning.direction == REQUEST:
                last_node_for_type[frame.type] = meaning.message.node
            if meaning.message is None:
                record["payload"] = frame.payload.hex()
        else:
            record["payload"] = frame.payload.hex()
        print(json.dumps(record, ensure_ascii=False), file=out)
    return decoder.counters.as_dict()


def decode_dynamixel(data: bytes, direction: str, out: Any) -> dict[str, int]:
    """Print one JSON line per Dynamixel 1.0 packet found in ``data``."""
    from protocol.dynamixel_capture import decode_dynamixel_capture

    records, counters = decode_dynamixel_capture(data, direction)
    for record in records:
        print(json.dumps(jsonable(record)), file=out)
    return counters


def cmd_decode(args: argparse.Namespace, out: Any) -> int:
    if args.file != "-" and not args.hex:
        from tools import mcap_capture

        if mcap_capture.is_mcap(args.file):
            return _decode_mcap(args, out)
    data = read_input(args.file, args.hex, sys.stdin.buffer)
    if args.dynamixel:
        counters = decode_dynamixel(data, args.direction, out)
    else:
        counters = decode_hand(data, args.node, args.max_payload, out)
    print(json.dumps({"summary": counters}), file=out)
    return 0


def _decode_mcap(args: argparse.Namespace, out: Any) -> int:
    """``decode FILE.mcap``: the raw-frame channels of a recording (:mod:`tools.mcap_capture`)."""
    from tools import mcap_capture

    def decoder(topic: str) -> mcap_capture.Decoder:
        if not args.dynamixel:
            return lambda data, sink: decode_hand(data, args.node, args.max_payload, sink)
        direction = args.direction
        if direction == "auto":
            direction = "instruction" if topic.endswith("/tx") else "status"
        return lambda data, sink: decode_dynamixel(data, direction, sink)

    encoding = (mcap_capture.ARM_BYTES_ENCODING if args.dynamixel
                else mcap_capture.HAND_FRAME_ENCODING)
    try:
        counters = mcap_capture.decode_mcap(args.file, encoding, decoder, out)
    except mcap_capture.McapCaptureError as exc:
        raise UsageError(f"{exc}{'' if args.dynamixel else ' (arm recordings: --dynamixel)'}"
                         ) from exc
    print(json.dumps({"summary": counters}), file=out)
    return 0


def cmd_encode(args: argparse.Namespace, out: Any) -> int:
    try:
        msg = CATALOGUE.by_name(args.name)
    except ProtocolError:
        close = difflib.get_close_matches(args.name, CATALOGUE.names(), n=3)
        hint = f"; did you mean {', '.join(close)}?" if close else "; 'handbus list' lists them"
        raise UsageError(f"no message called {args.name!r}{hint}") from None
    direction = REPLY if args.reply else REQUEST
    con = msg.request if direction == REQUEST else msg.reply
    if con is None:
        raise UsageError(f"{msg.name} has no {direction}")
    fields = build_fields(con, args.fields)
    if args.reply:
        frame = msg.reply_frame(fields)
    elif args.addr is None:
        raise UsageError(f"--addr is required for a request (fmcb/palm {ADDR_FMCB}, "
                         f"f2 {ADDR_F2}, f3 {ADDR_F3})")
    else:
        frame = msg.request_frame(args.addr, fields)
    print(frame.hex(" ") if args.spaced else frame.hex(), file=out)
    return 0


def cmd_list(args: argparse.Namespace, out: Any) -> int:
    for msg in CATALOGUE:
        tag = "" if msg.original else " (new)"
        print(f"{msg.name:22s} {msg.node:10s} 0x{msg.type_id:02x}  {msg.summary}{tag}", file=out)
    return 0


def _int(text: str) -> int:
    try:
        return int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None


def make_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="handbus", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)

    dec = sub.add_parser("decode", help="decode a capture into JSON lines")
    dec.add_argument("file", nargs="?", default="-", help="capture file, or - for stdin")
    dec.add_argument("--hex", action="store_true", help="the input is hex text, not raw bytes")
    dec.add_argument("--dynamixel", action="store_true", help="decode Dynamixel 1.0 packets")
    dec.add_argument("--direction", choices=("auto", "instruction", "status"), default="auto",
                     help="with --dynamixel: what the packets are")
    dec.add_argument("--node", choices=("fmcb", "palm", "f2", "f3", "bootloader"),
                     help="decode frames as this node's messages first")
    dec.add_argument("--max-payload", type=_int, default=DEFAULT_MAX_PAYLOAD,
                     help="bound on the length field (bytes)")
    dec.set_defaults(func=cmd_decode)

    enc = sub.add_parser("encode", help="build a frame and print it as hex")
    enc.add_argument("name", help="message name, e.g. fmcb.status ('handbus list')")
    enc.add_argument("fields", nargs="*", help="field=value (lists: 1,2,3; bytes: hex; "
                                               "nested: args.target=0.1,0.2,0.3)")
    enc.add_argument("--addr", type=_int, help="destination address")
    enc.add_argument("--reply", action="store_true", help="build the reply (to address 0)")
    enc.add_argument("--spaced", action="store_true", help="separate bytes by spaces")
    enc.set_defaults(func=cmd_encode)

    lst = sub.add_parser("list", help="list the message catalogue")
    lst.set_defaults(func=cmd_list)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``handbus`` console script."""
    parser = make_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:
        # argparse stops collecting the positional field=value words at the first option
        # (``encode NAME --addr 10 mode=2``): take the rest of them too.
        if args.command == "encode" and all("=" in w and not w.startswith("-") for w in extra):
            args.fields = [*args.fields, *extra]
        else:
            parser.error(f"unrecognized arguments: {' '.join(extra)}")
    try:
        return int(args.func(args, sys.stdout))
    except (UsageError, FieldValueError) as exc:
        print(f"handbus: error: {exc}", file=sys.stderr)
        return 2
    except ProtocolError as exc:
        print(f"handbus: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        return 0


if __name__ == "__main__":
    sys.exit(main())
