"""armctl as an engineer bringing the arm up uses it: torque off, a held joint, a goal out of
range, a latched alarm (the in-process emulator, simulation clock)."""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import pytest

from host.arm.facade import Arm
from host.errors import HomingError, TransportError, UsageError
from protocol.control_tables import STEPPER_TABLE
from protocol.dynamixel import ErrorBit
from tests.ground_truth import arm_plant_of, emulator_of
from tools.cli import armctl

URL = "emu://arm/arm?name=test_armctl"


def run(*argv: str) -> tuple[int, dict[str, Any]]:
    out = io.StringIO()
    code = armctl.main(["--port", URL, "--json", *argv], out=out)
    return code, json.loads(out.getvalue()) if out.getvalue() else {}


def test_a_move_with_torque_off_is_refused_at_once_and_sends_no_goal(
        arm: Arm, capsys: pytest.CaptureFixture[str]) -> None:
    """Before, the move waited its whole timeout and left the goals in the nodes: the next
    ``torque on`` made the joints jump there."""
    t0 = arm.transport.now()
    goals = list(arm.stepper_goals)
    code, _ = run("move", "--unhomed", "--joints", "0,0.3,0,0.2,0,0,0")
    assert code == armctl.EXIT_USAGE
    err = capsys.readouterr().err
    assert "torque is off on J1, J2, J3, J4, J5, J6, J7" in err and "armctl torque on" in err
    assert arm.transport.now() - t0 < 0.5  # no waiting for a move that cannot happen
    arm.read_goals()
    assert arm.stepper_goals == goals


def test_torque_on_holds_where_the_joints_are_not_at_an_old_goal(arm: Arm) -> None:
    """A goal sent while the torque was off stays in the node; ``torque on`` used to drive
    the joint there at full speed (J2 0.3 rad away latched STALLED under the arm's weight)."""
    arm.cycle([arm.make_position(1, 0.3), arm.make_position(3, 0.2),
               arm.make_position(5, 0.5)])  # torque off: nothing moves
    before = arm.state()
    code, status = run("torque", "on")
    assert code == armctl.EXIT_OK and status["enabled"] == [True] * 7
    arm.transport.sleep(1.0)
    after = arm.state()
    for i in range(7):
        assert after.joints[i] == pytest.approx(before.joints[i], abs=0.02), f"J{i + 1} moved"
    assert not any(s.stalled for s in after.steppers) and after.errors == {}
    code, status = run("status")
    assert code == armctl.EXIT_OK and status["torque"] == [True] * 7


def test_a_goal_outside_a_joints_range_is_refused_naming_it(
        arm: Arm, capsys: pytest.CaptureFixture[str]) -> None:
    """J7 was driven to its end stop (2.60 rad) and the move reported 'not settled' after
    10 s, asking whether the torque was on."""
    assert run("torque", "on")[0] == armctl.EXIT_OK
    code, _ = run("move", "--unhomed", "--joints", "0", "0", "0", "0", "0", "0", "4")
    assert code == armctl.EXIT_USAGE
    assert "J7 goal +4.000 rad is outside the joint's range -2.60 … +2.60 rad" in \
        capsys.readouterr().err
    assert abs(arm.state().joints[6]) < 0.05


def test_a_joint_its_node_turned_off_is_named_by_torque_on_and_cleared_by_clear(
        arm: Arm, capsys: pytest.CaptureFixture[str]) -> None:
    plant = arm_plant_of(emulator_of(arm))
    shutdown = STEPPER_TABLE["alarm_shutdown"]
    # a node told to cut its coils on OVERLOAD (the factory setting holds a STALLED joint)
    arm.bus.write(4, shutdown.address, bytes([int(ErrorBit.OVERLOAD | ErrorBit.OVERHEATING)]))
    arm.torque(True, hold=True)
    plant.push(3, -25.0)  # a hand holding the forearm against the elbow's drive
    arm.cycle([arm.make_position(3, arm.state().joints[3] + 0.6)])
    arm.transport.sleep(2.0)
    assert arm.state().steppers[3].stalled
    plant.push(3, 0.0)
    code, status = run("torque", "on")
    assert code == armctl.EXIT_ROBOT and status["enabled"][3] is False
    err = capsys.readouterr().err
    assert "J4 stayed off" in err and "armctl clear" in err  # J2 too: the routes couple them
    code, status = run("clear")
    assert code == armctl.EXIT_OK and status["cleared"] is True and "J4" in status["latched"]
    out = io.StringIO()
    assert armctl.main(["--port", URL, "clear"], out=out) == armctl.EXIT_OK
    assert out.getvalue() == "no alarm was latched\n"
    code, status = run("torque", "on")
    assert code == armctl.EXIT_OK and status["enabled"] == [True] * 7
    arm.bus.write(4, shutdown.address, bytes([shutdown.default]))


def test_homing_stops_with_the_joint_named_when_its_node_stops_it(
        arm: Arm, capsys: pytest.CaptureFixture[str]) -> None:
    """A held joint used to keep the search waiting for it forever."""
    plant = arm_plant_of(emulator_of(arm))
    plant.push(3, -40.0)
    t0 = arm.transport.now()
    with pytest.raises(HomingError, match="J4: the node stopped the joint") as caught:
        arm.home()
    assert caught.value.joint == "J4" and arm.transport.now() - t0 < 30.0
    plant.push(3, 0.0)
    arm.clear_errors()
    plant.push(3, -40.0)
    assert run("home")[0] == armctl.EXIT_ROBOT
    assert "the node stopped the joint during the search" in capsys.readouterr().err
    plant.push(3, 0.0)


def test_the_homing_search_time_covers_the_widest_search() -> None:
    from host.arm.homing import search_targets, search_time

    plan = search_targets(1.0, 0.25)  # +0.25 -0.25 +0.5 -0.5: 0.25 + 0.5 + 0.75 + 1.0
    assert search_time([plan, [0.1, -0.1]], 0.5) == pytest.approx(2 * 2.5 / 0.5 + 5.0)


def test_a_joint_beyond_its_range_may_hold_there(arm: Arm) -> None:
    """Homing's move back (the servos where they are) must not trip on a servo that sits
    a little past its range, as a servo driven to its end stop does (2.6027 rad)."""
    present = [0.0] * 6 + [2.61]
    arm.check_limits([0.0] * 6 + [2.62], present)
    with pytest.raises(UsageError, match="J7 goal"):
        arm.check_limits([0.0] * 6 + [2.7], present)


def test_scan_finds_a_node_at_an_unexpected_id_that_ping_misses(
        arm: Arm, capsys: pytest.CaptureFixture[str]) -> None:
    """A servo whose ID was changed: ``ping`` could only say J7 does not answer."""
    arm.bus.write(7, 3, b"\x09")  # J7's RX-64 now at ID 9
    code, _ = run("ping")
    assert code == armctl.EXIT_ROBOT
    err = capsys.readouterr().err
    assert "J7 (bus ID 7) does not answer" in err and "(armctl scan)" in err
    code, found = run("scan", "--ids", "0-12")
    assert code == armctl.EXIT_OK and found["missing"] == ["J7 (ID 7)"]
    nodes = found["nodes"]
    assert isinstance(nodes, list) and [n["id"] for n in nodes] == [1, 2, 3, 4, 5, 6, 9]
    assert nodes[-1]["model"] == 64 and nodes[-1]["joint"] is None
    assert run("scan", "--ids", "20-30")[0] == armctl.EXIT_ROBOT
    assert run("scan", "--ids", "9-x")[0] == armctl.EXIT_USAGE


def test_an_output_file_that_cannot_be_written_is_refused_before_the_arm_goes_limp(
        arm: Arm, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``waypoints record`` turned the torque off, recorded, then failed to save (exit 1,
    '[Errno 2] …'): the recording lost, the arm limp."""
    arm.torque(True, hold=True)
    t0 = arm.transport.now()
    missing = tmp_path / "no-such-dir" / "path.jsonl"
    assert run("waypoints", "record", str(missing), "--seconds", "2")[0] == armctl.EXIT_USAGE
    assert f"no directory {missing.parent}" in capsys.readouterr().err
    assert arm.transport.now() - t0 < 0.5 and run("status")[1]["torque"] == [True] * 7
    assert run("record", str(tmp_path), "--seconds", "1")[0] == armctl.EXIT_USAGE
    assert "is a directory" in capsys.readouterr().err
    assert run("waypoints", "play", str(tmp_path / "none.jsonl"))[0] == armctl.EXIT_USAGE
    assert "armctl waypoints record" in capsys.readouterr().err


@pytest.mark.slow
def test_moveto_takes_a_tolerance_and_refuses_a_timeout_that_is_not_positive(
        arm: Arm, capsys: pytest.CaptureFixture[str]) -> None:
    assert run("move", "--unhomed", "--joints", *["0"] * 7, "--timeout", "-1")[0] == \
        armctl.EXIT_USAGE
    assert run("torque", "on")[0] == armctl.EXIT_OK and run("home")[0] == armctl.EXIT_OK
    assert run("moveto", "0.25", "-0.08", "-0.52", "--timeout", "0")[0] == armctl.EXIT_USAGE
    capsys.readouterr()
    code, result = run("moveto", "0.25", "-0.08", "-0.52", "--tolerance", "0.001",
                       "--timeout", "0.1")
    assert code == armctl.EXIT_NOT_SETTLED and result["reached"] is False
    assert "(--tolerance 0.001 mm)" in capsys.readouterr().err
    code, result = run("moveto", "0.25", "-0.08", "-0.52", "--tolerance", "50")
    assert code == armctl.EXIT_OK and result["reached"] is True
    assert isinstance(result["position_error_m"], float) and result["position_error_m"] < 0.05


@pytest.mark.parametrize("stop", [KeyboardInterrupt, TransportError])
def test_waypoints_recorded_before_ctrl_c_or_a_lost_link_are_saved(
        arm: Arm, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str], stop: type[BaseException]) -> None:
    """They lived in memory until the end: Ctrl-C or the emulator killed mid-recording lost
    them all."""
    from host.arm.waypoints import load_waypoints

    opened = Arm.open

    def open_failing_later(url: str, **options: object) -> Arm:
        recording = opened(url, **options)  # type: ignore[arg-type]

        def tap(state: object) -> None:
            if recording.cycles > 60:
                raise stop("the port is gone")

        recording.state_taps.append(tap)
        return recording

    monkeypatch.setattr(armctl.Arm, "open", open_failing_later)
    path = tmp_path / "path.jsonl"
    code = armctl.main(["--port", URL, "waypoints", "record", str(path), "--seconds", "5"],
                       out=io.StringIO())
    assert code == (130 if stop is KeyboardInterrupt else armctl.EXIT_ROBOT)
    assert "were saved to" in capsys.readouterr().err
    assert load_waypoints(path)[0].t == 0.0
    # an MCAP recording cut short is a finished file, and armctl says where it is
    mcap = tmp_path / "arm.mcap"
    assert armctl.main(["--port", URL, "record", str(mcap), "--seconds", "5"],
                       out=io.StringIO()) == code
    assert f"what was recorded before this is in {mcap}" in capsys.readouterr().err
    from mcap.reader import make_reader

    with mcap.open("rb") as stream:
        assert sum(1 for _ in make_reader(stream).iter_messages()) > 60


def test_joint_angles_take_every_form_python_reads(arm: Arm) -> None:
    """``--joints 0 -1e-3 …`` was "unrecognized arguments": argparse took -1e-3 for an
    option."""
    assert run("torque", "on")[0] == armctl.EXIT_OK
    code, state = run("move", "--unhomed", "--timeout", "20", "--joints",
                      "0", "-1e-3", "0", "-2E-2", "0", "-.05", "0")
    assert code == armctl.EXIT_OK, state


@pytest.mark.parametrize("argv", [
    ("moveto", "nan", "0", "-0.5"), ("moveto", "0.2", "0", "-0.5", "--rpy", "0", "-inf", "0"),
    ("move", "--joints", "0,0,0,0,0,0,0", "--duration", "-1e-3"),
    ("move", "--joints", "0,0,0,0,0,0,0", "--duration", "nan")])
def test_non_finite_or_negative_numbers_are_a_bad_command_line(
        arm: Arm, capsys: pytest.CaptureFixture[str], argv: tuple[str, ...]) -> None:
    assert run(*argv)[0] == armctl.EXIT_USAGE
    err = capsys.readouterr().err
    assert "Traceback" not in err and "error: argument" in err


def test_a_file_that_holds_no_waypoints_says_so(arm: Arm, tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    assert run("torque", "on")[0] == armctl.EXIT_OK
    capsys.readouterr()
    assert run("waypoints", "play", "/dev/null", "--unhomed")[0] == armctl.EXIT_USAGE
    assert capsys.readouterr().err.strip() == "armctl: error: /dev/null holds no waypoints"
    assert run("waypoints", "play", str(tmp_path), "--unhomed")[0] == armctl.EXIT_USAGE
    assert "is a directory, not a waypoint file" in capsys.readouterr().err


def test_a_stalled_joint_is_held_and_clear_says_so(arm: Arm) -> None:
    """With the factory alarm_shutdown a STALLED node stops and holds its joint, torque on:
    the forearm does not fall, and clear leaves it held."""
    plant = arm_plant_of(emulator_of(arm))
    arm.torque(True, hold=True)
    plant.push(3, -25.0)
    arm.cycle([arm.make_position(3, arm.state().joints[3] + 0.6)])
    arm.transport.sleep(2.0)
    state = arm.state()
    assert state.steppers[3].stalled and arm.torque_enabled() == (True,) * 7
    plant.push(3, 0.0)
    arm.transport.sleep(0.5)
    held = arm.state().joints[3]
    code, status = run("clear")
    assert code == armctl.EXIT_OK and "J4" in status["latched"]
    arm.transport.sleep(1.0)
    assert abs(arm.state().joints[3] - held) < 0.03  # cleared: still where it stopped
