"""armctl and handctl as a user meets safe motion: what is refused (exit 2, the joint named,
nothing moved), and Ctrl-C or SIGTERM mid-motion (exit 130, one line saying what was held,
the robot held).  In-process emulators (simulation clock); the pty test at the end runs
``hil-emulator`` and ``armctl`` as separate processes and interrupts armctl with SIGINT."""

from __future__ import annotations

import io
import json
import math
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from host.arm.facade import Arm
from tests.ground_truth import arm_joints
from tests.hil_emulator.emulator_process import (
    HANG_GUARD_S,
    ROOT,
    ask,
    running_emulator,
    wait_simulated,
)
from tools.cli import armctl
from tools.cli import common as cli_common

URL = "emu://arm/arm?name=test_armctl_safe_motion"


def run(*argv: str) -> int:
    return armctl.main(["--port", URL, *argv], out=io.StringIO())


@pytest.mark.parametrize(("argv", "message"), [
    (("moveto", "nan", "0", "-0.5"), "argument X: nan: give a position (m)"),
    (("moveto", "inf", "0", "-0.5"), "argument X: inf: give a position (m)"),
    (("moveto", "0.25", "-0.08", "-0.52", "--rpy", "nan", "0", "0"),
     "argument --rpy: nan: give an angle (rad)"),
    (("moveto", "0.25", "-0.08", "-0.52", "--rpy", "1e300", "0", "0"),
     "roll 1e+300 rad is not an orientation angle"),
    (("moveto", "0", "1e300", "0"), "is out of reach"),
    (("move", "--joints", "0,0,0,0,0,0,0", "--duration", "inf"),
     "argument --duration: inf: give a time (s) > 0"),
    (("move", "--joints", "0,0,0,0,0,0,0", "--duration", "2", "--speed", "0.3"),
     "give --duration or --speed, not both"),
    (("move", "--joints", "0,0,0,0,0,0,0", "--speed", "0"),
     "argument --speed: 0: give a speed (rad/s) > 0"),
    (("move", "--unhomed", "--joints", "0", "-4", "0", "0", "0", "0", "0"),
     "J2 goal -4.000 rad is 4.00 rad from where the joint is"),
    (("move", "--unhomed", "--joints", "0", "nan", "0", "0", "0", "0", "0"),
     "J2 goal nan is not a finite number"),
])
def test_non_finite_and_unreachable_goals_are_refused_without_a_traceback(
        arm: Arm, capsys: pytest.CaptureFixture[str], argv: tuple[str, ...],
        message: str) -> None:
    """These gave ValueError / LinAlgError tracebacks (exit 1), drove the flange to a
    meaningless orientation, or drove J2 into its stop."""
    assert run("torque", "on") == armctl.EXIT_OK
    before = arm_joints(arm)
    capsys.readouterr()
    assert run(*argv) == armctl.EXIT_USAGE
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    arm.transport.sleep(0.5)
    assert np.max(np.abs(arm_joints(arm) - before)) < math.radians(0.5)


def _write(path: Path, *points: tuple[float, list[float]]) -> str:
    path.write_text("".join(json.dumps({"t": t, "joints": q}) + "\n" for t, q in points))
    return str(path)


def test_waypoints_beyond_a_range_or_a_joints_speed_are_refused_before_anything_moves(
        arm: Arm, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    """J2 at 3.5 rad was sent (J2-J4 latched OVERLOAD, the arm fell) and a 2.5 rad jump
    within 1 ms 'played', exit 0."""
    assert run("torque", "on") == armctl.EXIT_OK and run("home") == armctl.EXIT_OK
    arm.transport.sleep(1.0)
    beyond = _write(tmp_path / "beyond.jsonl", (0.0, [0.0] * 7),
                    (3.0, [0.0, 3.5, 0.0, 0.0, 0.0, 0.0, 0.0]))
    jump = _write(tmp_path / "jump.jsonl", (0.0, [0.0] * 7), (0.001, [2.5] * 7))
    brisk = _write(tmp_path / "brisk.jsonl", (0.0, [0.0] * 7),
                   (0.5, [0.0, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0]), (1.0, [0.0] * 7))
    before = arm_joints(arm)
    capsys.readouterr()
    assert run("waypoints", "play", beyond) == armctl.EXIT_USAGE
    assert "J2 goal (waypoint 2) +3.500 rad is outside the joint's range -0.35 … +2.80 rad" \
        in capsys.readouterr().err
    assert run("waypoints", "play", jump) == armctl.EXIT_USAGE
    assert re.search(r"J\d from waypoint 1 to waypoint 2 needs \d+\.\d+ rad/s; its speed "
                     r"limit", capsys.readouterr().err)
    assert run("waypoints", "play", brisk) == armctl.EXIT_USAGE
    err = capsys.readouterr().err
    assert "J2 at waypoint 2 needs" in err and "--time-scale) of 1.2 or more" in err
    arm.transport.sleep(0.5)
    assert np.max(np.abs(arm_joints(arm) - before)) < math.radians(0.5)
    assert run("waypoints", "play", brisk, "--time-scale", "1.3") == armctl.EXIT_OK


def _signal_when(arm: Arm, joint: int, beyond: float, signum: int) -> threading.Thread:
    """A thread sending ``signum`` to this process once the plant's ``joint`` passed
    ``beyond`` rad (mid-move, whatever the machine's speed)."""
    def watch() -> None:
        deadline = time.monotonic() + HANG_GUARD_S
        while time.monotonic() < deadline:
            if arm_joints(arm)[joint] > beyond:
                os.kill(os.getpid(), signum)
                return
            time.sleep(0.002)

    thread = threading.Thread(target=watch, daemon=True)
    thread.start()
    return thread


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_mid_move_holds_the_arm_and_exits_130_saying_what_was_held(
        arm: Arm, capsys: pytest.CaptureFixture[str], signum: int) -> None:
    """Ctrl-C sent nothing: the arm drove on to the goal, J3 latched, the arm fell; SIGTERM
    (a service manager, `kill`) killed armctl the same way."""
    assert run("torque", "on") == armctl.EXIT_OK
    capsys.readouterr()
    watcher = _signal_when(arm, 1, 0.3, signum)
    code = run("move", "--unhomed", "--joints", "0", "1.5", "0", "1.5", "0", "0.2", "0",
               "--duration", "6")
    watcher.join()
    at = arm_joints(arm)
    assert code == cli_common.EXIT_INTERRUPTED
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert err.startswith("armctl: interrupted; the arm: held where they were, torque on: "
                          "J1 ")
    worst = 0.0
    for _ in range(20):
        arm.transport.sleep(0.1)
        worst = max(worst, float(np.max(np.abs(arm_joints(arm) - at))))
    state = arm.state()
    assert worst <= math.radians(2.0)
    assert arm.torque_enabled() == (True,) * 7
    assert state.errors == {} and not any(s.slip or s.stalled for s in state.steppers)


def test_a_second_signal_does_not_cut_the_hold_short() -> None:
    """Only the first SIGINT/SIGTERM within the block raises; later ones wait."""
    with pytest.raises(KeyboardInterrupt), cli_common.interrupts_as_ctrl_c():
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(1.0)  # the handler runs here
        finally:
            os.kill(os.getpid(), signal.SIGINT)  # as if pressed again during the hold
            time.sleep(0.05)
    assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL


# ----------------------------------------------------------------------------- over ptys


def _truth_over_control(info: dict[str, object]) -> dict[str, Any]:
    return dict(ask(info, "truth")["arm"])


@pytest.mark.slow
def test_ctrl_c_of_armctl_over_a_pty_holds_the_arm_where_it_was() -> None:
    """As a user would: ``hil-emulator --config arm`` and ``armctl move`` in their own
    processes, Ctrl-C (SIGINT) to armctl mid-move; judged on the emulator's ground truth."""
    with running_emulator("--config", "arm") as info:
        port = str(info["arm"])
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        cli = [sys.executable, "-m", "tools.cli.armctl", "--port", port]
        torque = subprocess.run([*cli, "torque", "on"], env=env, cwd=ROOT, capture_output=True,
                                text=True, timeout=HANG_GUARD_S)
        assert torque.returncode == 0, torque.stderr
        move = subprocess.Popen([*cli, "move", "--unhomed", "--joints", "0", "1.5", "0", "1.5",
                                 "0", "0.2", "0", "--duration", "6", "--timeout", "20"],
                                env=env, cwd=ROOT, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + HANG_GUARD_S
            while _truth_over_control(info)["joints"][1] < 0.3:
                assert time.monotonic() < deadline and move.poll() is None
                time.sleep(0.02)
            move.send_signal(signal.SIGINT)
            _, err = move.communicate(timeout=HANG_GUARD_S)
        finally:
            if move.poll() is None:
                move.kill()
        at = np.array(_truth_over_control(info)["joints"])
        assert move.returncode == 130, err
        assert err.strip().startswith("armctl: interrupted; the arm: held where they were, "
                                      "torque on: J1 "), err
        wait_simulated(info, 2.0)
        truth = _truth_over_control(info)
        moved = np.abs(np.array(truth["joints"]) - at)
        assert float(moved.max()) <= math.radians(2.0), moved
        nodes = truth["nodes"]
        assert all(n["torque_enable"] == 1 and n["alarms"] == 0
                   for n in nodes.values()), nodes
