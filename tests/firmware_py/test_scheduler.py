"""The scheduler: periodic timers of one period and phase share a queue entry, and the
order of events is exactly that of one entry per timer.

The reference (``reference_scheduler.py``) is the scheduler as it was before timers shared entries: every timer
its own heap entry, re-pushed with a fresh sequence number each time it runs.  Random
programs of periodic timers (mostly in phase), one-shots landing on the ticks, cancels and
timers created from inside callbacks run on both and must log the same calls at the same
times.
"""

from __future__ import annotations

import itertools
import random
from collections.abc import Callable
from functools import partial
from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_py.scheduler import Scheduler, TimerHandle
from tests.firmware_py.reference_scheduler import ReferenceScheduler

PERIOD = 1_000


def run_program(sched: Any, seed: int, actors: int, horizon_us: int) -> list[tuple[str, int]]:
    """Start ``actors`` periodic timers (mostly in phase) whose callbacks, drawing from one
    seeded generator in the order they run, log themselves and schedule, start or cancel
    more; the log of (name, time)."""
    rng = random.Random(seed)
    log: list[tuple[str, int]] = []
    timers: list[TimerHandle] = []
    names = itertools.count()

    def make(name: str) -> Callable[[], None]:
        def callback() -> None:
            now = sched.now_us()
            log.append((name, now))
            roll = rng.random()
            if roll < 0.15:  # a one-shot exactly on a coming tick, or now
                delay = rng.choice([0, PERIOD, 2 * PERIOD, PERIOD - now % PERIOD])
                sched.call_later(delay, make(f"once{next(names)}"))
            elif roll < 0.22:  # a new periodic timer, in phase or not
                first = rng.choice([PERIOD, 0, 2 * PERIOD, 250, PERIOD - now % PERIOD])
                period = rng.choice([PERIOD, PERIOD, 2 * PERIOD])
                timers.append(sched.call_every(period, make(f"tick{next(names)}"), first))
            elif roll < 0.27 and timers:
                rng.choice(timers).cancel()
        return callback

    for _ in range(actors):
        first = rng.choice([PERIOD, PERIOD, 0, 500, 2 * PERIOD])
        timers.append(sched.call_every(PERIOD, make(f"tick{next(names)}"), first))
        if rng.random() < 0.3:
            sched.call_at(rng.choice([PERIOD, 2 * PERIOD, 1500]), make(f"once{next(names)}"))
    step = rng.choice([PERIOD, 333, 2 * PERIOD + 1])
    t = 0
    while t < horizon_us:
        t += step
        sched.run_until(t)
    return log


@settings(max_examples=150, deadline=None)
@given(st.integers(0, 2**32), st.integers(1, 8))
def test_shared_entries_keep_the_order_of_one_entry_per_timer(seed: int, actors: int) -> None:
    expected = run_program(ReferenceScheduler(), seed, actors, 12_000)
    assert run_program(Scheduler(), seed, actors, 12_000) == expected


def test_ticks_in_phase_share_one_queue_entry() -> None:
    sched = Scheduler()
    seen: list[str] = []
    ticks = [sched.call_every(PERIOD, partial(seen.append, f"t{k}")) for k in range(5)]
    sched.call_every(PERIOD, lambda: seen.append("off"), first_us=PERIOD // 2)
    assert len(sched._queue) == 2  # five ticks behind one entry, the one out of phase
    sched.run_until(2 * PERIOD)
    assert seen == ["off", "t0", "t1", "t2", "t3", "t4"] * 2
    ticks[1].cancel()
    assert ticks[2].due_us == 3 * PERIOD
    sched.run_until(3 * PERIOD)
    assert seen[-4:] == ["t0", "t2", "t3", "t4"]


def test_an_event_scheduled_between_two_ticks_runs_between_them() -> None:
    sched = Scheduler()
    seen: list[str] = []

    def first() -> None:
        seen.append(f"a@{sched.now_us()}")
        if sched.now_us() == PERIOD:  # lands on the next tick, after a's turn, before b's
            sched.call_later(PERIOD, lambda: seen.append(f"x@{sched.now_us()}"))

    sched.call_every(PERIOD, first)
    sched.call_every(PERIOD, lambda: seen.append(f"b@{sched.now_us()}"))
    sched.run_until(2 * PERIOD)
    assert seen == ["a@1000", "b@1000", "a@2000", "x@2000", "b@2000"]


def test_a_tick_started_just_before_the_group_fires_runs_first_from_then_on() -> None:
    sched = Scheduler()
    seen: list[str] = []

    def start_b() -> None:
        sched.call_every(PERIOD, lambda: seen.append("b"))

    # At 1000, before a's turn: the new tick b is due at 2000, with an older sequence number
    # than the one a takes when it runs at 1000.
    sched.call_at(PERIOD, start_b)
    sched.call_every(PERIOD, lambda: seen.append("a"))
    sched.run_until(3 * PERIOD)
    assert seen == ["a", "b", "a", "b", "a"]
    assert len(sched._queue) == 1


def test_times_given_as_floats_are_taken_in_whole_microseconds() -> None:
    """``run_for(2e3)`` and friends, as pure Python always took them (the compiled core's
    signatures say ``float``): the clock stays a whole number of µs."""
    sched = Scheduler()
    ran: list[int] = []
    sched.call_at(1500.7, lambda: ran.append(sched.now_us()))
    sched.call_later(2000.2, lambda: ran.append(sched.now_us()))
    timer = sched.call_every(1000.0, lambda: ran.append(sched.now_us()), first_us=2500.0)
    assert sched.run_for(2e3) == 2
    assert sched.now_us() == 2000 and type(sched.now_us()) is int
    sched.run_until(3000.9)
    timer.cancel()
    assert ran == [1500, 2000, 2500]
    assert sched.now_us() == 3000 and type(sched.now_us()) is int


def test_a_one_shot_timer_is_complete_however_it_was_made() -> None:
    """From source call_at and call_later make their timers without __init__: every slot
    is set as the constructor sets it, and the timer runs, reports and cancels alike."""
    sched = Scheduler()
    ran: list[str] = []
    at = sched.call_at(30, lambda: ran.append("at"))
    later = sched.call_later(20, lambda: ran.append("later"))
    gone = sched.call_later(10, lambda: ran.append("gone"))
    for handle, due in ((at, 30), (later, 20), (gone, 10)):
        assert (handle.t_us, handle.period_us, handle.due_us, handle.active) == (due, 0, due, True)
    assert later.seq == at.seq + 1 and gone.seq == later.seq + 1
    gone.cancel()
    sched.run_for(100)
    assert ran == ["later", "at"] and not at.active and not later.active
