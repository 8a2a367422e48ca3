"""The fleet update through the two image slots, on the in-process emulator: writes through
the palm and fmcb tunnels while the applications run, twelve nodes swapped and confirmed,
a failed check rolling the fleet back, --rollback, --keep-trial, and one-slot nodes."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from bootloader.batch import RunReport, run_plan, run_rollback
from bootloader.plan import make_plan, rollback_plan
from bootloader.slot_update import SWAP_WITHIN_S
from firmware_py.mcu import Mcu
from firmware_py.sim.boards import install_one_slot_firmware
from hil_emulator.emulator import Emulator
from hil_emulator.inprocess import EmulatorTransport, bring_up
from host.hand.session import HandSession, Target
from protocol.image import BoardType, FirmwareImage, split_pages
from protocol.messages.boot_program import AUTOBOOT_WINDOW_US, WriteStatus
from protocol.messages.common import Running
from protocol.messages.slots import TRIAL_TIMEOUT_US
from protocol.topology import Hop
from tools.cli import flash_all_fingers

BOARDS = (BoardType.FMCB, BoardType.F2, BoardType.F3)


def images(version: str, app: dict[BoardType, str] | None = None) -> dict[BoardType, FirmwareImage]:
    names = app or {}
    return {b: FirmwareImage.build(bytes(range(256)) * 9 + version.encode() + b.name.encode(),
                                   b, version, names.get(b, b.name.lower())) for b in BOARDS}


NEW = images("2.3.4")


@pytest.fixture()
def emu() -> Iterator[Emulator]:
    emulator = Emulator("hand", physics=False, can="none")
    bring_up(emulator)
    try:
        yield emulator
    finally:
        emulator.close()


def nodes(emu: Emulator) -> list[Mcu]:
    assert emu.hand is not None
    return [m for f in emu.hand.fingers for m in (f.fmcb, f.f2, f.f3)]


def versions(emu: Emulator) -> set[tuple[int, ...]]:
    out = set()
    for mcu in nodes(emu):
        assert mcu.program_name not in (None, "bootloader"), mcu.identity
        out.add(getattr(mcu.program, "fw_version", ()))
    return out


def run(emu: Emulator, plan: Any) -> RunReport:
    with HandSession(EmulatorTransport(emu, "palm")) as session:
        return run_plan(session, plan)


def test_the_secondary_slot_of_f3_is_written_through_both_tunnels_while_it_runs(
        emu: Emulator) -> None:
    assert emu.hand is not None
    f3 = emu.hand.fingers[1].f3
    boots = f3.boots
    image = NEW[BoardType.F3]
    with HandSession(EmulatorTransport(emu, "palm")) as session:
        to = Target(1, Hop.F3)
        for index, data in enumerate(split_pages(image.to_bytes())):
            reply = session.request("slot.write", {"index": index, "data": data}, to=to,
                                    extra_ms=12)
            assert reply == {"index": index, "status": WriteStatus.OK}
            assert f3.program_name == "f3" and f3.boots == boots
        assert session.request("identify", to=to)["running"] == Running.APPLICATION
        info = session.request("slot.info", to=to)
    assert info["secondary_sha256"] == image.header.sha256
    assert info["secondary_version"] == {"major": 2, "minor": 3, "patch": 4}


def test_twelve_nodes_updated_through_their_slots_down_one_reboot_each(emu: Emulator) -> None:
    before = versions(emu)
    report = run(emu, make_plan(NEW))
    assert report.ok, [r.to_dict() for r in report.nodes]
    assert versions(emu) == {(2, 3, 4)}
    for r in report.nodes:
        d = r.to_dict()
        assert d["layout"] == "two-slot" and d["result"] == "flashed"
        assert d["slots"]["state"] == "confirmed" and d["slots"]["primary"] == "2.3.4"
        assert d["slots"]["secondary"] == r.version_before
        assert d["downtime_s"] is not None
        if r.job.board == BoardType.FMCB:
            assert d["downtime_s"] < 0.5  # one reboot: the swap and the jump
        else:
            # Behind its rebooted fmcb it boots again (its window), then its own swap.
            assert d["downtime_s"] < AUTOBOOT_WINDOW_US / 1e6 + 1.0
    assert before != {(2, 3, 4)}
    # A second run finds every node on the image, confirmed: nothing is touched.
    again = run(emu, make_plan(NEW))
    assert again.ok and {r.result for r in again.nodes} == {"skipped"}


def test_a_node_failing_its_check_rolls_the_whole_update_back(emu: Emulator) -> None:
    before = versions(emu)
    bad = images("2.3.4", {BoardType.F3: "nosuchapp"})  # verifies, but cannot start
    report = run(emu, make_plan(bad, [0, 1]))
    assert not report.ok
    by = {(r.job.finger, r.job.board): r for r in report.nodes}
    failed = by[(0, BoardType.F3)]
    assert failed.result == "failed" and failed.error is not None
    assert "did not start" in failed.error
    rolled = [r for r in report.nodes if r.result == "rolled back"]
    assert {(r.job.finger, r.job.board) for r in rolled} >= {(0, BoardType.FMCB),
                                                             (0, BoardType.F2)}
    assert all(r.rollback_s is not None and r.rollback_s < SWAP_WITHIN_S for r in rolled)
    assert versions(emu) == before
    assert report.next_step is not None and "rolled back" in report.next_step


def test_no_fleet_rollback_keeps_the_nodes_that_passed(emu: Emulator) -> None:
    bad = images("2.3.4", {BoardType.F3: "nosuchapp"})
    report = run(emu, make_plan(bad, [0], fleet_rollback=False))
    by = {r.job.board: r for r in report.nodes}
    assert by[BoardType.FMCB].result == "flashed" and by[BoardType.F2].result == "flashed"
    assert by[BoardType.F3].result == "failed"
    assert emu.hand is not None
    finger = emu.hand.fingers[0]
    assert getattr(finger.fmcb.program, "fw_version", None) == (2, 3, 4)
    assert getattr(finger.f3.program, "fw_version", None) != (2, 3, 4)


def test_rollback_option_puts_every_node_back(emu: Emulator, tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str],
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    before = versions(emu)
    assert run(emu, make_plan(NEW)).ok
    monkeypatch.setattr(flash_all_fingers, "open_transport",
                        lambda url: EmulatorTransport(emu, "palm"))
    assert flash_all_fingers.main(["--port", "emu://hand/palm", "--rollback", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["ok"] is True and out["mode"] == "rollback"
    assert {n["result"] for n in out["nodes"]} == {"rolled back"}
    assert all(n["slots"]["state"] == "confirmed" and n["rollback_s"] > 0
               for n in out["nodes"])
    assert versions(emu) == before
    # --rollback takes no images.
    img = tmp_path / "f2.img"
    img.write_bytes(NEW[BoardType.F2].to_bytes())
    assert flash_all_fingers.main(["--port", "x", "--rollback", "--f2", str(img)]) == 2
    assert "--rollback takes no --f2" in capsys.readouterr().err


def test_keep_trial_leaves_the_images_unconfirmed_and_the_trial_watchdog_reverts(
        emu: Emulator) -> None:
    before = versions(emu)
    report = run(emu, make_plan(NEW, [2], keep_trial=True))
    assert report.ok
    assert {r.to_dict()["slots"]["state"] for r in report.nodes} == {"trial"}
    emu.step(TRIAL_TIMEOUT_US + AUTOBOOT_WINDOW_US)
    # The fmcb's trial watchdog reset it (its phalanges' power too, as any fmcb reset
    # does, until the host powers them): every node comes back on its previous image.
    with HandSession(EmulatorTransport(emu, "palm")) as session:
        session.request("fmcb.phalange_power", {"on": 1}, to=Target(2, Hop.FMCB))
    emu.step(AUTOBOOT_WINDOW_US + 500_000)
    assert versions(emu) == before


def test_one_slot_nodes_are_flashed_as_before_and_the_report_says_which(
        emu: Emulator) -> None:
    assert emu.hand is not None
    finger = emu.hand.fingers[3]
    for mcu in (finger.fmcb, finger.f2, finger.f3):
        install_one_slot_firmware(mcu)
    with HandSession(EmulatorTransport(emu, "palm")) as session:
        session.request("palm.finger_power", {"finger": 3, "state": 0, "stagger_ms": 0})
        session.sleep(0.05)
        session.request("palm.finger_power", {"finger": 3, "state": 2, "stagger_ms": 0})
    emu.step(2 * AUTOBOOT_WINDOW_US)
    report = run(emu, make_plan(NEW, [2, 3]))
    assert report.ok, [r.to_dict() for r in report.nodes]
    layouts = {(r.job.finger, r.job.board): r.layout for r in report.nodes}
    assert {v for (f, _), v in layouts.items() if f == 3} == {"one-slot"}
    assert {v for (f, _), v in layouts.items() if f == 2} == {"two-slot"}
    assert versions(emu) >= {(2, 3, 4)}


def test_rollback_of_a_node_never_updated_says_it_has_no_previous_image(
        emu: Emulator) -> None:
    assert emu.hand is not None
    with HandSession(EmulatorTransport(emu, "palm")) as session:
        report = run_rollback(session, rollback_plan([1]))
    # Never updated through its slots: no previous image in the secondary slot.
    assert not report.ok
    assert versions(emu) != {(2, 3, 4)}  # all still run what they ran
    assert all(r.result == "failed" and r.error and "no previous image" in r.error
               for r in report.nodes)
