"""Unmodified host software against the emulator's ports: dynamixel-sdk on the arm port,
the hand protocol on the palm and loose-finger ports, python-can's slcan on the CAN port."""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import pytest

from host.errors import HostError, ReplyTimeout
from host.hand.session import HandSession, Target, Timeouts
from host.transports.base import open_transport
from protocol.control_tables import RX64_TABLE, STEPPER_MODEL_NUMBER, STEPPER_TABLE
from protocol.messages import CATALOGUE
from protocol.messages.boot_program import AUTOBOOT_WINDOW_US
from protocol.messages.palm import FingerPower
from protocol.topology import ADDR_FMCB, ADDR_PALM, Hop
from tests.hil_emulator.emulator_process import (
    SimulatedDeadline,
    flood_arm_port,
    late_s,
    running_emulator,
    wait_simulated,
)

#: The host link's share of a reply's time over a pty (s): generous on a busy machine.
PTY_LINK = Timeouts(link_s=0.5)

#: How late this test process itself may be woken on a busy machine (s).
CLIENT_SLACK_S = 0.05
#: dynamixel-sdk 1.0's ping timeout with the default 16 ms latency timer (s), and the
#: ping's and its reply's own time on the 1 Mbaud wire with the servo's return delay (s).
SDK_PING_TIMEOUT_S = 0.034
PING_EXCHANGE_S = 0.002


def _until(what: Callable[[], Any], info: dict[str, Any], simulated_s: float,
           every_s: float = 0.1) -> Any:
    """Call ``what`` until it returns something truthy (a host error counts as no), for at
    most ``simulated_s`` of the emulator's simulation clock."""
    deadline = SimulatedDeadline(info, simulated_s)
    while True:
        try:
            value = what()
        except HostError:
            value = None
        if value:
            return value
        if deadline.passed():
            raise AssertionError(f"not within {simulated_s} s of simulated time")
        time.sleep(every_s)


def _running(reply: dict[str, Any]) -> dict[str, Any] | None:
    return reply if reply["running"] == 1 else None


@pytest.mark.slow
def test_stock_dynamixel_sdk_drives_the_arm_through_the_physics(tmp_path: Path) -> None:
    """As a user runs it: with --link-dir, talking to DIR/arm."""
    from dynamixel_sdk import COMM_SUCCESS, GroupSyncWrite, PacketHandler, PortHandler

    robot = tmp_path / "robot"
    with running_emulator("--config", "arm", "--seed", "7", "--link-dir", str(robot)) as info:
        port = PortHandler(str(robot / "arm"))
        assert port.openPort()
        assert port.setBaudRate(1_000_000)  # dynamixel-sdk closes and reopens the port here
        sdk = PacketHandler(1.0)
        try:
            for dxl_id in range(1, 8):
                model, result, error = _retried(partial(sdk.ping, port, dxl_id))
                assert result == COMM_SUCCESS and error == 0, (dxl_id, result, error)
                expected = STEPPER_MODEL_NUMBER if dxl_id <= 4 else RX64_TABLE.model_number
                assert model == expected
                value, result, _ = _retried(partial(sdk.read2ByteTxRx, port, dxl_id, 0))
                assert result == COMM_SUCCESS and value == expected
            _, result, _ = sdk.ping(port, 9)
            assert result != COMM_SUCCESS  # nobody at 9: a timeout, as on the real bus

            stepper_goal = STEPPER_TABLE["goal_position"]
            servo_goal = RX64_TABLE["goal_position"]
            start: dict[int, int] = {}
            for dxl_id in range(1, 8):
                if dxl_id <= 4:
                    start[dxl_id], res, _ = _retried(partial(
                        sdk.read4ByteTxRx, port, dxl_id, STEPPER_TABLE["present_position"].address))
                    start[dxl_id] = _signed32(start[dxl_id])
                else:
                    start[dxl_id], res, _ = _retried(partial(
                        sdk.read2ByteTxRx, port, dxl_id, RX64_TABLE["present_position"].address))
                assert res == COMM_SUCCESS
                torque = STEPPER_TABLE if dxl_id <= 4 else RX64_TABLE
                res, err = _retried(partial(
                    sdk.write1ByteTxRx, port, dxl_id, torque["torque_enable"].address, 1))
                assert res == COMM_SUCCESS and err == 0, (dxl_id, res, err)

            # Joint 1 (no coupling into it) and the wrist servos; joints 2-4 hold.
            moves = {1: 500, 5: 60, 6: -60, 7: 80}  # counts (0.036 deg) / units (0.29 deg)
            goals = {i: start[i] + moves.get(i, 0) for i in range(1, 8)}
            steppers = GroupSyncWrite(port, sdk, stepper_goal.address, 4)
            for i in range(1, 5):
                assert steppers.addParam(i, list(goals[i].to_bytes(4, "little", signed=True)))
            assert steppers.txPacket() == COMM_SUCCESS
            servos = GroupSyncWrite(port, sdk, servo_goal.address, 2)
            for i in range(5, 8):
                assert servos.addParam(i, list(goals[i].to_bytes(2, "little")))
            assert servos.txPacket() == COMM_SUCCESS

            wait_simulated(info, 2.5)  # 2.5 s of the robot's time, however busy the machine
            present: dict[int, int] = {}
            for dxl_id in range(1, 8):
                if dxl_id <= 4:
                    value, res, _ = _retried(partial(
                        sdk.read4ByteTxRx, port, dxl_id, STEPPER_TABLE["present_position"].address))
                    present[dxl_id] = _signed32(value)
                else:
                    present[dxl_id], res, _ = _retried(partial(
                        sdk.read2ByteTxRx, port, dxl_id, RX64_TABLE["present_position"].address))
                assert res == COMM_SUCCESS
            for dxl_id, delta in moves.items():
                moved = present[dxl_id] - start[dxl_id]
                # The physics moved the joint most of the way toward its goal (elastic
                # deflection and compliance margins leave a little).
                assert abs(moved - delta) <= 0.25 * abs(delta), (dxl_id, start, present)
            for dxl_id in (2, 3, 4):
                assert abs(present[dxl_id] - start[dxl_id]) < 112  # held within ±4 deg
        finally:
            port.closePort()


@pytest.mark.slow
def test_stock_dynamixel_sdk_pings_every_arm_node_with_a_cpu_hog_running() -> None:
    """A user's first check, on a busy machine: the stock sdk's ping (no retries) against
    ``--config full --ready`` while another process keeps a core busy, 35 pings (5 rounds
    over the 7 arm ids).  Every reply the sdk reads is right.  With real-time scheduling
    the emulator delivers every reply within the sdk's own timeout (its packet timeout with
    the default latency timer, ~34 ms of wall time) by its own clock: host input never
    waits behind the simulation's backlog; what the sdk then sees also depends
    on the client's and the kernel's scheduling on a busy machine (a pty's bytes are moved
    by a kernel worker), so a miss is not the emulator's.  Without real-time scheduling
    the emulator promises no wall-clock bound on a busy machine, and none is asserted."""
    from dynamixel_sdk import COMM_SUCCESS, PacketHandler, PortHandler

    hog = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        with running_emulator("--config", "full", "--ready") as info:
            port = PortHandler(info["arm"])
            assert port.openPort() and port.setBaudRate(1_000_000)
            sdk = PacketHandler(1.0)
            missed: list[tuple[int, int, str]] = []
            wrong: list[tuple[int, int, str]] = []
            try:
                for round_ in range(5):
                    for dxl_id in range(1, 8):
                        try:
                            model, result, error = sdk.ping(port, dxl_id)
                        except IndexError:  # the sdk read a stale reply as its own
                            missed.append((round_, dxl_id, "stale reply"))
                            continue
                        expected = (STEPPER_MODEL_NUMBER if dxl_id <= 4
                                    else RX64_TABLE.model_number)
                        if result != COMM_SUCCESS:
                            missed.append((round_, dxl_id, sdk.getTxRxResult(result)))
                        elif error != 0 or model != expected:
                            wrong.append((round_, dxl_id, f"model {model}, error {error}"))
            finally:
                port.closePort()
    finally:
        hog.kill()
        hog.wait()
    stats = info["stats"]
    seen = (f"{35 - len(missed)}/35 pings answered in the sdk's time", missed, stats)
    assert wrong == [], seen  # every reply the sdk took as its answer was the right one
    assert stats["ports"]["arm"]["bytes_out"] > 0 and stats["count"] >= 35, seen
    if stats["scheduling"] != "SCHED_OTHER":  # in time, by the emulator's own clock
        assert late_s(stats) < SDK_PING_TIMEOUT_S - PING_EXCHANGE_S, seen


def _retried(call: Callable[[], tuple[Any, ...]], tries: int = 5) -> tuple[Any, ...]:
    """Call a dynamixel-sdk TxRx function again when it timed out, as a host on a busy
    machine would (the sdk's own timeout is a few tens of ms of wall time)."""
    from dynamixel_sdk import COMM_RX_TIMEOUT

    for _ in range(tries - 1):
        out = call()
        if COMM_RX_TIMEOUT not in out[-2:]:
            return out
    return call()


def _signed32(value: int) -> int:
    return value - (1 << 32) if value & 0x8000_0000 else value


@pytest.mark.slow
def test_every_hand_node_answers_over_the_palm_port() -> None:
    with running_emulator("--config", "full") as info, \
            HandSession(open_transport(info["palm"]), timeouts=PTY_LINK) as hand:

        def identify(to: Target | None = None) -> dict[str, Any] | None:
            """The node's ``identify`` reply once it runs its application, else None."""
            return _running(hand.request("identify", to=to))

        palm = _until(identify, info, 10)
        assert palm["board"] == 1
        uids = {palm["uid"]}
        hand.request("palm.finger_power", {"finger": 0xFF, "state": FingerPower.FULL, "stagger_ms": 5})
        for k in range(4):
            fmcb = _until(partial(identify, Target(k, Hop.FMCB)), info, 10)
            assert fmcb["board"] == 2
            uids.add(fmcb["uid"])
            hand.request("fmcb.phalange_power", {"on": 1}, to=Target(k, Hop.FMCB))
        for k in range(4):
            for hop, board in ((1, 3), (2, 4)):
                node = _until(partial(identify, Target(k, hop)), info, 10)
                assert node["board"] == board
                uids.add(node["uid"])
        assert len(uids) == 13  # palm, four fmcbs, eight phalanges


@pytest.mark.slow
def test_original_bootloader_sequence_over_a_loose_finger_port() -> None:
    with running_emulator("--config", "loose-finger") as info, \
            HandSession(open_transport(info["fingers"][0]), link="finger",
                        timeouts=PTY_LINK) as finger:
        # The original host's frames: no txn envelope.
        finger.request("reset", txn=False)  # acknowledged, then the fmcb restarts into its bootloader
        time.sleep(0.05)
        assert finger.request("bl.halt", txn=False) == {}  # inside the autoboot window
        assert finger.request("ping", txn=False) == {}
        ident = finger.request("identify", txn=False)
        assert ident["board"] == 2 and ident["running"] == 0
        page = finger.request("bl.read_page", {"page": 32}, txn=False)
        assert len(page["data"]) == 256 and page["data"][:4] == b"HAND"  # the image header
        wait_simulated(info, AUTOBOOT_WINDOW_US / 1e6 + 0.5)  # the halted bootloader does not boot by itself
        assert finger.request("identify", txn=False)["running"] == 0
        try:
            finger.request("bl.boot", txn=False)
        except ReplyTimeout:
            pass  # the ack came late (a busy machine); the application answering is the check
        ident = _until(lambda: _running(finger.request("identify", txn=False)), info, 2)
        assert ident["board"] == 2
        assert finger.request("ping", txn=False) == {}  # the application answers ping too


@pytest.mark.slow
def test_a_148_byte_status_takes_its_wire_time_through_the_pty() -> None:
    """fmcb.status: a 148-byte payload, 155 bytes framed, 775 µs at 2 Mbaud (10 bits/byte)."""
    import serial

    status = CATALOGUE["fmcb.status"]
    request = status.request_frame(ADDR_FMCB)
    wire_s = (len(request) + 148 + 7) * 10 / 2_000_000
    with running_emulator("--config", "loose-finger") as info:
        with HandSession(open_transport(info["fingers"][0]), link="finger",
                         timeouts=PTY_LINK) as finger:
            _until(lambda: _running(finger.request("identify")), info, 6)
        with serial.Serial(info["fingers"][0], 2_000_000, timeout=0) as port:
            times = []
            for _ in range(20):
                port.reset_input_buffer()
                got = b""
                t0 = time.perf_counter()
                port.write(request)
                while len(got) < 155 and time.perf_counter() - t0 < 2.0:
                    got += port.read(4096)
                times.append(time.perf_counter() - t0)
                assert len(got) == 155
                assert got[0] == request[0]  # a whole frame, from its sync byte
                time.sleep(0.01)
    times.sort()
    # Never faster than the wire, whatever the load.  How much later is up to the machine:
    # the emulator reports its own worst lateness; this client may be woken late as well.
    assert wire_s <= times[0]
    assert times[len(times) // 2] <= wire_s + late_s(info["stats"]) + CLIENT_SLACK_S
    # (the exact time is checked on the simulation clock in test_emulator.py)


@pytest.mark.slow
def test_python_can_slcan_reaches_the_palm() -> None:
    import can

    from protocol.canlink import CanReassembler, can_id, segment

    with running_emulator("--config", "hand") as info:
        bus = can.Bus(interface="slcan", channel=info["can"], bitrate=1_000_000,
                      sleep_after_open=0)
        try:
            ident = CATALOGUE["identify"]
            frame = ident.request_frame(ADDR_PALM)
            rx = CanReassembler()
            deadline = SimulatedDeadline(info, 10)
            reply = None
            while reply is None and not deadline.passed():
                for chunk in segment(frame):
                    bus.send(can.Message(arbitration_id=can_id(10, to_host=False), data=chunk,
                                         is_extended_id=False))
                end = time.monotonic() + 0.2
                while reply is None and time.monotonic() < end:
                    msg = bus.recv(0.05)
                    if msg is None or msg.arbitration_id != can_id(10, to_host=True):
                        continue
                    for f in rx.feed(msg.arbitration_id, bytes(msg.data)):
                        if f.type == ident.type_id:
                            parsed = ident.parse_reply(f.payload)
                            reply = parsed if parsed["running"] else None
            assert reply is not None and reply["board"] == 1
        finally:
            bus.shutdown()


@pytest.mark.slow
def test_ready_names_the_ports_with_every_hand_node_running() -> None:
    with running_emulator("--config", "hand", "--ready", "--can", "none") as info, \
            HandSession(open_transport(info["palm"]), timeouts=PTY_LINK) as hand:
        assert info["ready"] is True
        assert hand.request("identify")["running"] == 1  # no waiting: it is up already
        for k in range(4):
            assert hand.request("identify", to=Target(k, Hop.FMCB))["running"] == 1
            for hop in (1, 2):
                assert hand.request("identify", to=Target(k, hop))["running"] == 1
        status = hand.request("fmcb.status", to=Target(2, Hop.FMCB))
        assert status["pp_time"] > 0 and status["dp_time"] > 0  # autopoll has run


@pytest.mark.slow
def test_a_flood_on_the_arm_port_is_an_overrun_and_the_next_ping_is_answered() -> None:
    """A host writing as fast as a pty takes for 3 s: the port keeps only what its
    adapter buffer holds (4 KiB: 41 ms of its 1 Mbaud wire; the rest is an overrun,
    counted); memory stays flat; a ping written afterwards is answered within 50 ms (plus what the emulator reports as late).
    benchmarks/bench_backpressure.py reports the same figures."""
    from hil_emulator.ports.host_links import ADAPTER_BUFFER_BYTES
    from protocol.topology import ARM_BUS_BAUD, wire_time_us

    flood = flood_arm_port(3.0)
    stats, written = flood.stats, flood.written
    arm = stats["ports"]["arm"]
    assert flood.reply[:6] == bytes([0xFF, 0xFF, 1, 2, 0, 0xFC])  # id 1, no error
    assert flood.answered_s <= 0.050 + late_s(stats) + CLIENT_SLACK_S, (flood.answered_s, stats)
    assert written > 3 * 100_000  # more than the 1 Mbaud wire could carry in 3 s
    assert arm["overrun"] > written - 3.5 * 100_000  # the rest was lost, and counted
    # The queue stayed bounded: an adapter's buffer of wire time.
    assert arm["queue_peak_us"] <= wire_time_us(ADAPTER_BUFFER_BYTES, ARM_BUS_BAUD) + 1_000
    assert flood.rss_growth_kb < 10_000  # kB: memory flat
