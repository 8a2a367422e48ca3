"""Ctrl-C at many moments of a move that starts from a loaded pose (the full configuration
in process, simulation clock), judged on the plant's ground truth: nothing latches, the
torque stays on, and the arm is held within 2° of where it was.

The moves start with the shoulder raised and the elbow bent (the elbow's spring carries
three quarters of its stall limit there) and go down: a hold that stopped the motors
abruptly while the links swung ahead of them (0.1-0.4 s into the move) wound the elbow's
spring past the limit, and its node latched STALLED.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from hil_emulator.inprocess import forget_shared_emulators
from host.arm import Arm
from protocol.control_tables import StepperFlag
from tests.ground_truth import arm_joints, emulator_of

#: The loaded pose the moves start from, and where they go.
LOADED = [0.0, 0.625, 0.0, 0.71, 0.0, -0.05, 0.0]
LOWER = [0.0, 0.3, 0.0, 0.4, 0.0, 0.0, 0.0]
TWO_DEGREES = math.radians(2.0)
LATCHES = int(StepperFlag.SLIP | StepperFlag.STALLED)


def interrupt_moves(cycles: list[int]) -> list[str]:
    """For each count in ``cycles``: move to :data:`LOADED` and let it settle, start the
    6 s move to :data:`LOWER`, raise KeyboardInterrupt after that many of its cycles (as
    Ctrl-C does, the move's cycles every 10 ms), hold, and watch the plant for 2 s.  The
    problems found, one line each (empty: all held)."""
    forget_shared_emulators()
    problems: list[str] = []
    with Arm.open("emu://full/arm?name=interrupt-moments") as arm:
        emulator = emulator_of(arm)
        nodes = [emulator.arm.app(i) for i in range(1, 8)]
        arm.torque(True, hold=True)
        arm.home()  # as armctl moves: homed
        for count in cycles:
            arm.move(LOADED, duration=3.0)
            seen: list[np.ndarray] = []

            def ctrl_c(_state: object, count: int = count,
                       seen: list[np.ndarray] = seen) -> None:
                seen.append(arm_joints(arm))
                if len(seen) == count:
                    raise KeyboardInterrupt

            arm.state_taps.append(ctrl_c)
            try:
                with pytest.raises(KeyboardInterrupt):
                    arm.move(LOWER, duration=6.0)
            finally:
                arm.state_taps.remove(ctrl_c)
            arm.hold()
            at = seen[-1]
            worst = 0.0
            for step in range(200):
                emulator.step(10_000)
                if step >= 100:  # from 1 s on: held there
                    worst = max(worst, float(np.max(np.abs(arm_joints(arm) - at))))
            where = f"Ctrl-C after {count} cycles"
            if worst > TWO_DEGREES:
                problems.append(f"{where}: a joint {math.degrees(worst):.2f}° from where it was")
            for k, node in enumerate(nodes):
                if not node.get("torque_enable"):
                    problems.append(f"{where}: J{k + 1} torque off")
                if k < 4 and node.get("status_flags") & LATCHES:
                    problems.append(f"{where}: J{k + 1} latched "
                                    f"{StepperFlag(node.get('status_flags') & LATCHES)!r}")
            if problems:
                break  # a latch stays: the rest would only repeat it
    forget_shared_emulators()
    return problems


def test_ctrl_c_early_in_a_move_from_a_loaded_pose_latches_nothing() -> None:
    """Two moments that latched the elbow (0.25 and 0.3 s into the move, its link swinging
    ahead of its motor): the first with the start ramped but the hold at the motor's
    present angle, the second with the hold at its stopping point but no ramp."""
    assert interrupt_moves([25, 29]) == []


@pytest.mark.slow
def test_ctrl_c_at_any_moment_of_the_first_half_second_holds_the_arm() -> None:
    """Every fourth cycle of the move's first 0.45 s, where the links still swing about
    their motors after the start."""
    assert interrupt_moves(list(range(5, 46, 4))) == []


def test_a_hold_leaves_a_loaded_wrist_where_it_is() -> None:
    """An RX-64 under load sits off its goal by the error its compliance needs for that
    torque: a hold at its present angle let it give way by that much (J6 about 1°); the hold
    at its setpoint (angle plus that error, from its load) keeps it there."""
    forget_shared_emulators()
    with Arm.open("emu://full/arm?ready=0&name=wrist-hold") as arm:
        emulator = emulator_of(arm)
        arm.torque(True, hold=True)
        arm.move(LOADED, duration=3.0)
        state = arm.state()
        assert abs(state.servos[1].load) > 0.1  # J6 carries the hand
        at = arm_joints(arm)
        arm.hold()
        emulator.step(1_000_000)
        assert abs(arm_joints(arm)[5] - at[5]) <= math.radians(0.3)
    forget_shared_emulators()
