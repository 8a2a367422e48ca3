"""A deterministic discrete-event scheduler: the one simulation clock firmware runs on.

Time is an integer number of microseconds.  Events at the same time run in the order they
were scheduled, so a run is repeatable.  The emulator owns one scheduler for the whole
robot; tests make one per firmware under test.

Periodic timers of the same period and phase (the robot's 1 kHz ticks: each node's control
loop and the plant's exchange, all started on whole milliseconds) share one entry in the
event queue, a :class:`_TickGroup` that runs them in turn.  Each still takes its own place
in the order of events: before running a member the group gives way to any event due at
the same time that was scheduled before that member's turn, exactly as if every member had
its own entry.
"""

from __future__ import annotations

import itertools
import sys
from collections.abc import Callable
from heapq import heappop, heappush, heapreplace  # by name: compiled, heapq.x is a lookup
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

#: Run from source (not the compiled core): there ``int()`` of what is already an int
#: costs more than a timer's other work, so :meth:`Scheduler.call_at` and
#: :meth:`Scheduler.call_later` skip it (compiled, a time is a C double: always converted),
#: and they make a one-shot timer with ``__new__`` and four stores, a third cheaper than
#: through ``__init__`` (compiled, the constructor is the cheaper).
_FROM_SOURCE: Final = __file__.endswith(".py")
_new_timer: Final = TimerHandle.__new__


class _TickGroup:
    """Periodic timers of one period and phase behind one queue entry.

    ``members`` are in the order they run, which is the order of their sequence numbers:
    a member's ``t_us`` and ``seq`` are what its own entry would hold.  During a firing at
    time t, the members before ``next_index`` have run (they are due at t + period) and
    the rest have not; a timer joining then for t + period goes in at ``next_index``, which
    is where its fresh sequence number puts it, and ``next_index`` moves past it.  Between
    firings (``next_index`` at the end) a timer due at the pending firing ``next_t`` goes
    last; one due a period after it goes before every member (they take fresh sequence
    numbers when they run at ``next_t``), after the others that joined so, and sits out the
    pending firing.  A member's callback is read at its turn, so replacing or cancelling it
    works as on a timer of its own.
    """

    __slots__ = ("ahead", "entry", "members", "next_index", "next_t", "period_us",
                 "scheduler")

    def __init__(self, scheduler: Scheduler, period_us: int, members: list[TimerHandle],
                 next_t: int, ahead: int) -> None:
        self.scheduler = scheduler
        self.period_us = period_us
        self.members = members
        #: Where a joining timer goes during a firing (between firings: the end).
        self.next_index = len(members)
        #: The pending firing (between firings) or the next one (during one) (µs).
        self.next_t = next_t
        #: Members in front that sit out the pending firing.
        self.ahead = ahead
        #: The group's queue entry, reused: it is out of the queue whenever it is pushed.
        self.entry = TimerHandle(next_t, 0, self.run)

    def run(self) -> None:
        """One firing (or the rest of one the group gave way in): each due member in turn."""
        sched = self.scheduler
        queue, seq = sched._queue, sched._seq
        t = sched.now
        period = self.period_us
        members = self.members
        n = len(members)
        i = self.next_index
        if i >= n:  # a new firing (not the rest of one)
            i = self.next_index = 0
            self.ahead = 0
            self.next_t = t + period
        next_t = t + period
        # The events that must run before a member are those due now and scheduled before
        # its turn: the queue's head (the earliest of them) is the one to look at, and it
        # stays so, as whatever a callback schedules comes after every member still to run
        # (their sequence numbers are older).
        first_seq = queue[0][1] if queue and queue[0][0] == t else _UNBOUNDED
        # ``i`` is the member's index; ``next_index`` is kept up to date whenever anything
        # else may run (a callback may join the group, which reads it and moves it on:
        # then ``n``, the number of members, is counted again).
        while i < n:
            m = members[i]
            cb = m.callback
            if cb is None:  # cancelled: leaves the group
                del members[i]
                n -= 1
                continue
            if m.t_us != t:  # joined for the next firing
                i += 1
                continue
            if first_seq < m.seq:
                # An event scheduled before this member's turn comes first.
                self.next_index = i
                self._push(t, m.seq)
                return
            m.t_us = next_t
            m.seq = next(seq)
            i += 1
            self.next_index = i
            cb()
            if self.next_index != i:  # a timer joined during the callback
                i = self.next_index
                n = len(members)
        self.next_index = n
        if n:
            # The entry's key: the first member due at the next firing (those ahead, which
            # joined during this one, sit it out), or, if none is, the first of them.
            first = members[self.ahead] if self.ahead < n else members[0]
            self._push(first.t_us, first.seq)
        else:
            sched._forget_group(self)

    def _push(self, t_us: int, seq: int) -> None:
        """Queue the group's entry (popped, so out of the queue: :meth:`run` is running)."""
        entry = self.entry
        entry.t_us, entry.seq, entry.callback = t_us, seq, self.run
        heappush(self.scheduler._queue, (t_us, seq, entry))

    def join(self, timer: TimerHandle) -> bool:
        """Add ``timer`` (its sequence number the newest) if the group can take it where
        its own entry would run; False if not (it then needs an entry of its own)."""
        members = self.members
        if self.next_index < len(members):  # during a firing
            if timer.t_us != self.next_t:
                return False
            members.insert(self.next_index, timer)
            self.next_index += 1
        elif timer.t_us == self.next_t:
            members.append(timer)
            self.next_index = len(members)
        elif timer.t_us == self.next_t + self.period_us:
            members.insert(self.ahead, timer)
            self.ahead += 1
            self.next_index = len(members)
        else:
            return False
        return True


class Scheduler:
    """Discrete-event scheduler with integer-microsecond time."""

    def __init__(self, start_us: int = 0) -> None:
        #: Current simulation time (µs), read-only: what :meth:`now_us` returns, read by
        #: the emulator's per-frame paths without the call.
        self.now = start_us
        self._queue: list[tuple[int, int, TimerHandle]] = []
        self._seq = itertools.count()
        #: Per (period, phase): the tick group, or the one periodic timer with its own entry.
        self._ticks: dict[tuple[int, int], _TickGroup | TimerHandle] = {}

    def now_us(self) -> int:
        """Current simulation time (µs)."""
        return self.now

    def call_at(self, t_us: float, callback: Callback) -> TimerHandle:
        """Run ``callback`` at time ``t_us`` (µs, whole µs taken; not earlier than now)."""
        t = t_us if _FROM_SOURCE and type(t_us) is int else int(t_us)
        if t < self.now:
            t = self.now
        seq = next(self._seq)
        if _FROM_SOURCE:  # TimerHandle(t, seq, callback), a third cheaper
            ev = _new_timer(TimerHandle)
            ev.t_us = t
            ev.seq = seq
            ev.callback = callback
            ev.period_us = 0
        else:
            ev = TimerHandle(t, seq, callback)
        heappush(self._queue, (t, seq, ev))
        return ev

    def call_later(self, delay_us: float, callback: Callback) -> TimerHandle:
        """Run ``callback`` once, ``delay_us`` µs from now."""
        # call_at(now + delay), written out: the firmware's timers come this way.
        delay = delay_us if _FROM_SOURCE and type(delay_us) is int else int(delay_us)
        t = self.now + delay if delay > 0 else self.now
        seq = next(self._seq)
        if _FROM_SOURCE:  # TimerHandle(t, seq, callback), a third cheaper
            ev = _new_timer(TimerHandle)
            ev.t_us = t
            ev.seq = seq
            ev.callback = callback
            ev.period_us = 0
        else:
            ev = TimerHandle(t, seq, callback)
        heappush(self._queue, (t, seq, ev))
        return ev

    def call_every(self, period_us: float, callback: Callback, first_us: float | None = None
                   ) -> TimerHandle:
        """Run ``callback`` every ``period_us`` µs, first after ``first_us`` (default: one period)."""
        if period_us <= 0:
            raise ValueError("period must be positive")
        delay = period_us if first_us is None else first_us
        period = int(period_us)
        ev = TimerHandle(self.now + max(0, int(delay)), next(self._seq), callback, period)
        key = (period, ev.t_us % period)
        shared = self._ticks.get(key)
        if isinstance(shared, _TickGroup):
            if shared.join(ev):
                return ev
        elif shared is not None and shared.callback is not None and self._group(key, shared, ev):
            return ev
        else:
            self._ticks[key] = ev
        heappush(self._queue, (ev.t_us, ev.seq, ev))
        return ev

    def _group(self, key: tuple[int, int], lone: TimerHandle, ev: TimerHandle) -> bool:
        """Put ``lone`` (a periodic timer with its own queue entry) and ``ev`` behind one
        group entry, which takes ``lone``'s place in the queue, if ``ev`` is due when
        ``lone`` is (it runs after it) or a period later (before it: ``lone`` takes a
        fresh sequence number when it runs first)."""
        period = lone.period_us
        if ev.t_us == lone.t_us:
            group = _TickGroup(self, period, [lone, ev], lone.t_us, 0)
        elif ev.t_us == lone.t_us + period:
            group = _TickGroup(self, period, [ev, lone], lone.t_us, 1)
        else:
            return False
        queue = self._queue
        for i, queued in enumerate(queue):
            if queued[2] is lone:
                # Same (t, seq) key: the heap stays ordered.
                entry = group.entry
                entry.t_us, entry.seq = lone.t_us, lone.seq
                queue[i] = (lone.t_us, lone.seq, entry)
                self._ticks[key] = group
                return True
        return False

    def _forget_group(self, group: _TickGroup) -> None:
        """``group`` has no members left."""
        for key, shared in list(self._ticks.items()):
            if shared is group:
                del self._ticks[key]

    def next_due_us(self) -> int | None:
        """Time of the next pending event, or None."""
        while self._queue and self._queue[0][2].callback is None:
            heappop(self._queue)
        return self._queue[0][0] if self._queue else None

    def run_until(self, t_us: float) -> int:
        """Run every event due up to and including ``t_us``; then time is ``t_us``.

        Returns the number of callbacks run.
        """
        return self.run_some(t_us, _UNBOUNDED)

    def run_some(self, t_us: float, max_events: int) -> int:
        """Run events due up to and including ``t_us``, at most ``max_events`` callbacks.

        Time becomes ``t_us`` only when every event due by then has run; otherwise it stays
        at the last event run, and a later call carries on from there.  A real-time runner
        uses it to look at its ports and its stop flag during a long catch-up.  Returns the
        number of callbacks run (``max_events`` means there may be more).
        """
        ran = 0
        limit = int(t_us)  # whole µs
        queue = self._queue
        pop, replace, seq = heappop, heapreplace, self._seq
        while ran < max_events and queue:
            when, _, ev = queue[0]
            if when > limit:
                break
            cb = ev.callback
            if cb is None:
                pop(queue)
                continue
            self.now = when
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
        if ran < max_events and limit > self.now:
            self.now = limit
        return ran

    def run_for(self, duration_us: float) -> int:
        """Run for ``duration_us`` µs of simulation time."""
        return self.run_until(self.now + int(duration_us))
