"""Firmware inputs and image files: raw .bin, Intel HEX, ELF (``pyelftools``).

A payload is the bytes from the application's link address up: real firmware is linked at
the payload address (0x402100 on the SAM3S: the header takes page 32), so an Intel HEX or
ELF input must start there and end inside the application area; gaps between its segments
are filled with 0xFF (erased flash).  A raw .bin is taken as the payload itself.

The readers are strict, because a file cut short still looks like firmware and a truncated
application that verifies would boot: an Intel HEX file needs every record well formed with
a valid checksum, no byte written twice, and its end-of-file record (nothing but blank lines
after it); an ELF file must be 32-bit little-endian ARM (``EM_ARM``, the boards' Cortex-M3),
its loadable segments must not overlap and must lie in the application area.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Final

from elftools.common.exceptions import ELFError
from elftools.elf.elffile import ELFFile
from elftools.elf.enums import ENUM_E_MACHINE

from bootloader.errors import ImageFileError
from protocol import topology
from protocol.errors import ImageError
from protocol.image import (
    APP_START_ADDRESS,
    FLASH,
    HEADER_SIZE,
    MAX_PAYLOAD,
    BoardType,
    FirmwareImage,
    parse_image,
)
from protocol.topology import FINGER_BOARDS
from protocol.topology import board as board_row

#: Where a payload is linked: right after the one-page header (bytes).
PAYLOAD_ADDRESS: Final = APP_START_ADDRESS + HEADER_SIZE
_ELF_MAGIC: Final = b"\x7fELF"
_PT_LOAD: Final = "PT_LOAD"
#: One past the last byte an application may occupy: the end of the application area.
APP_END_ADDRESS: Final = APP_START_ADDRESS + FLASH.app_area_bytes


#: Boards with the hand bootloader: a finger's in hop order, then the others.
HAND_BOARDS: Final = (*(b.board_type for b in FINGER_BOARDS),
                      *(b.board_type for b in topology.HAND_BOARDS if b.hop is None))
#: Their names, in that order (``fmcb``, ``f2``, ``f3``, ``palm``).
HAND_BOARD_NAMES: Final = tuple(board_row(b).app for b in HAND_BOARDS)


def board_of(name: str) -> BoardType:
    """The hand board called ``name`` (one of :data:`HAND_BOARD_NAMES`)."""
    try:
        board = BoardType[name.upper()]
    except KeyError:
        raise ImageFileError(f"unknown board {name!r}: choose "
                             f"{', '.join(HAND_BOARD_NAMES[:-1])} or {HAND_BOARD_NAMES[-1]}"
                             ) from None
    if board not in HAND_BOARDS:
        raise ImageFileError(f"{name}: not a hand board ({', '.join(HAND_BOARD_NAMES)})")
    return board


def default_app(board: BoardType) -> str:
    """The application an image for ``board`` runs unless told otherwise (its name)."""
    return board.name.lower()


def _read(path: Path) -> bytes:
    try:
        return Path(path).read_bytes()
    except FileNotFoundError:
        raise ImageFileError(f"{path}: no such file") from None
    except OSError as exc:
        raise ImageFileError(f"cannot read {path}: {exc.strerror or exc}") from exc


def _from_segments(segments: list[tuple[int, bytes]], path: Path) -> bytes:
    """Bytes from the lowest address to the highest, gaps 0xFF.

    Every segment must lie in the application area and the lowest must start at the payload
    address; segments must not overlap.  Addresses in bytes.
    """
    segments = sorted((a, d) for a, d in segments if d)
    if not segments:
        raise ImageFileError(f"{path}: holds no loadable bytes")
    for address, data in segments:
        if address < PAYLOAD_ADDRESS and address + len(data) > PAYLOAD_ADDRESS:
            raise ImageFileError(
                f"{path}: bytes at 0x{address:x}..0x{address + len(data) - 1:x} reach below "
                f"the payload address 0x{PAYLOAD_ADDRESS:x} (the header takes "
                f"0x{APP_START_ADDRESS:x})")
        if address >= PAYLOAD_ADDRESS and address + len(data) > APP_END_ADDRESS:
            raise ImageFileError(
                f"{path}: bytes at 0x{address:x}..0x{address + len(data) - 1:x} lie outside "
                f"the application area 0x{PAYLOAD_ADDRESS:x}..0x{APP_END_ADDRESS - 1:x}")
    start = segments[0][0]
    end = max(a + len(d) for a, d in segments)
    if start != PAYLOAD_ADDRESS:
        raise ImageFileError(
            f"{path}: linked at 0x{start:x}, but an application must be linked at the "
            f"payload address 0x{PAYLOAD_ADDRESS:x} (the header takes 0x{APP_START_ADDRESS:x})")
    if end - start > MAX_PAYLOAD:
        raise ImageFileError(f"{path}: {end - start} bytes do not fit the application area "
                             f"({MAX_PAYLOAD} bytes)")
    for (a, d), (b, _) in zip(segments, segments[1:], strict=False):
        if a + len(d) > b:
            raise ImageFileError(f"{path}: segments at 0x{a:x} and 0x{b:x} overlap")
    out = bytearray(b"\xff" * (end - start))
    for address, data in segments:
        out[address - start : address - start + len(data)] = data
    return bytes(out)


def _hex_record(line: str, lineno: int, path: Path) -> tuple[int, int, bytes]:
    """One Intel HEX record's (type, 16-bit address, data), its length and checksum checked."""
    text = line.strip()
    if not text.startswith(":"):
        raise ImageFileError(f"{path}: line {lineno}: not an Intel HEX record (no ':')")
    try:
        raw = bytes.fromhex(text[1:])
    except ValueError:
        raise ImageFileError(f"{path}: line {lineno}: not hex digits") from None
    if len(raw) < 5 or len(raw) != 5 + raw[0]:
        raise ImageFileError(f"{path}: line {lineno}: record length does not match its "
                             f"byte count (cut short?)")
    if sum(raw) & 0xFF:
        raise ImageFileError(f"{path}: line {lineno}: checksum 0x{raw[-1]:02x} is wrong "
                             f"(0x{(raw[-1] - sum(raw)) & 0xFF:02x} expected)")
    kind = raw[3]
    if kind > 5:
        raise ImageFileError(f"{path}: line {lineno}: unknown record type {kind:02d}")
    return kind, int.from_bytes(raw[1:3], "big"), raw[4:-1]


def read_hex(path: Path) -> bytes:
    """The payload an Intel HEX file holds (records 00 data, 01 end of file, 02/04 address
    bases, 03/05 start addresses, which are ignored).  Refused: a bad record or checksum, a
    byte written twice, a missing end-of-file record, anything but blank lines after it."""
    data = _read(Path(path))
    try:
        text = data.decode("ascii")
    except UnicodeDecodeError as exc:
        raise ImageFileError(f"{path}: not an Intel HEX file (byte {exc.start} is not "
                             "ASCII)") from None
    base = 0
    written: dict[int, int] = {}
    segments: list[tuple[int, bytes]] = []
    ended = 0
    for lineno, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        if ended:
            raise ImageFileError(f"{path}: line {lineno}: a record after the end-of-file "
                                 f"record (line {ended})")
        kind, address, body = _hex_record(line, lineno, path)
        if kind == 0:
            first = base + address
            for offset in range(len(body)):
                if first + offset in written:
                    raise ImageFileError(
                        f"{path}: line {lineno}: overlaps line {written[first + offset]} "
                        f"at 0x{first + offset:x}")
                written[first + offset] = lineno
            segments.append((first, body))
        elif kind == 1:
            if body:
                raise ImageFileError(f"{path}: line {lineno}: an end-of-file record with data")
            ended = lineno
        elif kind in (2, 4):
            if len(body) != 2:
                raise ImageFileError(f"{path}: line {lineno}: an address record needs 2 bytes")
            base = int.from_bytes(body, "big") << (4 if kind == 2 else 16)
        elif len(body) != 4:
            raise ImageFileError(f"{path}: line {lineno}: a start-address record needs 4 bytes")
    if not ended:
        raise ImageFileError(f"{path}: no end-of-file record (:00000001FF): the file is cut "
                             "short or was not written whole")
    return _from_segments(segments, path)


#: ``e_machine`` of the boards' firmware (ARM); names of the others, for messages.
_EM_ARM: Final = ENUM_E_MACHINE["EM_ARM"]
_MACHINES: Final = {number: name for name, number in ENUM_E_MACHINE.items()
                    if name.startswith("EM_")}


def _elf_machine(head: bytes, path: Path) -> None:
    """Refuse an ELF that is not 32-bit little-endian ARM, from its identification bytes
    (before parsing the rest, which depends on them)."""
    if len(head) < 20:
        raise ImageFileError(f"{path}: not a valid ELF file: {len(head)} bytes, cut short")
    bits = {1: "32", 2: "64"}.get(head[4], f"class-{head[4]}")
    order = {1: "little", 2: "big"}.get(head[5], f"data-{head[5]}")
    number = int.from_bytes(head[18:20], "big" if head[5] == 2 else "little")
    machine = _MACHINES.get(number, f"machine {number}")
    if (bits, order, number) != ("32", "little", _EM_ARM):
        raise ImageFileError(
            f"{path}: a {bits}-bit {order}-endian {machine} ELF; the boards run 32-bit "
            "little-endian ARM (EM_ARM, Cortex-M3) firmware")


def read_elf(path: Path) -> bytes:
    """The payload of an ELF file's loadable segments, at their physical addresses.

    Refused: an ELF that is not 32-bit little-endian ARM, loadable bytes outside the
    application area, overlapping segments."""
    _elf_machine(_read(Path(path))[:20], path)
    try:
        with open(path, "rb") as f:
            elf = ELFFile(f)
            segments = [(seg["p_paddr"], seg.data()[: seg["p_filesz"]])
                        for seg in elf.iter_segments() if seg["p_type"] == _PT_LOAD]
    except FileNotFoundError:
        raise ImageFileError(f"{path}: no such file") from None
    except (ELFError, ValueError, struct.error) as exc:
        raise ImageFileError(f"{path}: not a valid ELF file: {exc}") from exc
    except OSError as exc:
        raise ImageFileError(f"cannot read {path}: {exc.strerror or exc}") from exc
    return _from_segments(segments, path)


def read_payload(path: Path) -> bytes:
    """The payload in ``path``: ELF by its magic, Intel HEX by ``.hex``/``.ihex``, else raw."""
    path = Path(path)
    head = _read(path)
    if head.startswith(_ELF_MAGIC):
        return read_elf(path)
    if path.suffix.lower() in (".hex", ".ihex"):
        return read_hex(path)
    if not head:
        raise ImageFileError(f"{path}: is empty")
    _refuse_an_image(path, head)
    if len(head) > MAX_PAYLOAD:
        raise ImageFileError(f"{path}: {len(head)} bytes do not fit the application area "
                             f"({MAX_PAYLOAD} bytes)")
    return head


def _refuse_an_image(path: Path, data: bytes) -> None:
    """An image file given where a payload belongs would be wrapped in a second header."""
    try:
        image = parse_image(data)
    except ImageError:
        return
    h = image.header
    raise ImageFileError(
        f"{path}: already a firmware image ({h.board.name.lower()} {h.app_name} {h.version}); "
        "build from the application's .bin, .hex or .elf, or sign this image with "
        "fwimage sign")


def read_image(path: Path, board: BoardType | None = None) -> FirmwareImage:
    """The checked image in ``path`` (header, CRC, SHA-256; the board if ``board``)."""
    data = _read(Path(path))
    try:
        return parse_image(data, expected_board=board)
    except ImageError as exc:
        raise ImageFileError(f"{path}: {exc}") from exc
