"""``handbus``: decode and encode hand-bus and arm-bus captures at the bench.

    handbus decode [FILE|-] [--hex] [--dynamixel] [--node NODE]   one JSON object per frame,
                                                                  then a summary line
    handbus decode RUN.mcap [--dynamixel]                         the raw-frame channels of a
                                                                  recording, with channel, t
    handbus encode NAME [field=value …] --addr A [--reply]        the frame as hex
    handbus list                                                  the message catalogue

Like a logic-analyser decoder: it never crashes on garbage; bad input files (an empty
one, a ``.mcap`` that is not a recording) or bad arguments give a clear message on standard
error and exit status 2.  A recording cut short (a killed recorder, a full disk) decodes up
to its cut, then a warning on standard error says how many bytes at the end could not be
read, and the exit status is 3.

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
import time
from collections.abc import Callable, Sequence
from typing import Any, BinaryIO, TextIO

import construct as c

from protocol.catalogue import REPLY, REQUEST, Message
from protocol.errors import ProtocolError
from protocol.framing import DEFAULT_MAX_PAYLOAD, Frame
from protocol.interpret import NODE_KINDS_TRIED, interpret, unwrap_envelopes
from protocol.messages import CATALOGUE
from protocol.stream import FrameTuple, StreamDecoder
from protocol.topology import ADDR_BROADCAST, ADDR_HOST, NODE_ADDRESS, NodeKind
from tools.cli.numeric import read_negative_numbers
from tools.cli.output import guard_output
from tools.cli.values import FieldValueError, build_fields, check_fields
from tools.errors import InputError


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
                raise InputError(f"line {lineno}: {token!r} is not hex bytes")
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
        raise InputError(f"cannot read {path}: {exc.strerror}") from exc
    if not as_hex:
        return raw
    try:
        return parse_hex_text(raw.decode("ascii"))
    except UnicodeDecodeError as exc:
        raise InputError(f"{path} is not hex text (byte {exc.start} is not ASCII)") from exc


#: Bytes fed to the stream decoder at a time (the progress bar moves once per chunk).
CHUNK = 1 << 18
#: Frames whose payload is at most this long have their whole JSON line kept by content.
_LINE_CACHE_PAYLOAD = 16
#: Bound on the lines kept (all are dropped when it is reached).
_LINE_CACHE_LIMIT = 1 << 16


def _hex_bytes(value: Any) -> str:
    """The encoder's fallback: bytes print as hex (as :func:`jsonable` makes them)."""
    if isinstance(value, bytes | bytearray):
        return value.hex()
    raise TypeError(f"Object of type {value.__class__.__name__} is not JSON serializable")


def _json_encoder() -> Callable[[Any], str]:
    """``json.dumps(jsonable(x), ensure_ascii=False)`` without the copy, made once.

    ``JSONEncoder.encode`` makes a new C encoder on every call; this keeps one (the same
    C encoder with the same settings, so the same text), or falls back to ``encode`` where
    the C accelerator is missing.
    """
    encoder = json.JSONEncoder(ensure_ascii=False, default=_hex_bytes)
    make = getattr(json.encoder, "c_make_encoder", None)
    if make is None:
        return encoder.encode
    c_encode = make(None, encoder.default, json.encoder.encode_basestring, encoder.indent,
                    encoder.key_separator, encoder.item_separator, encoder.sort_keys,
                    encoder.skipkeys, encoder.allow_nan)

    def encode(value: Any) -> str:
        return "".join(c_encode(value, 0))

    return encode


_encode = _json_encoder()


#: Construct classes whose parsed values are only ints, floats, text, bytes, lists and
#: dicts: the encoder prints those exactly as ``jsonable`` + ``json.dumps`` would.
_PLAIN_CONSTRUCTS = (c.FormatField, c.Struct, c.Array, c.Bytes, c.StringEncoded, c.Prefixed,
                     c.Padded, c.Renamed, c.Switch, c.Rebuild, c.Check, c.Const, c.FocusedSeq,
                     c.Terminated.__class__, c.GreedyBytes.__class__, c.Pass.__class__,
                     c.Error.__class__)


def _plain_declaration(con: Any) -> bool:
    """True when every construct in ``con`` is one of :data:`_PLAIN_CONSTRUCTS`."""
    if not isinstance(con, _PLAIN_CONSTRUCTS):
        return False
    subs = [*getattr(con, "subcons", ()),
            *(getattr(con, attr) for attr in ("subcon", "lengthfield", "default")
              if isinstance(getattr(con, attr, None), c.Construct)),
            *getattr(con, "cases", {}).values()]
    return all(_plain_declaration(sub) for sub in subs)


_coded_cache: dict[tuple[str, str], frozenset[str]] = {}


def _coded_keys(msg: Message, direction: str) -> frozenset[str]:
    """The top-level fields of ``msg``'s ``direction`` whose values may hold something other
    than plain values (e.g. coded values of an adapter): only those go through ``jsonable``."""
    key = (msg.name, direction)
    coded = _coded_cache.get(key)
    if coded is None:
        struct_con = msg.declaration(direction)
        while isinstance(struct_con, c.Renamed):
            struct_con = struct_con.subcon
        if isinstance(struct_con, c.Struct):
            coded = frozenset(sub.name for sub in struct_con.subcons
                              if sub.name is not None and not _plain_declaration(sub))
        else:  # not a Struct: map the whole record
            coded = frozenset() if _plain_declaration(struct_con) else frozenset({"*"})
        _coded_cache[key] = coded
    return coded


#: JSON text of each message name and direction (and of no name).
_names: dict[str | None, str] = {n: _encode(n) for n in (*CATALOGUE.names(), REQUEST, REPLY)}
_names[None] = "null"


class HandRecords:
    """Turns decoded hand frames into the JSON lines ``handbus decode`` prints.

    One line per frame: ``offset``, ``addr``, ``type``, ``name``, ``length``, ``crc_ok``,
    ``fields``, then ``direction`` (and ``error`` when no declaration fits, ``payload`` hex
    when the type is unknown) for a good frame, ``payload`` for a CRC-failed one.  A reply
    is named with the node of the last request of its type when no ``node`` is given.
    Lines of short payloads are kept by content, since the same polls recur all capture
    long; everything else is encoded as it comes.
    """

    def __init__(self, node: str | None = None) -> None:
        self.node = node
        self._last_node_for_type: dict[int, str] = {}
        self._lines: dict[tuple[int, int, bytes, str | None], tuple[str, str | None]] = {}

    def lines(self, frames: list[FrameTuple]) -> str:
        """The lines of ``frames`` (from :meth:`StreamDecoder.feed_tuples`), each ending in
        a newline."""
        node = self.node
        last_node = self._last_node_for_type
        cache = self._lines
        out: list[str] = []
        append = out.append
        for address, msg_type, payload, offset, crc_ok in frames:
            if not crc_ok:
                append(self._rejected(address, msg_type, payload, offset))
                continue
            hint = node or (last_node.get(msg_type) if address == ADDR_HOST else None)
            if len(payload) <= _LINE_CACHE_PAYLOAD:
                key = (address, msg_type, payload, hint)
                hit = cache.get(key)
                if hit is None:
                    if len(cache) >= _LINE_CACHE_LIMIT:
                        cache.clear()
                    hit = cache[key] = self._tail(Frame(address, msg_type, payload), hint)
            else:
                hit = self._tail(Frame(address, msg_type, payload), hint)
            tail, request_node = hit
            if request_node is not None:
                last_node[msg_type] = request_node
            append(f'{{"offset": {offset}, {tail}')
        return "".join(out)

    @staticmethod
    def _tail(frame: Frame, hint: str | None) -> tuple[str, str | None]:
        """A good frame's line after its offset, and the node it names as requested."""
        meaning = interpret(frame, hint)
        msg = meaning.message
        fields = meaning.fields
        if msg is not None and fields is not None:
            coded = _coded_keys(msg, meaning.direction)
            if "*" in coded:
                fields = jsonable(fields)
            elif coded:
                fields = {k: jsonable(v) if k in coded else v for k, v in fields.items()}
        text = (f'"addr": {frame.address}, "type": {frame.type}, "name": {_names[meaning.name]}, '
                f'"length": {len(frame.payload)}, "crc_ok": true, '
                f'"fields": {_encode(fields)}, "direction": {_names[meaning.direction]}')
        if meaning.error:
            text += f', "error": {_encode(meaning.error)}'
        if msg is None:
            text += f', "payload": "{frame.payload.hex()}"'
        layers = unwrap_envelopes(meaning, frame)
        if layers:  # what the envelopes (txn, palm.route) carry, decoded beside their bytes
            wrapped = []
            for layer in layers:
                entry: dict[str, Any] = {"name": layer.name, "fields": (
                    jsonable(layer.fields) if layer.fields is not None else None)}
                if layer.error:
                    entry["error"] = layer.error
                wrapped.append(entry)
            text += f', "wrapped": {_encode(wrapped)}'
        request_node = msg.node if msg is not None and meaning.direction == REQUEST else None
        return text + "}\n", request_node

    @staticmethod
    def _rejected(address: int, msg_type: int, payload: bytes, offset: int) -> str:
        record = {"offset": offset, "addr": address, "type": msg_type, "name": None,
                  "length": len(payload), "crc_ok": False, "fields": None,
                  "payload": payload.hex()}
        return _encode(record) + "\n"


class Progress:
    """A one-line progress bar on a terminal (``stream``), redrawn at most 10 times a second."""

    def __init__(self, stream: TextIO, total: int, what: str = "decoding") -> None:
        self.stream = stream
        self.total = total
        self.what = what
        self._start = time.perf_counter()
        self._drawn = 0.0
        self._shown = -1  # bytes shown by the last redraw

    def update(self, done: int, force: bool = False) -> None:
        """Show ``done`` of ``total`` bytes (throttled unless ``force``)."""
        now = time.perf_counter()
        if (not force and now - self._drawn < 0.1) or done == self._shown:
            return
        self._drawn, self._shown = now, done
        fraction = done / self.total if self.total else 1.0
        width = 30
        filled = int(width * fraction)
        rate = done / max(now - self._start, 1e-9) / 1e6
        self.stream.write(f"\rhandbus: {self.what} [{'#' * filled}{'.' * (width - filled)}] "
                          f"{fraction:4.0%} {done / 1e6:.1f}/{self.total / 1e6:.1f} MB "
                          f"{rate:.1f} MB/s")
        self.stream.flush()

    def close(self) -> None:
        """Draw 100 % and end the line."""
        self.update(self.total, force=True)
        self.stream.write("\n")
        self.stream.flush()


def progress_for(stream: TextIO, total: int) -> Progress | None:
    """A :class:`Progress` when ``stream`` is a terminal, else None (pipes stay clean)."""
    try:
        tty = stream.isatty()
    except (AttributeError, ValueError):
        tty = False
    return Progress(stream, total) if tty else None


def decode_hand(data: bytes, node: str | None, max_payload: int, out: Any,
                progress: Progress | None = None) -> dict[str, int]:
    """Write one JSON line per frame found in ``data`` (rejected ones with crc_ok false)."""
    decoder = StreamDecoder(max_payload=max_payload, gap_s=None, report_rejected=True)
    records = HandRecords(node)
    view = memoryview(data)
    for start in range(0, len(data), CHUNK):
        out.write(records.lines(decoder.feed_tuples(view[start : start + CHUNK])))
        if progress is not None:
            progress.update(min(start + CHUNK, len(data)))
    out.write(records.lines(decoder.flush_tuples()))
    if progress is not None:
        progress.close()
    return decoder.counters.as_dict()


def decode_dynamixel(data: bytes, direction: str, out: Any) -> dict[str, int]:
    """Print one JSON line per Dynamixel 1.0 packet found in ``data``."""
    from protocol.dynamixel_capture import decode_dynamixel_capture

    records, counters = decode_dynamixel_capture(data, direction)
    for record in records:
        print(json.dumps(jsonable(record)), file=out)
    return counters


#: ``decode`` of an MCAP recording cut short (or damaged) before its end: every message
#: before the cut was decoded, and standard error says how many bytes at the end were not.
EXIT_CUT = 3


def cmd_decode(args: argparse.Namespace, out: Any) -> int:
    if args.file != "-" and not args.hex:
        from tools.cli import mcap_capture

        if mcap_capture.is_mcap(args.file):
            return _decode_mcap(args, out)
    data = read_input(args.file, args.hex, sys.stdin.buffer)
    name = "standard input" if args.file == "-" else args.file
    if not data:
        raise InputError(f"{name} is empty (0 bytes): nothing to decode")
    if args.file.lower().endswith(".mcap") and not args.hex:
        from tools.cli import mcap_capture

        raise InputError(f"{name} is not an MCAP recording: "
                         f"{mcap_capture.describe_start(data)}")
    if args.dynamixel:
        counters = decode_dynamixel(data, args.direction, out)
    else:
        progress = progress_for(sys.stderr, len(data))
        counters = decode_hand(data, args.node, args.max_payload, out, progress)
    print(json.dumps({"summary": counters}), file=out)
    return 0


def _decode_mcap(args: argparse.Namespace, out: Any) -> int:
    """``decode FILE.mcap``: the raw-frame channels of a recording (:mod:`tools.cli.mcap_capture`),
    up to where it is cut short (exit :data:`EXIT_CUT`, with a warning)."""
    from tools.cli import mcap_capture

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
        contents = mcap_capture.read_recording(args.file)
        counters = mcap_capture.decode_mcap(args.file, encoding, decoder, out, contents)
    except mcap_capture.McapCaptureError as exc:
        raise InputError(str(exc)) from exc
    print(json.dumps({"summary": counters}), file=out)
    if contents.stopped:
        out.flush()
        print(f"handbus: warning: {args.file} is {contents.stopped}: the last "
              f"{contents.unread} of its {contents.size} bytes (from byte {contents.end}) "
              f"could not be read whole; the {len(contents.messages)} messages before the "
              f"cut are decoded above{_salvaged(contents.salvaged)}",
              file=sys.stderr)
        return EXIT_CUT
    return 0


def _salvaged(n: int) -> str:
    return f" ({n} of them from the start of the chunk it cuts)" if n else ""


def _node_addresses() -> str:
    """The hand nodes' addresses, for messages: ``"fmcb/palm 10, f2 1, f3 2"``."""
    names: dict[int, list[str]] = {}
    for name in NODE_KINDS_TRIED:
        if name in tuple(NodeKind):
            names.setdefault(NODE_ADDRESS[NodeKind(name)], []).append(name)
    return ", ".join(f"{'/'.join(kinds)} {address}" for address, kinds in names.items())


def cmd_encode(args: argparse.Namespace, out: Any) -> int:
    try:
        msg = CATALOGUE.by_name(args.name)
    except ProtocolError:
        close = difflib.get_close_matches(args.name, CATALOGUE.names(), n=3)
        hint = f"; did you mean {', '.join(close)}?" if close else "; 'handbus list' lists them"
        raise InputError(f"no message called {args.name!r}{hint}") from None
    direction = REPLY if args.reply else REQUEST
    con = msg.request if direction == REQUEST else msg.reply
    if con is None:
        raise InputError(f"{msg.name} has no {direction}")
    addresses = _node_addresses()
    if not args.reply:
        if args.addr is None:
            raise InputError(f"--addr is required for a request ({addresses})")
        if not 0 <= args.addr <= 0xFF:
            raise InputError(f"address {args.addr} is outside 0..255 ({addresses}, "
                             f"broadcast {ADDR_BROADCAST})")
    fields = build_fields(con, args.fields)
    check_fields(con, fields, msg.name)
    payload = msg.build(direction, fields)
    if len(payload) > args.max_payload:
        raise InputError(f"the {msg.name} {direction} payload is {len(payload)} bytes; a decoder "
                         f"reading at most {args.max_payload} bytes (--max-payload) drops it")
    frame = msg.reply_frame(fields) if args.reply else msg.request_frame(args.addr, fields)
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
    dec.add_argument("--node", choices=NODE_KINDS_TRIED,
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
    enc.add_argument("--max-payload", type=_int, default=DEFAULT_MAX_PAYLOAD,
                     help="refuse payloads longer than a decoder with this bound reads (bytes)")
    enc.set_defaults(func=cmd_encode)

    lst = sub.add_parser("list", help="list the message catalogue")
    lst.set_defaults(func=cmd_list)
    return parser


@guard_output("handbus")
def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``handbus`` console script."""
    parser = make_parser()
    args, extra = read_negative_numbers(parser).parse_known_args(argv)
    if extra:
        # argparse stops collecting the positional field=value words at the first option
        # (``encode NAME --addr 10 mode=2``): take the rest of them too.
        if args.command == "encode" and all("=" in w and not w.startswith("-") for w in extra):
            args.fields = [*args.fields, *extra]
        else:
            parser.error(f"unrecognized arguments: {' '.join(extra)}")
    try:
        return int(args.func(args, sys.stdout))
    except (InputError, FieldValueError) as exc:
        print(f"handbus: error: {exc}", file=sys.stderr)
        return 2
    except ProtocolError as exc:
        print(f"handbus: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
