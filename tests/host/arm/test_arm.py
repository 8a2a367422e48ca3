"""The arm end to end on the in-process emulator (``emu://arm/arm``, simulation clock)."""

from __future__ import annotations

import io
import json
import math

import pytest

from firmware_py.arm_stepper import StepperNodeApp
from host.arm.facade import SLOW_READ_EVERY, STEPPER_READ_AT, Arm, discover
from host.arm.joint_loop import elastic_deflections
from host.arm.motor_goals import power_up_angles
from host.arm.state import DEFAULT_STIFFNESS_NM_PER_RAD
from host.errors import NodeError
from protocol.control_tables import STEPPER_FIRMWARE_VERSION, STEPPER_TABLE, StepperFlag
from protocol.dynamixel import ErrorBit
from protocol.robot import series_elastic_torque
from tests.ground_truth import arm_rig_of, emulator_of
from tools.cli import armctl

URL = "emu://arm/arm?name=test_arm"


def test_discovery_finds_seven_joints_from_their_registers(arm: Arm) -> None:
    assert [j.dxl_id for j in arm.joints] == [1, 2, 3, 4, 5, 6, 7]
    assert [j.kind for j in arm.joints] == ["stepper"] * 4 + ["servo"] * 3
    assert [j.model_number for j in arm.joints] == [0x5E50] * 4 + [64] * 3
    assert [j.reduction for j in arm.steppers] == [6.0, 10.0, 13.0, 13.0]
    assert {(j.steps_per_rev, j.microstepping) for j in arm.steppers} == {(200, 10)}
    assert [j.stiffness for j in arm.steppers] == list(DEFAULT_STIFFNESS_NM_PER_RAD)
    assert all(j.firmware_version == STEPPER_FIRMWARE_VERSION for j in arm.steppers)


def test_open_sets_the_fast_return_delay(arm: Arm) -> None:
    assert [arm.bus.read(i, 5, 1) for i in range(1, 8)] == [b"\x00"] * 7
    assert arm.bus.return_delay_us == {i: 0 for i in range(1, 8)}


def test_a_stepper_joint_and_a_servo_reach_their_goals(arm: Arm) -> None:
    arm.torque(True)
    goals = [0.0, 0.0, 0.0, 0.25, 0.0, -0.3, 0.0]
    t0 = arm.transport.now()
    state, ok = arm.move(goals, timeout=5.0)
    elapsed = arm.transport.now() - t0
    assert ok and 0.1 < elapsed < 5.0
    j4 = state.steppers[3]
    assert j4.goal == pytest.approx(0.25, abs=1e-3)
    assert j4.motor_angle == pytest.approx(0.25, abs=0.02)
    # the joint sits off the motor by the elastic deflection (gravity on the forearm)
    # (to the count: the node rounds the motor position to whole counts)
    assert j4.angle - j4.motor_angle == pytest.approx(-j4.deflection_rad, abs=2 * math.pi / 1e4)
    assert abs(j4.angle - 0.25) < 0.1
    assert state.servos[1].angle == pytest.approx(-0.3, abs=0.02)
    assert state.t == pytest.approx(arm.transport.now())


def test_cycle_state_fields_are_consistent(arm: Arm) -> None:
    state = arm.cycle()
    assert len(state.joints) == 7 and len(state.motor_joints) == 4
    # the torque is the element's: its deflection is the node's plus the routes' coupling
    q_ref = power_up_angles(arm.calibration, arm.steppers, arm.encoder_at_power_up)
    elements = elastic_deflections(state, q_ref)
    for s, k, e in zip(state.steppers, DEFAULT_STIFFNESS_NM_PER_RAD, elements, strict=True):
        assert s.torque == pytest.approx(series_elastic_torque(float(e), k), abs=1e-9)
        assert s.deflection_rad == pytest.approx(s.deflection * 2 * math.pi / 10_000)
    assert state.slip == [False] * 4
    assert state.errors == {}
    assert all(20.0 <= s.temperature <= 60.0 for s in state.servos)
    assert all(10.0 <= s.voltage <= 20.0 for s in state.servos)


def test_servo_voltage_and_temperature_are_read_one_cycle_in_ten(arm: Arm) -> None:
    """They drift over seconds: the ordinary cycle reads 6 bytes per RX-64, the slow one 8,
    and every state reports the last values read."""
    hal, _servo = arm_rig_of(emulator_of(arm)).nodes[5]
    sensors = hal.sensors.values
    supply = sensors["supply_mv"]
    while arm.cycles % SLOW_READ_EVERY:
        arm.cycle()
    sensors["supply_mv"] = 15_100
    state = arm.cycle()
    assert state.servos[0].voltage == pytest.approx(15.1) and len(state.raw[5]) == 8
    sensors["supply_mv"] = 16_200
    for _ in range(SLOW_READ_EVERY - 1):
        state = arm.cycle()
        assert state.servos[0].voltage == pytest.approx(15.1) and len(state.raw[5]) == 6
    assert arm.cycle().servos[0].voltage == pytest.approx(16.2)
    sensors["supply_mv"] = supply


def test_the_cycle_block_reports_the_nodes_scattered_registers(arm: Arm) -> None:
    arm.transport.sleep(0.5)  # J4 holds 0.25 rad against gravity: its element deflects
    state = arm.cycle()
    assert any(s.deflection for s in state.steppers)
    for j, s in zip(arm.steppers, state.steppers, strict=True):
        data = arm.bus.read(j.dxl_id, 26, STEPPER_TABLE["deflection"].end - 26)  # one later read

        def value(name: str, data: bytes = data) -> int:
            reg = STEPPER_TABLE[name]
            return reg.decode(data[reg.address - 26 : reg.end - 26])

        # the joint holds still: a read one exchange later sees the same values
        assert s.deflection == value("deflection")
        assert s.step_count == value("step_count")
        assert abs(j.rad_to_counts(s.angle) - value("present_position")) <= 1
        assert int(s.flags) == value("status_flags")
        assert j.rad_to_counts(s.goal) == value("goal_position")


def test_a_node_without_the_cycle_block_is_refused(arm: Arm) -> None:
    app = arm_rig_of(emulator_of(arm)).app(2)
    app.set("firmware_version", 1)
    try:
        with pytest.raises(NodeError, match=r"\(J2\) runs stepper firmware 1"):
            discover(arm.bus)
    finally:
        app.set("firmware_version", STEPPER_TABLE["firmware_version"].default)


def test_flags_and_error_bits_decode_by_name(arm: Arm) -> None:
    state = arm.cycle()
    replies = {s.joint + 1: (0, state.raw[s.joint + 1]) for s in state.steppers}
    replies |= {s.joint + 1: (0, state.raw[s.joint + 1]) for s in state.servos}
    data = bytearray(replies[2][1])
    data[STEPPER_TABLE["cycle_status_flags"].address - STEPPER_READ_AT] = int(StepperFlag.SLIP | StepperFlag.MOVING | StepperFlag.STALLED)
    replies[2] = (int(ErrorBit.OVERLOAD), bytes(data))
    replies[6] = (int(ErrorBit.OVERHEATING | ErrorBit.INPUT_VOLTAGE), replies[6][1])
    decoded = arm.decode_state(0.0, replies)
    assert decoded.slip == [False, True, False, False]
    assert decoded.steppers[1].stalled and decoded.steppers[1].moving
    assert decoded.errors == {"J2": ["OVERLOAD"], "J6": ["INPUT_VOLTAGE", "OVERHEATING"]}


def test_clear_errors_clears_a_latched_slip(arm: Arm) -> None:
    app = arm_rig_of(emulator_of(arm)).app(3)
    assert isinstance(app, StepperNodeApp)
    app._flags |= int(StepperFlag.SLIP)  # what the node latches when steps are lost
    assert arm.cycle().slip == [False, False, True, False]
    arm.clear_errors()
    assert arm.cycle().slip == [False] * 4
    assert STEPPER_TABLE["clear_flags"].address == 27


def test_armctl_json_status(arm: Arm) -> None:
    arm.torque(True)  # a known pose, whatever ran before (J4 at 0.25 rad)
    _, ok = arm.move([0.0, 0.0, 0.0, 0.25, 0.0, -0.3, 0.0], timeout=5.0)
    assert ok
    arm.clear_errors()
    out = io.StringIO()
    assert armctl.main(["--port", URL, "--json", "status"], out=out) == 0
    status = json.loads(out.getvalue())
    assert len(status["joints"]) == 7 and len(status["motor_joints"]) == 4
    assert len(status["torques"]) == 4 and status["slip"] == [False] * 4
    assert status["errors"] == {}
    assert status["joints"][3] == pytest.approx(0.25, abs=0.1)


def test_armctl_says_what_to_do_when_the_port_is_missing(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert armctl.main(["--port", "/nonexistent/arm", "status"]) == armctl.EXIT_ROBOT
    err = capsys.readouterr().err
    assert err.startswith("armctl: ") and "check the path" in err.lower() and "Traceback" not in err


def test_a_recording_counts_its_cycles_rather_than_comparing_clock_readings() -> None:
    """0.1 s at 100 Hz is 10 cycles whatever the clock reads at the start; comparing
    ``start + 10 · 0.01 − start`` with 0.1 made it 11 for about a third of start times."""
    from host.arm.recording import cycle_count

    assert [cycle_count(s, r) for s, r in ((0.1, 100.0), (0.105, 100.0), (1.0, 3.0),
                                            (0.0, 100.0), (5.0, 100.0))] == [10, 11, 3, 0, 500]
    start = 0.030907  # such a start time (s): the old loop's bound let an 11th cycle in
    assert (start + 10 * 0.01) - start < 0.1


def test_armctl_record_writes_raw_bytes_and_states(arm: Arm, tmp_path: object) -> None:
    from pathlib import Path

    from mcap.reader import make_reader

    from host.recording.writer import SOURCE_METADATA
    from protocol.dynamixel import DynamixelStreamDecoder

    path = Path(str(tmp_path)) / "arm.mcap"
    assert armctl.main(["--port", URL, "record", str(path), "--seconds", "0.1"],
                       out=io.StringIO()) == 0
    with path.open("rb") as stream:
        reader = make_reader(stream)
        source = next(m.metadata for m in reader.iter_metadata() if m.name == SOURCE_METADATA)
        messages = [(ch.topic, msg.data, msg.publish_time / 1e9)
                    for _, ch, msg in reader.iter_messages()]
    states = [json.loads(d) for t, d, _ in messages if t == "/arm/state"]
    assert len(states) == 10 and all(len(s["joints"]) == 7 for s in states)
    decoder = DynamixelStreamDecoder("status")
    # the recorded cycles' replies; the link's opening before them is the file's prologue
    start = float(source["start_t"])
    replies = [p for t, d, at in messages if t == "/arm/bus/rx" and at > start
               for p in decoder.feed(d)]
    assert len(replies) == 7 * 10
    assert any(t == "/arm/bus/rx" and at < start for t, _, at in messages)
