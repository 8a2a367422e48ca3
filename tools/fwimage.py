"""``fwimage``: build, inspect and sign hand firmware images; make signing keys.

::

    fwimage build --board f2 --version 1.2.0 --input f2.elf -o f2.img [--app f2] [--sign KEY]
    fwimage inspect f2.img [--json] [--key KEY.pub]
    fwimage keygen -o signing          # signing (private, PEM) and signing.pub (public, PEM)

``build`` takes a raw .bin (the payload as is), an Intel HEX (.hex) or an ELF file linked at
the payload address (0x402100).  ``inspect`` shows the header and checks CRC, size and
SHA-256 (and the signature against ``--key``).  Exit 0 on success, 1 when a file or image is
bad, 2 for a bad command line.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bootloader.errors import FlashError
from bootloader.image_files import board_of, default_app, read_image, read_payload
from bootloader.signing import (
    generate_key_pair,
    load_private_key,
    load_public_key,
    sign_image,
    signature_ok,
)
from protocol.errors import ImageError
from protocol.image import FirmwareImage, Version

EXIT_BAD = 1
EXIT_USAGE = 2


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="fwimage", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    build = sub.add_parser("build", help="make an image from a .bin, .hex or .elf")
    build.add_argument("--board", required=True, choices=("fmcb", "f2", "f3", "palm"))
    build.add_argument("--version", required=True, help="major.minor.patch")
    build.add_argument("--app", help="application name (default: the board's own)")
    build.add_argument("--input", required=True, type=Path, help=".bin, .hex or .elf")
    build.add_argument("-o", "--output", required=True, type=Path)
    build.add_argument("--sign", type=Path, metavar="KEY", help="ED25519 private key (PEM)")
    build.add_argument("--timestamp", type=int, default=None,
                       help="build time, unix s (default: now; 0 for reproducible builds)")
    inspect = sub.add_parser("inspect", help="show an image's header and check it")
    inspect.add_argument("image", type=Path)
    inspect.add_argument("--json", action="store_true")
    inspect.add_argument("--key", type=Path, help="public key the signature must verify with")
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
    payload = read_payload(args.input)
    stamp = int(time.time()) if args.timestamp is None else args.timestamp
    image = FirmwareImage.build(payload, board, Version.parse(args.version),
                                args.app or default_app(board), stamp)
    if args.sign is not None:
        image = sign_image(image, load_private_key(args.sign))
    args.output.write_bytes(image.to_bytes())
    signed = " signed" if image.header.signed else ""
    print(f"{args.output}: {board.name.lower()} {image.header.app_name} "
          f"{image.header.version}{signed}, {len(payload)} payload bytes, "
          f"{len(image.pages())} pages")
    return 0


def _inspect(args: argparse.Namespace) -> int:
    key = load_public_key(args.key) if args.key is not None else None
    info = describe(read_image(args.image), key)
    if args.json:
        print(json.dumps(info, indent=2))
    else:
        for name, value in info.items():
            print(f"{name:>14}: {value}")
    return 0 if info.get("signature_ok", True) else EXIT_BAD


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


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``fwimage``; returns the exit status."""
    args = _parser().parse_args(argv)
    try:
        return {"build": _build, "inspect": _inspect, "keygen": _keygen}[args.command](args)
    except (FlashError, ImageError) as exc:
        print(f"fwimage: {exc}", file=sys.stderr)
        return EXIT_BAD
    except OSError as exc:
        print(f"fwimage: {exc}", file=sys.stderr)
        return EXIT_BAD


if __name__ == "__main__":
    sys.exit(main())
