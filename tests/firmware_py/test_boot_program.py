"""Tests of the bootloader runtime, driven over its upstream UART through the VirtualHal."""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from typing import Any

import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from bootloader.signing import raw_public_key, sign_image
from firmware_py.boot_program import AUTOBOOT_US, BootProgram, inspect_image
from firmware_py.flash_layout import (
    BOOT_CONTROL_PAGE,
    HEADER_PAGE,
    PAYLOAD_FIRST_PAGE,
    ActivationRecord,
    page_address,
)
from firmware_py.hal import Hal
from firmware_py.hand_node import HandNode
from firmware_py.mcu import Mcu
from firmware_py.scheduler import Scheduler
from firmware_py.sim.boards import default_image, install_image, make_node, provision_key
from firmware_py.sim.virtual_hal import VirtualFlash, VirtualHal
from firmware_py.sim.virtual_ports import VirtualUart
from protocol.image import (
    MAX_PAYLOAD,
    BoardType,
    FirmwareImage,
    ImageHeader,
    Version,
    make_image,
    split_pages,
)
from protocol.messages import CATALOGUE
from protocol.messages.boot_program import BootState, WriteStatus
from protocol.stream import decode_all
from protocol.topology import ADDR_BROADCAST

UPSTREAM = {BoardType.FMCB: "pogo", BoardType.F2: "tendon", BoardType.F3: "tendon",
            BoardType.PALM: "host"}
ADDRESS = {BoardType.FMCB: 10, BoardType.F2: 1, BoardType.F3: 2, BoardType.PALM: 10}
WINDOW = AUTOBOOT_US


class TinyApp(HandNode):
    """A stand-in application: answers the common messages on the upstream UART."""

    node_kind = "fmcb"

    def __init__(self, hal: Hal, mcu: Mcu, uart: str = "pogo") -> None:
        super().__init__(hal)
        self.uart_name = uart

    def start(self) -> None:
        self.listen(self.hal.uart(self.uart_name))


def tiny_apps() -> dict[str, Callable[[Hal, Mcu], Any]]:
    return {
        "fmcb": lambda hal, mcu: TinyApp(hal, mcu, "pogo"),
        "f2": lambda hal, mcu: TinyApp(hal, mcu, "tendon"),
        "f3": lambda hal, mcu: TinyApp(hal, mcu, "tendon"),
        "palm": lambda hal, mcu: TinyApp(hal, mcu, "host"),
    }


def new_node(board: BoardType = BoardType.FMCB, **kw: Any) -> Mcu:
    return make_node(Scheduler(), board, apps=tiny_apps(), **kw)


def vhal(mcu: Mcu) -> VirtualHal:
    assert isinstance(mcu.hal, VirtualHal)
    return mcu.hal


def vflash(mcu: Mcu) -> VirtualFlash:
    flash = vhal(mcu).flash
    assert isinstance(flash, VirtualFlash)
    return flash


def upstream(mcu: Mcu) -> VirtualUart:
    return vhal(mcu).uart(UPSTREAM[BoardType(mcu.identity.board)])


def run(mcu: Mcu, us: int) -> None:
    vhal(mcu).scheduler.run_for(us)


def send(mcu: Mcu, name: str, address: int | None = None, **fields: Any) -> None:
    msg = CATALOGUE[name]
    addr = ADDRESS[BoardType(mcu.identity.board)] if address is None else address
    upstream(mcu).deliver(msg.request_frame(addr, fields))


def replies(mcu: Mcu, name: str) -> list[dict[str, Any]]:
    msg = CATALOGUE[name]
    frames = decode_all(b"".join(upstream(mcu).take_sent()))
    return [msg.parse_reply(f.payload) for f in frames if f.type == msg.type_id]


def ask(mcu: Mcu, name: str, run_us: int = 20_000, **fields: Any) -> dict[str, Any]:
    """Send one request, run the node, and return its only reply."""
    upstream(mcu).take_sent()
    send(mcu, name, **fields)
    run(mcu, run_us)
    got = replies(mcu, name)
    assert len(got) == 1, f"{name}: expected one reply, got {got}"
    return got[0]


def unanswered(mcu: Mcu, name: str, run_us: int = 100_000, **fields: Any) -> None:
    """Send one request, run the node, and check that nothing answered it."""
    upstream(mcu).take_sent()
    send(mcu, name, **fields)
    run(mcu, run_us)
    assert replies(mcu, name) == [], f"{name} was answered"


def halted_node(board: BoardType = BoardType.FMCB, **kw: Any) -> Mcu:
    mcu = new_node(board, **kw)
    mcu.power_on()
    run(mcu, 1_000)
    ask(mcu, "bl.halt")
    return mcu


def bootloader(mcu: Mcu) -> BootProgram:
    assert isinstance(mcu.program, BootProgram)
    return mcu.program


# --- autoboot ---------------------------------------------------------------------------------
@pytest.mark.parametrize("board", list(UPSTREAM))
def test_valid_image_autoboots_after_the_window(board: BoardType) -> None:
    mcu = new_node(board)
    mcu.power_on()
    assert mcu.in_bootloader
    run(mcu, WINDOW - 1_000)
    assert mcu.in_bootloader
    run(mcu, 2_000)
    assert mcu.program_name == default_image(board)[24:40].rstrip(b"\0").decode()
    assert mcu.boots == 1


def test_autoboot_window_is_configurable() -> None:
    mcu = make_node(Scheduler(), BoardType.FMCB, apps=tiny_apps(),
                    bootloader=lambda hal, m: BootProgram(hal, m, autoboot_us=500_000))
    mcu.power_on()
    run(mcu, 499_000)
    assert mcu.in_bootloader
    run(mcu, 2_000)
    assert mcu.program_name == "fmcb"


@pytest.mark.parametrize("board", list(UPSTREAM))
def test_bootloader_listens_on_the_upstream_uart_and_identifies(board: BoardType) -> None:
    mcu = new_node(board)
    mcu.power_on()
    reply = ask(mcu, "identify")
    assert reply["running"] == 0
    assert reply["board"] == int(board)
    assert reply["address"] == ADDRESS[board]


@pytest.mark.parametrize("name", ["bl.halt", "bl.read_page", "bl.info", "bl.status"])
def test_a_bootloader_command_inside_the_window_halts_autoboot(name: str) -> None:
    mcu = new_node()
    mcu.power_on()
    run(mcu, 2_000_000)
    fields = {"page": 32} if name == "bl.read_page" else {}
    ask(mcu, name, **fields)
    run(mcu, 10 * WINDOW)
    assert mcu.in_bootloader
    info = ask(mcu, "bl.info")
    assert info["state"] == BootState.HALTED
    assert info["autoboot_ms_left"] == 0
    assert info["image_status"] == 0


@pytest.mark.parametrize("name", ["ping", "identify", "hw_version"])
def test_common_messages_are_answered_without_halting_autoboot(name: str) -> None:
    """A host polling identify to learn when a node has booted must not strand it."""
    mcu = new_node()
    mcu.power_on()
    for _ in range(5):
        assert ask(mcu, name) is not None
        run(mcu, 200_000)
    run(mcu, WINDOW)
    assert mcu.program_name == "fmcb"


def test_an_enveloped_bootloader_command_halts_autoboot() -> None:
    """The host library sends bl.* inside a txn envelope: that halts the countdown too (a
    halted phalange left waiting while its sibling is flashed must not boot meanwhile)."""
    mcu = new_node(BoardType.F3)
    mcu.power_on()
    run(mcu, 1_000)
    send(mcu, "txn", seq=7, inner_type=CATALOGUE["bl.halt"].type_id, inner=b"")
    run(mcu, 2 * WINDOW)
    assert mcu.in_bootloader
    assert ask(mcu, "bl.info")["autoboot_ms_left"] == 0


def test_a_broadcast_halts_autoboot_without_a_reply() -> None:
    mcu = new_node()
    mcu.power_on()
    send(mcu, "bl.halt", address=ADDR_BROADCAST)
    run(mcu, WINDOW * 2)
    assert mcu.in_bootloader
    assert replies(mcu, "bl.halt") == []


def test_a_frame_for_another_node_does_not_halt_autoboot() -> None:
    mcu = new_node()
    mcu.power_on()
    send(mcu, "bl.halt", address=3)
    run(mcu, WINDOW + 1_000)
    assert mcu.program_name == "fmcb"
    assert replies(mcu, "bl.halt") == []


def test_application_traffic_does_not_halt_autoboot() -> None:
    """A palm polling fmcb.status while a re-attached finger boots must not strand it."""
    mcu = new_node()
    mcu.power_on()
    for _ in range(5):
        send(mcu, "fmcb.status")
        run(mcu, 200_000)
    run(mcu, WINDOW)
    assert mcu.program_name == "fmcb"


def test_original_sequence_reset_halt_ping_read_boot() -> None:
    image = default_image(BoardType.FMCB)
    mcu = new_node()
    mcu.power_on()
    run(mcu, WINDOW + 1_000)
    assert mcu.program_name == "fmcb"
    ask(mcu, "reset")
    assert mcu.in_bootloader
    run(mcu, 100_000)
    ask(mcu, "bl.halt")
    assert ask(mcu, "ping") == {}
    assert ask(mcu, "bl.read_page", page=HEADER_PAGE)["data"] == image[:256]
    assert ask(mcu, "bl.read_page", page=PAYLOAD_FIRST_PAGE)["data"] == image[256:512]
    run(mcu, 5 * WINDOW)
    assert mcu.in_bootloader
    assert ask(mcu, "bl.boot") == {}
    assert mcu.program_name == "fmcb"
    assert mcu.boots == 2
    assert ask(mcu, "identify")["running"] == 1


def test_fmcb_bootloader_holds_phalange_power_off() -> None:
    mcu = new_node()
    hal = vhal(mcu)
    hal.power("phalange").set(2)  # whatever the hardware did before the bootloader starts
    bl = BootProgram(hal, mcu)
    bl.start()
    assert hal.power("phalange").state == 0
    mcu.power_on()
    assert hal.power("phalange").state == 0
    assert set(range(32)) <= vflash(mcu).locked


# --- decisions on every kind of image ---------------------------------------------------------
def _image_with(board: BoardType = BoardType.FMCB) -> bytes:
    return default_image(board)


def _flip(data: bytes, index: int) -> bytes:
    out = bytearray(data)
    out[index] ^= 0x01
    return bytes(out)


def _too_large_header() -> bytes:
    return ImageHeader(BoardType.FMCB, Version(1, 0, 0), MAX_PAYLOAD + 1, bytes(32),
                       "fmcb").to_bytes()


def _install(mcu: Mcu, data: bytes, activate_sha: bytes | None) -> None:
    flash = vflash(mcu)
    flash.load(page_address(HEADER_PAGE), data)
    if activate_sha is not None:
        flash.load(page_address(BOOT_CONTROL_PAGE), ActivationRecord(activate_sha).to_page())


GOOD = default_image(BoardType.FMCB)
GOOD_SHA = GOOD[40:72]
F2_IMAGE = default_image(BoardType.F2)
CASES: dict[str, tuple[bytes | None, bytes | None, int]] = {
    # name: (flash content from page 32, activation sha, expected image status)
    "valid": (GOOD, GOOD_SHA, 0),
    "empty": (None, None, 1),
    "bad_header_crc": (_flip(GOOD, 100), GOOD_SHA, 2),
    "wrong_board": (F2_IMAGE, F2_IMAGE[40:72], 3),
    "bad_hash": (_flip(GOOD, 256 + 700), GOOD_SHA, 4),
    "truncated": (GOOD[:256 + 1024], GOOD_SHA, 4),
    "not_activated": (GOOD, None, 5),
    "activated_for_other_image": (GOOD, hashlib.sha256(b"other").digest(), 5),
    "too_large": (_too_large_header(), None, 6),
    # What the original host tools write: a raw binary, vectors on page 32, no header.
    "raw_binary": (bytes(range(256)) * 8, None, 2),
}


@pytest.mark.parametrize("case", list(CASES))
def test_autoboot_decision_for_each_kind_of_image(case: str) -> None:
    content, sha, expected = CASES[case]
    mcu = new_node(installed=False)
    if content is not None:
        _install(mcu, content, sha)
    assert inspect_image(vflash(mcu), BoardType.FMCB).status == expected
    mcu.power_on()
    run(mcu, WINDOW + 1_000)
    if expected == 0:
        assert mcu.program_name == "fmcb"
        return
    assert mcu.in_bootloader
    status = ask(mcu, "bl.status")
    assert status["state"] == BootState.NO_VALID_IMAGE
    assert status["image_status"] == expected
    assert status["text"]
    assert ask(mcu, "bl.info")["image_status"] == expected


@pytest.mark.parametrize("case", [c for c, v in CASES.items() if v[2] not in (0, 5)])
def test_explicit_boot_never_starts_an_invalid_image(case: str) -> None:
    content, sha, expected = CASES[case]
    mcu = new_node(installed=False)
    if content is not None:
        _install(mcu, content, sha)
    record_before = vflash(mcu).read_page(BOOT_CONTROL_PAGE)
    mcu.power_on()
    run(mcu, 1_000)
    # No acknowledgement: the original host reads the missing reply as "failed to boot".
    unanswered(mcu, "bl.boot")
    assert mcu.in_bootloader
    status = ask(mcu, "bl.status")
    assert status["image_status"] == expected
    assert status["last_error"] != 0
    assert "boot refused" in status["text"]
    assert vflash(mcu).read_page(BOOT_CONTROL_PAGE) == record_before


def test_not_activated_image_stays_then_boots_on_explicit_boot() -> None:
    mcu = new_node(installed=False)
    install_image(vhal(mcu), GOOD, activate=False)
    mcu.power_on()
    run(mcu, 2 * WINDOW)
    assert mcu.in_bootloader
    assert ask(mcu, "bl.status")["image_status"] == 5
    ask(mcu, "bl.boot")
    assert mcu.program_name == "fmcb"
    record = ActivationRecord.from_page(vflash(mcu).read_page(BOOT_CONTROL_PAGE))
    assert record == ActivationRecord(GOOD_SHA)


def test_boot_of_a_valid_image_whose_app_is_missing_stays_with_a_reason() -> None:
    mcu = make_node(Scheduler(), BoardType.FMCB, apps={})
    mcu.power_on()
    run(mcu, WINDOW + 1_000)
    assert mcu.in_bootloader
    status = ask(mcu, "bl.status")
    assert status["state"] == BootState.NO_VALID_IMAGE
    assert "no application" in status["text"]
    unanswered(mcu, "bl.boot")  # nothing to jump to: not acknowledged either
    assert mcu.in_bootloader
    assert "no application" in ask(mcu, "bl.status")["text"]


def test_boot_is_acknowledged_only_once_the_image_is_activated() -> None:
    """The acknowledgement follows the activation record's programming, then the jump."""
    mcu = new_node(installed=False)
    install_image(vhal(mcu), GOOD, activate=False)
    mcu.power_on()
    run(mcu, 1_000)
    ask(mcu, "bl.halt")
    upstream(mcu).take_sent()
    send(mcu, "bl.boot")
    run(mcu, 200)  # far less than a page program: not yet acknowledged
    assert replies(mcu, "bl.boot") == []
    run(mcu, 50_000)
    assert replies(mcu, "bl.boot") == [{}]
    assert mcu.program_name == "fmcb"


# --- page writes ------------------------------------------------------------------------------
@pytest.mark.parametrize(("page", "status"), [
    (0, 1), (5, 1), (31, 1), (1024, 1), (0xFFFFFFFF, 1), (BOOT_CONTROL_PAGE, 2)])
def test_write_page_refusals(page: int, status: int) -> None:
    mcu = halted_node()
    before = bytes(vflash(mcu).memory)
    reply = ask(mcu, "bl.write_page", page=page, data=b"\x00" * 256)
    assert reply == {"page": page, "status": status}
    assert bytes(vflash(mcu).memory) == before
    assert ask(mcu, "bl.status")["last_error"] == status


def test_write_reply_comes_when_the_page_is_programmed() -> None:
    mcu = halted_node()
    data = bytes(range(256))
    send(mcu, "bl.write_page", page=900, data=data)
    run(mcu, 1_000)
    assert replies(mcu, "bl.write_page") == []
    run(mcu, 20_000)
    assert replies(mcu, "bl.write_page") == [{"page": 900, "status": 0}]
    assert vflash(mcu).read_page(900) == data
    # the first image-area write of the session erased the activation record first
    assert vflash(mcu).writes == [BOOT_CONTROL_PAGE, 900]
    assert ask(mcu, "bl.status")["last_page"] == 900


def test_activation_is_cleared_once_per_session() -> None:
    mcu = halted_node()
    for page in (800, 801):
        assert ask(mcu, "bl.write_page", page=page, data=b"\x11" * 256)["status"] == 0
    assert vflash(mcu).writes == [BOOT_CONTROL_PAGE, 800, 801]


def test_parameter_page_write_keeps_the_activation() -> None:
    mcu = halted_node()
    assert ask(mcu, "bl.write_page", page=1020, data=b"\x22" * 256)["status"] == 0
    assert vflash(mcu).writes == [1020]
    assert ask(mcu, "bl.status")["image_status"] == 0


def test_write_while_busy_is_refused() -> None:
    mcu = halted_node()
    send(mcu, "bl.write_page", page=700, data=b"\x01" * 256)
    send(mcu, "bl.write_page", page=701, data=b"\x02" * 256)
    run(mcu, 50_000)
    assert replies(mcu, "bl.write_page") == [{"page": 701, "status": 3},
                                             {"page": 700, "status": 0}]


def test_flash_failure_reports_word_zero() -> None:
    mcu = halted_node()
    vflash(mcu).lock(600, 1)  # the flash refuses: done(False)
    assert ask(mcu, "bl.write_page", page=600, data=b"\x00" * 256)["status"] == 0x80


def test_a_word_that_reads_back_wrong_is_reported() -> None:
    mcu = halted_node()
    flash = vflash(mcu)
    real_write = flash.write_page

    def faulty(page: int, data: bytes, done: Callable[[bool], None]) -> None:
        bad = bytearray(data)
        if page == 650:
            bad[13] ^= 0xFF  # word 3 does not program
        real_write(page, bytes(bad), done)

    flash.write_page = faulty  # type: ignore[method-assign]
    assert ask(mcu, "bl.write_page", page=650, data=b"\x00" * 256)["status"] == 0x83


def test_power_lost_mid_write_leaves_the_node_in_its_bootloader() -> None:
    mcu = halted_node()
    send(mcu, "bl.write_page", page=PAYLOAD_FIRST_PAGE + 2, data=b"\x55" * 256)
    run(mcu, 3_000)  # activation erased, payload page being programmed
    mcu.power_off()
    mcu.power_on()
    run(mcu, 2 * WINDOW)
    assert mcu.in_bootloader
    assert ActivationRecord.from_page(vflash(mcu).read_page(BOOT_CONTROL_PAGE)) is None
    status = ask(mcu, "bl.status")
    assert status["image_status"] in (4, 5)
    assert status["state"] == BootState.NO_VALID_IMAGE


def test_power_lost_while_erasing_the_activation_stays_too() -> None:
    mcu = halted_node()
    send(mcu, "bl.write_page", page=500, data=b"\x55" * 256)
    run(mcu, 500)
    mcu.power_off()
    mcu.power_on()
    run(mcu, 2 * WINDOW)
    assert mcu.in_bootloader
    assert ask(mcu, "bl.info")["image_status"] == 5


def test_reset_mid_write_silences_the_old_program() -> None:
    mcu = halted_node()
    send(mcu, "bl.write_page", page=500, data=b"\x55" * 256)
    run(mcu, 500)
    mcu.reset()
    run(mcu, 20_000)
    assert replies(mcu, "bl.write_page") == []
    assert vflash(mcu).read_page(500) == b"\xff" * 256  # the second step never started
    run(mcu, 2 * WINDOW)
    assert mcu.in_bootloader


# --- reading, hashing, info --------------------------------------------------------------------
def test_read_page_out_of_range_gets_no_reply_and_is_counted() -> None:
    mcu = halted_node()
    send(mcu, "bl.read_page", page=1024)
    run(mcu, 20_000)
    assert replies(mcu, "bl.read_page") == []
    assert bootloader(mcu).refused_reads == 1
    assert ask(mcu, "bl.status")["last_error"] == 1
    assert len(ask(mcu, "bl.read_page", page=31)["data"]) == 256


def test_hash_of_a_range_and_out_of_range() -> None:
    mcu = halted_node()
    flash = vflash(mcu)
    reply = ask(mcu, "bl.hash", start_page=32, pages=9)
    assert reply["status"] == 0
    assert reply["sha256"] == hashlib.sha256(flash.read(page_address(32), 9 * 256)).digest()
    for start, count in ((1000, 30), (1024, 0), (0, 0xFFFFFFFF)):
        assert ask(mcu, "bl.hash", start_page=start, pages=count) == {
            "status": 1, "sha256": bytes(32)}


def test_info_reports_geometry_and_header() -> None:
    mcu = halted_node()
    info = ask(mcu, "bl.info")
    assert info["board"] == int(BoardType.FMCB)
    assert info["bl_version"] == {"major": 1, "minor": 0, "patch": 0}
    assert (info["page_size"], info["page_count"]) == (256, 1024)
    assert (info["app_start_page"], info["app_end_page"], info["param_page"]) == (32, 1020, 1020)
    assert info["header"] == GOOD[:256]


# --- a whole update over the protocol ----------------------------------------------------------
def _flash_pages(mcu: Mcu, image: bytes) -> list[bytes]:
    pages = split_pages(image)
    for i, data in enumerate(pages):
        reply = ask(mcu, "bl.write_page", page=HEADER_PAGE + i, data=data)
        assert reply == {"page": HEADER_PAGE + i, "status": 0}
    return pages


def test_flash_verify_activate_boot() -> None:
    mcu = halted_node()
    new = make_image(bytes(range(256)) * 13 + b"tail", BoardType.FMCB, "2.1.0", "fmcb")
    pages = _flash_pages(mcu, new)
    digest = ask(mcu, "bl.hash", start_page=HEADER_PAGE, pages=len(pages))
    assert digest == {"status": 0, "sha256": hashlib.sha256(b"".join(pages)).digest()}
    assert ask(mcu, "bl.status")["image_status"] == 5
    wrong = ask(mcu, "bl.activate", sha256=GOOD_SHA)
    assert wrong == {"status": 3, "image_status": 5}
    assert ask(mcu, "bl.activate", sha256=new[40:72]) == {"status": 0, "image_status": 0}
    ask(mcu, "bl.boot")
    assert mcu.program_name == "fmcb"
    mcu.reset()
    run(mcu, WINDOW + 1_000)  # and it autoboots from now on
    assert mcu.program_name == "fmcb"
    assert inspect_image(vflash(mcu), BoardType.FMCB).header.version == Version(2, 1, 0)  # type: ignore[union-attr]


def test_activate_refuses_a_bad_staged_image() -> None:
    mcu = halted_node()
    new = make_image(b"\x42" * 1000, BoardType.FMCB, "2.0.0", "fmcb")
    _flash_pages(mcu, new[:512])  # truncated: header says 1000 bytes of payload
    assert ask(mcu, "bl.activate", sha256=new[40:72]) == {"status": 3, "image_status": 4}
    # A header for another board is refused when written; planted in flash another way
    # (a debugger, a worn cell), activation still refuses it.
    vflash(mcu).load(page_address(HEADER_PAGE), split_pages(F2_IMAGE)[0])
    assert ask(mcu, "bl.activate", sha256=F2_IMAGE[40:72]) == {"status": 4, "image_status": 3}
    ask(mcu, "bl.write_page", page=HEADER_PAGE, data=b"\x00" * 256)
    assert ask(mcu, "bl.activate", sha256=new[40:72]) == {"status": 2, "image_status": 2}


def test_activate_queued_behind_a_write_waits_for_it() -> None:
    mcu = halted_node()
    new = make_image(b"\x42" * 200, BoardType.FMCB, "2.0.0", "fmcb")
    pages = split_pages(new)
    _flash_pages(mcu, new[:256])
    send(mcu, "bl.write_page", page=PAYLOAD_FIRST_PAGE, data=pages[1])
    send(mcu, "bl.activate", sha256=new[40:72])
    run(mcu, 50_000)
    assert replies(mcu, "bl.activate") == [{"status": 0, "image_status": 0}]


def test_original_write_then_boot_flow_activates_on_boot() -> None:
    mcu = halted_node()
    new = make_image(b"\x42" * 3000, BoardType.FMCB, "3.0.0", "fmcb")
    _flash_pages(mcu, new)
    ask(mcu, "bl.boot")
    assert mcu.program_name == "fmcb"
    assert inspect_image(vflash(mcu), BoardType.FMCB).status == 0


def test_a_board_knows_its_applications_before_it_has_booted_one() -> None:
    """A reset while still in the first bootloader window, then an explicit bl.boot: the
    board's application table names the program even though it was never loaded."""
    from firmware_py.sim.boards import _LazyApps

    apps = _LazyApps({"fmcb": "firmware_py.fmcb:FmcbApp"})
    assert "fmcb" in apps and "palm" not in apps
    assert dict.__len__(apps) == 0  # nothing imported by asking


# --- a header the node would never activate is refused before anything is erased ------------
def _signed_fmcb_image(private_key: Ed25519PrivateKey) -> bytes:
    """An fmcb image (3000 B of payload) signed with ``private_key``."""
    image = FirmwareImage.build(b"\x42" * 3000, BoardType.FMCB, "3.0.0", "fmcb")
    return sign_image(image, private_key).to_bytes()


def _refusals() -> dict[str, tuple[bytes, Ed25519PrivateKey | None, int]]:
    node_key, other_key = Ed25519PrivateKey.generate(), Ed25519PrivateKey.generate()
    unsigned = make_image(b"\x42" * 3000, BoardType.FMCB, "3.0.0", "fmcb")
    moved = make_image(b"\x42" * 300, BoardType.FMCB, "3.0.0", "fmcb",
                       load_address=page_address(HEADER_PAGE + 1))
    return {
        # name: (header page written, the node's key or None, write status)
        "another_board": (F2_IMAGE, None, WriteStatus.NOT_FOR_THIS_NODE),
        "another_load_address": (moved, None, WriteStatus.NOT_FOR_THIS_NODE),
        "too_large": (_too_large_header(), None, WriteStatus.NOT_FOR_THIS_NODE),
        "signed_by_another_key": (_signed_fmcb_image(other_key), node_key,
                                  WriteStatus.BAD_SIGNATURE),
        "unsigned_where_a_signature_is_required": (unsigned, node_key,
                                                   WriteStatus.BAD_SIGNATURE),
    }


@pytest.mark.parametrize("case", list(_refusals()))
def test_a_header_the_node_would_never_activate_is_refused_and_the_old_image_boots(
        case: str) -> None:
    header, key, status = _refusals()[case]
    if key is None:
        mcu = new_node()
    else:  # a provisioned node, running an image signed with its key
        mcu = new_node(image=_signed_fmcb_image(key))
        provision_key(vhal(mcu), raw_public_key(key.public_key()))
    mcu.power_on()
    run(mcu, 1_000)
    ask(mcu, "bl.halt")
    before = bytes(vflash(mcu).memory)
    writes_before = list(vflash(mcu).writes)
    reply = ask(mcu, "bl.write_page", page=HEADER_PAGE, data=split_pages(header)[0])
    assert reply == {"page": HEADER_PAGE, "status": status}
    assert bytes(vflash(mcu).memory) == before and vflash(mcu).writes == writes_before
    got = ask(mcu, "bl.status")
    assert got["last_error"] == status and got["last_page"] == HEADER_PAGE
    assert "header refused" in got["text"]
    # The installed image and its activation are untouched: the next power-up boots it.
    mcu.power_off()
    mcu.power_on()
    run(mcu, WINDOW + 1_000)
    assert mcu.program_name == "fmcb"


def test_a_header_the_key_accepts_is_written_and_boots() -> None:
    node_key = Ed25519PrivateKey.generate()
    mcu = new_node(installed=False)
    provision_key(vhal(mcu), raw_public_key(node_key.public_key()))
    mcu.power_on()
    run(mcu, 1_000)
    ask(mcu, "bl.halt")
    _flash_pages(mcu, _signed_fmcb_image(node_key))
    ask(mcu, "bl.boot")
    assert mcu.program_name == "fmcb"


def test_a_page_that_is_no_image_header_is_still_written() -> None:
    mcu = halted_node()
    for data in (b"\x00" * 256, bytes(range(256))):  # zeros; an original raw binary
        assert ask(mcu, "bl.write_page", page=HEADER_PAGE, data=data)["status"] == 0
        assert vflash(mcu).read_page(HEADER_PAGE) == data
