"""Real-time scheduling for a thread the robot's timing hangs on: a host's control loop
(the robot CLIs' ``--priority``), the emulator's pacing thread.

On a busy machine a normally scheduled process waits for the CPU behind other processes: a
host's 10 ms cycles come 30-70 ms apart and its node watchdogs come near their timeout, an
emulator's replies come late.  :func:`request_priority` asks Linux for ``SCHED_RR`` at a modest
priority (:data:`RT_PRIORITY`) for the calling thread only, where that is allowed (root,
``CAP_SYS_NICE`` — ``setcap cap_sys_nice+ep`` on the interpreter —, or an ``rtprio`` limit
from ``/etc/security/limits.d``); where it is not, the thread runs on as it was.  Children
never inherit it (``SCHED_RESET_ON_FORK``), and neither do the threads it starts: a thread
that shares the interpreter's lock with the real-time thread takes it with :func:`adopt`.
A real-time thread must sleep between its cycles (the host's waits on its link, the
emulator's between events, with a yield when busy for long), so it never takes a core from
the machine for good.
"""

from __future__ import annotations

import os
import resource
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Final

#: What ``--priority`` accepts: ask for real-time scheduling (where allowed), or do not.
PRIORITIES: Final = ("realtime", "normal")
#: The real-time priority asked for (1 lowest … 99 highest): above every normal process,
#: below the kernel's own real-time threads (50) and audio servers.
RT_PRIORITY: Final = 10
#: The real-time priority a host's control loop asks for (the robot CLIs, the demo): above
#: every normal process, below the emulator's pacing thread (:data:`RT_PRIORITY`), so that on
#: a machine running both the robot's clock comes first (two equal round-robin threads
#: would wait up to a 100 ms slice for each other).
HOST_RT_PRIORITY: Final = 5


@dataclass(frozen=True)
class Scheduling:
    """What a thread got: ``policy`` (``SCHED_RR``, ``SCHED_FIFO`` or
    ``SCHED_OTHER``), its ``priority`` (0 for ``SCHED_OTHER``) and, when it asked for
    real time and did not get it, ``why`` not."""

    policy: str
    priority: int
    why: str = ""

    @property
    def realtime(self) -> bool:
        """True with a real-time policy."""
        return self.policy != "SCHED_OTHER"

    def describe(self, thread: str = "the simulation thread") -> str:
        """One line for standard error, ``thread`` naming what got it."""
        if self.realtime:
            return (f"real-time scheduling: {self.policy} priority {self.priority} for "
                    f"{thread}")
        if self.why:
            return (f"normal scheduling ({self.why}); {thread} may run late on a busy "
                    "machine: see 'Real-time scheduling' in docs/EMULATOR.md to allow it")
        return "normal scheduling (--priority normal)"


_POLICY_NAMES: Final = {getattr(os, name): name for name in ("SCHED_OTHER", "SCHED_FIFO",
                                                             "SCHED_RR", "SCHED_BATCH",
                                                             "SCHED_IDLE")
                        if hasattr(os, name)}


def current() -> Scheduling:
    """The calling thread's policy and priority now."""
    try:
        policy = os.sched_getscheduler(0) & ~getattr(os, "SCHED_RESET_ON_FORK", 0)
        priority = os.sched_getparam(0).sched_priority
    except (OSError, AttributeError):
        return Scheduling("SCHED_OTHER", 0)
    name = _POLICY_NAMES.get(policy, "SCHED_OTHER")
    return Scheduling(name, priority if name in ("SCHED_RR", "SCHED_FIFO") else 0)


def rtprio_limit() -> int:
    """The ``RLIMIT_RTPRIO`` soft limit: the highest real-time priority this process may
    take without privilege (0: none)."""
    try:
        soft, _ = resource.getrlimit(resource.RLIMIT_RTPRIO)
    except (OSError, AttributeError, ValueError):
        return 0
    return int(soft) if soft != resource.RLIM_INFINITY else 99


_CAP_SYS_NICE: Final = 23


def has_cap_sys_nice() -> bool:
    """True when this process holds ``CAP_SYS_NICE`` in its effective set
    (``/proc/self/status``)."""
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("CapEff:"):
                    return bool(int(line.split()[1], 16) >> _CAP_SYS_NICE & 1)
    except (OSError, ValueError):
        pass
    return False


def request_priority(priority: str = "realtime", rt_priority: int = RT_PRIORITY
                     ) -> Scheduling:
    """Ask for real-time scheduling of the calling thread (``priority`` ``"realtime"``) or
    leave it as it is (``"normal"``); returns what it has afterwards.

    Already real-time (started under ``chrt``), the thread keeps what it has.  The priority
    asked for is ``rt_priority`` or the ``rtprio`` limit, whichever is lower.
    """
    if priority not in PRIORITIES:
        raise ValueError(f"priority must be one of {', '.join(PRIORITIES)}, got {priority!r}")
    now = current()
    if priority == "normal" or now.realtime:
        return now
    if not hasattr(os, "SCHED_RR"):
        return Scheduling("SCHED_OTHER", 0, "this system has no real-time scheduling")
    limit = rtprio_limit()
    wanted = rt_priority if os.geteuid() == 0 or limit == 0 else min(rt_priority, limit)
    policy = os.SCHED_RR | getattr(os, "SCHED_RESET_ON_FORK", 0)
    try:
        os.sched_setscheduler(0, policy, os.sched_param(wanted))
    except PermissionError:
        if has_cap_sys_nice():
            return Scheduling("SCHED_OTHER", 0, "refused although CAP_SYS_NICE is held: a "
                                                "control group without real-time budget?")
        return Scheduling("SCHED_OTHER", 0, "not allowed: needs CAP_SYS_NICE or an rtprio "
                                            "limit")
    except OSError as exc:
        return Scheduling("SCHED_OTHER", 0, f"refused: {exc.strerror or exc}")
    return current()


def adopt(scheduling: Scheduling) -> Scheduling:
    """Give the calling thread ``scheduling`` when it is real-time (what the thread that
    started it got: ``SCHED_RESET_ON_FORK`` keeps new threads from inheriting it); returns
    what the calling thread has afterwards.

    A helper thread of a real-time loop (an emulator port's reader) holds the interpreter's lock
    while it queues bytes; left at normal priority, a CPU-bound process can preempt it
    there, and the real-time thread then waits for the lock for a scheduler slice (several ms)
    however high its own priority.  Refused (no privilege any more), the thread runs on as
    it is."""
    if not scheduling.realtime or not hasattr(os, "SCHED_RR"):
        return current()
    policy = getattr(os, scheduling.policy) | getattr(os, "SCHED_RESET_ON_FORK", 0)
    try:
        os.sched_setscheduler(0, policy, os.sched_param(scheduling.priority))
    except OSError:
        pass
    return current()


@contextmanager
def priority_for(priority: str = "realtime", rt_priority: int = RT_PRIORITY
                 ) -> Iterator[Scheduling]:
    """:func:`request_priority` (``priority``, ``rt_priority``) for the ``with`` block,
    yielding what the calling thread got; it has its own scheduling back afterwards (where
    it may still set it)."""
    before = os.sched_getscheduler(0), os.sched_getparam(0)
    try:
        yield request_priority(priority, rt_priority)
    finally:
        if (os.sched_getscheduler(0), os.sched_getparam(0)) != before:
            try:
                os.sched_setscheduler(0, *before)
            except OSError:
                pass
