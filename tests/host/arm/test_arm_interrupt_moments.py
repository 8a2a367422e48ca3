"""Ctrl-C at many moments of a move that starts from a loaded pose (the full configuration
in process, simulation clock), judged on the plant's ground truth: nothing latches, the
torque stays on, and the arm is held within 2° of where it was.

The moves start with the shoulder raised and the elbow bent (the elbow's spring carries
three quarters of its stall limit there) and go down: a hold that stopped the motors
abruptly while the links swung ahead of them (0.1-0.4 s into the move) wound the elbow's
spring past the limit, and its node latched STALLED.

A Ctrl-C lands on a live host anywhere, also while a cycle's replies are on the line: the
hold written at once then collided with them on the half-duplex bus and was lost, the nodes
drove on through the hold's wait for the link's latency (100 ms on a serial port or a pty),
and the goals sent after it lay behind the motors: J2 or J4 drove back against its swinging
link and latched STALLED (through the ptys, a Ctrl-C 0.13 s into the move down).

The Ctrl-C tests share one homed arm (:class:`SharedArm`, brought up and homed once per
module): each moment starts by moving it to its start pose and letting it come to rest, so
a moment depends only on "a homed arm at rest there", as the moments of one test always
shared one arm; after a test that found a problem (a latch stays) the next gets a fresh one.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Iterator

import numpy as np
import pytest

from hil_emulator.inprocess import forget_shared_emulators
from host.arm.bus import SERIAL_LATENCY_S
from host.arm.facade import Arm
from protocol.control_tables import StepperFlag
from tests.ground_truth import arm_joints, arm_rig_of, arm_velocities, emulator_of

#: The loaded pose the moves start from, and where they go (the elbow at 0.81 rad: where a
#: motor goal of 0.71 left it before moves cancelled the routes' coupling, 0.18 of J2's).
LOADED = [0.0, 0.625, 0.0, 0.81, 0.0, -0.05, 0.0]
LOWER = [0.0, 0.3, 0.0, 0.4, 0.0, 0.0, 0.0]
TWO_DEGREES = math.radians(2.0)
LATCHES = int(StepperFlag.SLIP | StepperFlag.STALLED)


class SharedArm:
    """One homed arm on the full configuration (in process) for the tests of a module, and
    a fresh one after a test that left a problem behind."""

    def __init__(self) -> None:
        self._arm: Arm | None = None

    def get(self) -> Arm:
        """The homed arm (torque on, held), brought up and homed if there is none."""
        if self._arm is None:
            forget_shared_emulators()
            arm = Arm.open("emu://full/arm?name=interrupt-moments")
            forget_shared_emulators()
            try:
                arm.torque(True, hold=True)
                arm.home()  # as armctl moves: homed
            except BaseException:
                arm.close()
                raise
            self._arm = arm
        return self._arm

    def spoilt(self) -> None:
        """The arm met a problem (a latch stays): the next :meth:`get` brings up another."""
        self.close()

    def close(self) -> None:
        if self._arm is not None:
            self._arm.close()
            self._arm = None


@pytest.fixture(scope="module")
def shared_arm() -> Iterator[SharedArm]:
    shared = SharedArm()
    try:
        yield shared
    finally:
        shared.close()


def interrupt_moves(shared: SharedArm, cycles: list[int], *, start: list[float] = LOADED,
                    goal: list[float] = LOWER, in_exchange: bool = False,
                    first_write_lost: bool = False) -> list[str]:
    """For each count in ``cycles``, on the shared homed arm: move to ``start`` and let it
    settle, start the 6 s move to ``goal``, raise KeyboardInterrupt after that many of its cycles (as Ctrl-C
    does, the move's cycles every 10 ms; ``in_exchange``: inside that cycle's exchange,
    while the host waits for the nodes' replies, on a link with a serial port's latency),
    hold (``first_write_lost``: its first write, the one sent at once, never arrives), and
    watch the plant for 2 s.  The problems found, one line each (empty: all held)."""
    problems: list[str] = []
    arm = shared.get()
    emulator = emulator_of(arm)
    nodes = [arm_rig_of(emulator).app(i) for i in range(1, 8)]
    default_latency = arm.bus.latency_s
    if in_exchange or first_write_lost:
        arm.bus.latency_s = SERIAL_LATENCY_S
    try:
        transport = arm.transport
        real_recv = transport.recv
        for count in cycles:
            arm.move(start, duration=3.0)
            while np.max(np.abs(arm_velocities(arm)[:4])) >= 0.02:
                emulator.step(10_000)  # from rest
            seen: list[np.ndarray] = []
            first = arm.cycles

            def ctrl_c(_state: object, count: int = count,
                       seen: list[np.ndarray] = seen) -> None:
                seen.append(arm_joints(arm))
                if len(seen) == count and not in_exchange:
                    raise KeyboardInterrupt

            def ctrl_c_in_exchange(timeout: float | None = 0.0, count: int = count,
                                   first: int = first, seen: list[np.ndarray] = seen) -> bytes:
                if timeout and arm.cycles - first == count - 1 and len(seen) < count:
                    seen.append(arm_joints(arm))
                    raise KeyboardInterrupt  # the replies are on their way
                return real_recv(timeout)

            arm.state_taps.append(ctrl_c)
            if in_exchange:
                transport.recv = ctrl_c_in_exchange  # type: ignore[method-assign]
            try:
                with pytest.raises(KeyboardInterrupt):
                    arm.move(goal, duration=6.0)
            finally:
                arm.state_taps.remove(ctrl_c)
                transport.recv = real_recv  # type: ignore[method-assign]
            if first_write_lost:
                arm.send = lambda commands: None  # type: ignore[method-assign]  # this arm's write is lost
            try:
                arm.hold()
            finally:
                vars(arm).pop("send", None)  # the class's again
            at = seen[-1]
            worst = 0.0
            for step in range(200):
                emulator.step(10_000)
                if step >= 100:  # from 1 s on: held there
                    worst = max(worst, float(np.max(np.abs(arm_joints(arm) - at))))
            where = f"Ctrl-C after {count} cycles{' (within an exchange)' if in_exchange else ''}"
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
    except BaseException:
        shared.spoilt()  # left in the middle of a moment
        raise
    finally:
        arm.bus.latency_s = default_latency
    if problems:
        shared.spoilt()
    return problems


def test_ctrl_c_early_in_a_move_from_a_loaded_pose_latches_nothing(shared_arm: SharedArm) -> None:
    """Two moments that latched the elbow (0.25 and 0.3 s into the move, its link swinging
    ahead of its motor): the first with the start ramped but the hold at the motor's
    present angle, the second with the hold at its stopping point but no ramp."""
    assert interrupt_moves(shared_arm, [25, 29]) == []


@pytest.mark.slow
def test_ctrl_c_at_any_moment_of_the_first_half_second_holds_the_arm(shared_arm: SharedArm) -> None:
    """Every fourth cycle of the move's first 0.45 s, where the links still swing about
    their motors after the start."""
    assert interrupt_moves(shared_arm, list(range(5, 46, 4))) == []


def test_ctrl_c_while_the_replies_are_on_the_line_latches_nothing(shared_arm: SharedArm) -> None:
    """Two moments that latched (0.17 s into the move J4, 0.29 s J2, through the ptys'
    latency): the hold's first write collided with the interrupted cycle's replies, and
    its goals, sent 100 ms later, lay behind the motors."""
    assert interrupt_moves(shared_arm, [17, 29], in_exchange=True) == []


def test_a_hold_whose_first_write_is_lost_does_not_drive_the_motors_back(shared_arm: SharedArm) -> None:
    """The hold writes its goals again after reading the arm: from where each motor is
    and how fast it turns then, not the first write's goals (computed before the nodes
    drove on for the link's latency, they lay behind the motors: J4 latched STALLED).
    The joints drove on meanwhile, so only the latches are checked."""
    problems = interrupt_moves(shared_arm, [17, 29], first_write_lost=True)
    assert [p for p in problems if "from where it was" not in p] == []


@pytest.mark.slow
@pytest.mark.parametrize("direction", ["down", "up"])
def test_ctrl_c_within_any_exchange_of_the_first_moments_holds_the_arm(
        shared_arm: SharedArm, direction: str) -> None:
    """Every third cycle of the first 0.3 s (the speed ramp) of the move down from the
    loaded pose and of the move back up to it, the Ctrl-C inside the cycle's exchange."""
    start, goal = (LOADED, LOWER) if direction == "down" else (LOWER, LOADED)
    assert interrupt_moves(shared_arm, list(range(3, 31, 3)), start=start, goal=goal,
                           in_exchange=True) == []


def test_a_hold_leaves_a_loaded_wrist_where_it_is() -> None:
    """An RX-64 under load sits off its goal by the error its compliance needs for that
    torque: a hold at its present angle let it give way by that much (J6 about 1°); the hold
    at its setpoint (angle plus that error, from its load) keeps it there."""
    forget_shared_emulators()
    with Arm.open("emu://full/arm?ready=0&name=wrist-hold") as arm:
        emulator = emulator_of(arm)
        arm.torque(True, hold=True)
        arm.move(LOADED, duration=3.0)
        # J6 carries the hand: its load reads 0.12, flickering by a unit (0.03) either way
        # as the servo hunts by a position unit, so the median of a few cycles
        loads = [abs(arm.state().servos[1].load) for _ in range(9)]
        assert statistics.median(loads) > 0.1
        at = arm_joints(arm)
        arm.hold()
        emulator.step(1_000_000)
        assert abs(arm_joints(arm)[5] - at[5]) <= math.radians(0.3)
    forget_shared_emulators()
