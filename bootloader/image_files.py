"""Firmware inputs and image files: raw .bin, Intel HEX (``intelhex``), ELF (``pyelftools``).

A payload is the bytes from the application's link address up: real firmware is linked at
the payload address (0x402100 on the SAM3S: the header takes page 32), so an Intel HEX or
ELF input must start there; gaps between its segments are filled with 0xFF (erased flash).
A raw .bin is taken as the payload itself.
"""

from __future__ import annotations

from pathlib import Path
from typing import Final

from elftools.common.exceptions import ELFError
from elftools.elf.elffile import ELFFile
from intelhex import HexReaderError, IntelHex

from bootloader.errors import ImageFileError
from protocol.errors import ImageError
from protocol.image import (
    APP_START_ADDRESS,
    HEADER_SIZE,
    MAX_PAYLOAD,
    BoardType,
    FirmwareImage,
    parse_image,
)

#: Where a payload is linked: right after the one-page header (bytes).
PAYLOAD_ADDRESS: Final = APP_START_ADDRESS + HEADER_SIZE
_ELF_MAGIC: Final = b"\x7fELF"
_PT_LOAD: Final = "PT_LOAD"


def board_of(name: str) -> BoardType:
    """The hand board called ``name`` (``fmcb``, ``f2``, ``f3``, ``palm``)."""
    try:
        board = BoardType[name.upper()]
    except KeyError:
        raise ImageFileError(f"unknown board {name!r}: choose fmcb, f2, f3 or palm") from None
    if board not in HAND_BOARDS:
        raise ImageFileError(f"{name}: not a hand board (fmcb, f2, f3, palm)")
    return board


#: Boards with the hand bootloader.
HAND_BOARDS: Final = (BoardType.FMCB, BoardType.F2, BoardType.F3, BoardType.PALM)


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
    """Bytes from the lowest address to the highest, gaps 0xFF; must start at the payload."""
    segments = [(a, d) for a, d in segments if d]
    if not segments:
        raise ImageFileError(f"{path}: holds no loadable bytes")
    start = min(a for a, _ in segments)
    end = max(a + len(d) for a, d in segments)
    if start != PAYLOAD_ADDRESS:
        raise ImageFileError(
            f"{path}: linked at 0x{start:x}, but an application must be linked at the "
            f"payload address 0x{PAYLOAD_ADDRESS:x} (the header takes 0x{APP_START_ADDRESS:x})")
    if end - start > MAX_PAYLOAD:
        raise ImageFileError(f"{path}: {end - start} bytes do not fit the application area "
                             f"({MAX_PAYLOAD} bytes)")
    out = bytearray(b"\xff" * (end - start))
    for address, data in segments:
        out[address - start : address - start + len(data)] = data
    return bytes(out)


def read_hex(path: Path) -> bytes:
    """The payload an Intel HEX file holds."""
    ih = IntelHex()
    try:
        with open(path, encoding="ascii") as f:
            ih.loadhex(f)
    except FileNotFoundError:
        raise ImageFileError(f"{path}: no such file") from None
    except (HexReaderError, UnicodeDecodeError, ValueError) as exc:
        raise ImageFileError(f"{path}: not a valid Intel HEX file: {exc}") from exc
    except OSError as exc:
        raise ImageFileError(f"cannot read {path}: {exc.strerror or exc}") from exc
    segments = [(lo, ih.tobinstr(start=lo, end=hi - 1)) for lo, hi in ih.segments()]
    return _from_segments(segments, path)


def read_elf(path: Path) -> bytes:
    """The payload of an ELF file's loadable segments, at their physical addresses."""
    try:
        with open(path, "rb") as f:
            elf = ELFFile(f)
            segments = [(seg["p_paddr"], seg.data()[: seg["p_filesz"]])
                        for seg in elf.iter_segments() if seg["p_type"] == _PT_LOAD]
    except FileNotFoundError:
        raise ImageFileError(f"{path}: no such file") from None
    except (ELFError, ValueError) as exc:
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
