"""Bringing the emulated hand up from power-on, as the README walks a user through it:
``power all`` tells the states after the palm's stagger, ``handctl up`` (``Hand.bring_up``)
boots every finger board and starts autopoll, and before that ``status`` and ``home`` say
what is missing instead of failing.  In process (``emu://``), on the simulation clock."""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from pathlib import Path

import pytest
from mcap.reader import make_reader

from hil_emulator.emulator import Emulator
from hil_emulator.inprocess import EmulatorTransport
from host.errors import TransportError
from host.hand.bring_up import BOOT_TIMEOUT_S
from host.hand.facade import Hand
from host.transports.base import _registered as transport_registry
from host.transports.base import open_transport
from protocol.messages.boot_program import AUTOBOOT_WINDOW_US
from protocol.topology import FINGERS
from tests.host.slow_link import FastLinkClock
from tools.cli.handctl import main

#: Simulation time for the palm to leave its bootloader after power-on (µs).
PALM_BOOT_US = AUTOBOOT_WINDOW_US + 500_000
AUTOBOOT_S = AUTOBOOT_WINDOW_US / 1e6


def _emulator(url: str) -> Emulator:
    """The in-process emulator behind ``url`` (shared by every transport opened on it)."""
    transport = open_transport(url)
    assert isinstance(transport, EmulatorTransport)
    emulator = transport.emulator
    transport.close()
    return emulator


def _autopolling(emulator: Emulator) -> list[bool]:
    assert emulator.hand is not None
    return [bool(getattr(f.fmcb.program, "autopoll", False)) for f in emulator.hand.fingers]


def test_power_all_reports_every_fingers_state_after_the_stagger() -> None:
    emulator = Emulator("hand", physics=False, can="none")
    emulator.step(PALM_BOOT_US)
    with Hand.open(EmulatorTransport(emulator, "palm")) as hand:
        start = hand.session.now()
        states = hand.power("all", "full", stagger_ms=50)
        # The palm answers at the first switch; the states come after the last one.
        assert hand.session.now() - start >= (FINGERS - 1) * 0.050
        assert states == ["full"] * FINGERS
        assert hand.power("all", "off", stagger_ms=50) == ["off"] * FINGERS
        assert hand.power(1, "low") == ["off", "low", "off", "off"]


@pytest.fixture(scope="module")
def phalanges_off() -> Iterator[str]:
    """A hand (with physics: the fmcbs' accelerometers feel gravity) whose fingers were
    switched on by ``handctl power all full`` and booted, their phalanges never powered."""
    url = "emu://hand/palm?ready=0&name=handctl-up-phalanges-off"
    emulator = _emulator(url)
    emulator.step(PALM_BOOT_US)
    yield url


def test_power_all_prints_every_finger_on(phalanges_off: str,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--port", phalanges_off, "--json", "power", "all", "full"]) == 0
    assert json.loads(capsys.readouterr().out)["power"] == ["full"] * FINGERS
    _emulator(phalanges_off).step(PALM_BOOT_US)  # the fmcbs boot


def test_status_with_unpowered_phalanges_gives_null_joints_accel(
        phalanges_off: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--port", phalanges_off, "--json", "status"]) == 0
    fingers = json.loads(capsys.readouterr().out)["fingers"]
    assert [f["present"] for f in fingers] == [True] * FINGERS
    for f in fingers:
        assert f["joints_accel"] is None and f["homed"] is False
        assert "proximal phalange (f2)" in f["accel_problem"]
        assert "handctl up" in f["accel_problem"]
        assert "np.float64" not in f["accel_problem"]
        assert len(f["joints"]) == 3  # the rest of the status is there


def test_home_with_unpowered_phalanges_names_them_and_says_what_to_do(
        phalanges_off: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--port", phalanges_off, "home"]) == 1
    out = capsys.readouterr().out
    for k in range(FINGERS):
        assert (f"finger {k}: not homed: the proximal phalange (f2) and the distal "
                f"phalange (f3) do not answer (no_reply)") in out
    assert "power the phalanges: `handctl up`" in out and "np.float64" not in out
    assert main(["--port", phalanges_off, "home", "--finger", "2"]) == 2
    err = capsys.readouterr().err
    assert "finger 2: the proximal phalange (f2) and the distal phalange (f3)" in err
    assert "Traceback" not in err


def test_up_then_status_reads_the_phalanges_accelerometers(
        phalanges_off: str, capsys: pytest.CaptureFixture[str]) -> None:
    emulator = _emulator(phalanges_off)
    assert main(["--port", phalanges_off, "up"]) == 0
    out = capsys.readouterr().out
    # The fmcbs were running already: only the phalanges had to boot.
    assert "phalanges: power on (fingers 0, 1, 2, 3)" in out
    assert "up: 12 of 12 finger boards run their application" in out
    assert _autopolling(emulator) == [True] * FINGERS
    assert main(["--port", phalanges_off, "--json", "status"]) == 0
    fingers = json.loads(capsys.readouterr().out)["fingers"]
    assert all(isinstance(f["joints_accel"], list) and "accel_problem" not in f
               for f in fingers)


def test_up_brings_every_finger_board_up_from_power_on(
        capsys: pytest.CaptureFixture[str]) -> None:
    url = "emu://hand/palm?ready=0&physics=0&name=handctl-up-from-power-on"
    emulator = _emulator(url)
    start_us = emulator.scheduler.now_us()
    assert main(["--port", url, "--json", "up"]) == 0
    captured = capsys.readouterr()
    elapsed_s = (emulator.scheduler.now_us() - start_us) / 1e6
    report = json.loads(captured.out)
    assert report["down"] == []
    assert all(f["up"] and f["autopoll"] and f["power"] == "full" for f in report["fingers"])
    # The palm, then the fmcbs, then the phalanges each wait out an autoboot window.
    assert 3 * AUTOBOOT_S <= elapsed_s < 3 * BOOT_TIMEOUT_S
    for f in report["fingers"]:
        fmcb, f2, f3 = f["nodes"]
        assert f2["after_s"] - fmcb["after_s"] >= AUTOBOOT_S
    assert "finger 3 f3: up after" in captured.err  # progress, off stdout with --json
    assert _autopolling(emulator) == [True] * FINGERS
    assert main(["--port", url, "--json", "ping"]) == 0
    nodes = json.loads(capsys.readouterr().out)["nodes"]
    assert len(nodes) == 13 and all(n["running"] == "application" for n in nodes)


def test_up_reports_a_finger_that_cannot_boot_and_exits_non_zero(
        capsys: pytest.CaptureFixture[str]) -> None:
    url = "emu://hand/palm?ready=0&physics=0&name=handctl-up-broken-away"
    emulator = _emulator(url)
    emulator.break_away(2)  # the break_away fault: off its pogo pins, no power, no link
    assert main(["--port", url, "up", "--boot-timeout", "6"]) == 1
    captured = capsys.readouterr()
    assert "handctl: not up: finger 2 fmcb, finger 2 f2, finger 2 f3" in captured.err
    assert "finger 2 fmcb: no_reply 6 s after power-up" in captured.err
    assert "its fmcb did not come up" in captured.err
    assert "finger 2 fmcb: NOT UP" in captured.out
    assert _autopolling(emulator) == [True, True, False, True]
    with Hand.open(url) as hand:
        results = hand.bring_up(timeout=6)
    assert [r.up for r in results] == [True, True, False, True]
    assert results[2].down == ["finger 2 fmcb", "finger 2 f2", "finger 2 f3"]
    assert results[2].nodes[0].problem is not None and not results[2].autopoll


def test_status_says_why_a_finger_does_not_answer_and_what_to_do(
        capsys: pytest.CaptureFixture[str]) -> None:
    url = "emu://hand/palm?ready=0&physics=0&name=handctl-status-unpowered"
    _emulator(url).step(PALM_BOOT_US)
    assert main(["--port", url, "status"]) == 0
    out = capsys.readouterr().out
    assert ("finger 1: power off, not answering (unpowered: bring it up with "
            "`handctl up --finger 1`)") in out
    assert main(["--port", url, "--json", "status"]) == 0
    fingers = json.loads(capsys.readouterr().out)["fingers"]
    assert [f["problem"] for f in fingers] == ["unpowered"] * FINGERS
    assert main(["--port", url, "ping"]) == 0
    assert ("hint: finger(s) 0, 1, 2, 3 unpowered: `handctl up` powers them"
            in capsys.readouterr().out)
    assert main(["--port", url, "up", "--finger", "1"]) == 0
    capsys.readouterr()
    assert main(["--port", url, "--json", "status"]) == 0
    fingers = json.loads(capsys.readouterr().out)["fingers"]
    assert [f["problem"] for f in fingers] == ["unpowered", None, "unpowered", "unpowered"]


def test_record_cut_short_by_a_lost_link_keeps_a_readable_file_and_says_so(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    url = "emu://hand/palm?physics=0&name=handctl-record-unplugged"
    real_status = Hand.status
    calls = []

    def status(hand: Hand, fingers: bool = True) -> object:
        calls.append(1)
        if len(calls) > 3:  # the USB adapter is pulled after three states
            raise TransportError(f"{url}: the port is gone")
        return real_status(hand, fingers)

    monkeypatch.setattr(Hand, "status", status)
    path = tmp_path / "run.mcap"
    assert main(["--port", url, "record", str(path), "--seconds", "5"]) == 1
    err = capsys.readouterr().err
    assert f"{path}: kept what was recorded before it stopped:" in err
    assert ", 3 states" in err and "the port is gone" in err
    with path.open("rb") as stream:
        states = [m for _s, c, m in make_reader(stream).iter_messages()
                  if c.topic == "/hand/state"]
    assert len(states) == 3


@pytest.mark.parametrize("argv", [
    ["record", "RUN", "--seconds", "-1"], ["record", "RUN", "--seconds", "1", "--rate", "0"],
    ["move", "--finger", "1", "--joints", "0,0.3,0.3", "--duration", "-1"],
    ["grasp", "open", "1", "--duration", "0"], ["up", "--boot-timeout", "0"]])
def test_a_time_or_rate_that_is_not_positive_is_refused_before_anything_is_opened(
        argv: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "run.mcap"
    argv = [str(path) if a == "RUN" else a for a in argv]
    assert main(["--port", "/dev/no-such-hand", *argv]) == 2
    assert "give a number > 0" in capsys.readouterr().err
    assert not path.exists()


@pytest.mark.parametrize("command", [["ping"], ["status"]])
def test_a_loose_fingers_cable_is_named_as_such_not_as_a_palm_in_its_bootloader(
        command: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    url = "emu://loose-finger/finger0?physics=0&name=handctl-loose-finger"
    assert main(["--port", url, *command]) == 1
    err = capsys.readouterr().err
    assert f"the node on {url} is a fmcb board, not a palm: a loose finger's cable?" in err
    assert 'link="finger"' in err and "bootloader" not in err


@pytest.mark.parametrize("factor", [1.0, 3.0])
def test_a_move_that_did_not_settle_says_when_the_robot_ran_slower_than_the_link(
        factor: float, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The emulator on a busy machine: its clock (the fmcbs' status timestamps) ran at a
    third of the link's, so --duration on the wall gave the move a third of it."""
    url = f"emu://hand/palm?physics=0&name=handctl-slow-robot-{factor:g}"
    monkeypatch.setitem(transport_registry, "slowemu",
                        lambda _url, **_options: FastLinkClock(open_transport(url), factor))
    argv = ["--port", "slowemu://palm", "--json", "move", "--finger", "1", "--joints",
            "0,0.5,0.5", "--unhomed", "--duration", "0.3"]
    assert main(argv) == 1  # no physics: the fingers never get there
    captured = capsys.readouterr()
    # Within the fmcb's 5 ms status refresh over the 0.3 s the move was watched.
    assert json.loads(captured.out)["robot_rate"] == pytest.approx(1 / factor, abs=0.03)
    slow = re.search(r"The robot's clock ran at 3\d% of this link's meanwhile", captured.err)
    assert (slow is not None) == (factor == 3.0)
    if factor == 3.0:
        assert "give --duration 1 or more" in captured.err


def test_grasp_with_a_finger_broken_away_names_the_others_and_grasps_with_them(
        capsys: pytest.CaptureFixture[str]) -> None:
    url = "emu://hand/palm?physics=0&name=handctl-grasp-broken-away"
    _emulator(url).break_away(2)
    assert main(["--port", url, "grasp", "open", "0.5", "--unhomed"]) == 1
    err = capsys.readouterr().err
    assert "finger 2 fmcb: route no_reply" in err
    assert "To grasp with the others: --fingers 0,1,3" in err
    assert main(["--port", url, "--json", "grasp", "open", "0.5", "--unhomed",
                 "--fingers", "0,1,3", "--duration", "0.3"]) in (0, 1)  # no physics
    assert sorted(json.loads(capsys.readouterr().out)["targets"]) == ["0", "1", "3"]
    assert main(["--port", url, "grasp", "open", "0.5", "--fingers", "0,7"]) == 2
    assert "give fingers 0..3" in capsys.readouterr().err
