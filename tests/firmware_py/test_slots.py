"""The two image slots on one node: writing the secondary while the application runs, the
swap at reset, the trial boot, confirmation by host or application, and the revert."""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from typing import Any

import pytest

from firmware_py.flash_layout import page_address
from firmware_py.hal import Hal
from firmware_py.mcu import Mcu
from firmware_py.scheduler import Scheduler
from firmware_py.sim.boards import make_node
from firmware_py.sim.virtual_hal import VirtualFlash, VirtualHal
from firmware_py.sim.virtual_ports import VirtualUart
from firmware_py.slot_service import SELF_CHECK_US
from firmware_py.slot_swap import SwapRecord, read_record
from protocol.image import FLASH, SLOT_MAX_PAYLOAD, BoardType, make_image, split_pages
from protocol.messages import CATALOGUE
from protocol.messages.boot_program import BootState, ImageStatus, WriteStatus
from protocol.messages.common import Running
from protocol.messages.slots import (
    TRIAL_TIMEOUT_US,
    ConfirmBy,
    SlotEvent,
    SlotResult,
    SlotState,
)
from protocol.stream import decode_all
from tests.firmware_py.stand_ins import TinyApp

ADDRESS = 10
#: Enough for a swap of the test images and the jump, far less than the autoboot window.
SWAP_RUN_US = 300_000



class CrashingApp(TinyApp):
    """An image that crashes at boot: it resets 1 ms after it starts (a hard fault)."""

    def start(self) -> None:
        super().start()
        self.hal.clock.call_later(1_000, self.hal.reset)


class SickApp(TinyApp):
    """An image whose own health check fails: it never confirms itself."""

    def health_check(self) -> bool:
        return False


def apps() -> dict[str, Callable[[Hal, Mcu], Any]]:
    return {"fmcb": TinyApp, "crash": CrashingApp, "sick": SickApp}


def image(version: str, pages: int, app: str = "fmcb") -> bytes:
    """An fmcb image of ``pages`` pages in all (header included), payload unique per version."""
    size = (pages - 1) * 256 - 7
    seed = version.encode()
    payload = b"".join(hashlib.sha256(seed + i.to_bytes(2, "little")).digest()
                       for i in range(size // 32 + 1))[:size]
    return make_image(payload, BoardType.FMCB, version, app)


OLD = image("1.0.0", 9)
NEW = image("2.0.0", 14)


def sha(img: bytes) -> bytes:
    return img[40:72]


def node(installed: bytes = OLD) -> Mcu:
    mcu = make_node(Scheduler(), BoardType.FMCB, image=installed, apps=apps())
    return mcu


def vhal(mcu: Mcu) -> VirtualHal:
    assert isinstance(mcu.hal, VirtualHal)
    return mcu.hal


def vflash(mcu: Mcu) -> VirtualFlash:
    return vhal(mcu).flash


def pogo(mcu: Mcu) -> VirtualUart:
    return vhal(mcu).uart("pogo")


def run(mcu: Mcu, us: int) -> None:
    vhal(mcu).scheduler.run_for(us)


def ask(mcu: Mcu, name: str, run_us: int = 30_000, **fields: Any) -> dict[str, Any]:
    msg = CATALOGUE[name]
    pogo(mcu).take_sent()
    pogo(mcu).deliver(msg.request_frame(ADDRESS, fields))
    run(mcu, run_us)
    got = [msg.parse_reply(f.payload) for f in decode_all(b"".join(pogo(mcu).take_sent()))
           if f.type == msg.type_id]
    assert len(got) == 1, f"{name}: expected one reply, got {got}"
    return got[0]


def running_version(mcu: Mcu) -> str:
    reply = ask(mcu, "identify")
    assert reply["running"] == Running.APPLICATION, "the node is in its bootloader"
    v = reply["fw_version"]
    return f"{v['major']}.{v['minor']}.{v['patch']}"


def booted(mcu: Mcu) -> Mcu:
    """Power on and let the autoboot window pass: the installed image runs."""
    mcu.power_on()
    run(mcu, 4_600_000)
    assert mcu.program_name == "fmcb"
    return mcu


def download(mcu: Mcu, img: bytes) -> None:
    """Write ``img`` into the secondary slot through slot.write, page by page."""
    for index, data in enumerate(split_pages(img)):
        reply = ask(mcu, "slot.write", index=index, data=data)
        assert reply == {"index": index, "status": WriteStatus.OK}


def updated(img: bytes = NEW, confirm_by: ConfirmBy = ConfirmBy.HOST) -> Mcu:
    """A node running OLD that has downloaded ``img`` and swapped to it (on trial)."""
    mcu = booted(node())
    download(mcu, img)
    reply = ask(mcu, "slot.swap", sha256=sha(img), confirm_by=confirm_by)
    assert reply["status"] == SlotResult.OK
    run(mcu, SWAP_RUN_US)
    return mcu


# --- layout -------------------------------------------------------------------------------------
def test_the_two_slot_layout_tiles_the_application_area() -> None:
    assert (FLASH.primary_slot, FLASH.secondary_slot) == (range(32, 524), range(524, 1016))
    assert FLASH.scratch == range(1016, 1020)
    assert FLASH.swap_status_pages == (1022, 1023)
    assert SLOT_MAX_PAYLOAD == 491 * 256 == 125696


def test_swap_record_golden_bytes() -> None:
    rec = SwapRecord(SlotState.SWAPPING, SlotEvent.NONE, ConfirmBy.APPLICATION, pages=14,
                     index=4, step=2, sha256=bytes(range(32)), seq=7)
    body = (b"SLT1" + b"\x07\x00\x00\x00" + b"\x02\x00\x01\x02" + b"\x0e\x00" + b"\x04\x00"
            + bytes(range(32)))
    import zlib
    page = rec.to_page()
    assert page[:48] == body
    assert page[48:52] == zlib.crc32(body).to_bytes(4, "little")
    assert page[52:] == b"\xff" * 204
    assert SwapRecord.from_page(page) == rec
    torn = page[:20] + b"\xff" * 236
    assert SwapRecord.from_page(torn) is None


# --- writing while running ---------------------------------------------------------------------
def test_the_secondary_slot_is_written_while_the_application_keeps_running() -> None:
    mcu = booted(node())
    boots = mcu.boots
    download(mcu, NEW)
    assert mcu.program_name == "fmcb" and mcu.boots == boots
    assert running_version(mcu) == "1.0.0"
    pages = len(split_pages(NEW))
    digest = ask(mcu, "slot.hash", pages=pages)
    assert digest["sha256"] == hashlib.sha256(b"".join(split_pages(NEW))).digest()
    assert digest["image_status"] == ImageStatus.VALID
    info = ask(mcu, "slot.info")
    assert info["secondary_version"] == {"major": 2, "minor": 0, "patch": 0}
    assert info["secondary_sha256"] == sha(NEW)
    assert info["primary_sha256"] == sha(OLD) and info["primary_status"] == ImageStatus.VALID
    assert info["state"] == SlotState.CONFIRMED


def test_write_refusals() -> None:
    mcu = booted(node())
    other = make_image(b"x" * 300, BoardType.F2, "2.0.0", "f2")
    header = split_pages(other)[0]
    assert ask(mcu, "slot.write", index=0, data=header)["status"] == WriteStatus.NOT_FOR_THIS_NODE
    big = make_image(b"y" * (SLOT_MAX_PAYLOAD + 1), BoardType.FMCB, "2.0.0", "fmcb",
                     max_payload=SLOT_MAX_PAYLOAD + 1)
    assert (ask(mcu, "slot.write", index=0, data=split_pages(big)[0])["status"]
            == WriteStatus.NOT_FOR_THIS_NODE)
    assert (ask(mcu, "slot.write", index=492, data=bytes(256))["status"]
            == WriteStatus.PAGE_OUT_OF_RANGE)
    assert vflash(mcu).read_page(FLASH.secondary_slot.start) == b"\xff" * 256


def test_a_running_image_burnt_past_its_slot_protects_the_secondary() -> None:
    large = image("1.5.0", 600)
    mcu = booted(node(large))
    assert (ask(mcu, "slot.write", index=0, data=split_pages(NEW)[0])["status"]
            == WriteStatus.PAGE_PROTECTED)
    assert running_version(mcu) == "1.5.0"


# --- swap and trial ----------------------------------------------------------------------------
def test_swap_boots_the_new_image_on_trial_at_once_and_confirm_keeps_it() -> None:
    mcu = updated()
    # Down only for the swapping reboot: well inside the 4.5 s autoboot window.
    assert running_version(mcu) == "2.0.0"
    info = ask(mcu, "slot.info")
    assert (info["state"], info["event"]) == (SlotState.TRIAL, SlotEvent.INSTALLED)
    assert info["secondary_sha256"] == sha(OLD)
    assert vhal(mcu).watchdog.timeout_us == TRIAL_TIMEOUT_US
    assert ask(mcu, "slot.confirm") == {"status": SlotResult.OK, "state": SlotState.CONFIRMED}
    assert vhal(mcu).watchdog.timeout_us == 0
    assert ask(mcu, "slot.confirm")["status"] == SlotResult.OK  # idempotent
    ask(mcu, "reset")
    run(mcu, 4_600_000)
    assert running_version(mcu) == "2.0.0"
    assert ask(mcu, "slot.info")["event"] == SlotEvent.CONFIRMED


def test_an_unconfirmed_trial_is_reverted_at_the_next_reset() -> None:
    mcu = updated()
    ask(mcu, "reset")
    run(mcu, SWAP_RUN_US)
    assert running_version(mcu) == "1.0.0"
    info = ask(mcu, "slot.info")
    assert (info["state"], info["event"]) == (SlotState.CONFIRMED, SlotEvent.REVERTED)
    assert info["primary_sha256"] == sha(OLD) and info["secondary_sha256"] == sha(NEW)
    assert vhal(mcu).watchdog.timeout_us == 0


def test_an_image_that_never_confirms_is_reverted_by_the_trial_watchdog() -> None:
    mcu = updated()
    run(mcu, TRIAL_TIMEOUT_US - SWAP_RUN_US - 100_000)
    assert running_version(mcu) == "2.0.0"
    run(mcu, 200_000 + SWAP_RUN_US)
    assert vhal(mcu).watchdog.expired == 1
    assert running_version(mcu) == "1.0.0"
    assert ask(mcu, "slot.info")["event"] == SlotEvent.REVERTED


def test_an_image_that_crashes_at_boot_is_reverted() -> None:
    mcu = updated(image("2.0.0", 12, app="crash"))
    run(mcu, SWAP_RUN_US)
    assert running_version(mcu) == "1.0.0"
    assert ask(mcu, "slot.info")["event"] == SlotEvent.REVERTED


def test_the_application_confirms_itself_after_its_health_check() -> None:
    mcu = updated(confirm_by=ConfirmBy.APPLICATION)
    assert ask(mcu, "slot.info")["state"] == SlotState.TRIAL
    run(mcu, SELF_CHECK_US)
    assert ask(mcu, "slot.info")["state"] == SlotState.CONFIRMED
    ask(mcu, "reset")
    run(mcu, 4_600_000)
    assert running_version(mcu) == "2.0.0"


def test_an_application_that_fails_its_health_check_is_reverted() -> None:
    mcu = updated(image("2.0.0", 12, app="sick"), confirm_by=ConfirmBy.APPLICATION)
    run(mcu, TRIAL_TIMEOUT_US + SWAP_RUN_US)
    assert running_version(mcu) == "1.0.0"


def test_host_confirmation_keeps_the_application_from_confirming_itself() -> None:
    """confirm_by HOST (the --keep-trial way): nobody confirms, the next reset reverts."""
    mcu = updated(confirm_by=ConfirmBy.HOST)
    run(mcu, 2 * SELF_CHECK_US)
    assert ask(mcu, "slot.info")["state"] == SlotState.TRIAL
    assert (ask(mcu, "slot.write", index=0, data=split_pages(NEW)[0])["status"]
            == WriteStatus.PAGE_PROTECTED)  # the secondary holds the way back


def test_rollback_of_a_confirmed_update_swaps_the_previous_image_back() -> None:
    mcu = updated()
    ask(mcu, "slot.confirm")
    reply = ask(mcu, "slot.swap", sha256=sha(OLD), confirm_by=ConfirmBy.HOST)
    assert reply["status"] == SlotResult.OK
    run(mcu, SWAP_RUN_US)
    assert running_version(mcu) == "1.0.0"
    assert ask(mcu, "slot.confirm")["status"] == SlotResult.OK


def test_swap_refuses_an_image_that_does_not_verify() -> None:
    mcu = booted(node())
    download(mcu, NEW)
    assert (ask(mcu, "slot.swap", sha256=sha(OLD), confirm_by=0)["status"]
            == SlotResult.HASH_MISMATCH)
    pages = split_pages(NEW)
    ask(mcu, "slot.write", index=5, data=bytes(256))
    reply = ask(mcu, "slot.swap", sha256=sha(NEW), confirm_by=0)
    assert reply == {"status": SlotResult.BAD_IMAGE, "image_status": ImageStatus.HASH_MISMATCH}
    ask(mcu, "slot.write", index=5, data=pages[5])
    assert ask(mcu, "slot.confirm")["status"] == SlotResult.NOT_IN_TRIAL
    run(mcu, SWAP_RUN_US)
    assert running_version(mcu) == "1.0.0" and mcu.resets == 0


def test_a_pending_image_altered_before_the_reset_is_refused_and_the_old_one_boots() -> None:
    mcu = booted(node())
    download(mcu, NEW)
    pending = SwapRecord(SlotState.PENDING, sha256=sha(NEW), seq=5).to_page()
    vflash(mcu).load(page_address(FLASH.swap_status_pages[0]), pending)
    vflash(mcu).load(page_address(FLASH.secondary_slot[3]), bytes(256))
    ask(mcu, "reset")
    run(mcu, 4_600_000)
    assert running_version(mcu) == "1.0.0"
    info = ask(mcu, "slot.info")
    assert (info["state"], info["event"]) == (SlotState.CONFIRMED, SlotEvent.REFUSED)


def test_a_swapped_in_image_that_does_not_verify_is_swapped_back_at_once() -> None:
    mcu = booted(node())
    download(mcu, NEW)
    ask(mcu, "slot.swap", sha256=sha(NEW), confirm_by=0)
    run(mcu, 3_000)
    vflash(mcu).load(page_address(FLASH.secondary_slot[12]), bytes(256))  # mid-swap damage
    run(mcu, SWAP_RUN_US * 2)
    assert running_version(mcu) == "1.0.0"
    assert ask(mcu, "slot.info")["event"] == SlotEvent.REVERTED


def test_the_bootloader_answers_the_slot_messages_and_a_halt_during_a_swap_stays() -> None:
    mcu = updated()
    ask(mcu, "reset")
    run(mcu, 5_000)  # the revert has begun
    assert ask(mcu, "bl.halt", run_us=1_000) == {}
    run(mcu, SWAP_RUN_US)
    status = ask(mcu, "bl.status")
    assert status["state"] == BootState.HALTED and "reverted" in status["text"]
    assert ask(mcu, "slot.info")["event"] == SlotEvent.REVERTED
    assert ask(mcu, "slot.confirm")["status"] == SlotResult.NOT_IN_TRIAL


def test_a_one_slot_burn_forgets_an_update_in_progress() -> None:
    """The original host tools write the primary slot with bl.write_page: an unconfirmed
    trial must not swap back over the image they burn."""
    mcu = updated()
    ask(mcu, "reset")
    run(mcu, 1_000)
    assert ask(mcu, "bl.halt", run_us=1_000) == {}
    run(mcu, SWAP_RUN_US)  # the revert finishes; the bootloader stays
    third = image("3.0.0", 5)
    for i, data in enumerate(split_pages(third)):
        assert ask(mcu, "bl.write_page", page=32 + i, data=data)["status"] == WriteStatus.OK
    assert read_record(vflash(mcu))[0].state == SlotState.CONFIRMED
    ask(mcu, "bl.boot")
    run(mcu, 10_000)
    assert running_version(mcu) == "3.0.0"


@pytest.mark.parametrize("state", [SlotState.PENDING, SlotState.TRIAL])
def test_a_one_slot_program_ignores_the_slot_messages(state: SlotState) -> None:
    class OneSlotApp(TinyApp):
        two_slots = False

    mcu = make_node(Scheduler(), BoardType.FMCB, image=OLD, apps={"fmcb": OneSlotApp})
    booted(mcu)
    pogo(mcu).take_sent()
    pogo(mcu).deliver(CATALOGUE["slot.info"].request_frame(ADDRESS, {}))
    run(mcu, 30_000)
    assert pogo(mcu).take_sent() == []
