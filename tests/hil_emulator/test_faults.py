"""The fault registry: every fault's effect is observable, and gone once cleared; plans,
timelines and their replay; the control channel."""

from __future__ import annotations

import json
import os
import socket
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hil_emulator.emulator import Emulator
from hil_emulator.errors import EmulatorConfigError, FaultPlanError
from hil_emulator.faults import (
    FAULTS,
    NOT_YET_IMPLEMENTED,
    FaultInjector,
    catalogue,
    make_fault,
    parse_plan,
)
from hil_emulator.faults.control import ControlChannel
from hil_emulator.faults.nodes import FaultySensors
from hil_emulator.inprocess import BOOT_US, EmulatorTransport, bring_up
from host.errors import HostError, TransportError
from host.hand import Hand
from host.hand_session import HandSession
from protocol.dynamixel import ErrorBit, make_ping

MS = 1_000


class FaultyEmulator(Emulator):
    """An emulator and the fault injector that whoever runs a plan owns (here: the test)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.faults = FaultInjector(self)

    def open_control(self, path: str) -> str:
        """Serve the control channel at ``path`` on this emulator's injector."""
        self.add_port(ControlChannel(self, path, self.faults))
        return path


@pytest.fixture
def hand() -> Iterator[FaultyEmulator]:
    """A hand without physics, brought up (about 1 s of wall time)."""
    emu = FaultyEmulator("hand", seed=4, physics=False, can="none")
    bring_up(emu)
    yield emu
    emu.close()


def _host(emu: Emulator) -> Hand:
    return Hand(HandSession(EmulatorTransport(emu, "palm"), retries=0))


def _answers(node: object) -> bool:
    try:
        node.identify()  # type: ignore[attr-defined]
    except HostError:
        return False
    return True


def _arm_ping_answered(emu: Emulator, dxl_id: int = 5) -> bool:
    assert emu.arm is not None
    emu.arm.take_host_bytes()
    emu.arm.send_from_host(make_ping(dxl_id).encode())
    emu.step(2 * MS)
    return bytes(emu.arm.take_host_bytes()).startswith(b"\xff\xff" + bytes([dxl_id]))


def test_every_fault_declares_an_entry_point_a_summary_and_typed_defaults() -> None:
    assert len(FAULTS) >= 25
    for name, cls in FAULTS.items():
        assert cls.summary and cls.entry_point, name
        fault = cls()  # every parameter has a default
        assert make_fault(name, fault.params()).params() == fault.params()
    listed = {f["name"]: f for f in catalogue()}
    assert all(not listed[n]["implemented"] for n in NOT_YET_IMPLEMENTED)


def test_every_fault_of_the_catalogue_is_implemented() -> None:
    assert not NOT_YET_IMPLEMENTED
    assert {"spring_drift", "serial_driver_stuck", "baud_mismatch",
            "duplicate_servo_id"} <= set(FAULTS)
    assert all(f["implemented"] for f in catalogue())


def test_parameters_are_checked_and_errors_name_the_key() -> None:
    with pytest.raises(FaultPlanError, match=r"faults\[0\]\.params\.finger.*not a int"):
        parse_plan([{"fault": "break_away", "params": {"finger": "two"}}])
    with pytest.raises(FaultPlanError, match=r"faults\[1\]\.params\.colour"):
        parse_plan([{"fault": "node_reset"}, {"fault": "node_reset", "params": {"colour": 1}}])
    with pytest.raises(FaultPlanError, match=r"faults\[0\]: unknown fault 'gremlin'"):
        parse_plan([{"fault": "gremlin"}])
    with pytest.raises(FaultPlanError, match=r"faults\[0\]: axis 'w' is not x, y, z"):
        parse_plan([{"fault": "sensor_fault", "params": {"mode": "misaligned", "axis": "w"}}])
    with pytest.raises(FaultPlanError, match=r"faults\[0\]\.params\.side"):
        parse_plan([{"fault": "baud_mismatch", "params": {"side": "both"}}])
    with pytest.raises(FaultPlanError, match=r"faults\[0\]\.when: unknown key"):
        parse_plan([{"fault": "node_reset", "when": 3}])
    with pytest.raises(FaultPlanError, match=r"faults\[0\]\.every_s"):
        parse_plan([{"fault": "line_cut", "count": 3}])
    with pytest.raises(FaultPlanError, match=r"faults\[0\]\.duration_s"):
        parse_plan([{"fault": "line_cut", "count": 2, "every_s": 0.1, "duration_s": 0.2}])
    with pytest.raises(FaultPlanError, match=r"faults\[0\]\.after_flash_bytes"):
        parse_plan([{"fault": "node_power_cut", "after_flash_bytes": 10}])
    with pytest.raises(FaultPlanError, match=r"faults\[0\]: rate 2.0 is not a probability"):
        parse_plan([{"fault": "bus_bit_errors", "params": {"rate": 2.0}}])


# ---------------------------------------------------------------------------- line models


def test_arm_bus_bit_errors_loss_bursts_jam_and_cut_each_clear() -> None:
    emu = FaultyEmulator("arm", seed=1, physics=False)
    bus = emu.arm.bus  # type: ignore[union-attr]
    assert _arm_ping_answered(emu)
    for name, params in (("bus_bit_errors", {"rate": 0.5}), ("bus_frame_loss",
                         {"probability": 1.0}), ("line_cut", {}), ("stuck_driver", {}),
                         ("burst_dropout", {"p_enter": 1.0, "p_leave": 0.0})):
        entry = emu.faults.inject(name, {"bus": "arm", **params})
        assert not any(_arm_ping_answered(emu) for _ in range(3)), name
        emu.faults.clear(entry)
        assert _arm_ping_answered(emu), name
    assert bus.bit_error_rate == 0.0 and bus.drop_probability == 0.0 and not bus.line_cut
    assert bus.fault_filter is None


def test_burst_dropout_loses_frames_in_runs() -> None:
    fault = make_fault("burst_dropout", {"bus": "arm", "p_enter": 0.1, "p_leave": 0.25})
    emu = FaultyEmulator("arm", seed=2, physics=False)
    emu.faults.inject(fault)
    answered = [_arm_ping_answered(emu) for _ in range(300)]
    losses = [i for i, ok in enumerate(answered) if not ok]
    runs = sum(1 for i in losses if i - 1 not in losses)
    assert losses and len(losses) / runs > 1.8  # bursts, not isolated losses


def test_a_tendon_load_driven_burst_dropout_loses_more_frames_the_harder_the_finger_pulls(
        ) -> None:
    """Finger 1's tendon bus (≈ 400 frames/s: the fmcb's autopoll of f2 and f3) with bursts
    entered at ``p_enter · load / tendon_torque_nm``: slack (motors coasting, load 0) it loses
    nothing; holding a pose (≈ 0.23 N·m at the capstan) it loses frames; holding against a
    3 N press on its fingertip (≈ 0.48 N·m, the most loaded tendon) more."""
    emu = FaultyEmulator("hand", seed=3, physics=True, can="none")
    try:
        bring_up(emu)
        plant = emu.finger_plants[1]
        fault = make_fault("burst_dropout", {"bus": "tendon1", "p_enter": 0.2, "p_leave": 0.3,
                                             "tendon_torque_nm": 0.5})
        emu.faults.inject(fault)

        def loss_rate_over_500_ms() -> tuple[float, float]:
            """Lost / seen frames, and the largest tendon load (N·m) sampled every 50 ms."""
            frames, lost = fault.frames, fault.lost
            loads = []
            for _ in range(10):
                emu.step(50 * MS)
                loads.append(plant.tendon_load_nm())
            assert fault.frames - frames > 100
            return (fault.lost - lost) / (fault.frames - frames), max(loads)

        slack, slack_load = loss_rate_over_500_ms()
        Hand(HandSession(EmulatorTransport(emu, "palm"), retries=1)).move_fingers(
            {1: [0.0, 1.0, 0.5]}, effort=255, timeout=1.0, unhomed=True)
        held, held_load = loss_rate_over_500_ms()
        plant.press("F3", 3.0)
        pressed, pressed_load = loss_rate_over_500_ms()
    finally:
        emu.close()
    assert slack_load == 0.0 and slack == 0.0
    assert 0.1 < held_load < pressed_load < 1.0
    assert 0.1 < held < pressed


def test_a_tendon_load_driven_burst_dropout_needs_a_tendon_bus_and_physics(hand: FaultyEmulator
                                                                          ) -> None:
    with pytest.raises(FaultPlanError, match="needs a tendon<k> bus"):
        make_fault("burst_dropout", {"bus": "arm", "tendon_torque_nm": 0.5})
    with pytest.raises(FaultPlanError, match="must be positive"):
        make_fault("burst_dropout", {"bus": "tendon0", "tendon_torque_nm": 0.0})
    with pytest.raises(EmulatorConfigError, match="no physics"):
        hand.faults.inject("burst_dropout", {"bus": "tendon2", "tendon_torque_nm": 0.5})
    assert hand.hand.fingers[2].tendon_bus.fault_filter is None  # type: ignore[union-attr]


def test_tendon_chip_errors_garble_characters_until_cleared(hand: FaultyEmulator) -> None:
    bus = hand.hand.fingers[1].tendon_bus  # type: ignore[union-attr]
    assert bus is not None
    before = bus.manchester_bad_characters
    entry = hand.faults.inject("tendon_chip_errors", {"finger": 1, "rate": 0.02})
    hand.step(100 * MS)  # the fmcb's 100 Hz autopoll of f2/f3
    during = bus.manchester_bad_characters
    assert during > before
    hand.faults.clear(entry)
    hand.step(100 * MS)
    assert bus.manchester_bad_characters == during


def test_a_cut_tendon_line_silences_the_phalanges_only(hand: FaultyEmulator) -> None:
    host = _host(hand)
    entry = hand.faults.inject("line_cut", {"bus": "tendon2"})
    assert not _answers(host.fingers[2].distal)
    assert _answers(host.fingers[2].motor)
    hand.faults.clear(entry)
    assert _answers(host.fingers[2].distal)


def test_tendon_glitch_within_hold_up_is_ridden_through_beyond_it_reboots(hand: FaultyEmulator
                                                                           ) -> None:
    f2 = hand.hand.fingers[0].f2  # type: ignore[union-attr]
    boots = f2.boots
    hand.faults.inject("tendon_glitch", {"finger": 0, "duration_us": 1_500})
    hand.step(20 * MS)
    assert f2.program_name == "f2" and f2.boots == boots
    hand.faults.inject("tendon_glitch", {"finger": 0, "duration_us": 8_000})
    hand.step(20 * MS)
    assert f2.powered and f2.program_name == "bootloader"


# ---------------------------------------------------------------------------- contacts


def test_break_away_and_its_clear_a_cold_booting_reattach(hand: FaultyEmulator) -> None:
    finger = hand.hand.fingers[3]  # type: ignore[union-attr]
    boots = finger.fmcb.boots
    entry = hand.faults.inject("break_away", {"finger": 3})
    assert not finger.attached and not finger.fmcb.powered
    hand.faults.clear(entry)
    hand.step(BOOT_US)
    assert finger.attached and finger.fmcb.program_name == "fmcb"
    assert finger.fmcb.boots == boots + 1


def test_reattach_and_pogo_chatter_power_cycle_the_fmcb(hand: FaultyEmulator) -> None:
    finger = hand.hand.fingers[1]  # type: ignore[union-attr]
    hand.break_away(1)
    hand.faults.inject("reattach", {"finger": 1, "bounce": False})
    assert finger.attached and finger.fmcb.in_bootloader
    hand.step(BOOT_US)
    assert finger.fmcb.program_name == "fmcb"
    hand.faults.inject("pogo_chatter", {"finger": 1, "contacts": 4})
    assert not finger.fmcb.powered
    hand.step(50 * MS)
    assert finger.attached and finger.fmcb.in_bootloader


def test_partial_contact_powers_the_finger_but_carries_no_data(hand: FaultyEmulator) -> None:
    host = _host(hand)
    finger = hand.hand.fingers[0]  # type: ignore[union-attr]
    entry = hand.faults.inject("partial_contact", {"finger": 0})
    assert not _answers(host.fingers[0].motor)
    assert finger.fmcb.powered and finger.fmcb.program_name == "fmcb"
    hand.faults.clear(entry)
    assert _answers(host.fingers[0].motor)


def test_a_shorted_tendon_trips_the_phalange_breaker_until_cleared(hand: FaultyEmulator) -> None:
    host = _host(hand)
    finger = hand.hand.fingers[2]  # type: ignore[union-attr]
    entry = hand.faults.inject("shorted_tendon", {"finger": 2})
    hand.step(200 * MS)
    assert finger.fmcb.program.breaker_tripped  # type: ignore[union-attr]
    assert not finger.f2.powered
    host.fingers[2].motor.request("fmcb.phalange_power", {"on": 1})
    hand.step(200 * MS)
    assert finger.fmcb.program.breaker_tripped  # type: ignore[union-attr]  # trips again
    hand.faults.clear(entry)
    host.fingers[2].motor.request("fmcb.phalange_power", {"on": 1})
    hand.step(200 * MS)
    assert not finger.fmcb.program.breaker_tripped  # type: ignore[union-attr]
    assert finger.f2.powered


def test_node_power_cut_triggered_in_the_middle_of_a_flash_write(hand: FaultyEmulator) -> None:
    from hil_emulator.faults import Schedule

    fmcb = hand.hand.fingers[1].fmcb  # type: ignore[union-attr]
    flash = fmcb.hal.flash
    hand.faults.inject("node_power_cut", {"node": "finger1.fmcb"},
                       schedule=Schedule(after_flash_bytes=2 * flash.page_size,
                                         flash_node="finger1.fmcb"))
    page = bytes(range(256)) * (flash.page_size // 256)
    results: list[bool] = []
    flash.write_page(600, page, results.append)
    hand.step(10 * MS)
    assert fmcb.powered and results == [True]
    flash.write_page(601, page, results.append)
    hand.step(10 * MS)
    assert not fmcb.powered and results == [True]  # cut before the write finished
    half = flash.page_size // 2
    written = flash.read(flash.base_address + 601 * flash.page_size, flash.page_size)
    assert written[:half] == page[:half] and written[half:] == b"\xff" * half
    assert [e.action for e in hand.faults.timeline] == ["apply"]


def test_a_flash_page_that_fails_to_write(hand: FaultyEmulator) -> None:
    flash = hand.hand.fingers[0].f3.hal.flash  # type: ignore[union-attr]
    entry = hand.faults.inject("flash_page_fail", {"node": "finger0.f3", "page": 700})
    results: list[bool] = []
    page = b"\x55" * flash.page_size
    for p in (700, 701):
        flash.write_page(p, page, results.append)
        hand.step(10 * MS)
    assert results == [False, True]
    hand.faults.clear(entry)
    flash.write_page(700, page, results.append)
    hand.step(10 * MS)
    assert results[-1] is True and "write_page" not in vars(flash)


# ---------------------------------------------------------------------------- nodes


def test_node_hang_reset_and_reset_storm(hand: FaultyEmulator) -> None:
    host = _host(hand)
    fmcb = hand.hand.fingers[2].fmcb  # type: ignore[union-attr]
    entry = hand.faults.inject("node_hang", {"node": "finger2.fmcb"})
    assert not _answers(host.fingers[2].motor)
    hand.faults.clear(entry)
    assert fmcb.in_bootloader
    resets = fmcb.resets
    hand.faults.inject("node_reset", {"node": "finger2.fmcb"})
    assert fmcb.resets == resets + 1
    hand.faults.inject("reset_storm", {"node": "finger2.fmcb", "resets": 4,
                                       "period_us": 10_000})
    hand.step(50 * MS)
    assert fmcb.resets == resets + 5


def test_a_sensor_stuck_biased_or_noisy_and_restored(hand: FaultyEmulator) -> None:
    sensors = hand.hand.fingers[0].f2.hal.sensors  # type: ignore[union-attr]
    true = sensors.read("strain")
    assert isinstance(true, int)
    for params, check in (({"mode": "stuck", "value": 1234}, lambda v: v == 1234),
                          ({"mode": "biased", "bias": 300}, lambda v: v == true + 300),
                          ({"mode": "noisy", "sigma": 50.0}, lambda v: v != true)):
        entry = hand.faults.inject("sensor_fault", {"node": "finger0.f2", "channel": "strain",
                                                    **params})
        assert isinstance(sensors, FaultySensors)
        assert any(check(sensors.read("strain")) for _ in range(5)), params
        hand.faults.clear(entry)
        assert type(sensors).__name__ == "VirtualSensors" and sensors.read("strain") == true
    with pytest.raises(Exception, match="no sensor channel"):
        hand.faults.inject("sensor_fault", {"node": "finger0.f2", "channel": "pressure"})


def test_a_misaligned_accelerometer_reads_the_vector_rotated_and_is_restored(hand: FaultyEmulator
                                                                            ) -> None:
    sensors = hand.hand.fingers[1].f3.hal.sensors  # type: ignore[union-attr]
    sensors.set_accel(0, 0, 1000)  # 1 g along its z axis
    entry = hand.faults.inject("sensor_fault", {"node": "finger1.f3", "channel": "accel",
                                                "mode": "misaligned", "angle_deg": 90.0,
                                                "axis": "x"})
    assert sensors.read("accel") == (0, -1000, 0)  # z turns to −y about x
    hand.faults.clear(entry)
    entry = hand.faults.inject("sensor_fault", {"node": "finger1.f3", "channel": "accel",
                                                "mode": "misaligned", "angle_deg": 10.0,
                                                "axis": "0,1,0"})
    x, y, z = sensors.read("accel")  # type: ignore[misc]
    assert (x, y, z) == (174, 0, 985)  # 1000·(sin 10°, 0, cos 10°): the magnitude kept
    hand.faults.clear(entry)
    assert sensors.read("accel") == (0, 0, 1000)
    with pytest.raises(Exception, match="not a three-axis vector"):
        hand.faults.inject("sensor_fault", {"node": "finger0.f2", "channel": "strain",
                                            "mode": "misaligned"})


# ---------------------------------------------------------------------------- arm


def test_servo_overheat_overload_and_supply_sag_latch_alarms() -> None:
    emu = FaultyEmulator("arm", seed=1, physics=False)
    arm = emu.arm
    assert arm is not None
    servo = arm.app(5)
    entry = emu.faults.inject("servo_overheat", {"servo": 5, "temperature_c": 95.0})
    emu.step(5 * MS)
    assert servo.alarms & ErrorBit.OVERHEATING and servo.shutdown  # type: ignore[attr-defined]
    emu.faults.clear(entry)
    arm.nodes[5][0].reset()
    emu.step(5 * MS)
    assert not servo.alarms  # type: ignore[attr-defined]
    servo6 = arm.app(6)
    servo6.set("torque_enable", 1)
    servo6.reload_registers()
    emu.faults.inject("servo_overload", {"servo": 6})
    emu.step(2_000 * MS)
    assert servo6.alarms & ErrorBit.OVERLOAD  # type: ignore[attr-defined]
    sag = emu.faults.inject("supply_sag", {"supply_mv": 5_000})
    emu.step(5 * MS)
    assert arm.app(1).alarm_bits() & ErrorBit.INPUT_VOLTAGE
    assert arm.app(7).alarms & ErrorBit.INPUT_VOLTAGE  # type: ignore[attr-defined]
    emu.faults.clear(sag)
    emu.step(5 * MS)
    assert not arm.app(1).alarm_bits() & ErrorBit.INPUT_VOLTAGE


def test_a_missed_index_pulse_is_never_latched_until_cleared() -> None:
    emu = FaultyEmulator("arm", seed=1, physics=False)
    hal, app = emu.arm.nodes[2]  # type: ignore[union-attr]
    entry = emu.faults.inject("missed_index", {"joint": 1})
    hal.encoder().pulse_index(1234)
    assert app.get("index_seen") == 0 and hal.encoder().missed == 1  # type: ignore[attr-defined]
    emu.faults.clear(entry)
    hal.encoder().pulse_index(1234)
    assert app.get("index_seen") == 1 and app.get("index_encoder_count") == 1234


def test_an_arm_push_moves_the_joint_and_stops_when_cleared() -> None:
    emu = FaultyEmulator("arm", seed=1)
    plant = emu.arm_plant
    emu.step(300 * MS)
    q0 = plant.joint_angles()[4]
    entry = emu.faults.inject("arm_push", {"joint": 4, "torque_nm": 3.0})
    emu.step(100 * MS)
    assert plant.joint_angles()[4] - q0 > 0.01
    emu.faults.clear(entry)
    assert plant._push[4] == 0.0


@pytest.mark.slow
def test_spring_drift_changes_the_deflection_under_the_same_load_until_cleared() -> None:
    from host.arm import Arm

    emu = FaultyEmulator("arm", seed=1)
    plant = emu.arm_plant
    arm = Arm.open(EmulatorTransport(emu, "arm"))
    arm.torque(True)

    def mean_over_1_s() -> tuple[float, float]:
        """Mean deflection (counts) and host torque estimate (N·m) of J2 over 1 s (the
        loaded joint swings at about 1.3 Hz)."""
        rows = []
        for _ in range(20):
            emu.step(50 * MS)
            j2 = arm.cycle().steppers[1]
            rows.append((j2.deflection, j2.torque))
        return float(np.mean([r[0] for r in rows])), float(np.mean([r[1] for r in rows]))

    emu.faults.inject("arm_push", {"joint": 1, "torque_nm": 6.0})  # a steady load on J2
    deflection, torque = mean_over_1_s()
    assert 5.0 < -torque < 7.0  # the host's estimate k·δ finds the load (resisting it)
    entry = emu.faults.inject("spring_drift", {"joint": 1, "final_fraction": 0.5,
                                               "drift_s": 0.2})
    emu.step(100 * MS)
    assert 100.0 < plant.stiffness[1] < 200.0  # half-way down the drift
    drifted_deflection, drifted_torque = mean_over_1_s()
    assert plant.stiffness[1] == pytest.approx(100.0)
    assert drifted_deflection / deflection > 1.6  # the same load, a softer spring
    assert drifted_torque / torque > 1.6  # so the host's estimate drifts (× 1 / 0.5)
    emu.faults.clear(entry)
    assert plant.stiffness[1] == 200.0
    _, restored = mean_over_1_s()
    assert restored == pytest.approx(torque, rel=0.2)


def test_spring_drift_sets_every_use_of_the_stiffness() -> None:
    emu = FaultyEmulator("arm", seed=1)
    plant = emu.arm_plant
    entry = emu.faults.inject("spring_drift", {"joint": 2, "final_fraction": 1.5,
                                               "drift_s": 0.01, "update_us": 5_000})
    emu.step(20 * MS)
    jid = plant._stepper_jids[2]
    assert plant.model.jnt_stiffness[jid] == pytest.approx(165.0)
    assert plant._stepper_rows[2][6] == pytest.approx(165.0)
    assert plant._k_solid[2] == pytest.approx(165.0 * (plant.params.stop_stiffness_factor - 1))
    emu.faults.clear(entry)
    assert plant.model.jnt_stiffness[jid] == 110.0 and plant.params.stiffness[2] == 110.0


def test_a_duplicate_servo_id_garbles_that_servos_replies_until_unplugged() -> None:
    emu = FaultyEmulator("arm", seed=1, physics=False)
    bus = emu.arm.bus  # type: ignore[union-attr]
    assert _arm_ping_answered(emu, 5)
    entry = emu.faults.inject("duplicate_servo_id", {"servo": 5})
    collisions = bus.collisions
    assert not any(_arm_ping_answered(emu, 5) for _ in range(3))
    assert bus.collisions == collisions + 3  # both answered, at once
    assert _arm_ping_answered(emu, 6)  # the others answer as before
    emu.faults.clear(entry)
    assert _arm_ping_answered(emu, 5) and bus.collisions == collisions + 3
    assert bus.names.count("id5") == 1 and len(bus.names) == 8


# ---------------------------------------------------------------------------- host links


def test_link_corruption_loss_latency_noise_and_vanish_on_the_palm_link(hand: FaultyEmulator) -> None:
    host = _host(hand)
    tap = hand.link_tap("palm")
    tap.record = True
    entry = hand.faults.inject("link_corruption", {"link": "palm", "byte_error_rate": 1.0,
                                                   "direction": "down"})
    assert not _answers(host.palm)
    assert tap.received and all(a != b for a, b in zip(tap.sent, tap.received, strict=True))
    hand.faults.clear(entry)
    assert _answers(host.palm)
    entry = hand.faults.inject("link_loss", {"link": "palm", "probability": 1.0})
    assert not _answers(host.palm)
    hand.faults.clear(entry)
    t0 = host.session.now()
    host.palm.ping()
    quick = host.session.now() - t0
    entry = hand.faults.inject("link_latency", {"link": "palm", "latency_us": 5_000,
                                                "jitter_us": 1_000})
    t0 = host.session.now()
    host.palm.ping()  # 5–6 ms more, within the 30 ms link timeout
    assert host.session.now() - t0 >= quick + 0.005
    hand.faults.clear(entry)
    hand.faults.inject("link_noise_burst", {"link": "palm", "length": 40})
    hand.step(5 * MS)
    assert _answers(host.palm)  # both ends resynchronise
    entry = hand.faults.inject("port_vanish", {"link": "palm"})
    with pytest.raises(TransportError, match="vanished"):
        host.palm.ping()
    hand.faults.clear(entry)
    assert _answers(host.palm)


def test_a_stuck_host_transmitter_blocks_the_link_until_cleared(hand: FaultyEmulator) -> None:
    host = _host(hand)
    tap = hand.link_tap("palm")
    tap.record = True
    palm_received: list[bytes] = []
    palm_uart = hand.hand.host_uart  # type: ignore[union-attr]
    receiver = palm_uart._receiver
    assert receiver is not None

    def spy(data: bytes, t_us: int) -> None:
        palm_received.append(data)
        receiver(data, t_us)

    palm_uart.set_receiver(spy)
    entry = hand.faults.inject("serial_driver_stuck", {"link": "palm"})
    hand.step(10 * MS)
    assert not _answers(host.palm)
    assert tap.sent and not tap.received  # nothing the host wrote reached the line
    line = b"".join(palm_received)
    assert len(line) >= 0.9 * 200 * 40 and set(line) == {0}  # a break at line rate (2 Mbaud)
    hand.faults.clear(entry)
    palm_received.clear()
    hand.step(5 * MS)
    assert not palm_received  # the line idles
    assert _answers(host.palm)


def test_a_stuck_host_transmitter_on_the_arm_link_jams_until_cleared() -> None:
    emu = FaultyEmulator("arm", seed=1, physics=False)
    tap = emu.link_tap("arm")
    entry = emu.faults.inject("serial_driver_stuck", {"link": "arm", "mode": "noise"})
    emu.step(5 * MS)
    assert tap.down(make_ping(5).encode()) == b""  # the host's frames never reach the line
    sent = [t for t in emu.arm.bus.log if t.name == "host"]  # type: ignore[union-attr]
    assert sum(len(t.data) for t in sent) >= 500  # 1 Mbaud: 100 characters a ms
    emu.faults.clear(entry)
    emu.step(2 * MS)
    assert tap.down(make_ping(5).encode()) == make_ping(5).encode()
    assert _arm_ping_answered(emu, 5)


def test_misread_resamples_uart_characters_bit_by_bit() -> None:
    from hil_emulator.uart_sampling import misread

    data = bytes(range(0, 256, 7))
    assert misread(data, 115_200, 115_200) == data
    assert misread(data, 2_000_000, 2_010_000) == data  # 0.5 %: within a UART's tolerance
    # 0x55 is start 0, data 1,0,1,0,1,0,1,0 (LSB first), stop 1.  Read twice as fast, the
    # first character samples sent bits 0,1,1,2,2,3,3,4 → 0x66 and its stop bit at 4.75
    # finds 0 (framing error: left out); the next falling edge is the 1 → 0 at bit 6, whose
    # samples run into the stop bit and the idle line: 0,1,1,0,0,1,1,1 → 0xE6.
    assert misread(b"\x55", 1, 2) == b"\xe6"
    # 0x0F read twice as slow: the start bit's sample (at bit 1) finds 1, a glitch; the next
    # edge is bit 5, whose samples at 7, 9, 11 … read 0 then the idle line → 0xFE.
    assert misread(b"\x0f", 2, 1) == b"\xfe"
    fast = misread(data, 1_000_000, 2_000_000)
    slow = misread(data, 2_000_000, 1_000_000)
    assert fast != data and len(data) > len(slow) > 0  # a slow receiver spans characters
    assert misread(data, 2_000_000, 2_200_000) != data  # 10 % off: every frame broken
    assert misread(b"", 1, 2) == b""


def test_a_baud_mismatch_breaks_every_frame_both_ways_until_cleared(hand: FaultyEmulator) -> None:
    from protocol.stream import decode_all

    host = _host(hand)
    tap = hand.link_tap("palm")
    tap.record = True
    entry = hand.faults.inject("baud_mismatch", {"link": "palm", "baud": 1_000_000})
    assert not _answers(host.palm)
    assert tap.sent and tap.received != tap.sent
    assert not [f for f in decode_all(bytes(tap.received)) if f.crc_ok]  # nothing whole
    hand.faults.clear(entry)
    assert _answers(host.palm)
    arm = FaultyEmulator("arm", seed=1, physics=False)
    entry = arm.faults.inject("baud_mismatch", {"link": "arm", "baud": 1_100_000,
                                                "side": "host"})
    arm_tap = arm.link_tap("arm")
    assert arm_tap.down(make_ping(5).encode()) != make_ping(5).encode()
    replies: list[bytes] = []
    arm_tap.up(make_ping(5).encode(), 0, lambda data, t: replies.append(data))
    assert replies and replies[0] != make_ping(5).encode()  # the host misreads the replies
    arm.faults.clear(entry)
    assert arm_tap.down(make_ping(5).encode()) == make_ping(5).encode()


def test_port_vanish_recreates_the_pty_at_the_same_link_path(tmp_path: Path) -> None:
    emu = FaultyEmulator("arm", physics=False)
    try:
        emu.open_ports(str(tmp_path))
        link = tmp_path / "arm"
        before = os.path.realpath(link)
        entry = emu.faults.inject("port_vanish", {"link": "arm"})
        assert not link.exists()
        emu.step(1 * MS)
        emu.faults.clear(entry)
        assert link.exists()
        fd = os.open(link, os.O_RDWR | os.O_NOCTTY)
        try:
            os.write(fd, make_ping(5).encode())
            emu.step(3 * MS)
            assert os.read(fd, 64)[:3] == b"\xff\xff\x05"
        finally:
            os.close(fd)
        assert os.path.realpath(link) != before or emu.links["arm"].port.is_open
    finally:
        emu.close()


# ---------------------------------------------------------------------------- timelines


def _plan() -> list[dict[str, object]]:
    return [{"fault": "bus_frame_loss", "params": {"bus": "arm", "probability": 0.3},
             "at_s": 0.01, "duration_s": 0.02, "every_s": 0.05, "count": 3, "jitter_s": 0.01},
            {"fault": "stuck_driver", "params": {"bus": "arm"}, "at_s": 0.2,
             "duration_s": 0.005}]


def _run(seed: int, replay: list[dict[str, object]] | None = None
         ) -> tuple[list[dict[str, object]], bytes]:
    emu = FaultyEmulator("arm", seed=seed, physics=False)
    if replay is None:
        emu.faults.load(parse_plan(_plan()))
    else:
        emu.faults.replay(replay)  # type: ignore[arg-type]
    replies = bytearray()
    for _ in range(120):
        emu.arm.send_from_host(make_ping(6).encode())  # type: ignore[union-attr]
        emu.step(2 * MS)
        replies += emu.arm.take_host_bytes()  # type: ignore[union-attr]
    return emu.faults.timeline_dicts(), bytes(replies)


def test_same_seed_and_plan_same_timeline_and_run_and_a_timeline_replays() -> None:
    timeline, replies = _run(11)
    assert _run(11) == (timeline, replies)
    assert [e["action"] for e in timeline].count("apply") == 4
    other, _ = _run(12)
    assert [e["t_us"] for e in other] != [e["t_us"] for e in timeline]  # jitter from the seed
    replayed = _run(11, replay=json.loads(json.dumps(timeline)))
    assert replayed == (timeline, replies)


def test_the_control_channel_injects_into_a_running_emulator(tmp_path: Path) -> None:
    emu = FaultyEmulator("arm", physics=False)
    path = emu.open_control(str(tmp_path / "control"))
    client = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        client.connect(path)
        client.sendall(b'{"op": "inject", "fault": "line_cut", "params": {"bus": "arm"}}\n'
                       b'{"op": "inject", "fault": "line_cut", "params": {"wire": 1}}\n')
        emu.step(1 * MS)
        answers = [json.loads(line) for line in client.recv(4096).splitlines()]
        assert answers[0]["ok"] and answers[0]["id"] == 0
        assert not answers[1]["ok"] and "params.wire" in answers[1]["error"]
        assert emu.arm.bus.line_cut  # type: ignore[union-attr]
        client.sendall(b'{"op": "clear", "id": 0}\n{"op": "timeline"}\n')
        emu.step(1 * MS)
        lines = client.recv(65536).splitlines()
        assert json.loads(lines[0]) == {"ok": True}
        assert [e["action"] for e in json.loads(lines[1])["events"]] == ["apply", "clear"]
        assert not emu.arm.bus.line_cut  # type: ignore[union-attr]
        client.sendall(b'{"op": "status"}\n')
        t_us = emu.scheduler.now_us()
        emu.step(1 * MS)
        status = json.loads(client.recv(65536))
        assert status["ok"] and status["t_us"] == t_us  # the simulation clock when read
        assert status["max_ms"] is None and status["slipped_s"] == 0.0  # never paced
        assert status["count"] == 0 and type(status["count"]) is int
        assert type(status["late_episodes"]) is int
        client.sendall(b"status\n[1, 2]\n\xff\xfe\n")  # not JSON objects
        emu.step(1 * MS)
        errors = [json.loads(line) for line in client.recv(65536).splitlines()]
        assert [e["ok"] for e in errors] == [False, False, False]
        assert all('{"op": "status"}' in e["error"] for e in errors)
        assert errors[0]["error"].startswith("not a JSON line")
    finally:
        client.close()
        emu.close()
    assert not os.path.exists(path)


def _ask(client: socket.socket, emu: Emulator, request: bytes) -> dict[str, object]:
    """One control-channel request answered while ``emu`` steps 1 ms."""
    client.sendall(request + b"\n")
    emu.step(1 * MS)
    answer: dict[str, object] = json.loads(client.recv(65536))
    return answer


def test_the_control_channel_tells_the_arm_plants_ground_truth(tmp_path: Path) -> None:
    emu = FaultyEmulator("arm", seed=1)
    path = emu.open_control(str(tmp_path / "control"))
    client = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        client.connect(path)
        emu.step(20 * MS)
        truth = _ask(client, emu, b'{"op": "truth"}')
        assert truth["ok"] and truth["t_us"] == 20 * MS
        arm = truth["arm"]
        assert isinstance(arm, dict)
        assert arm["joints"] == pytest.approx(list(emu.arm_plant.joint_angles()), abs=1e-3)
        assert len(arm["velocities"]) == 7 and len(arm["deflections"]) == 4
        assert sorted(arm["nodes"], key=int) == [str(i) for i in range(1, 8)]
        assert all(n["torque_enable"] == 0 for n in arm["nodes"].values())  # comes up off
        assert emu.arm is not None
        emu.arm.app(2).set("torque_enable", 1)
        arm = _ask(client, emu, b'{"op": "truth"}')["arm"]
        assert isinstance(arm, dict)
        assert [n["torque_enable"] for n in arm["nodes"].values()] == [0, 1, 0, 0, 0, 0, 0]
    finally:
        client.close()
        emu.close()
    hand = FaultyEmulator("hand", physics=False)
    try:
        client = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        client.connect(hand.open_control(str(tmp_path / "hand-control")))
        assert _ask(client, hand, b'{"op": "truth"}')["arm"] is None
        client.close()
    finally:
        hand.close()


def test_rngs_differ_by_entry_and_occurrence() -> None:
    emu = FaultyEmulator("arm", seed=3, physics=False)
    draws = {(e, k): emu.faults._rng(e, k).random() for e in range(2) for k in range(2)}
    assert len(set(draws.values())) == 4
    assert np.isclose(emu.faults._rng(1, 1).random(), draws[(1, 1)])


def test_the_command_loads_a_plan_and_takes_faults_from_another_process(tmp_path: Path
                                                                        ) -> None:
    import time

    from tests.hil_emulator.emulator_process import running_emulator

    plan = tmp_path / "plan.toml"
    plan.write_text('[[faults]]\nfault = "supply_sag"\nparams = { supply_mv = 6000 }\n'
                    'at_s = 0.0\nduration_s = 0.05\nlabel = "sag"\n')
    links = tmp_path / "links"
    links.mkdir()
    with running_emulator("--config", "arm", "--no-physics", "--link-dir", str(links),
                          "--faults", str(plan)) as info:
        assert info["control"] == str(links / "control") and info["faults"] == 1
        client = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        client.settimeout(10)
        client.connect(info["control"])
        fd = os.open(links / "arm", os.O_RDWR | os.O_NOCTTY)
        try:
            client.sendall(b'{"op": "inject", "fault": "line_cut", "params": {"bus": "arm"}}\n')
            assert json.loads(client.recv(4096))["ok"]
            os.write(fd, make_ping(5).encode())
            time.sleep(0.2)
            os.set_blocking(fd, False)
            with pytest.raises(BlockingIOError):
                os.read(fd, 64)  # the line is cut: no answer
            client.sendall(b'{"op": "clear", "id": 1}\n')
            assert json.loads(client.recv(4096)) == {"ok": True}
            os.write(fd, make_ping(5).encode())
            deadline = time.monotonic() + 5
            reply = b""
            while not reply and time.monotonic() < deadline:
                time.sleep(0.02)
                try:
                    reply = os.read(fd, 64)
                except BlockingIOError:
                    pass
            assert reply[:3] == b"\xff\xff\x05"
        finally:
            os.close(fd)
            client.close()
    timeline = info["stats"]["fault_timeline"]
    assert sorted((e["label"], e["action"]) for e in timeline) == [
        ("line_cut", "apply"), ("line_cut", "clear"), ("sag", "apply"), ("sag", "clear")]
    assert not (links / "control").exists()


def test_overlapping_repeats_of_a_fault_are_cleared_before_applied_again() -> None:
    """A repeat that starts while the last one is still applied (a fault that stays until
    cleared, repeated) clears it first: each apply has its clear, and clearing the fault
    once leaves nothing of it (two stacked applies would leave frames lost for good)."""
    emu = FaultyEmulator("arm", seed=3, physics=False)
    try:
        emu.faults.load(parse_plan([
            {"fault": "bus_frame_loss", "params": {"bus": "arm", "probability": 1.0},
             "at_s": 0.01, "every_s": 0.02, "count": 2}]))
        emu.step(50 * MS)
        timeline = [(e["action"], e["occurrence"], e["t_us"])
                    for e in emu.faults.timeline_dicts()]
        assert timeline == [("apply", 0, 10_000), ("clear", 0, 30_000),
                            ("apply", 1, 30_000)]
        assert not _arm_ping_answered(emu)  # the repeat is applied
        emu.faults.clear_all()
        assert emu.faults.active == []
        assert _arm_ping_answered(emu)  # and nothing of the fault is left
    finally:
        emu.close()
