"""The fmcb's control tick sleeps while nothing it reads changes, and the robot cannot tell.

A sleeping tick returns at once; a hall edge (the pin-change interrupt), a change of the
phalange-bus current (the current sense's comparator) or any frame for the fmcb wakes it at
its next tick.  The properties compare a sleeping fmcb with one that never sleeps under the
same random script of hall edges, loads and commands: motors, efforts, counts and status
bytes stay identical.
"""

from __future__ import annotations

import sys
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_py.fmcb import VELOCITY_WINDOW
from protocol.robot import HALL_SEQUENCE

sys.path.insert(0, str(Path(__file__).parent))
from test_fmcb import Rig  # noqa: E402


def settled(rig: Rig) -> None:
    """Long enough for the velocity window to fill with one count: the tick sleeps."""
    rig.run_ms(VELOCITY_WINDOW + 3)


def test_a_holding_fmcb_sleeps_and_a_hall_edge_wakes_it() -> None:
    rig = Rig()
    rig.send("fmcb.control", {"mode": 1, "args": {"hall_target": [40, 0, 0]}})
    settled(rig)
    assert rig.app.asleep and rig.duties()[0] > 0
    rig.step_hall(0, 1)  # one edge, then 1 ms: the tick counted it
    assert not rig.app.asleep
    assert rig.ask("fmcb.hall_counts", {"raw": 1})["counts"] == [1, 0, 0]
    settled(rig)
    assert rig.app.asleep


def test_a_command_and_a_load_change_wake_it() -> None:
    rig = Rig()
    settled(rig)
    assert rig.app.asleep
    rig.send("fmcb.control", {"mode": 1, "args": {"hall_target": [-30, 0, 0]}}, run_ms=1.5)
    assert rig.duties()[0] < 0  # the woken tick drove towards the new target
    rig.send("fmcb.phalange_power", {"on": 1})
    settled(rig)
    assert rig.app.asleep
    rig.hal.power("phalange").load_ma = 400  # over the breaker's limit: it must time it
    rig.run_ms(1)
    assert not rig.app.asleep
    rig.run_ms(20)
    assert rig.hal.power("phalange").state == 0  # tripped, as without sleeping


def test_an_invalid_hall_state_keeps_it_awake() -> None:
    rig = Rig()
    rig.hal.motors[1].hall = 0  # impossible: counted as invalid every tick
    settled(rig)
    assert not rig.app.asleep
    assert rig.app.hall[1].invalid == VELOCITY_WINDOW + 3


def observe(rig: Rig) -> tuple[object, ...]:
    app = rig.app
    return (rig.duties(), [m.enabled for m in rig.hal.motors], list(app.effort),
            [h.count for h in app.hall], [h.invalid for h in app.hall], app.velocity,
            list(app.hall_target), app.pb_current, app.breaker_tripped,
            rig.hal.power("phalange").state, rig.status_bytes())


ACTIONS = st.one_of(
    st.tuples(st.just("hall"), st.integers(0, 2), st.sampled_from([-1, 1, 2])),
    st.tuples(st.just("load"), st.sampled_from([0, 100, 150, 400])),
    st.tuples(st.just("control"), st.lists(st.integers(-60, 60), min_size=3, max_size=3)),
    st.tuples(st.just("idle")),
    st.tuples(st.just("cap"), st.integers(0, 255)),
    st.tuples(st.just("phalange"), st.integers(0, 1)),
    st.tuples(st.just("wait"), st.integers(1, 30)),
)


def act(rig: Rig, action: tuple[object, ...]) -> None:
    kind = action[0]
    if kind == "hall":
        _, motor, step = action
        m = rig.hal.motors[int(motor)]  # type: ignore[call-overload]
        m.hall = HALL_SEQUENCE[(HALL_SEQUENCE.index(m.hall) + int(step)) % 6]  # type: ignore[call-overload]
        rig.run_ms(1)
    elif kind == "load":
        rig.hal.power("phalange").load_ma = int(action[1])  # type: ignore[call-overload]
        rig.run_ms(1)
    elif kind == "control":
        rig.send("fmcb.control", {"mode": 1, "args": {"hall_target": action[1]}})
    elif kind == "idle":
        rig.send("fmcb.control", {"mode": 0, "args": {}})
    elif kind == "cap":
        rig.send("fmcb.effort_cap", {"cap": action[1]})
    elif kind == "phalange":
        rig.send("fmcb.phalange_power", {"on": action[1]})
    else:
        rig.run_ms(int(action[1]))  # type: ignore[call-overload]


@settings(max_examples=40, deadline=None)
@given(st.lists(ACTIONS, min_size=1, max_size=25))
def test_sleeping_changes_nothing_the_robot_does(actions: list[tuple[object, ...]]) -> None:
    sleeper, awake = Rig(), Rig()
    awake.app._can_sleep = False  # a board without the interrupts: it polls every tick
    for action in actions:
        act(sleeper, action)
        act(awake, action)
        assert observe(sleeper) == observe(awake), action
        assert not awake.app.asleep
    settled(sleeper)
    settled(awake)
    app = sleeper.app
    if app._over_since is None and all(h.holds() for h in app.hall):  # nothing to do
        assert app.asleep
    assert observe(sleeper) == observe(awake)
