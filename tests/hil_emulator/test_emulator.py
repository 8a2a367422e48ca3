"""The emulator in process: one clock, repeatable runs, wire timing, faults."""

from __future__ import annotations

import os
import tty
from typing import Any

import numpy as np
import pytest

from firmware_py.sim.virtual_sensors import VirtualSensors
from hil_emulator.emulator import Emulator
from hil_emulator.errors import EmulatorConfigError
from hil_emulator.inprocess import BOOT_US, EmulatorTransport, bring_up
from hil_emulator.ports.host_links import SerialLink
from protocol.framing import parse_frame
from protocol.messages import CATALOGUE
from protocol.stream import decode_all
from tests.ground_truth import hand_rig_of

S = 1_000_000


def _frame(name: str, address: int = 10, **fields: Any) -> bytes:
    return CATALOGUE[name].request_frame(address, fields)


def _route(finger: int, hop: int, name: str, **fields: Any) -> bytes:
    inner = _frame(name, {0: 10, 1: 1, 2: 2}[hop], **fields)
    return _frame("palm.route", finger=finger, hop=hop, timeout_ms=20, frame=inner)


def _replies(data: bytes, name: str) -> list[dict[str, Any]]:
    msg = CATALOGUE[name]
    return [msg.parse_reply(f.payload) for f in decode_all(data) if f.type == msg.type_id]


def _boot_hand(emu: Emulator) -> bytearray:
    """Palm, fingers and phalanges booted; returns the buffer collecting host bytes."""
    hand = emu.hand
    assert hand is not None
    out = bytearray()
    hand.on_host_bytes = lambda data, t: out.extend(data)
    emu.step(BOOT_US)
    hand.send_from_host(_frame("palm.finger_power", finger=0xFF, state=2, stagger_ms=5))
    emu.step(BOOT_US + 100_000)
    for k in range(4):
        hand.send_from_host(_route(k, 0, "fmcb.phalange_power", on=1))
        emu.step(30_000)
    emu.step(BOOT_US)
    return out


def _routed(emu: Emulator, out: bytearray, finger: int, hop: int, name: str,
            **fields: Any) -> dict[str, Any] | None:
    assert emu.hand is not None
    out.clear()
    emu.hand.send_from_host(_route(finger, hop, name, **fields))
    emu.step(40_000)
    replies = _replies(bytes(out), "palm.route")
    if not replies or replies[-1]["status"] != 0:
        return None
    return CATALOGUE[name].parse_reply(parse_frame(replies[-1]["frame"]).payload)


def test_unknown_configuration_seed_and_layout_are_refused() -> None:
    with pytest.raises(EmulatorConfigError, match="loose-finger"):
        Emulator("octopus")
    with pytest.raises(EmulatorConfigError, match="seed"):
        Emulator("arm", seed=-1, physics=False)
    with pytest.raises(EmulatorConfigError, match="four-finger-thumb"):
        Emulator("hand", layout="octopus")


@pytest.mark.slow
def test_same_seed_same_frames_and_physics_other_seed_other_noise() -> None:
    def run(seed: int) -> tuple[bytes, np.ndarray, tuple[int, ...]]:
        emu = Emulator("hand", seed=seed, can="none")
        out = _boot_hand(emu)
        for k in range(4):
            _routed(emu, out, k, 0, "fmcb.imu")
        out.clear()
        hand_rig_of(emu).send_from_host(_route(2, 0, "fmcb.imu"))
        emu.step(40_000)
        assert emu.plant is not None
        sensors = hand_rig_of(emu).fingers[0].f3.hal.sensors
        assert isinstance(sensors, VirtualSensors)
        accel = sensors.values["accel"]
        assert isinstance(accel, tuple)  # 3-axis counts
        return bytes(out), emu.plant.data.qpos.copy(), tuple(accel)

    a, b, c = run(5), run(5), run(6)
    assert a[0] == b[0] and np.array_equal(a[1], b[1]) and a[2] == b[2]
    assert a[0]  # the reply did come back
    assert a[2] != c[2]  # sensor noise follows the seed


def test_a_148_byte_status_takes_its_wire_time_on_the_simulation_clock() -> None:
    """Host adapter → fmcb pogo UART → host at 2 Mbaud, 10 bits a byte: a 7-byte request
    arrives after 35 µs, the 155-byte framed status (148-byte payload) after 775 µs more."""
    emu = Emulator("loose-finger", physics=False)
    ports = emu.open_ports()
    finger_port = ports["fingers"][0]
    assert finger_port is not None
    fd = os.open(finger_port, os.O_RDWR | os.O_NOCTTY)
    try:
        tty.setraw(fd)
        emu.step(BOOT_US)  # bootloader window, then the fmcb application
        emitted: list[int] = []
        link = emu.links["finger0"]
        assert isinstance(link, SerialLink)
        link.on_emit = emitted.append
        request = _frame("fmcb.status")
        os.write(fd, request)
        t0 = emu.scheduler.now_us()
        for _ in range(20):
            emu.step(100)
        reply = os.read(fd, 4096)
        assert len(reply) == 155 and len(parse_frame(reply).payload) == 148
        assert emitted == [t0 + len(request) * 5 + 155 * 5]  # 5 µs a byte at 2 Mbaud
    finally:
        os.close(fd)
        emu.close()


@pytest.mark.slow
def test_breakaway_is_reported_and_a_bouncing_reattach_comes_back() -> None:
    emu = Emulator("hand", seed=2, can="none")
    out = _boot_hand(emu)
    assert _routed(emu, out, 2, 0, "identify") is not None
    hand_rig_of(emu).send_from_host(_frame("palm.poll", rate_hz=100))
    emu.step(100_000)
    out.clear()
    emu.break_away(2)
    emu.step(200_000)
    events = _replies(bytes(out), "palm.finger_event")
    assert {"finger": 2, "event": 0} in [{k: e[k] for k in ("finger", "event")} for e in events]
    assert not emu.finger_plants[2].attached
    assert _routed(emu, out, 2, 0, "identify") is None
    emu.reattach(2, bounce=True)
    emu.step(BOOT_US + 300_000)  # contacts settle, the fmcb's bootloader window, its application
    assert emu.finger_plants[2].attached
    ident = _routed(emu, out, 2, 0, "identify")
    assert ident is not None and ident["running"] == 1


@pytest.mark.slow
def test_tendon_glitches_shorter_than_hold_up_are_ridden_through() -> None:
    emu = Emulator("hand", seed=3, can="none", physics=False)
    out = _boot_hand(emu)
    before = _routed(emu, out, 1, 2, "identify")
    assert before is not None and before["running"] == 1
    emu.tendon_glitch(1, 1_000)  # 1 ms: within the 2 ms hold-up
    emu.step(5_000)
    after = _routed(emu, out, 1, 2, "identify")
    assert after is not None and after["uptime_us"] > before["uptime_us"]
    emu.tendon_glitch(1, 10_000)  # 10 ms: the phalanges brown out and restart
    emu.step(15_000)
    rebooted = _routed(emu, out, 1, 2, "identify")
    assert rebooted is not None and rebooted["running"] == 0  # back in its bootloader
    assert rebooted["uptime_us"] < 100_000


def test_python_can_virtual_channel_reaches_the_palm_in_process() -> None:
    import can

    from protocol.canlink import CanReassembler, can_id, segment

    emu = Emulator("hand", physics=False, can="virtual:hil-test-palm")
    ports = emu.open_ports()
    assert ports["can"] == "virtual:hil-test-palm" and ports["can_interface"] == "virtual"
    host = can.Bus(interface="virtual", channel="hil-test-palm", receive_own_messages=False)
    try:
        emu.step(BOOT_US)  # the palm's bootloader window, then its application
        ident = CATALOGUE["identify"]
        for chunk in segment(_frame("identify")):
            host.send(can.Message(arbitration_id=can_id(10, to_host=False), data=chunk,
                                  is_extended_id=False))
        emu.step(5_000)
        rx = CanReassembler()
        frames = []
        while (msg := host.recv(0.0)) is not None:
            assert msg.arbitration_id == can_id(10, to_host=True)
            frames += rx.feed(msg.arbitration_id, bytes(msg.data))
        replies = [ident.parse_reply(f.payload) for f in frames if f.type == ident.type_id]
        assert replies and replies[-1]["board"] == 1 and replies[-1]["running"] == 1
    finally:
        host.shutdown()
        emu.close()


@pytest.mark.slow
def test_the_phalanges_draw_their_supply_through_the_fmcb_switch() -> None:
    from hil_emulator.hand.rig import PHALANGE_LOAD_MA
    from protocol.sensor_counts import pb_current_amps, pb_current_counts

    emu = Emulator("hand", seed=4, can="none", physics=False)
    out = _boot_hand(emu)
    status = _routed(emu, out, 3, 0, "fmcb.status")
    # The original status carries the ADC's counts; the conversion is protocol's.
    assert status is not None and status["pb_current"] == pb_current_counts(
        2 * PHALANGE_LOAD_MA / 1000)
    assert pb_current_amps(status["pb_current"]) == pytest.approx(
        2 * PHALANGE_LOAD_MA / 1000, abs=0.002)
    assert _routed(emu, out, 3, 0, "fmcb.phalange_power", on=0) == {}
    emu.step(5_000)
    status = _routed(emu, out, 3, 0, "fmcb.status")
    assert status is not None and status["pb_current"] == 0


def test_bring_up_of_a_loose_finger_and_a_clear_error_when_a_node_cannot_boot() -> None:
    from firmware_py.flash_layout import BOOT_CONTROL_PAGE, page_address
    from firmware_py.sim.virtual_hal import VirtualFlash
    from hil_emulator.errors import EmulatorError

    emu = Emulator("loose-finger", physics=False)
    bring_up(emu)
    assert emu.loose is not None
    finger = emu.loose.finger
    assert [m.program_name for m in (finger.fmcb, finger.f2, finger.f3)] == ["fmcb", "f2", "f3"]

    broken = Emulator("loose-finger", physics=False)
    assert broken.loose is not None
    flash = broken.loose.finger.f3.hal.flash
    assert isinstance(flash, VirtualFlash)
    flash.load(page_address(BOOT_CONTROL_PAGE), b"\xff" * 256)
    with pytest.raises(EmulatorError, match="uid"):
        bring_up(broken)  # f3's image is not activated: it stays in its bootloader


def test_bring_up_is_the_host_library_and_leaves_thirteen_applications_answering(
        monkeypatch: pytest.MonkeyPatch) -> None:
    from host.hand.facade import Hand
    from host.hand.session import HandSession

    sent: list[tuple[str, int | None, bool]] = []
    start = HandSession.start

    def spy(self: HandSession, name: str, *args: Any, **kw: Any) -> Any:
        sent.append((name, kw["to"].finger, kw.get("txn", True)))
        return start(self, name, *args, **kw)

    monkeypatch.setattr(HandSession, "start", spy)
    emu = Emulator("hand", seed=2, can="none", physics=False)
    recorded: list[bytes] = []
    hand_rig_of(emu).on_host_bytes = lambda data, t_us: recorded.append(data)
    bring_up(emu)
    assert sent == ([("palm.finger_power", None, False)]
                    + [("fmcb.phalange_power", k, False) for k in range(4)]
                    + [("fmcb.autopoll", k, False) for k in range(4)])
    # The listener the link had kept every reply (tee), and has the link back.
    replies = decode_all(b"".join(recorded))
    assert sum(f.type == CATALOGUE["palm.route"].type_id for f in replies) == 8
    monkeypatch.undo()
    with Hand(HandSession(EmulatorTransport(emu, "palm"))) as hand:
        found = hand.discover()
    assert len(found) == 13
    assert all(n.answered and n.running == "application" for n in found), found
    hand_rig_of(emu).on_host_bytes = None
