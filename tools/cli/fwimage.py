"""``fwimage``: build, inspect and sign hand firmware images; make signing keys.

::

    fwimage build --board f2 --version 1.2.0 --input f2.elf -o f2.img [--app f2] [--sign KEY]
    fwimage inspect f2.img [--json] [--key KEY.pub]
    fwimage sign f2.img --key KEY -o f2-signed.img   # sign (or re-sign) a built image
    fwimage keygen -o signing          # signing (private, PEM) and signing.pub (public, PEM)

``build`` takes a raw .bin (the payload as is), an Intel HEX (.hex) or an ELF file linked at
the payload address (0x402100); it refuses, before anything is signed or written, an input
it cannot trust whole: a HEX file without its end-of-file record, with a bad checksum or
overlapping records; an ELF that is not 32-bit little-endian ARM or loads bytes outside the
application area; an image file (``sign`` signs one).  ``inspect`` shows the header and
checks CRC, size and SHA-256 (and the signature against ``--key``: exit 1, saying why, when
it does not verify).  Exit 0 on success, 1 when an image, a key or an output is bad, 2 for a
bad command line (a bad ``--version``, ``--app``, ``--timestamp``, or an ``--input`` that
``build`` refuses).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bootloader.errors import FlashError, ImageFileError
from bootloader.image_files import (
    HAND_BOARD_NAMES,
    board_of,
    default_app,
    read_image,
    read_payload,
)
from bootloader.signing import (
    generate_key_pair,
    load_private_key,
    load_public_key,
    sign_image,
    signature_ok,
)
from protocol.errors import ImageError
from protocol.image import BoardType, FirmwareImage, Version
from tools.cli.common import parse
from tools.cli.output import guard_output

EXIT_BAD = 1
EXIT_USAGE = 2


def _version(text: str) -> Version:
    try:
        return Version.parse(text)
    except ImageError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _app_name(text: str) -> str:
    """An application name the image header takes (checked by building a 1-byte probe)."""
    if text:
        try:
            FirmwareImage.build(b"\xff", BoardType.F2, Version(0, 0, 0), text, 0)
        except ImageError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def _timestamp(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected unix seconds") from None
    if not 0 <= value <= 0xFFFF_FFFF:
        raise argparse.ArgumentTypeError(f"{value}: a timestamp is a u32 (0..4294967295)")
    return value


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="fwimage", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    build = sub.add_parser("build", help="make an image from a .bin, .hex or .elf")
    build.add_argument("--board", required=True, choices=HAND_BOARD_NAMES)
    build.add_argument("--version", required=True, type=_version, help="major.minor.patch")
    build.add_argument("--app", type=_app_name,
                       help="application name (default: the board's own)")
    build.add_argument("--input", required=True, type=Path, help=".bin, .hex or .elf")
    build.add_argument("-o", "--output", required=True, type=Path)
    build.add_argument("--sign", type=Path, metavar="KEY", help="ED25519 private key (PEM)")
    build.add_argument("--timestamp", type=_timestamp, default=None,
                       help="build time, unix s (default: now; 0 for reproducible builds)")
    inspect = sub.add_parser("inspect", help="show an image's header and check it")
    inspect.add_argument("image", type=Path)
    inspect.add_argument("--json", action="store_true")
    inspect.add_argument("--key", type=Path, help="public key the signature must verify with")
    sign = sub.add_parser("sign", help="sign (or re-sign) a built image")
    sign.add_argument("image", type=Path)
    sign.add_argument("--key", required=True, type=Path, help="ED25519 private key (PEM)")
    sign.add_argument("-o", "--output", required=True, type=Path,
                      help="the signed image (may be the input)")
    keygen = sub.add_parser("keygen", help="make an ED25519 key pair")
    keygen.add_argument("-o", "--output", type=Path, default=Path("fwimage-key"),
                        help="private key path; the public key gets .pub appended")
    keygen.add_argument("--force", action="store_true", help="overwrite existing files")
    return p


def describe(image: FirmwareImage, key: bytes | None = None) -> dict[str, Any]:
    """The header as plain data, with the checks' results."""
    h = image.header
    out: dict[str, Any] = {
        "board": h.board.name.lower(), "version": str(h.version), "app": h.app_name,
        "payload_bytes": h.payload_size, "load_address": f"0x{h.load_address:x}",
        "timestamp": h.timestamp, "sha256": h.sha256.hex(), "header_crc": f"0x{h.crc:08x}",
        "signed": h.signed, "hash_ok": True, "pages": len(image.pages()),
    }
    if key is not None:
        out["signature_ok"] = signature_ok(image, key)
    return out


def _build(args: argparse.Namespace) -> int:
    board = board_of(args.board)
    try:
        payload = read_payload(args.input)
    except ImageFileError as exc:
        print(f"fwimage: {exc}", file=sys.stderr)
        return EXIT_USAGE
    stamp = int(time.time()) if args.timestamp is None else args.timestamp
    image = FirmwareImage.build(payload, board, args.version,
                                args.app or default_app(board), stamp)
    if args.sign is not None:
        image = sign_image(image, load_private_key(args.sign))
    _write(args.output, image)
    signed = " signed" if image.header.signed else ""
    print(f"{args.output}: {board.name.lower()} {image.header.app_name} "
          f"{image.header.version}{signed}, {len(payload)} payload bytes, "
          f"{len(image.pages())} pages")
    return 0


def _write(path: Path, image: FirmwareImage) -> None:
    try:
        path.write_bytes(image.to_bytes())
    except OSError as exc:
        raise ImageFileError(f"cannot write {path}: {exc.strerror or exc}") from exc


def _inspect(args: argparse.Namespace) -> int:
    key = load_public_key(args.key) if args.key is not None else None
    info = describe(read_image(args.image), key)
    if args.json:
        print(json.dumps(info, indent=2))
    else:
        for name, value in info.items():
            print(f"{name:>14}: {value}")
    if info.get("signature_ok", True):
        return 0
    why = "unsigned" if not info["signed"] else f"signature does not verify with {args.key}"
    print(f"fwimage: {args.image}: {why}", file=sys.stderr)
    return EXIT_BAD


def _sign(args: argparse.Namespace) -> int:
    image = sign_image(read_image(args.image), load_private_key(args.key))
    _write(args.output, image)
    h = image.header
    print(f"{args.output}: {h.board.name.lower()} {h.app_name} {h.version} signed")
    return 0


def _keygen(args: argparse.Namespace) -> int:
    private = args.output
    public = private.with_name(private.name + ".pub")
    for path in (private, public):
        if path.exists() and not args.force:
            print(f"fwimage: {path} exists; pass --force to overwrite", file=sys.stderr)
            return EXIT_BAD
    raw = generate_key_pair(private, public)
    print(f"private key {private}, public key {public} ({raw.hex()})")
    return 0


@guard_output("fwimage")
def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``fwimage``; returns the exit status."""
    args = parse(_parser(), argv)
    if isinstance(args, int):
        return args  # --help (0) or a bad command line (2), already said
    try:
        return {"build": _build, "inspect": _inspect, "sign": _sign,
                "keygen": _keygen}[args.command](args)
    except (FlashError, ImageError) as exc:
        print(f"fwimage: {exc}", file=sys.stderr)
        return EXIT_BAD
    except OSError as exc:
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"fwimage: {where}{exc.strerror or exc}", file=sys.stderr)
        return EXIT_BAD


if __name__ == "__main__":
    sys.exit(main())
