"""A synthetic hand-bus capture for decode benchmarks and byte-for-byte output checks.

:func:`make_capture` concatenates valid frames of every message of the catalogue, each
request to its node's address followed by its reply to the host (as a palm USB capture
looks), with field values drawn by a seeded generator that follows the construct
declarations (the catalogue's builders make the payloads), plus the frames of
``tools/samples/hand_session.hex``.  With ``noise`` it also sprinkles line noise and
frames with a corrupted CRC, so the decoder's resynchronisation paths run too.
"""

from __future__ import annotations

import random
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import construct as c

from protocol.enum_field import EnumField
from protocol.messages import CATALOGUE
from protocol.strategies import switch_keys
from protocol.topology import ADDR_FMCB, NODE_ADDRESS

SAMPLE = Path(__file__).resolve().parents[1] / "tools" / "samples" / "hand_session.hex"

#: Address of a request to each message namespace (bootloader and common ones go to fmcb's).
_ADDRESS = {**{kind.value: address for kind, address in NODE_ADDRESS.items()},
            "bootloader": ADDR_FMCB, "common": ADDR_FMCB}
#: Largest variable byte field drawn (bytes): keeps frames capture-sized.
_MAX_BYTES = 64


def _unwrap(con: Any) -> Any:
    while isinstance(con, c.Renamed):
        con = con.subcon
    return con


def _number(rng: random.Random, fmt: str) -> Any:
    code = fmt[-1]
    if code in "fd":
        return struct.unpack("<f", struct.pack("<f", rng.uniform(-4.0, 4.0)))[0]
    size = struct.calcsize("<" + code)
    if code.isupper() or code == "B":
        return rng.randrange(1 << (8 * size))
    return rng.randrange(-(1 << (8 * size - 1)), 1 << (8 * size - 1))


def _value(rng: random.Random, con: Any) -> Any:
    """A value ``con`` builds (Rebuild, Padding, Check and Const fields are left out)."""
    con = _unwrap(con)
    if isinstance(con, c.Struct):
        keys = switch_keys(con)
        out: dict[str, Any] = {}
        for sub in con.subcons:
            inner = _unwrap(sub)
            if sub.name is None or isinstance(inner, c.Rebuild | c.Check | c.Padded | c.Const):
                continue
            if sub.name in keys:
                out[sub.name] = rng.choice(keys[sub.name])
            elif isinstance(inner, c.Switch):
                out[sub.name] = _value(rng, inner.cases[inner.keyfunc(out)])
            else:
                out[sub.name] = _value(rng, inner)
        return out
    if isinstance(con, EnumField):  # any code the field holds, named or not
        return _value(rng, con.subcon)
    if isinstance(con, c.FormatField):
        return _number(rng, con.fmtstr)
    if isinstance(con, c.Array):
        return [_value(rng, con.subcon) for _ in range(con.count)]
    if isinstance(con, c.Bytes):
        n = con.length if isinstance(con.length, int) else rng.randrange(_MAX_BYTES)
        return rng.randbytes(n)
    if con is c.GreedyBytes:
        return rng.randbytes(rng.randrange(_MAX_BYTES))
    if isinstance(con, c.StringEncoded):
        return "".join(rng.choice("abcdefghij_") for _ in range(rng.randrange(1, 24)))
    raise NotImplementedError(f"no value for {con!r}")


def _exchanges(rng: random.Random) -> Iterator[bytes]:
    """Request/reply frame pairs of random messages, forever."""
    messages = list(CATALOGUE)
    while True:
        msg = rng.choice(messages)
        if msg.request is not None:
            yield msg.request_frame(_ADDRESS[msg.node], _value(rng, msg.request))
        if msg.reply is not None:
            yield msg.reply_frame(_value(rng, msg.reply))


def sample_bytes() -> bytes:
    """The bytes of ``tools/samples/hand_session.hex`` (comments and spacing dropped)."""
    text = "".join(line.split("#", 1)[0] for line in SAMPLE.read_text().splitlines())
    return bytes.fromhex("".join(text.split()))


def make_capture(size: int, seed: int = 1, noise: bool = False) -> bytes:
    """About ``size`` bytes (at least) of hand-bus traffic, the same for the same arguments.

    Without ``noise`` every byte belongs to a valid frame (the sample's noise and
    corrupted frame excepted, which come first); with it, about 1 frame in 50 has a
    flipped bit and 1 in 50 is followed by a few bytes of line noise.
    """
    rng = random.Random(seed)
    parts = [sample_bytes()]
    total = len(parts[0])
    for frame in _exchanges(rng):
        if noise and rng.random() < 0.02:
            corrupt = bytearray(frame)
            corrupt[rng.randrange(1, len(corrupt))] ^= 1 << rng.randrange(8)
            frame = bytes(corrupt)
        parts.append(frame)
        total += len(frame)
        if noise and rng.random() < 0.02:
            junk = rng.randbytes(rng.randrange(1, 12))
            parts.append(junk)
            total += len(junk)
        if total >= size:
            return b"".join(parts)
    raise AssertionError("unreachable")


def main() -> None:
    """``python -m benchmarks.capture SIZE OUT [--noise]``: write a capture file."""
    import sys

    size, out = int(float(sys.argv[1])), Path(sys.argv[2])
    out.write_bytes(make_capture(size, noise="--noise" in sys.argv[3:]))


if __name__ == "__main__":
    main()
