"""Faults of the arm's servos, steppers and plant (``hil_emulator/faults/arm.py``): each effect
observable, and gone once cleared."""

from __future__ import annotations

import numpy as np
import pytest

from hil_emulator.inprocess import EmulatorTransport
from protocol.dynamixel import ErrorBit
from tests.ground_truth import arm_plant_of, arm_rig_of
from tests.hil_emulator.faults.probes import MS, FaultyEmulator, arm_ping_answered


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
    hal, app = arm_rig_of(emu).nodes[2]
    entry = emu.faults.inject("missed_index", {"joint": 1})
    hal.encoder().pulse_index(1234)
    assert app.get("index_seen") == 0 and hal.encoder().missed == 1
    emu.faults.clear(entry)
    hal.encoder().pulse_index(1234)
    assert app.get("index_seen") == 1 and app.get("index_encoder_count") == 1234


def test_an_arm_push_moves_the_joint_and_stops_when_cleared() -> None:
    emu = FaultyEmulator("arm", seed=1)
    plant = arm_plant_of(emu)
    emu.step(300 * MS)
    q0 = plant.joint_angles()[4]
    entry = emu.faults.inject("arm_push", {"joint": 4, "torque_nm": 3.0})
    emu.step(100 * MS)
    assert plant.joint_angles()[4] - q0 > 0.01
    emu.faults.clear(entry)
    assert plant._push[4] == 0.0


@pytest.mark.slow
def test_spring_drift_changes_the_deflection_under_the_same_load_until_cleared() -> None:
    from host.arm.facade import Arm

    emu = FaultyEmulator("arm", seed=1)
    plant = arm_plant_of(emu)
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
    plant = arm_plant_of(emu)
    entry = emu.faults.inject("spring_drift", {"joint": 2, "final_fraction": 1.5,
                                               "drift_s": 0.01, "update_us": 5_000})
    emu.step(20 * MS)
    jid = plant._stepper_jids[2]
    assert plant.model.jnt_stiffness[jid] == pytest.approx(165.0)
    coupling = plant._couplings[2]
    assert coupling.k == pytest.approx(165.0)
    k, k_solid = coupling.constants[4], coupling.constants[8]  # what the tick reads
    assert k == pytest.approx(165.0) and k_solid == coupling.k_solid
    assert plant._k_solid[2] == pytest.approx(165.0 * (plant.params.stop_stiffness_factor - 1))
    emu.faults.clear(entry)
    assert plant.model.jnt_stiffness[jid] == 110.0 and plant.params.stiffness[2] == 110.0


def test_a_duplicate_servo_id_garbles_that_servos_replies_until_unplugged() -> None:
    emu = FaultyEmulator("arm", seed=1, physics=False)
    bus = arm_rig_of(emu).bus
    assert arm_ping_answered(emu, 5)
    entry = emu.faults.inject("duplicate_servo_id", {"servo": 5})
    collisions = bus.collisions
    assert not any(arm_ping_answered(emu, 5) for _ in range(3))
    assert bus.collisions == collisions + 3  # both answered, at once
    assert arm_ping_answered(emu, 6)  # the others answer as before
    emu.faults.clear(entry)
    assert arm_ping_answered(emu, 5) and bus.collisions == collisions + 3
    assert bus.names.count("id5") == 1 and len(bus.names) == 8
