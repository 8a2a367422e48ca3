"""A host that vanishes mid-move leaves a held arm: the stepper nodes' command watchdog, as
the host library sets it, on the full configuration in process (simulation clock), judged
on the plant's ground truth."""

from __future__ import annotations

import math
from typing import TypedDict

import numpy as np
import pytest

from hil_emulator.inprocess import EmulatorTransport
from host.arm.facade import HOST_WATCHDOG_MS, MOVE_MIN_SPEED, SERVO_GOAL_LEAD_S, Arm, servo_lead
from protocol.control_tables import (
    GOAL_FINE_PER_COUNT,
    REST_DEFLECTION_UNKNOWN,
    StepperFlag,
    WatchdogFeed,
)
from protocol.dynamixel import rx64_position_to_radians
from protocol.robot import (
    STEPPER_SETTLE_MAX_BACK_COUNTS,
    STEPPER_SETTLE_MAX_CHANGE_COUNTS,
    microsteps_per_encoder_count,
)
from tests.ground_truth import arm_plant_of, arm_rig_of, emulator_of

GOALS = [0.0, 1.5, 0.0, 1.5, 0.0, 0.2, 0.0]  # the 6 s move of armctl's example
DURATION_S = 6.0
FALL_LIMIT = math.radians(2.0)
#: Driving on: the watchdog's time at the move's speed, the braking, the elastic overshoot.
DRIVE_ON_LIMIT = math.radians(8.0)
#: A stepper joint at rest (rad/s).
REST_SPEED = 0.02
#: What the nodes' settling reaches in process (ms after the host's last cycle; measured
#: 0.6-1.5 s over 20 stop moments, docs/decisions/watchdog-default.md): the 0.5 s bound's
#: stand-in until the hold reaches it.
SETTLED_MS = 1_500


class VanishRun(TypedDict):
    """What :func:`vanish_mid_move` saw: the plant's angles when the host vanished and every
    ms after (rad), the steppers' speeds (rad/s), rates (microsteps/s) and goals (counts),
    their WATCHDOG flag each ms, their flags and torque at the end, slips, and the flags of
    J2's goal as the host last read them."""

    q0: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    rates: np.ndarray
    goals: np.ndarray
    stopped: np.ndarray
    flags: np.ndarray
    torque: np.ndarray
    slips: np.ndarray
    goal_flags: StepperFlag


def vanish_mid_move(watchdog_ms: int | None, after_s: float) -> VanishRun:
    """Open the arm (torque on, held), start the 6 s move as :meth:`Arm.move` runs it,
    stop cycling after ``after_s`` (the host killed), then watch the plant for 2 s."""
    with Arm.open(f"emu://full/arm?ready=0&name=watchdog-{watchdog_ms}-{after_s}",
                  watchdog_ms=watchdog_ms) as arm:
        emu = emulator_of(arm)
        state = arm.torque(True, hold=True)
        speeds = [max(abs(a - b) / DURATION_S, MOVE_MIN_SPEED)
                  for a, b in zip(GOALS, state.joints, strict=True)]
        clock = arm.transport
        start = clock.now()
        arm.set_positions(servo_lead(state.joints, GOALS, speeds, 0.0), speeds)
        end = start + after_s
        while clock.now() < end:
            clock.sleep(0.01)
            arm.set_positions(servo_lead(state.joints, GOALS, speeds, clock.now() - start))
        plant, rig = arm_plant_of(emu), arm_rig_of(emu)
        apps = [rig.app(i) for i in range(1, 5)]
        steppers = [hal.stepper() for hal in rig.stepper_hals]
        q0 = plant.joint_angles().copy()
        q, qd, rates, goals, stopped = [], [], [], [], []
        watchdog = int(StepperFlag.WATCHDOG)
        for _ in range(2000):  # 2 s, one sample a millisecond
            emu.step(1_000)
            q.append(plant.joint_angles().copy())
            qd.append(plant.joint_velocities()[:4].copy())
            rates.append([s.rate for s in steppers])
            goals.append([a.get("command_goal") / GOAL_FINE_PER_COUNT for a in apps])
            stopped.append([bool(a.get("status_flags") & watchdog) for a in apps])
        return {"q0": q0, "q": np.array(q), "qd": np.array(qd), "rates": np.array(rates),
                "goals": np.array(goals), "stopped": np.array(stopped),
                "flags": np.array([a.get("status_flags") for a in apps]),
                "torque": np.array([a.get("torque_enable") for a in apps]),
                "slips": plant.slips().copy(), "goal_flags": state.steppers[1].flags}


@pytest.mark.parametrize("after_s", [0.7, 1.5])
def test_a_host_killed_mid_move_leaves_the_arm_held(after_s):
    run = vanish_mid_move(HOST_WATCHDOG_MS, after_s)
    q0, q = run["q0"], run["q"]
    moving = np.sign(np.round(np.array(GOALS) - q0, 2))  # J2, J4 rise, J6 turns; the rest stay
    along = (q - q0) * np.where(moving == 0, 1, moving)
    # the motors stop within 0.5 s of the host's last cycle (braking, and the settling's
    # first corrections at the links' first turns) and stay stopped once settled
    still = ~np.any(run["rates"] != 0.0, axis=1)
    assert still[SETTLED_MS:].all()
    # no joint falls back more than 2° (nor, not moving, strays 2°); a stepper's driving on
    # is bounded; the RX-64s (no watchdog, as their real firmware) go on to the goal last
    # sent, which the move keeps a short lead ahead of their way: 2° at most
    for j in range(7):
        if moving[j] == 0:
            assert np.abs(q[:, j] - q0[j]).max() <= FALL_LIMIT, f"J{j + 1}"
            continue
        assert along[:, j].min() >= -FALL_LIMIT, f"J{j + 1}"
        limit = DRIVE_ON_LIMIT if j < 4 else FALL_LIMIT
        assert along[:, j].max() <= limit, f"J{j + 1}"
    # nothing latched, torque on; J2 and J4 (moving) say the watchdog stopped them
    latches = int(StepperFlag.SLIP | StepperFlag.STALLED)
    assert not any(int(f) & latches for f in run["flags"])
    assert run["torque"].all()
    assert not run["slips"].any()
    assert run["flags"][1] & StepperFlag.WATCHDOG and run["flags"][3] & StepperFlag.WATCHDOG


def _rest_ms(run: VanishRun) -> int:
    """Milliseconds after the host's last cycle from which every stepper joint stays below
    REST_SPEED (plant's truth)."""
    fast = np.nonzero((np.abs(run["qd"]) >= REST_SPEED).any(axis=1))[0]
    return 0 if fast.size == 0 else int(fast[-1]) + 1


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="the nodes' settling at the links' turns brings the "
                   "joints to rest 0.6-1.5 s after the host's last cycle, not 0.5 s: the "
                   "coupled J2/J4 modes and the elements' hysteresis leave a residual swing "
                   "(docs/decisions/watchdog-default.md)")
@pytest.mark.parametrize("after_s", [0.7, 1.5, 3.7])
def test_a_host_killed_mid_move_leaves_the_stepper_joints_at_rest_within_half_a_second(
        after_s):
    """The acceptance bound: every stepper joint below REST_SPEED (plant's truth) from 0.5 s
    after the host's last cycle on."""
    rest = _rest_ms(vanish_mid_move(HOST_WATCHDOG_MS, after_s))
    assert rest <= 500, f"moving until {rest} ms"


@pytest.mark.parametrize("after_s", [0.7, 1.5, 3.7])
def test_the_nodes_settle_the_joints_after_a_host_killed_mid_move(after_s):
    """The nodes' settling after the watchdog stop: every stepper joint below REST_SPEED
    within SETTLED_MS of the host's last cycle (the bare hold: 2.1-2.6 s at these moments)."""
    rest = _rest_ms(vanish_mid_move(HOST_WATCHDOG_MS, after_s))
    assert rest <= SETTLED_MS, f"moving until {rest} ms"


@pytest.mark.parametrize("after_s", [0.15, 0.4, 2.2, 5.6, 7.0])
def test_a_settling_correction_never_moves_a_motor_beyond_its_bound(after_s):
    """Whatever the moment (the move still accelerating, at speed, braking into its goal,
    or over): no node moves its goal further than STEPPER_SETTLE_MAX_CHANGE_COUNTS from the
    watchdog's hold, nor more than STEPPER_SETTLE_MAX_BACK_COUNTS back against the way it
    was going; nothing latches, no joint falls back more than 2°."""
    run = vanish_mid_move(HOST_WATCHDOG_MS, after_s)
    for node in range(4):
        stopped = np.nonzero(run["stopped"][:, node])[0]
        if stopped.size == 0:
            continue  # not moving when the host went: the watchdog leaves it alone
        hold = run["goals"][stopped[0], node]
        change = run["goals"][stopped[0]:, node] - hold
        # goals fall on whole microsteps, in 1/16 counts
        rounding = 0.5 / microsteps_per_encoder_count(node) + 1 / GOAL_FINE_PER_COUNT
        assert np.abs(change).max() <= STEPPER_SETTLE_MAX_CHANGE_COUNTS + rounding, f"J{node + 1}"
        way = np.sign(run["rates"][0, node])  # the motor's way when the host went
        if way:
            assert (change * way).min() >= -STEPPER_SETTLE_MAX_BACK_COUNTS - rounding, \
                f"J{node + 1}"
    latches = int(StepperFlag.SLIP | StepperFlag.STALLED)
    assert not any(int(f) & latches for f in run["flags"])
    assert run["torque"].all() and not run["slips"].any()
    ways = np.sign(run["rates"][0])
    back = (run["q0"][:4] - run["q"][:, :4]) * ways
    assert back.max() <= FALL_LIMIT  # the steppers that moved: none fell back


def test_a_move_sends_the_wrist_its_goal_only_a_short_lead_ahead():
    """:meth:`Arm.move` itself, the host gone after 0.3 s of the 6 s move: J6 (an RX-64, no
    watchdog) was sent a goal :data:`SERVO_GOAL_LEAD_S` of its 0.2 rad/s ahead of its way,
    not the move's end 0.2 rad away, so it stops within 2° of where the host left it."""

    class Vanished(BaseException):
        """The host killed between two cycles."""

    arm = Arm.open("emu://full/arm?ready=0&name=servo-lead")
    try:
        emu = emulator_of(arm)
        start = arm.torque(True, hold=True).joints[5]
        cycles: list[None] = []

        def vanish(_state: object) -> None:
            cycles.append(None)
            if len(cycles) == 30:
                raise Vanished

        arm.state_taps.append(vanish)
        with pytest.raises(Vanished):
            arm.move(GOALS, duration=DURATION_S)
        left = arm_plant_of(emu).joint_angles()[5]
        goal = rx64_position_to_radians(arm_rig_of(emu).app(6).get("goal_position"))
        assert 0.0 < goal - start <= MOVE_MIN_SPEED * (0.31 + SERVO_GOAL_LEAD_S) + 0.01
        emu.step(1_000_000)
        assert abs(arm_plant_of(emu).joint_angles()[5] - left) <= FALL_LIMIT
    finally:
        arm.close()


def test_without_the_watchdog_the_arm_drives_on():
    """The same with the watchdog off (a host that sets 0): the arm drives on towards the
    goal with the route-coupling offsets stale - what the watchdog is for."""
    run = vanish_mid_move(0, 1.5)
    assert (run["q"][-1, 1] - run["q0"][1]) > DRIVE_ON_LIMIT
    assert run["rates"][-1, 1] != 0.0


def test_an_idle_host_with_torque_on_is_not_disturbed():
    """Torque on, then nothing for 3 s (a program waiting for its user): a joint at rest is
    left alone - no WATCHDOG, no motion - and a move afterwards runs as usual."""
    with Arm.open("emu://arm/arm?name=watchdog-idle") as arm:
        emu = emulator_of(arm)
        before = arm.torque(True, hold=True)
        emu.step(3_000_000)
        state = arm.state()
        assert not any(s.watchdog for s in state.steppers)
        assert np.allclose(state.joints, before.joints, atol=math.radians(0.2))
        goals = list(state.joints)
        goals[1] += 0.3
        state, settled = arm.move(goals, duration=1.5)
        assert settled and not any(s.watchdog for s in state.steppers)


def test_a_late_host_that_sent_its_goal_once_is_resumed_by_the_next_cycle():
    """A host that sends a goal once and then only reads (homing's search does) and is late
    once by more than the watchdog's timeout: the node stops and holds, and the cycle after
    the one that saw WATCHDOG sends this arm's goal again, so the move goes on."""
    with Arm.open("emu://arm/arm?name=watchdog-late") as arm:
        emu = emulator_of(arm)
        state = arm.torque(True, hold=True)
        goal = state.joints[1] + 0.4
        arm.cycle([arm.make_position(1, goal, 0.2)])  # 2 s at 0.2 rad/s
        for _ in range(50):
            arm.transport.sleep(0.01)
            state = arm.cycle()
        emu.step(300_000)  # the host late by 0.3 s: the node stops
        state = arm.cycle()
        assert state.steppers[1].watchdog and not state.steppers[1].moving
        stopped_at = state.steppers[1].motor_angle
        for _ in range(300):
            arm.transport.sleep(0.01)
            state = arm.cycle()
        assert not state.steppers[1].watchdog
        assert state.steppers[1].motor_angle == pytest.approx(goal, abs=0.01)
        assert state.steppers[1].motor_angle > stopped_at + 0.1


def test_a_program_that_only_reads_leaves_the_stop_to_be_seen():
    """After the host vanished, another program that only reads (armctl status) sees
    WATCHDOG and changes nothing: only goals this arm sent are sent again."""
    with Arm.open("emu://arm/arm?name=watchdog-reader") as arm:
        emu = emulator_of(arm)
        state = arm.torque(True, hold=True)
        arm.cycle([arm.make_position(1, state.joints[1] + 0.4, 0.2)])
        emu.step(500_000)  # gone mid-move
    with Arm.on(EmulatorTransport(emu, "arm")) as reader:
        for _ in range(5):
            state = reader.state()
            assert state.steppers[1].watchdog


def test_after_a_hold_the_nodes_hold_without_settling():
    """A host that holds the arm mid-move (Ctrl-C) and then exits: the hold leaves the
    motors at rest where they stop (its second write from how they turn then), or, at some
    moments, a node finishing the count or two it overshot that by, which its watchdog
    stops there (2-3 of 10 moments of the 6 s move): no settling move either way.  A node
    still finishing a short way when the host goes quiet (a program's last short goal) is
    stopped by the watchdog and holds there as before - no settling move (it is for a move
    cut short; after a hold it moved the joints on and, through the ptys, latched J4)."""

    class Interrupted(BaseException):
        """Ctrl-C between two cycles."""

    arm = Arm.open("emu://full/arm?ready=0&name=hold-no-settle")
    try:
        emu = emulator_of(arm)
        arm.torque(True, hold=True)
        start = arm.transport.now()

        def interrupt(_state: object) -> None:
            if arm.transport.now() - start >= 1.15:
                raise Interrupted

        arm.state_taps.append(interrupt)
        with pytest.raises(Interrupted):
            arm.move(GOALS, duration=DURATION_S)
        arm.state_taps.clear()
        arm.hold()
        apps = [arm_rig_of(emu).app(i) for i in range(1, 5)]
        watchdog = int(StepperFlag.WATCHDOG)
        hold = [app.get("command_goal") / GOAL_FINE_PER_COUNT for app in apps]
        for _ in range(500):
            emu.step(1_000)
            # no settling move (it may move a motor 40 counts): each node's goal stays the
            # hold's, or where its watchdog stopped its last count or two
            now = [app.get("command_goal") / GOAL_FINE_PER_COUNT for app in apps]
            assert np.abs(np.subtract(now, hold)).max() <= 3
        # a short way (20 counts at 0.05 rad/s, 0.25 s) left to go when the host goes quiet
        state = arm.state()
        arm.cycle([arm.make_position(s.joint, s.motor_angle + 0.0126, 0.05)
                   for s in state.steppers])
        held: dict[int, float] = {}
        for _ in range(2000):
            emu.step(1_000)
            for node, app in enumerate(apps):
                goal = app.get("command_goal") / GOAL_FINE_PER_COUNT
                if app.get("status_flags") & watchdog:
                    assert held.setdefault(node, goal) == goal, f"J{node + 1} moved on"
        assert held, "the watchdog did not stop a node finishing a short way"
        latches = int(StepperFlag.SLIP | StepperFlag.STALLED)
        assert not any(app.get("status_flags") & latches for app in apps)
    finally:
        arm.close()


def test_a_homed_arm_tells_the_stepper_nodes_the_deflection_that_holds_them_at_rest():
    """With every goal a homed arm writes each stepper node's ``rest_deflection`` from its
    model (gravity, the hand, the routes' coupling): at rest it is what the node's own
    deflection reads there, within a few counts; an arm not homed (angles from power-up)
    leaves it "not given", and the node identifies it from the swing as before."""
    with Arm.open("emu://full/arm?ready=0&name=rest-model") as arm:
        emu = emulator_of(arm)
        apps = [arm_rig_of(emu).app(i) for i in range(1, 5)]
        arm.torque(True, hold=True)
        goals = list(arm.state().joints)
        goals[1] += 0.2
        arm.move(goals, duration=1.0)
        assert all(a.get("rest_deflection") == REST_DEFLECTION_UNKNOWN for a in apps)
        arm.home()
        state, settled = arm.move(GOALS, duration=4.0)
        assert settled
        state = arm.set_positions(GOALS)
        for node, app in enumerate(apps):
            told = app.get("rest_deflection")
            assert told != REST_DEFLECTION_UNKNOWN
            assert abs(told - state.steppers[node].deflection) <= 3, f"J{node + 1}"


def test_an_arm_feeds_the_watchdog_with_its_goals_only_and_gives_the_feed_back():
    """At open the arm sets the steppers' ``watchdog_feed`` to goals only; a loop that sends
    a goal once and then only cycles keeps its joint going (the cycles' keep-alives), while
    another program's reads alone do not (the host gone, the node stops); a clean close
    gives back the default it found, and a second session that found goals only keeps it."""
    feed = WatchdogFeed.GOALS_ONLY
    arm = Arm.open("emu://arm/arm?name=watchdog-feed")
    emu = emulator_of(arm)
    apps = [arm_rig_of(emu).app(i) for i in range(1, 5)]
    try:
        assert [a.get("watchdog_feed") for a in apps] == [feed] * 4
        state = arm.torque(True, hold=True)
        arm.cycle([arm.make_position(1, state.joints[1] + 0.4, 0.2)])  # 2 s at 0.2 rad/s
        for _ in range(50):  # 0.5 s of cycles without goals: keep-alives
            arm.transport.sleep(0.01)
            state = arm.cycle()
        assert not state.steppers[1].watchdog and state.steppers[1].moving
        with Arm.on(EmulatorTransport(emu, "arm")) as reader:  # found goals only
            for _ in range(30):  # the first host silent; another program only reads
                reader.transport.sleep(0.01)
                state = reader.cycle()
            assert state.steppers[1].watchdog and not state.steppers[1].moving
        assert [a.get("watchdog_feed") for a in apps] == [feed] * 4  # as it found them
    finally:
        arm.close()
    emu.step(1_000)  # the close's write on the wire
    assert [a.get("watchdog_feed") for a in apps] == [WatchdogFeed.ANY_INSTRUCTION] * 4
