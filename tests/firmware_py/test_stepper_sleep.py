"""The stepper node's control tick sleeps at rest, and the robot cannot tell.

A sleeping tick returns at once; an encoder count change, a temperature or supply change
(the HAL's interrupts), a host write or an index pulse wakes it at its next tick.  The
property compares a sleeping node with one that never sleeps under the same random script
of joint motion, sensor changes, goals, torque and watchdog settings: the register image,
the step generator and the step count stay identical.
"""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_py.arm_stepper import VELOCITY_WINDOW, StepperNodeApp
from firmware_py.scheduler import Scheduler
from firmware_py.sim.boards import make_arm_node
from firmware_py.sim.virtual_hal import VirtualHal
from protocol.control_tables import STEPPER_TABLE
from protocol.dynamixel import make_write
from protocol.image import BoardType
from tests.firmware_py.dxl_bench import transact


class Rig:
    """One stepper node (bus ID 2) on its own scheduler."""

    def __init__(self) -> None:
        self.sched = Scheduler()
        hal, app = make_arm_node(self.sched, BoardType.ARM_STEPPER, 2)
        assert isinstance(app, StepperNodeApp) and isinstance(hal, VirtualHal)
        self.hal, self.app = hal, app
        self.write("return_delay_time", 0)

    def write(self, name: str, value: int) -> None:
        reg = STEPPER_TABLE[name]
        transact(self.sched, self.hal, make_write(2, reg.address, reg.encode(value)).encode(),
                 run_us=600)

    def run_ms(self, ms: int) -> None:
        self.sched.run_for(ms * 1_000)

    def observe(self) -> tuple[object, ...]:
        stepper = self.hal.stepper()
        return (bytes(self.app.image), stepper.rate, stepper.current, stepper.step_count(),
                self.app._quiet_ticks)


def settled(rig: Rig) -> None:
    """Long enough for the velocity window to fill with one count."""
    rig.run_ms(VELOCITY_WINDOW + 3)


def test_a_node_at_rest_sleeps_and_the_encoder_wakes_it() -> None:
    rig = Rig()
    settled(rig)
    assert rig.app.asleep
    rig.hal.encoder().set_count(7)  # the plant moves the joint
    assert not rig.app.asleep
    rig.run_ms(1)
    assert rig.app.get("present_position") == 7
    settled(rig)
    assert rig.app.asleep
    rig.hal.sensors.set_temperature(900)  # over the limit: the alarm shows at the next tick
    rig.run_ms(1)
    assert rig.app.get("hardware_error_status")


def test_a_goal_wakes_it_and_it_sleeps_again_at_the_goal() -> None:
    rig = Rig()
    rig.write("torque_enable", 1)
    settled(rig)
    assert rig.app.asleep
    rig.write("goal_position", 20)
    assert not rig.app.asleep
    rig.run_ms(2)
    assert rig.app.get("status_flags") & 1  # MOVING
    rig.run_ms(300)
    assert rig.app.asleep
    assert round(rig.app.motor_position()) == 20


ACTIONS = st.one_of(
    st.tuples(st.just("enc"), st.integers(-300, 300)),
    st.tuples(st.just("temp"), st.sampled_from([250, 415, 900])),
    st.tuples(st.just("supply"), st.sampled_from([12000, 24000])),
    st.tuples(st.just("goal"), st.integers(-80, 80)),
    st.tuples(st.just("torque"), st.integers(0, 1)),
    st.tuples(st.just("watchdog"), st.sampled_from([0, 5, 50])),
    st.tuples(st.just("index"),),
    st.tuples(st.just("wait"), st.integers(1, 40)),
)


def act(rig: Rig, action: tuple[str] | tuple[str, int]) -> None:
    kind = action[0]
    value = action[1] if len(action) == 2 else 0
    encoder = rig.hal.encoder()
    if kind == "enc":
        encoder.set_count(encoder.count() + value)
        rig.run_ms(1)
    elif kind == "temp":
        rig.hal.sensors.set_temperature(value)
        rig.run_ms(1)
    elif kind == "supply":
        rig.hal.sensors.set_supply_mv(value)
        rig.run_ms(1)
    elif kind == "goal":
        rig.write("goal_position", value)
    elif kind == "torque":
        rig.write("torque_enable", value)
    elif kind == "watchdog":
        rig.write("watchdog_timeout", value)
    elif kind == "index":
        encoder.pulse_index()
        rig.run_ms(1)
    else:
        rig.run_ms(value)


@settings(max_examples=40, deadline=None)
@given(st.lists(ACTIONS, min_size=1, max_size=25))
def test_sleeping_changes_nothing_the_node_does(
        actions: list[tuple[str] | tuple[str, int]]) -> None:
    sleeper, awake = Rig(), Rig()
    awake.app._can_sleep = False  # a board without the interrupts: it polls every tick
    for action in actions:
        act(sleeper, action)
        act(awake, action)
        assert sleeper.observe() == awake.observe(), action
        assert not awake.app.asleep
    settled(sleeper)
    settled(awake)
    assert sleeper.observe() == awake.observe()
