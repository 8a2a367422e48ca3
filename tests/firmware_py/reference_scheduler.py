"""The scheduler as it was before periodic timers shared queue entries: every timer its own
heap entry, re-pushed with a fresh sequence number each time it runs.

:class:`ReferenceScheduler` is what ``test_scheduler`` compares the real one with;
:func:`run_due` is its event loop, which ``benchmarks/profile_emulator.py`` also runs on the
real :class:`~firmware_py.scheduler.Scheduler`'s queue (same order) to time each callback.
"""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Callable
from typing import Any

from firmware_py.scheduler import TimerHandle


def run_due(sched: Any, t_us: int,
            call: Callable[[Callable[[], None]], None] | None = None) -> int:
    """Run every event of ``sched``'s heap (``_queue`` of ``(t, seq, event)``, ``_seq``,
    ``now``: µs) due by ``t_us``, each through ``call`` if given; then time is ``t_us``.
    Returns the number of callbacks run."""
    queue = sched._queue
    ran = 0
    while queue and queue[0][0] <= t_us:
        when, _, ev = heapq.heappop(queue)
        cb = ev.callback
        if cb is None:
            continue
        sched.now = when
        if ev.period_us:
            ev.t_us = when + ev.period_us
            ev.seq = next(sched._seq)
            heapq.heappush(queue, (ev.t_us, ev.seq, ev))
        else:
            ev.callback = None
        if call is None:
            cb()
        else:
            call(cb)
        ran += 1
    sched.now = max(sched.now, t_us)
    return ran


class ReferenceScheduler:
    """One heap entry per timer (the order the shared entries must reproduce)."""

    def __init__(self) -> None:
        self.now = 0
        self._queue: list[tuple[int, int, TimerHandle]] = []
        self._seq = itertools.count()

    def now_us(self) -> int:
        return self.now

    def call_at(self, t_us: int, callback: Callable[[], None]) -> TimerHandle:
        t = max(int(t_us), self.now)
        ev = TimerHandle(t, next(self._seq), callback)
        heapq.heappush(self._queue, (t, ev.seq, ev))
        return ev

    def call_later(self, delay_us: int, callback: Callable[[], None]) -> TimerHandle:
        return self.call_at(self.now + max(0, int(delay_us)), callback)

    def call_every(self, period_us: int, callback: Callable[[], None],
                   first_us: int | None = None) -> TimerHandle:
        delay = period_us if first_us is None else first_us
        ev = TimerHandle(self.now + max(0, int(delay)), next(self._seq), callback, period_us)
        heapq.heappush(self._queue, (ev.t_us, ev.seq, ev))
        return ev

    def run_until(self, t_us: int) -> int:
        return run_due(self, t_us)
