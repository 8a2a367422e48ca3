"""Faults of the buses' lines (``hil_emulator/faults/line.py``): each effect observable, and
gone once cleared."""

from __future__ import annotations

import pytest

from hil_emulator.errors import EmulatorConfigError, FaultPlanError
from hil_emulator.faults import make_fault
from hil_emulator.faults.line import BurstDropout
from hil_emulator.inprocess import EmulatorTransport, bring_up
from host.hand.facade import Hand
from host.hand.session import HandSession
from tests.ground_truth import arm_rig_of, hand_rig_of
from tests.hil_emulator.faults.probes import MS, FaultyEmulator, answers, arm_ping_answered, host_of


def test_arm_bus_bit_errors_loss_bursts_jam_and_cut_each_clear() -> None:
    emu = FaultyEmulator("arm", seed=1, physics=False)
    bus = arm_rig_of(emu).bus
    assert arm_ping_answered(emu)
    for name, params in (("bus_bit_errors", {"rate": 0.5}), ("bus_frame_loss",
                         {"probability": 1.0}), ("line_cut", {}), ("stuck_driver", {}),
                         ("burst_dropout", {"p_enter": 1.0, "p_leave": 0.0})):
        entry = emu.faults.inject(name, {"bus": "arm", **params})
        assert not any(arm_ping_answered(emu) for _ in range(3)), name
        emu.faults.clear(entry)
        assert arm_ping_answered(emu), name
    assert bus.bit_error_rate == 0.0 and bus.drop_probability == 0.0 and not bus.line_cut
    assert bus.fault_filter is None


def test_burst_dropout_loses_frames_in_runs() -> None:
    fault = make_fault("burst_dropout", {"bus": "arm", "p_enter": 0.1, "p_leave": 0.25})
    emu = FaultyEmulator("arm", seed=2, physics=False)
    emu.faults.inject(fault)
    answered = [arm_ping_answered(emu) for _ in range(300)]
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
        assert isinstance(fault, BurstDropout)
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
    bus = hand_rig_of(hand).fingers[2].tendon_bus
    assert bus is not None and bus.fault_filter is None


def test_tendon_chip_errors_garble_characters_until_cleared(hand: FaultyEmulator) -> None:
    bus = hand_rig_of(hand).fingers[1].tendon_bus
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
    host = host_of(hand)
    entry = hand.faults.inject("line_cut", {"bus": "tendon2"})
    assert not answers(host.fingers[2].distal)
    assert answers(host.fingers[2].motor)
    hand.faults.clear(entry)
    assert answers(host.fingers[2].distal)


def test_tendon_glitch_within_hold_up_is_ridden_through_beyond_it_reboots(hand: FaultyEmulator
                                                                           ) -> None:
    f2 = hand_rig_of(hand).fingers[0].f2
    boots = f2.boots
    hand.faults.inject("tendon_glitch", {"finger": 0, "duration_us": 1_500})
    hand.step(20 * MS)
    assert f2.program_name == "f2" and f2.boots == boots
    hand.faults.inject("tendon_glitch", {"finger": 0, "duration_us": 8_000})
    hand.step(20 * MS)
    assert f2.powered and f2.program_name == "bootloader"
