"""A deterministic discrete-event scheduler: the one simulation clock firmware runs on.

Time is an integer number of microseconds.  Events at the same time run in the order they
were scheduled, so a run is repeatable.  The emulator owns one scheduler for the whole
robot; tests make one per firmware under test.
"""

from __future__ import annotations

import heapq
import itertools
import sys
from collections.abc import Callable
from typing import Final

Callback = Callable[[], None]


class TimerHandle:
    """A scheduled callback; :meth:`cancel` stops it (idempotent).

    It is also the scheduler's event: the heap holds ``(t_us, seq, handle)`` tuples,
    compared in C, so scheduling allocates one object besides the tuple.
    """

    __slots__ = ("callback", "period_us", "seq", "t_us")

    def __init__(self, t_us: int, seq: int, callback: Callback | None, period_us: int = 0
                 ) -> None:
        self.t_us = t_us
        self.seq = seq
        self.callback = callback
        self.period_us = period_us

    def cancel(self) -> None:
        """Never call the callback again."""
        self.callback = None

    @property
    def active(self) -> bool:
        """True until cancelled (or, for a one-shot, until it has run)."""
        return self.callback is not None

    @property
    def due_us(self) -> int:
        """When it fires next (µs)."""
        return self.t_us


#: "No bound" on the callbacks :meth:`Scheduler.run_some` may run.
_UNBOUNDED: Final = sys.maxsize


class Scheduler:
    """Discrete-event scheduler with integer-microsecond time."""

    def __init__(self, start_us: int = 0) -> None:
        self._now = start_us
        self._queue: list[tuple[int, int, TimerHandle]] = []
        self._seq = itertools.count()

    def now_us(self) -> int:
        """Current simulation time (µs)."""
        return self._now

    def call_at(self, t_us: int, callback: Callback) -> TimerHandle:
        """Run ``callback`` at time ``t_us`` (µs; not earlier than now)."""
        t = int(t_us)
        if t < self._now:
            t = self._now
        seq = next(self._seq)
        ev = TimerHandle(t, seq, callback)
        heapq.heappush(self._queue, (t, seq, ev))
        return ev

    def call_later(self, delay_us: int, callback: Callback) -> TimerHandle:
        """Run ``callback`` once, ``delay_us`` µs from now."""
        delay = int(delay_us)
        return self.call_at(self._now + delay if delay > 0 else self._now, callback)

    def call_every(self, period_us: int, callback: Callback, first_us: int | None = None
                   ) -> TimerHandle:
        """Run ``callback`` every ``period_us`` µs, first after ``first_us`` (default: one period)."""
        if period_us <= 0:
            raise ValueError("period must be positive")
        delay = period_us if first_us is None else first_us
        ev = TimerHandle(self._now + max(0, int(delay)), next(self._seq), callback,
                         int(period_us))
        heapq.heappush(self._queue, (ev.t_us, ev.seq, ev))
        return ev

    def next_due_us(self) -> int | None:
        """Time of the next pending event, or None."""
        while self._queue and self._queue[0][2].callback is None:
            heapq.heappop(self._queue)
        return self._queue[0][0] if self._queue else None

    def run_until(self, t_us: int) -> int:
        """Run every event due up to and including ``t_us``; then time is ``t_us``.

        Returns the number of callbacks run.
        """
        return self.run_some(t_us, _UNBOUNDED)

    def run_some(self, t_us: int, max_events: int) -> int:
        """Run events due up to and including ``t_us``, at most ``max_events`` callbacks.

        Time becomes ``t_us`` only when every event due by then has run; otherwise it stays
        at the last event run, and a later call carries on from there.  A real-time runner
        uses it to look at its ports and its stop flag during a long catch-up.  Returns the
        number of callbacks run (``max_events`` means there may be more).
        """
        ran = 0
        queue = self._queue
        pop, replace, seq = heapq.heappop, heapq.heapreplace, self._seq
        while ran < max_events and queue:
            when, _, ev = queue[0]
            if when > t_us:
                break
            cb = ev.callback
            if cb is None:
                pop(queue)
                continue
            self._now = when
            period = ev.period_us
            if period:
                # Pop and re-push in one sift (the order popped is that of (t, seq) alone).
                t = ev.t_us = when + period
                s = ev.seq = next(seq)
                replace(queue, (t, s, ev))
            else:
                pop(queue)
                ev.callback = None
            cb()
            ran += 1
        if ran < max_events and t_us > self._now:
            self._now = t_us
        return ran

    def run_for(self, duration_us: int) -> int:
        """Run for ``duration_us`` µs of simulation time."""
        return self.run_until(self._now + int(duration_us))
