"""fwimage: images from raw, Intel HEX and ELF inputs; inspect; keys, signing, refusal."""

from __future__ import annotations

import io
import json
import struct
from pathlib import Path

import pytest
from intelhex import IntelHex

from bootloader.errors import ImageFileError, PlanError
from bootloader.image_files import PAYLOAD_ADDRESS, read_image, read_payload
from bootloader.plan import make_plan
from bootloader.signing import load_public_key
from firmware_py.boot_program import inspect_image
from firmware_py.scheduler import Scheduler
from firmware_py.sim.boards import install_image, make_hal, provision_key
from protocol.image import BoardType
from protocol.messages.boot_program import ImageStatus
from tools.cli import fwimage

PAYLOAD = bytes((i * 7 + 3) & 0xFF for i in range(1000))


def tiny_elf(segments: list[tuple[int, bytes]]) -> bytes:
    """An ELF32 little-endian ARM executable with one PT_LOAD per segment, by hand."""
    ehsize, phentsize = 52, 32
    data_off = ehsize + phentsize * len(segments)
    ident = b"\x7fELF" + bytes([1, 1, 1, 0]) + bytes(8)
    header = ident + struct.pack("<HHIIIIIHHHHHH", 2, 40, 1, segments[0][0], ehsize, 0, 0,
                                 ehsize, phentsize, len(segments), 40, 0, 0)
    phdrs, blobs, off = b"", b"", data_off
    for address, data in segments:
        phdrs += struct.pack("<IIIIIIII", 1, off, address, address, len(data), len(data), 5, 4)
        blobs += data
        off += len(data)
    return header + phdrs + blobs


def build(tmp_path: Path, source: Path, *extra: str, board: str = "f2",
          name: str | None = None) -> Path:
    out = tmp_path / f"{name or source.stem}.img"
    assert fwimage.main(["build", "--board", board, "--version", "1.2.3", "--input",
                         str(source), "-o", str(out), "--timestamp", "0", *extra]) == 0
    return out


def test_build_from_a_raw_bin(tmp_path: Path) -> None:
    src = tmp_path / "fw.bin"
    src.write_bytes(PAYLOAD)
    image = read_image(build(tmp_path, src), BoardType.F2)
    assert image.payload == PAYLOAD
    assert str(image.header.version) == "1.2.3" and image.header.app_name == "f2"


def test_build_from_intel_hex_fills_gaps_with_erased_bytes(tmp_path: Path) -> None:
    ih = IntelHex()
    ih.puts(PAYLOAD_ADDRESS, PAYLOAD[:100])
    ih.puts(PAYLOAD_ADDRESS + 200, PAYLOAD[200:300])
    src = tmp_path / "fw.hex"
    ih.write_hex_file(str(src))
    image = read_image(build(tmp_path, src, "--app", "f3", board="f3"))
    assert image.payload == PAYLOAD[:100] + b"\xff" * 100 + PAYLOAD[200:300]
    assert image.header.app_name == "f3" and image.header.board == BoardType.F3


def test_build_from_elf_uses_the_loadable_segments(tmp_path: Path) -> None:
    src = tmp_path / "fw.elf"
    src.write_bytes(tiny_elf([(PAYLOAD_ADDRESS, PAYLOAD[:64]), (PAYLOAD_ADDRESS + 80, b"\x01\x02")]))
    image = read_image(build(tmp_path, src, board="fmcb"))
    assert image.payload == PAYLOAD[:64] + b"\xff" * 16 + b"\x01\x02"


def test_an_elf_linked_elsewhere_is_refused_with_the_address(tmp_path: Path) -> None:
    src = tmp_path / "bad.elf"
    src.write_bytes(tiny_elf([(0x402000, PAYLOAD[:64])]))
    with pytest.raises(ImageFileError, match="linked at 0x402000.*0x402100"):
        read_payload(src)


def test_inspect_json_shows_the_header_and_checks(tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "fw.bin"
    src.write_bytes(PAYLOAD)
    img = build(tmp_path, src)
    capsys.readouterr()
    assert fwimage.main(["inspect", str(img), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["board"] == "f2" and info["version"] == "1.2.3"
    assert info["payload_bytes"] == len(PAYLOAD) and info["hash_ok"] and not info["signed"]


def test_inspect_refuses_a_corrupted_or_truncated_image(tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "fw.bin"
    src.write_bytes(PAYLOAD)
    img = build(tmp_path, src)
    data = bytearray(img.read_bytes())
    data[300] ^= 1
    bad = tmp_path / "bad.img"
    bad.write_bytes(bytes(data))
    assert fwimage.main(["inspect", str(bad)]) == 1
    assert "SHA-256 mismatch" in capsys.readouterr().err
    bad.write_bytes(img.read_bytes()[:-10])
    assert fwimage.main(["inspect", str(bad)]) == 1
    assert "truncated" in capsys.readouterr().err


def test_keygen_sign_verify_and_refuse(tmp_path: Path) -> None:
    key, other = tmp_path / "k", tmp_path / "other"
    assert fwimage.main(["keygen", "-o", str(key)]) == 0
    assert fwimage.main(["keygen", "-o", str(other)]) == 0
    assert fwimage.main(["keygen", "-o", str(key)]) == 1  # never overwrites silently
    src = tmp_path / "fw.bin"
    src.write_bytes(PAYLOAD)
    signed = read_image(build(tmp_path, src, "--sign", str(key)))
    unsigned = read_image(build(tmp_path, src, name="u"))
    pub, other_pub = (load_public_key(Path(str(p) + ".pub")) for p in (key, other))
    assert fwimage.main(["inspect", str(tmp_path / "fw.img"), "--key", str(key) + ".pub"]) == 0
    assert fwimage.main(["inspect", str(tmp_path / "fw.img"), "--key", str(other) + ".pub"]) == 1
    make_plan({BoardType.F2: signed}, public_key=pub)
    with pytest.raises(PlanError, match="unsigned"):
        make_plan({BoardType.F2: unsigned}, public_key=pub)
    with pytest.raises(PlanError, match="does not verify"):
        make_plan({BoardType.F2: signed}, public_key=other_pub)

    # A provisioned node: its bootloader refuses other keys and, when required, no key.
    def status(image: bytes, key: bytes, required: bool) -> ImageStatus:
        hal = make_hal(Scheduler(), BoardType.F2)
        install_image(hal, image)
        provision_key(hal, key, required)
        return inspect_image(hal.flash, BoardType.F2).status

    assert status(signed.to_bytes(), pub, True) == ImageStatus.VALID
    assert status(signed.to_bytes(), other_pub, True) == ImageStatus.BAD_SIGNATURE
    # A key that is not "required" lets unsigned images through, never another key's.
    assert status(signed.to_bytes(), other_pub, False) == ImageStatus.BAD_SIGNATURE
    assert status(signed.to_bytes(), pub, False) == ImageStatus.VALID
    assert status(unsigned.to_bytes(), pub, True) == ImageStatus.UNSIGNED
    assert status(unsigned.to_bytes(), pub, False) == ImageStatus.VALID


def test_bad_build_arguments_are_a_bad_command_line(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "fw.bin"
    src.write_bytes(PAYLOAD)
    base = ["build", "--board", "f2", "--input", str(src), "-o", str(tmp_path / "x.img")]
    for bad, says in ((["--version", "1.2"], "major.minor.patch"),
                      (["--version", "300.0.0"], "0..255"),
                      (["--version", "1.2.3", "--app", "x" * 17], "1..16"),
                      (["--version", "1.2.3", "--timestamp", "-5"], "u32")):
        assert fwimage.main([*base, *bad]) == 2, bad
        err = capsys.readouterr().err
        assert says in err and "usage:" in err
    assert not (tmp_path / "x.img").exists()


def test_an_image_given_as_input_is_refused_not_wrapped_again(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "fw.bin"
    src.write_bytes(PAYLOAD)
    image = build(tmp_path, src)
    out = tmp_path / "again.img"
    assert fwimage.main(["build", "--board", "f2", "--version", "1.2.4", "--input",
                         str(image), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "already a firmware image (f2 f2 1.2.3)" in err and "fwimage sign" in err
    assert not out.exists()


def test_sign_an_existing_image_and_inspect_says_why_a_key_does_not_verify(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    key, other = tmp_path / "k", tmp_path / "other"
    assert fwimage.main(["keygen", "-o", str(key)]) == 0
    assert fwimage.main(["keygen", "-o", str(other)]) == 0
    src = tmp_path / "fw.bin"
    src.write_bytes(PAYLOAD)
    unsigned = build(tmp_path, src)
    capsys.readouterr()
    assert fwimage.main(["inspect", str(unsigned), "--key", f"{key}.pub"]) == 1
    assert f"{unsigned}: unsigned" in capsys.readouterr().err

    signed = tmp_path / "signed.img"
    assert fwimage.main(["sign", str(unsigned), "--key", str(key), "-o", str(signed)]) == 0
    capsys.readouterr()
    assert read_image(signed).header.version == read_image(unsigned).header.version
    assert read_image(signed).header.sha256 == read_image(unsigned).header.sha256
    assert fwimage.main(["inspect", str(signed), "--key", f"{key}.pub"]) == 0
    assert fwimage.main(["inspect", str(signed), "--key", f"{other}.pub"]) == 1
    assert "signature does not verify with" in capsys.readouterr().err
    make_plan({BoardType.F2: signed}, public_key=load_public_key(Path(f"{key}.pub")))
    # Re-signing with another key replaces the signature.
    assert fwimage.main(["sign", str(signed), "--key", str(other), "-o", str(signed)]) == 0
    assert fwimage.main(["inspect", str(signed), "--key", f"{other}.pub"]) == 0


def test_an_output_that_cannot_be_written_says_so(tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "fw.bin"
    src.write_bytes(PAYLOAD)
    out = tmp_path / "no-such-dir" / "x.img"
    assert fwimage.main(["build", "--board", "f2", "--version", "1.0.0", "--input", str(src),
                         "-o", str(out)]) == 1
    assert f"cannot write {out}: No such file or directory" in capsys.readouterr().err


# Strict inputs: a file cut short, corrupted or built for another machine is refused before
# anything is signed or written (exit 2, the reason on stderr).

PROGRAM = bytes((i * 13 + 5) & 0xFF for i in range(1472))


def hex_lines(program: bytes = PROGRAM) -> list[str]:
    """The Intel HEX text of ``program`` at the payload address, as lines (EOF last)."""
    ih = IntelHex()
    ih.puts(PAYLOAD_ADDRESS, program)
    buffer = io.StringIO()
    ih.write_hex_file(buffer)
    text = buffer.getvalue().splitlines()
    assert text[-1] == ":00000001FF"
    return text


def refused(tmp_path: Path, source: Path, capsys: pytest.CaptureFixture[str]) -> str:
    """Build ``source`` signed; assert exit 2 and no output; return stderr."""
    key = tmp_path / "key"
    if not key.exists():
        assert fwimage.main(["keygen", "-o", str(key)]) == 0
    out = tmp_path / "out.img"
    capsys.readouterr()
    assert fwimage.main(["build", "--board", "f2", "--version", "1.0.0", "--input", str(source),
                         "-o", str(out), "--sign", str(key)]) == 2
    assert not out.exists()
    err = capsys.readouterr().err
    assert err.startswith("fwimage: ") and err.count("\n") == 1, err
    return err


def test_a_whole_intel_hex_file_builds(tmp_path: Path) -> None:
    src = tmp_path / "fw.hex"
    src.write_text("\n".join(hex_lines()) + "\n")
    assert read_image(build(tmp_path, src)).payload == PROGRAM


def test_an_intel_hex_file_cut_at_a_line_boundary_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    lines = hex_lines()
    src = tmp_path / "cut.hex"
    src.write_text("\n".join(lines[: len(lines) // 3]) + "\n")  # whole records, no EOF
    assert "no end-of-file record" in refused(tmp_path, src, capsys)


def test_an_intel_hex_record_with_a_bad_checksum_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    lines = hex_lines()
    lines[3] = lines[3][:-2] + f"{(int(lines[3][-2:], 16) + 1) & 0xFF:02X}"
    src = tmp_path / "bad.hex"
    src.write_text("\n".join(lines) + "\n")
    assert "line 4: checksum" in refused(tmp_path, src, capsys)


def test_overlapping_intel_hex_records_are_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    lines = hex_lines()
    src = tmp_path / "twice.hex"
    src.write_text("\n".join([*lines[:-1], lines[2], lines[-1]]) + "\n")  # a record again
    assert f"line {len(lines)}: overlaps line 3" in refused(tmp_path, src, capsys)


def test_a_record_after_the_intel_hex_end_of_file_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    lines = hex_lines()
    src = tmp_path / "after.hex"
    src.write_text("\n".join([*lines[:-1], lines[-1], lines[-2], ""]) + "\n")
    assert "after the end-of-file record" in refused(tmp_path, src, capsys)


def elf64_x86(address: int, data: bytes) -> bytes:
    """An ELF64 little-endian x86-64 executable with one PT_LOAD at ``address``, by hand."""
    ehsize, phentsize = 64, 56
    ident = b"\x7fELF" + bytes([2, 1, 1, 0]) + bytes(8)
    header = ident + struct.pack("<HHIQQQIHHHHHH", 2, 62, 1, address, ehsize, 0, 0,
                                 ehsize, phentsize, 1, 64, 0, 0)
    phdr = struct.pack("<IIQQQQQQ", 1, 5, ehsize + phentsize, address, address,
                       len(data), len(data), 4096)
    return header + phdr + data


def test_an_x86_64_elf_linked_at_the_payload_address_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "x86.elf"
    src.write_bytes(elf64_x86(PAYLOAD_ADDRESS, PROGRAM))
    err = refused(tmp_path, src, capsys)
    assert "64-bit little-endian EM_X86_64" in err and "EM_ARM" in err


def test_a_big_endian_or_non_arm_elf32_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good = tiny_elf([(PAYLOAD_ADDRESS, PROGRAM)])
    other_machine = good[:18] + struct.pack("<H", 3) + good[20:]  # EM_386
    src = tmp_path / "i386.elf"
    src.write_bytes(other_machine)
    assert "32-bit little-endian EM_386" in refused(tmp_path, src, capsys)
    big = bytearray(good)
    big[5] = 2  # ELFDATA2MSB: every field is now read big-endian
    src.write_bytes(bytes(big))
    assert "EM_ARM" in refused(tmp_path, src, capsys)


def test_an_elf_loading_bytes_outside_the_application_area_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from bootloader.image_files import APP_END_ADDRESS

    src = tmp_path / "far.elf"
    src.write_bytes(tiny_elf([(PAYLOAD_ADDRESS, PROGRAM), (APP_END_ADDRESS - 4, PROGRAM[:8])]))
    assert "outside the application area" in refused(tmp_path, src, capsys)
    src.write_bytes(tiny_elf([(PAYLOAD_ADDRESS, PROGRAM), (PAYLOAD_ADDRESS + 100, b"\0" * 8)]))
    assert "overlap" in refused(tmp_path, src, capsys)
