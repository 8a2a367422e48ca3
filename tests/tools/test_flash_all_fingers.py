"""Flashing all twelve finger nodes on the in-process emulator: flash, skip, force, refuse,
and interruptions (host killed, node power lost, finger link dropped) resumed by a re-run."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bootloader.batch import RunReport, run_plan
from bootloader.errors import PlanError
from bootloader.node_session import NodeReport, NodeState
from bootloader.plan import FlashPlan, make_plan
from firmware_py.boot_program import inspect_image
from firmware_py.mcu import Mcu
from hil_emulator.emulator import Emulator
from hil_emulator.inprocess import EmulatorTransport, bring_up
from host.hand.session import HandSession
from protocol.image import BoardType, FirmwareImage, ImageHeader, Version
from protocol.messages.boot_program import AUTOBOOT_WINDOW_US, ImageStatus
from tools.cli import flash_all_fingers

BOARDS = (BoardType.FMCB, BoardType.F2, BoardType.F3)


def images(version: str) -> dict[BoardType, FirmwareImage]:
    return {b: FirmwareImage.build(bytes(range(256)) * 9 + version.encode() + b.name.encode(),
                                   b, version, b.name.lower()) for b in BOARDS}


NEW = images("2.3.4")


class Hand:
    """An emulated hand brought up, with a record of every boot of a finger node."""

    def __init__(self) -> None:
        self.emu = Emulator("hand", physics=False, can="none")
        bring_up(self.emu)
        assert self.emu.hand is not None
        self.rig = self.emu.hand
        self.boots: list[tuple[str, ImageStatus, ImageHeader | None]] = []
        for finger in self.rig.fingers:
            for mcu in (finger.fmcb, finger.f2, finger.f3):
                self._watch(f"finger {finger.index} {mcu.identity.board_type}", mcu)

    def _watch(self, name: str, mcu: Mcu) -> None:
        original = mcu.boot

        def boot(app_name: str, version: Version | None = None) -> None:
            check = inspect_image(mcu.hal.flash, mcu.identity.board_type)
            self.boots.append((name, check.status, check.header))
            original(app_name, version)

        mcu.boot = boot  # type: ignore[method-assign]  # this node's boots are watched

    def session(self) -> HandSession:
        return HandSession(EmulatorTransport(self.emu, "palm"))

    def nodes(self) -> list[Mcu]:
        return [m for f in self.rig.fingers for m in (f.fmcb, f.f2, f.f3)]

    def assert_all_run(self, version: str) -> None:
        for mcu in self.nodes():
            assert mcu.program_name not in (None, "bootloader"), mcu.identity
            assert getattr(mcu.program, "fw_version", None) == tuple(
                int(p) for p in version.split("."))
        # Never did a node boot an image that does not verify, nor a partial one.
        allowed = {img.header for img in NEW.values()}
        for name, status, header in self.boots:
            assert status == ImageStatus.VALID, name
            assert header is not None and (header in allowed or str(header.version) != "2.3.4")


@pytest.fixture()
def hand() -> Iterator[Hand]:
    h = Hand()
    yield h
    h.emu.close()


def run(hand: Hand, plan: FlashPlan) -> RunReport:
    with hand.session() as session:
        return run_plan(session, plan)


def test_flash_all_twelve_then_skip_then_force(hand: Hand) -> None:
    first = run(hand, make_plan(NEW))
    assert first.ok and len(first.nodes) == 12
    assert {r.result for r in first.nodes} == {"flashed"}
    assert all(r.version == "2.3.4" and r.bytes_written > 0 for r in first.nodes)
    hand.assert_all_run("2.3.4")

    second = run(hand, make_plan(NEW))
    assert second.ok and {r.result for r in second.nodes} == {"skipped"}
    assert sum(r.bytes_written for r in second.nodes) == 0

    forced = run(hand, make_plan(NEW, [1], force=True))
    assert forced.ok and {r.result for r in forced.nodes} == {"flashed"}
    assert all(r.bytes_written == len(NEW[r.job.board].pages()) * 256 for r in forced.nodes)
    hand.assert_all_run("2.3.4")


def test_all_or_nothing_stages_every_node_then_activates(hand: Hand) -> None:
    report = run(hand, make_plan(NEW, [0, 2], all_or_nothing=True))
    assert report.ok, [r.to_dict() for r in report.nodes]
    assert all(r.result == "flashed" for r in report.nodes)


def test_cli_json_and_refusals_before_touching_anything(
        hand: Hand, tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    paths = {}
    for board, image in NEW.items():
        paths[board] = tmp_path / f"{board.name.lower()}.img"
        paths[board].write_bytes(image.to_bytes())
    monkeypatch.setattr(flash_all_fingers, "open_transport",
                        lambda url: EmulatorTransport(hand.emu, "palm"))
    args = ["--port", "emu://hand/palm", "--fmcb", str(paths[BoardType.FMCB]),
            "--f2", str(paths[BoardType.F2]), "--f3", str(paths[BoardType.F3])]
    boots = len(hand.boots)

    # Wrong board, missing file, corrupted image, unsigned where required: exit 2, untouched.
    wrong = ["--port", "x", "--fmcb", str(paths[BoardType.F2])]
    assert flash_all_fingers.main(wrong) == 2
    assert "wrong board" in capsys.readouterr().err
    assert flash_all_fingers.main(["--port", "x", "--f2", str(tmp_path / "nope.img")]) == 2
    assert "no such file" in capsys.readouterr().err
    bad = tmp_path / "bad.img"
    bad.write_bytes(paths[BoardType.F3].read_bytes()[:-5])
    assert flash_all_fingers.main(["--port", "x", "--f3", str(bad)]) == 2
    assert "truncated" in capsys.readouterr().err
    key = tmp_path / "pub"
    key.write_bytes(bytes(range(32)))
    assert flash_all_fingers.main([*args, "--key", str(key)]) == 2
    assert "unsigned" in capsys.readouterr().err
    assert len(hand.boots) == boots

    # Dry run touches nothing.
    assert flash_all_fingers.main([*args, "--dry-run"]) == 0
    assert len(capsys.readouterr().out.splitlines()) == 12 and len(hand.boots) == boots

    # A finger that does not answer: refused before anything is touched.
    hand.emu.break_away(3)
    assert flash_all_fingers.main(args) == 2
    err = capsys.readouterr().err
    assert "finger 3 is not answering" in err and "--fingers 0,1,2" in err
    assert len(hand.boots) == boots

    # The rest, with --json; versions read back by identify match.
    assert flash_all_fingers.main([*args, "--fingers", "0,1,2", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert len(out["nodes"]) == 9 and out["total_seconds"] > 0
    assert {n["result"] for n in out["nodes"]} == {"flashed"}
    assert {n["version"] for n in out["nodes"]} == {"2.3.4"}
    assert {(n["finger"], n["board"]) for n in out["nodes"]} == {
        (f, b) for f in range(3) for b in ("fmcb", "f2", "f3")}


def test_a_nonexistent_port_is_a_clear_error(capsys: pytest.CaptureFixture[str],
                                            tmp_path: Path) -> None:
    img = tmp_path / "f2.img"
    img.write_bytes(NEW[BoardType.F2].to_bytes())
    assert flash_all_fingers.main(["--port", str(tmp_path / "ttyNONE"), "--f2", str(img)]) == 2
    err = capsys.readouterr().err
    assert "cannot open" in err and "nothing was touched" in err
    assert err.count("cannot open") == 1  # said once, not "cannot open P: cannot open P"
    assert "nothing else holds the port" in err


class HostKilled(BaseException):
    """The host process dies (nothing in the engine may catch it)."""


def interrupt_and_resume(kind: str, finger: int, after_frames: int) -> None:
    hand = Hand()
    try:
        emu, rig = hand.emu, hand.rig
        session = hand.session()
        sent = [0]

        def fault(direction: str, t: float, frame: bytes) -> None:
            if direction != "tx":
                return
            sent[0] += 1
            if sent[0] != after_frames:
                return
            f = rig.fingers[finger]
            if kind == "host_killed":
                raise HostKilled()
            if kind == "power_lost":
                for node in (f.f2, f.f3, f.fmcb):
                    node.power_off()
                emu.scheduler.call_later(20_000, f.fmcb.power_on)
            elif kind == "phalange_power_lost":
                f.f2.power_off()
                emu.scheduler.call_later(5_000, f.f2.power_on)
            else:
                emu.break_away(finger)
                emu.scheduler.call_later(150_000, lambda: emu.reattach(finger))

        session.taps.append(fault)
        try:
            run_plan(session, make_plan(NEW))
        except HostKilled:
            pass
        session.close()
        emu.step(200_000)
        report = run(hand, make_plan(NEW))
        assert report.ok, [r.to_dict() for r in report.nodes if r.result == "failed"]
        hand.assert_all_run("2.3.4")
    finally:
        hand.emu.close()


KINDS = st.sampled_from(["host_killed", "power_lost", "phalange_power_lost", "link_dropped"])


#: The frames after which a case breaks the flashing (the whole run: about 320 frames).
AFTER = st.integers(1, 320)


@settings(max_examples=4, deadline=None, suppress_health_check=list(HealthCheck))
@given(kind=KINDS, finger=st.integers(0, 3), after=AFTER)
def test_interrupted_flashing_resumes_and_never_boots_an_unverified_image(
        kind: str, finger: int, after: int) -> None:
    interrupt_and_resume(kind, finger, after)


@pytest.mark.long
@settings(max_examples=25, deadline=None, suppress_health_check=list(HealthCheck))
@given(kind=KINDS, finger=st.integers(0, 3), after=AFTER)
def test_interrupted_flashing_resumes_many_cases(kind: str, finger: int, after: int) -> None:
    """25 cases of the property above (``make test-long``; about 2 minutes of CPU):
    ``make test`` checks the same property, on the same cases' space, in 4 cases."""
    interrupt_and_resume(kind, finger, after)


def test_a_resumed_node_is_shown_with_the_partial_image_it_held(hand: Hand) -> None:
    """Killed mid-write, a node holds only the start of the new image (its header goes
    first): the re-run's table says so, never "2.3.4 → 2.3.4" as if it had run 2.3.4."""
    session = hand.session()
    writing: list[int] = []

    def on_change(report: NodeReport) -> None:
        if report.job.name == "finger 0 fmcb" and report.state == NodeState.WRITING:
            writing.append(0)

    def kill_mid_write(direction: str, t: float, frame: bytes) -> None:
        if direction == "tx" and writing:
            writing[0] += 1
            if writing[0] == 12:  # the header page and some of the payload are written
                raise HostKilled()

    session.taps.append(kill_mid_write)
    with pytest.raises(HostKilled):
        run_plan(session, make_plan(NEW, [0], slots=False), on_change=on_change)
    session.close()
    hand.emu.step(200_000)
    report = run(hand, make_plan(NEW, [0], slots=False))  # the one-slot way's own story
    assert report.ok
    fmcb = next(r for r in report.nodes if r.job.name == "finger 0 fmcb")
    assert fmcb.result == "flashed" and fmcb.version_before is None
    assert fmcb.partly_written == "2.3.4" and fmcb.to_dict()["partly_written"] == "2.3.4"
    row = next(line for line in flash_all_fingers.table(report).splitlines()
               if line.startswith("finger 0 fmcb"))
    assert "2.3.4 partly written → 2.3.4" in row and row.endswith("flashed")


def test_all_or_nothing_rerun_finishes_after_a_finger_broke_away(hand: Hand) -> None:
    # Finger 1 pops off while the nodes are being staged: nothing is activated, and every
    # staged fmcb waits in its bootloader with its old application gone.
    def on_change(report: NodeReport) -> None:
        if report.job.name == "finger 0 f3" and report.state == NodeState.STAGED:
            hand.emu.break_away(1)

    with hand.session() as session:
        first = run_plan(session, make_plan(NEW, all_or_nothing=True), on_change=on_change)
    assert not first.ok
    assert not any(r.state == NodeState.DONE for r in first.nodes)
    hand.emu.reattach(1)
    hand.emu.step(200_000)
    # The same command again finishes the job: the phalanges behind an fmcb that waits in
    # its bootloader are reached by finishing that fmcb first (its old image is gone).
    report = run(hand, make_plan(NEW, all_or_nothing=True))
    assert report.ok, [r.to_dict() for r in report.nodes if r.result == "failed"]
    hand.assert_all_run("2.3.4")


def test_a_hand_just_switched_on_is_waited_for_and_a_halted_palm_is_named() -> None:
    # The palm starts its application 4.5 s after power-up: preflight waits for it.
    emu = Emulator("hand", physics=False, can="none")
    try:
        with HandSession(EmulatorTransport(emu, "palm")) as session:
            report = run_plan(session, make_plan(NEW, [0]))
        assert report.ok, [r.to_dict() for r in report.nodes]
    finally:
        emu.close()
    # A palm that stays in its bootloader: refused before touching anything, saying so.
    emu = Emulator("hand", physics=False, can="none")
    try:
        with HandSession(EmulatorTransport(emu, "palm")) as session:
            session.request("bl.halt")
            with pytest.raises(PlanError, match="palm .* runs its bootloader"):
                run_plan(session, make_plan(NEW, [0]))
    finally:
        emu.close()


def test_ctrl_c_mid_flash_prints_where_every_node_stopped_then_a_rerun_resumes(
        hand: Hand, tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    paths = []
    for board, image in NEW.items():
        path = tmp_path / f"{board.name.lower()}.img"
        path.write_bytes(image.to_bytes())
        paths += [f"--{board.name.lower()}", str(path)]
    monkeypatch.setattr(flash_all_fingers, "open_transport",
                        lambda url: EmulatorTransport(hand.emu, "palm"))
    printer = flash_all_fingers.progress_printer

    def ctrl_c_while_writing(stream: Any) -> Any:
        show = printer(stream)

        def on_change(report: NodeReport) -> None:
            show(report)  # type: ignore[operator]
            if report.job.name == "finger 2 f2" and report.state == NodeState.WRITING:
                raise KeyboardInterrupt

        return on_change

    monkeypatch.setattr(flash_all_fingers, "progress_printer", ctrl_c_while_writing)
    args = ["--port", "emu://hand/palm", *paths, "--one-slot"]
    assert flash_all_fingers.main([*args, "--json"]) == 130
    captured = capsys.readouterr()
    assert "writing (3 blocks)" in captured.err  # progress names the blocks to write
    assert captured.err.startswith("checking the palm and fingers 0,1,2,3")
    out = json.loads(captured.out)  # the report is still printed, as JSON
    assert out["ok"] is False and out["stopped"] == "interrupted"
    states = {(n["finger"], n["board"]): n for n in out["nodes"]}
    assert states[(2, "f2")]["error"] == "interrupted in state writing"
    assert states[(2, "f2")]["seconds"] > 0  # the time it spent until Ctrl-C
    assert "finger 2 (" in out["next_step"] and "run the same command again" in out["next_step"]

    monkeypatch.setattr(flash_all_fingers, "progress_printer", printer)
    assert flash_all_fingers.main(args) == 0
    text = capsys.readouterr().out
    assert "all nodes verified" in text and "next:" not in text
    hand.assert_all_run("2.3.4")


def test_a_lost_link_is_said_once_and_each_node_names_where_it_stopped() -> None:
    from bootloader.batch import new_reports, settle
    reports = new_reports(make_plan(NEW, [1]))
    fmcb, f2, _ = reports.values()
    fmcb.state, fmcb.started = NodeState.WRITING, 1.0
    report = settle(reports, 0.5, 2.0, "link lost: /dev/ttyACM0: the port is gone")
    assert report.stopped == "link lost: /dev/ttyACM0: the port is gone" and not report.ok
    assert fmcb.error == "link lost in state writing" and fmcb.seconds == 1.0
    assert f2.error == "not started (link lost)"
    assert report.total_seconds == 1.5
    assert report.next_step is not None and "finger 1 (fmcb f2 f3)" in report.next_step


@pytest.mark.parametrize("all_or_nothing", [False, True])
def test_phalanges_of_an_unpowered_finger_are_flashed_after_powering_it(
        all_or_nothing: bool) -> None:
    emu = Emulator("hand", physics=False, can="none")  # the palm up, every finger off
    try:
        plan = make_plan({BoardType.F2: NEW[BoardType.F2], BoardType.F3: NEW[BoardType.F3]},
                         [1], all_or_nothing=all_or_nothing)
        with HandSession(EmulatorTransport(emu, "palm")) as session:
            report = run_plan(session, plan)
        assert report.ok, [r.to_dict() for r in report.nodes]
        assert [r.result for r in report.nodes] == ["flashed", "flashed"]
        # Progress starts when the finger is powered, not after its fmcb's boot (4.5 s).
        assert all(r.seconds > AUTOBOOT_WINDOW_US / 1e6 for r in report.nodes)
    finally:
        emu.close()


def test_a_node_refusing_the_signature_says_which_key_to_sign_with(tmp_path: Path) -> None:
    from bootloader.signing import generate_key_pair, load_private_key, sign_image
    from firmware_py.sim.boards import install_image, provision_key
    from firmware_py.sim.virtual_hal import VirtualHal
    hand = Hand()
    try:
        node_key = generate_key_pair(tmp_path / "node", tmp_path / "node.pub")
        generate_key_pair(tmp_path / "other", tmp_path / "other.pub")
        f2 = hand.rig.fingers[0].f2
        assert isinstance(f2.hal, VirtualHal)
        provision_key(f2.hal, node_key)
        # It runs an image signed with its key (version 2.3.3) …
        old = sign_image(images("2.3.3")[BoardType.F2], load_private_key(tmp_path / "node"))
        install_image(f2.hal, old.to_bytes())
        # … and is given one signed with another key.
        image = sign_image(NEW[BoardType.F2], load_private_key(tmp_path / "other"))
        report = run(hand, make_plan({BoardType.F2: image}, [0], slots=False))
        (node,) = report.nodes
        assert node.result == "failed" and node.error is not None
        assert "not signed with the key this node was provisioned with" in node.error
        assert "fwimage build --sign KEY" in node.error and "BootResult" not in node.error
        # Refused at its header page, before anything was erased: it runs its old image.
        assert "refused before anything was written" in node.error
        assert "keeps the image it had and runs it again" in node.error
        hand.emu.step(100_000)
        assert f2.program_name == "f2" and getattr(f2.program, "fw_version", None) == (2, 3, 3)
        assert inspect_image(f2.hal.flash, BoardType.F2).status == ImageStatus.VALID
    finally:
        hand.emu.close()


def test_a_finger_lost_during_its_power_cycle_is_named_with_what_to_check(hand: Hand) -> None:
    def on_change(report: NodeReport) -> None:
        if report.job.name == "finger 2 fmcb" and report.state == NodeState.FORCING:
            hand.emu.break_away(2)

    with hand.session() as session:
        report = run_plan(session, make_plan(NEW, [2], slots=False), on_change=on_change)
    fmcb = report.nodes[0]
    assert fmcb.result == "failed" and fmcb.error is not None
    assert "is the finger on its pogo pins?" in fmcb.error
    assert report.next_step is not None and "finger 2 (fmcb f2 f3)" in report.next_step
