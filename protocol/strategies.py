"""Hypothesis strategies derived from the wire declarations, declared once for every user.

The round-trip property tests, the live-target fuzzer (``tools.fuzz``) and the in-process
fuzzers all draw from here:

- :func:`values_for` — field values that a construct declaration builds (structs, coded
  ``EnumField`` fields, flat records, a ``Switch`` on a sibling such as the control mode,
  counted and greedy bytes), biased toward the extremes of each number's range;
- :func:`request_fields` / :func:`request_frames` — valid requests of catalogue messages;
- :func:`mutated_frames` — one hand frame made wrong: a lying length, a truncation, a bad
  CRC, a foreign address, a dropped sync;
- :func:`write_splits` — a byte string cut at arbitrary write boundaries with gaps (µs);
- :func:`dynamixel_instructions` — Dynamixel 1.0 instruction packets addressed to the
  registers of a control table (:mod:`protocol.control_tables`).

``hypothesis`` is imported inside the functions, so :mod:`protocol` works without it.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, Final, Literal

import construct as c

from protocol.catalogue import REQUEST, Message
from protocol.control_tables import ControlTable
from protocol.enum_field import EnumField
from protocol.framing import HEADER_SIZE, SYNC, encode_frame
from protocol.messages.fmcb import TUNNEL_MAX

if TYPE_CHECKING:
    from hypothesis.strategies import SearchStrategy

#: Inclusive ranges of construct's integer format codes.
INT_RANGES: Final = {
    "B": (0, 2**8 - 1),
    "H": (0, 2**16 - 1),
    "I": (0, 2**32 - 1),
    "L": (0, 2**32 - 1),
    "Q": (0, 2**64 - 1),
    "b": (-(2**7), 2**7 - 1),
    "h": (-(2**15), 2**15 - 1),
    "i": (-(2**31), 2**31 - 1),
    "l": (-(2**31), 2**31 - 1),
    "q": (-(2**63), 2**63 - 1),
}
#: Largest dynamically sized (counted) byte field generated: the tunnel's bound.
MAX_DYNAMIC: Final = TUNNEL_MAX
#: Largest greedy byte field generated.
MAX_GREEDY: Final = 64
#: Integers also come from 0..SMALL_MAX, where indices, counts and ids live.
SMALL_MAX: Final = 32
#: Float32 extremes worth trying on every float field.
FLOAT32_EXTREMES: Final = (0.0, -0.0, 1.0, -1.0, 3.4028234663852886e38, -3.4028234663852886e38,
                           1.401298464324817e-45, math.inf, -math.inf)

#: The ways :func:`mutated_frames` breaks a frame.
MUTATIONS: Final = ("bad_crc", "truncated", "long_length", "short_length", "foreign_address",
                    "no_sync", "garbage")


class _KeyProbe(dict[str, Any]):
    """A context that records which field a Switch's key function reads."""

    def __init__(self) -> None:
        super().__init__()
        self.read: list[str] = []

    def __getitem__(self, key: str) -> Any:
        self.read.append(key)
        return 0

    def __getattr__(self, key: str) -> Any:
        return self[key]


def unwrap(con: c.Construct) -> c.Construct:
    """The declaration under any field renames (``"name" / con * "doc"``)."""
    while isinstance(con, c.Renamed):
        con = con.subcon
    return con


def switch_keys(struct_con: c.Struct) -> dict[str, list[Any]]:
    """Field name → allowed values, for fields a Switch of this Struct is keyed on."""
    keys: dict[str, list[Any]] = {}
    for sub in struct_con.subcons:
        inner = unwrap(sub)
        if isinstance(inner, c.Switch):
            probe = _KeyProbe()
            inner.keyfunc(probe)
            if len(probe.read) != 1:
                raise NotImplementedError("a Switch keyed on one sibling field")
            keys[probe.read[0]] = sorted(inner.cases)
    return keys


def _integers(lo: int, hi: int) -> SearchStrategy[int]:
    from hypothesis import strategies as st

    extremes = sorted({lo, hi, 0 if lo <= 0 <= hi else lo, min(hi, lo + 1), max(lo, hi - 1)})
    small = st.integers(max(lo, 0), min(hi, SMALL_MAX))  # indices, counts, ids, modes
    return st.one_of(st.sampled_from(extremes), small, small, st.integers(lo, hi))


def _floats(width: Literal[32, 64], allow_nan: bool) -> SearchStrategy[float]:
    from hypothesis import strategies as st

    extremes = [v for v in FLOAT32_EXTREMES if allow_nan or math.isfinite(v)]
    plain = st.floats(width=width, allow_nan=allow_nan, allow_infinity=allow_nan)
    return st.one_of(st.sampled_from(extremes), plain)


def values_for(con: c.Construct, *, allow_nan: bool = False) -> SearchStrategy[Any]:
    """A strategy of values that ``con`` builds (Rebuild, Padding and Check fields omitted).

    Numbers are drawn from their whole range, from 0..:data:`SMALL_MAX` (indices, counts)
    and from the extremes (0, ±1, min, max and their neighbours; ±inf and NaN for floats when ``allow_nan``) tried first; coded fields give
    members, member names and unknown codes; counted bytes up to :data:`MAX_DYNAMIC`.
    """
    from hypothesis import strategies as st

    con = unwrap(con)
    if isinstance(con, c.Struct):
        return _struct_values(con, allow_nan)
    if isinstance(con, EnumField):
        members = list(con.enum_type)
        return st.one_of(
            st.sampled_from(members),
            st.sampled_from([m.name for m in members] + [m.name.lower() for m in members]),
            values_for(con.subcon, allow_nan=allow_nan),  # any code, known or not
        )
    if isinstance(con, c.FormatField):
        code = con.fmtstr[-1]
        if code == "f":
            return _floats(32, allow_nan)
        if code == "d":
            return _floats(64, allow_nan)
        lo, hi = INT_RANGES[code]
        return _integers(lo, hi)
    if isinstance(con, c.Array):
        if not isinstance(con.count, int):
            raise NotImplementedError("arrays of a fixed count")
        return st.lists(values_for(con.subcon, allow_nan=allow_nan),
                        min_size=con.count, max_size=con.count)
    if isinstance(con, c.Bytes):
        if isinstance(con.length, int):
            return st.binary(min_size=con.length, max_size=con.length)
        return st.one_of(st.binary(max_size=16), st.binary(max_size=MAX_DYNAMIC),
                         st.just(bytes(MAX_DYNAMIC)))
    if con is c.GreedyBytes:
        return st.binary(max_size=MAX_GREEDY)
    if isinstance(con, c.StringEncoded):
        if con.encoding != "ascii":
            raise NotImplementedError(f"strings encoded as {con.encoding}")
        return st.text(st.characters(max_codepoint=0x7F), max_size=255)
    raise NotImplementedError(f"no strategy for {con!r}")


def omitted(sub: c.Construct) -> bool:
    """True for a struct member the caller never gives (anonymous, computed or constant)."""
    inner = unwrap(sub)
    return (
        getattr(sub, "name", None) is None
        or isinstance(inner, c.Rebuild | c.Check | c.Padded | c.Const)
    )


def _struct_values(con: c.Struct, allow_nan: bool) -> SearchStrategy[dict[str, Any]]:
    from hypothesis import strategies as st

    keys = switch_keys(con)

    @st.composite
    def draw_struct(draw: st.DrawFn) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for sub in con.subcons:
            if omitted(sub):
                continue
            inner = unwrap(sub)
            if sub.name in keys:
                out[sub.name] = draw(st.sampled_from(keys[sub.name]))
            elif isinstance(inner, c.Switch):
                case = inner.cases[inner.keyfunc(out)]
                out[sub.name] = draw(values_for(case, allow_nan=allow_nan))
            else:
                out[sub.name] = draw(values_for(inner, allow_nan=allow_nan))
        return out

    return draw_struct()


def request_fields(msg: Message, *, allow_nan: bool = False) -> SearchStrategy[dict[str, Any]]:
    """Field dicts of ``msg``'s request (it must have one)."""
    return values_for(msg.declaration(REQUEST), allow_nan=allow_nan)


def request_payloads(msg: Message, *, allow_nan: bool = True) -> SearchStrategy[bytes]:
    """Valid request payloads of ``msg`` (built through the catalogue)."""
    return request_fields(msg, allow_nan=allow_nan).map(msg.build_request)


def request_frames(messages: Sequence[Message], address: int, *,
                   allow_nan: bool = True) -> SearchStrategy[bytes]:
    """Whole, valid hand frames to ``address`` carrying a request of one of ``messages``."""
    from hypothesis import strategies as st

    with_requests = [m for m in messages if m.request is not None]
    def framed(msg: Message) -> SearchStrategy[bytes]:
        return request_payloads(msg, allow_nan=allow_nan).map(
            lambda payload: encode_frame(address, msg.type_id, payload))

    return st.one_of(*(framed(m) for m in with_requests))


def mutate_frame(frame: bytes, how: str, value: int, avoid: Sequence[int] = ()) -> bytes:
    """``frame`` broken in the way ``how`` names (:data:`MUTATIONS`); ``value`` (any
    non-negative int) picks the detail: the CRC bit, the cut, the length error, the address.
    A deterministic function, so a reproducer can store (frame, how, value).  A foreign
    address is never the frame's own, broadcast, or one of ``avoid`` (the other nodes on
    the same line, which would rightly answer)."""
    body = bytearray(frame)
    if how == "bad_crc":
        body[-1 - (value // 8) % 2] ^= 1 << (value % 8)
    elif how == "truncated":
        cut = 1 + value % max(1, len(frame) - 1)
        del body[cut:]
    elif how in ("long_length", "short_length"):
        (length,) = struct.unpack_from("<H", body, 2)
        delta = 1 + value % 300
        new = (length + delta if how == "long_length" else length - delta) & 0xFFFF
        struct.pack_into("<H", body, 2, new)
    elif how == "foreign_address":
        address = body[1]
        foreign = [a for a in range(256) if a not in (address, 0xFF, *avoid)]
        body[1] = foreign[value % len(foreign)]
        crc_frame = encode_frame(body[1], body[HEADER_SIZE - 1], bytes(body[HEADER_SIZE:-2]))
        return crc_frame
    elif how == "no_sync":
        body[0] = (SYNC + 1 + value % 255) & 0xFF
    elif how == "garbage":
        return bytes((value * 2654435761 >> (8 * (i % 4))) & 0xFF for i in range(value % 48))
    else:
        raise ValueError(f"unknown mutation {how!r}; choose one of {', '.join(MUTATIONS)}")
    return bytes(body)


def mutated_frames(frames: SearchStrategy[bytes]) -> SearchStrategy[tuple[bytes, str, int]]:
    """(broken frame, mutation, detail) from a strategy of valid frames."""
    from hypothesis import strategies as st

    return st.tuples(frames, st.sampled_from(MUTATIONS), st.integers(0, 2**16)).map(
        lambda t: (mutate_frame(t[0], t[1], t[2]), t[1], t[2]))


def write_splits(data: bytes, max_gap_us: int) -> SearchStrategy[list[tuple[bytes, int]]]:
    """``data`` cut at arbitrary write boundaries: [(chunk, gap before it in µs), …]; the
    chunks join to ``data`` and each gap is at most ``max_gap_us``."""
    from hypothesis import strategies as st

    n = len(data)

    @st.composite
    def draw_split(draw: st.DrawFn) -> list[tuple[bytes, int]]:
        cuts = sorted(draw(st.sets(st.integers(1, max(1, n - 1)), max_size=min(6, n))))
        cuts = [k for k in cuts if 0 < k < n]
        bounds = [0, *cuts, n]
        return [(data[a:b], 0 if i == 0 else draw(st.integers(0, max_gap_us)))
                for i, (a, b) in enumerate(zip(bounds, bounds[1:], strict=False))]

    return draw_split()


def register_writes(table: ControlTable, exclude: Sequence[str] = ()
                    ) -> SearchStrategy[tuple[int, bytes]]:
    """(address, data) writes into ``table``: a writable register with an extreme or any
    encodable value, or any span of the table (possibly touching read-only or reserved
    bytes, or running past the end).  Registers named in ``exclude`` (say ``id`` and
    ``baud_rate``, which make a node answer elsewhere) are never written."""
    from hypothesis import strategies as st

    writable = [r for r in table if r.writable and r.name not in exclude]
    guarded = {a for r in table if r.name in exclude for a in range(r.address, r.end)}

    def encoded(reg: Any) -> SearchStrategy[tuple[int, bytes]]:
        lo, hi = reg.encodable
        return _integers(lo, hi).map(
            lambda v: (reg.address, int(v).to_bytes(reg.size, "little", signed=reg.signed)))

    whole = st.one_of(*(encoded(r) for r in writable))
    span = st.tuples(st.integers(0, table.size + 2), st.binary(min_size=1, max_size=8)).filter(
        lambda w: not guarded & set(range(w[0], w[0] + len(w[1]))))
    return st.one_of(whole, whole, span)


def dynamixel_instructions(table: ControlTable, ids: Sequence[int],
                           exclude: Sequence[str] = ()) -> SearchStrategy[bytes]:
    """Dynamixel 1.0 instruction packets (wire bytes) to ``ids`` (and the broadcast ID) over
    ``table``: PING, READ, WRITE, REG_WRITE, ACTION, RESET, SYNC_WRITE, BULK_READ, unknown
    instruction codes and known ones with too few parameters; ``exclude`` as in :func:`register_writes`."""
    from hypothesis import strategies as st

    from protocol import dynamixel as dx

    any_id = st.one_of(st.sampled_from(list(ids)), st.just(dx.BROADCAST_ID),
                       st.integers(0, dx.MAX_ID))
    writes = register_writes(table, exclude)
    read = st.builds(lambda i, a, n: dx.make_read(i, a, n), any_id,
                     st.integers(0, table.size + 2), st.integers(1, 64))
    write = st.builds(lambda i, w: dx.make_write(i, w[0], w[1]), any_id, writes)
    reg_write = st.builds(lambda i, w: dx.make_reg_write(i, w[0], w[1]), any_id, writes)
    sync = st.builds(
        lambda w, chosen: dx.make_sync_write(w[0], len(w[1]), {i: w[1] for i in chosen}),
        writes, st.sets(st.sampled_from(list(ids)), min_size=1))
    bulk = st.builds(lambda entries: dx.make_bulk_read(entries), st.lists(
        st.tuples(st.integers(1, 8), st.sampled_from(list(ids)), st.integers(0, table.size)),
        min_size=1, max_size=4, unique_by=lambda e: e[1]))
    known = sorted(int(i) for i in dx.Instruction)
    unknown = st.builds(lambda i, code, p: dx.InstructionPacket(i, code, p), any_id,
                        st.integers(0, 0xFF).filter(lambda code: code not in known),
                        st.binary(max_size=8))
    # A known instruction too short for its parameters (0 or 1 byte): never a valid write.
    malformed = st.builds(lambda i, code, p: dx.InstructionPacket(i, code, p), any_id,
                          st.sampled_from(known), st.binary(max_size=1))
    packets = st.one_of(
        st.builds(dx.make_ping, any_id), read, write, reg_write,
        st.builds(dx.make_action, any_id), st.builds(dx.make_reset, st.sampled_from(list(ids))),
        sync, bulk, unknown, malformed)
    return packets.map(lambda p: p.encode())
