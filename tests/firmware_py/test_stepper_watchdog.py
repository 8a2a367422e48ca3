"""The stepper node's command watchdog: a move with no instruction within
``watchdog_timeout`` stops and holds the motor, flags WATCHDOG, latches nothing."""

from __future__ import annotations

import pytest

from firmware_py.arm_stepper import StepperNodeApp
from firmware_py.scheduler import Scheduler
from firmware_py.sim.boards import make_arm_node
from firmware_py.sim.virtual_hal import VirtualHal
from protocol.control_tables import (
    STEPPER_FIRMWARE_VERSION,
    STEPPER_TABLE,
    STEPPER_WATCHDOG_DEFAULT_MS,
    STEPPER_WATCHDOG_FEED_FIRMWARE,
    STEPPER_WATCHDOG_FIRMWARE,
    StepperFlag,
    WatchdogFeed,
)
from protocol.dynamixel import make_ping, make_read, make_sync_write, make_write
from protocol.image import BoardType
from tests.firmware_py.dxl_bench import transact

#: Microsteps per joint count with the defaults: 6.00 x 200 x 10 / 10 000.
K = 600 * 200 * 10 / 1_000_000
SPEED = 1000  # counts/s
ACCEL = 20_000  # counts/s²: full speed within 50 ms
TIMEOUT_MS = 100


def write(sched: Scheduler, hal: VirtualHal, name: str, value: int) -> None:
    reg = STEPPER_TABLE[name]
    (ack,) = transact(sched, hal, make_write(2, reg.address, reg.encode(value)).encode(),
                      run_us=300)
    assert ack.error == 0


def fresh() -> tuple[Scheduler, VirtualHal, StepperNodeApp]:
    """Node 2 after power-up, replying at once; the encoder does not follow in these tests
    (thresholds out of reach)."""
    sched = Scheduler()
    hal, app = make_arm_node(sched, BoardType.ARM_STEPPER, 2)
    assert isinstance(app, StepperNodeApp)
    write(sched, hal, "return_delay_time", 0)
    write(sched, hal, "slip_threshold", 65535)
    write(sched, hal, "deflection_limit", 65535)
    return sched, hal, app


@pytest.fixture
def moving() -> tuple[Scheduler, VirtualHal, StepperNodeApp]:
    """Node 2 heading for a goal 5 s away at SPEED, watchdog at TIMEOUT_MS."""
    sched, hal, app = fresh()
    write(sched, hal, "velocity_limit", SPEED)
    write(sched, hal, "acceleration_limit", ACCEL)
    write(sched, hal, "watchdog_timeout", TIMEOUT_MS)
    write(sched, hal, "torque_enable", 1)
    write(sched, hal, "goal_position", 5 * SPEED)
    return sched, hal, app


def flags(app: StepperNodeApp) -> StepperFlag:
    """The node's status flags, looked at without an instruction (which would feed it)."""
    return StepperFlag(app.get("status_flags"))


def test_the_register_and_the_version():
    reg = STEPPER_TABLE["watchdog_timeout"]
    assert (reg.address, reg.size, reg.area, reg.default) == (98, 2, "RAM",
                                                             STEPPER_WATCHDOG_DEFAULT_MS)
    assert STEPPER_WATCHDOG_DEFAULT_MS > 0  # on from power-up
    assert STEPPER_WATCHDOG_FIRMWARE == 4 <= STEPPER_FIRMWARE_VERSION
    assert int(StepperFlag.WATCHDOG) == 0x20


def test_a_silent_host_mid_move_stops_the_motor_where_braking_ends(moving):
    sched, hal, app = moving
    stepper = hal.stepper()
    sched.run_for(TIMEOUT_MS * 1000 - 5_000)  # 95 ms after the goal: still going
    assert stepper.rate == pytest.approx(SPEED * K)
    assert not flags(app) & StepperFlag.WATCHDOG
    hal.encoder().value = -40  # the joint lags the motor (a load): that stays in the spring
    sched.run_for(10_000)
    assert flags(app) & StepperFlag.WATCHDOG
    assert 0 < stepper.rate < SPEED * K  # braking at the acceleration limit
    sched.run_for(SPEED * 1_000_000 // ACCEL + 20_000)
    assert stepper.rate == 0.0
    motor = stepper.step_count() / K
    # held where braking from the timeout ended (v²/2a on: what accelerating cost at the
    # start), not at the joint's angle
    assert motor == pytest.approx(SPEED * TIMEOUT_MS / 1000, abs=5)
    assert app.get("goal_position") == pytest.approx(motor, abs=1)
    assert app.get("command_goal") == pytest.approx(motor * 16, abs=16)
    # nothing latched: no alarm, torque and holding current on, only WATCHDOG (and not MOVING)
    f = flags(app)
    assert f & StepperFlag.WATCHDOG
    assert not f & (StepperFlag.SLIP | StepperFlag.STALLED | StepperFlag.MOVING
                    | StepperFlag.HARDWARE_ERROR)
    assert app.get("cycle_status_flags") == int(f)
    assert app.get("torque_enable") == 1 and stepper.current == 2000
    sched.run_for(1_000_000)
    assert stepper.step_count() / K == pytest.approx(motor)  # and it stays there
    (reply,) = transact(sched, hal, make_read(2, 26, 1).encode(), run_us=300)
    assert reply.error == 0 and reply.params[0] & StepperFlag.WATCHDOG


def test_a_new_goal_clears_the_flag_and_moves_again(moving):
    sched, hal, app = moving
    sched.run_for(500_000)
    assert flags(app) & StepperFlag.WATCHDOG and hal.stepper().rate == 0.0
    write(sched, hal, "goal_position", 5 * SPEED)
    sched.run_for(50_000)
    assert not flags(app) & StepperFlag.WATCHDOG
    assert hal.stepper().rate > 0


@pytest.mark.parametrize("keep_alive", ["ping", "read", "sync_write"])
def test_any_instruction_to_the_node_keeps_the_move_going(moving, keep_alive):
    sched, hal, app = moving
    packet = {"ping": make_ping(2), "read": make_read(2, 32, 4),
              "sync_write": make_sync_write(62, 2, {2: (65535).to_bytes(2, "little")})}
    for _ in range(20):  # 1 s of keep-alives every 50 ms (half the timeout)
        transact(sched, hal, packet[keep_alive].encode(), run_us=50_000)
    assert not flags(app) & StepperFlag.WATCHDOG
    assert hal.stepper().rate == pytest.approx(SPEED * K)


def test_instructions_for_other_nodes_do_not_keep_it_going(moving):
    sched, hal, app = moving
    other = make_sync_write(62, 2, {3: (65535).to_bytes(2, "little")})
    for _ in range(6):
        transact(sched, hal, other.encode(), run_us=50_000)
        transact(sched, hal, make_ping(3).encode(), run_us=1_000)
    assert flags(app) & StepperFlag.WATCHDOG


def test_zero_turns_it_off(moving):
    sched, hal, app = moving
    write(sched, hal, "watchdog_timeout", 0)
    sched.run_for(1_000_000)
    assert not flags(app) & StepperFlag.WATCHDOG
    assert hal.stepper().rate == pytest.approx(SPEED * K)


def test_a_node_at_rest_is_left_alone():
    sched, hal, app = fresh()
    write(sched, hal, "watchdog_timeout", TIMEOUT_MS)
    write(sched, hal, "torque_enable", 1)
    write(sched, hal, "goal_position", 50)  # reached within about 0.2 s, the host polling
    for _ in range(10):
        transact(sched, hal, make_ping(2).encode(), run_us=50_000)
    sched.run_for(2_000_000)  # then silent, at rest
    assert not flags(app) & StepperFlag.WATCHDOG
    assert app.get("goal_position") == 50
    assert hal.stepper().step_count() == round(50 * K)
    assert hal.stepper().current == 2000


def test_the_default_stops_a_move_after_half_a_second():
    sched, hal, app = fresh()
    write(sched, hal, "velocity_limit", SPEED)
    write(sched, hal, "torque_enable", 1)
    write(sched, hal, "goal_position", 5 * SPEED)
    sched.run_for(STEPPER_WATCHDOG_DEFAULT_MS * 1000 - 5_000)
    assert not flags(app) & StepperFlag.WATCHDOG
    sched.run_for(10_000)
    assert flags(app) & StepperFlag.WATCHDOG


@pytest.mark.parametrize("timeout_ms", range(90, 111))
def test_once_stopped_the_motor_stays_still(timeout_ms):
    """The stop point goes to a whole microstep: one half a microstep from two left the step
    generator dithering about it (J2's 2 microsteps per count)."""
    sched, hal, app = fresh()
    write(sched, hal, "gear_reduction_x100", 1000)
    write(sched, hal, "velocity_limit", 397)
    write(sched, hal, "watchdog_timeout", timeout_ms)
    write(sched, hal, "torque_enable", 1)
    write(sched, hal, "goal_position", 4000)
    sched.run_for(timeout_ms * 1000 + 200_000)  # the timeout, then braking at 5000 counts/s²
    assert flags(app) & StepperFlag.WATCHDOG
    rates = []
    for _ in range(300):
        sched.run_for(1_000)
        rates.append(hal.stepper().rate)
    assert not any(rates)


def test_goals_only_reads_do_not_keep_the_move_going(moving):
    """``watchdog_feed`` 1 (a host streaming goals): another program's READs, PINGs and
    non-goal writes do not feed it; the move stops as if nothing came."""
    sched, hal, app = moving
    write(sched, hal, "watchdog_feed", int(WatchdogFeed.GOALS_ONLY))
    for _ in range(6):  # 0.3 s of a monitor's traffic every 50 ms
        transact(sched, hal, make_read(2, 76, 13).encode(), run_us=25_000)
        transact(sched, hal, make_ping(2).encode(), run_us=25_000)
    assert flags(app) & StepperFlag.WATCHDOG
    sched.run_for(SPEED * 1_000_000 // ACCEL + 20_000)
    assert hal.stepper().rate == 0.0


@pytest.mark.parametrize("feed", ["goal", "keep_alive"])
def test_goals_only_goal_and_keep_alive_writes_keep_it_going(moving, feed):
    sched, hal, app = moving
    write(sched, hal, "watchdog_feed", int(WatchdogFeed.GOALS_ONLY))
    for _ in range(20):  # 1 s, every 50 ms
        if feed == "goal":
            write(sched, hal, "goal_position", 5 * SPEED)
        else:
            write(sched, hal, "keep_alive", 1)
        sched.run_for(50_000)
    assert not flags(app) & StepperFlag.WATCHDOG
    assert hal.stepper().rate == pytest.approx(SPEED * K)
    assert app.get("keep_alive") == 0


def test_the_feed_register_and_the_version():
    reg = STEPPER_TABLE["watchdog_feed"]
    assert (reg.address, reg.size, reg.area, reg.default) == (102, 1, "RAM", 0)
    assert STEPPER_TABLE["keep_alive"].address == 103
    assert STEPPER_WATCHDOG_FEED_FIRMWARE == 6 <= STEPPER_FIRMWARE_VERSION


def _blocked_move(sched: Scheduler, hal: VirtualHal, *, fresh_goals: bool) -> StepperFlag:
    """Node 2 stepping at SPEED on a joint that does not follow (the encoder held: a stale
    coupling winding the element), a reader polling every 20 ms so the default feed keeps
    it going, ``fresh_goals`` a host re-sending the goal with each poll; flags after 1 s."""
    write(sched, hal, "deflection_limit", 150)
    write(sched, hal, "velocity_limit", 200)  # 2 s to the goal
    write(sched, hal, "watchdog_timeout", TIMEOUT_MS)
    write(sched, hal, "torque_enable", 1)
    write(sched, hal, "goal_position", 400)
    for _ in range(50):
        if fresh_goals:  # (the reply's error byte says OVERLOAD once STALLED latched)
            goal = STEPPER_TABLE["goal_position"]
            transact(sched, hal, make_write(2, goal.address, goal.encode(400)).encode(),
                     run_us=300)
        transact(sched, hal, make_read(2, 76, 13).encode(), run_us=20_000)
    return StepperFlag(hal_app_flags(sched, hal))


def hal_app_flags(sched: Scheduler, hal: VirtualHal) -> int:
    (reply,) = transact(sched, hal, make_read(2, STEPPER_TABLE["status_flags"].address,
                                              1).encode(), run_us=300)
    return int(reply.params[0])


def test_stale_goals_winding_the_element_hold_instead_of_latching():
    """Whatever feeds the watchdog: stepping on goals older than its timeout into an element
    wound towards ``deflection_limit`` stops and holds (WATCHDOG) before STALLED would
    latch, the element short of the limit."""
    sched, hal, app = fresh()
    f = _blocked_move(sched, hal, fresh_goals=False)
    assert f & StepperFlag.WATCHDOG and not f & (StepperFlag.STALLED | StepperFlag.SLIP)
    assert hal.stepper().rate == 0.0 and app.get("torque_enable") == 1
    assert abs(app.deflection()) < 150


def test_fresh_goals_into_a_stall_still_latch():
    """A live host sending goals into a blocked joint: STALLED latches as it always did."""
    sched, hal, app = fresh()
    f = _blocked_move(sched, hal, fresh_goals=True)
    assert f & StepperFlag.STALLED
