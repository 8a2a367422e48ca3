"""What a test leaves behind: open file descriptors (a pty, a socket, a file), threads, and
running emulators (one serving on a thread of this process, or a process of its own).

:func:`snapshot` before a test and :func:`leaked` after it name everything that is new and
still there; the root ``conftest.py`` fails the test that leaked (as python-can's suite
refuses a channel left open).  A thread that is already told to stop gets
:data:`GRACE_S` to finish first.
"""

from __future__ import annotations

import os
import re
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Final

#: Descriptors a library keeps open for the life of the process once first used, not a
#: test's to close (their targets, by regular expression): matplotlib's font cache, which
#: holds its own fonts or the system's (``/usr/share/fonts``, where a package such as
#: Chromium brought them) open.
PROCESS_WIDE: Final = (re.compile(r"/matplotlib/mpl-data/fonts/"),
                       re.compile(r"\.(ttf|otf|ttc|pfb)$", re.IGNORECASE))

#: How long (s of wall time) threads and child processes that are on their way out get to
#: finish before they count as leaked: never a timing bound, only a busy machine's margin.
GRACE_S: Final = 5.0


@dataclass(frozen=True)
class Snapshot:
    """What this process holds at one moment: its descriptors (number → what it points at),
    its threads and its child processes' ids."""

    fds: dict[int, str]
    threads: frozenset[threading.Thread]
    children: frozenset[int]


def _fds() -> dict[int, str]:
    found: dict[int, str] = {}
    listing = f"/proc/{os.getpid()}/fd"
    for entry in os.scandir("/proc/self/fd"):
        try:
            target = os.readlink(entry.path)
        except OSError:  # the descriptor listing /proc/self/fd itself, closed meanwhile
            continue
        if target != listing and int(entry.name) > 2:  # pytest's capture swaps 0-2
            found[int(entry.name)] = target
    return found


def _children() -> frozenset[int]:
    """Ids of this process's children that still run (a zombie has exited)."""
    found: set[int] = set()
    for task in Path("/proc/self/task").iterdir():
        try:
            found.update(int(p) for p in (task / "children").read_text().split())
        except OSError:
            continue
    return frozenset(p for p in found if _state(p) not in ("Z", "X", "")
                     and "multiprocessing.resource_tracker" not in _command(p))  # one a process


def _state(pid: int) -> str:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return ""
    return stat.rpartition(")")[2].split()[0]


def _command(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode().strip()
    except OSError:
        return "?"


def _resource_tracker_fd() -> int | None:
    """The pipe to multiprocessing's resource tracker, opened by the first spawned process
    and kept for the life of this one (as its process is, :func:`_children`)."""
    from multiprocessing import resource_tracker

    fd = getattr(resource_tracker._resource_tracker, "_fd", None)
    return fd if isinstance(fd, int) else None


def snapshot() -> Snapshot:
    """What this process holds now."""
    return Snapshot(_fds(), frozenset(threading.enumerate()), _children())


def _serves_an_emulator(thread: threading.Thread) -> bool:
    """Whether ``thread`` runs an emulator's real-time loop (``Emulator.run``)."""
    target = getattr(thread, "_target", None)
    return getattr(target, "__name__", "") == "run" and \
        type(getattr(target, "__self__", None)).__name__ == "Emulator"


def _describe(thread: threading.Thread) -> str:
    if _serves_an_emulator(thread):
        return f"a running emulator (thread {thread.name!r} still in Emulator.run)"
    return f"a non-daemon thread {thread.name!r}"


def leaked(before: Snapshot, grace_s: float = GRACE_S) -> list[str]:
    """What is new since ``before`` and still there after at most ``grace_s`` (s) for
    threads and processes on their way out, one phrase each (empty: nothing)."""
    deadline = time.monotonic() + grace_s
    threads = [t for t in threading.enumerate() if t not in before.threads and t.is_alive()
               and (not t.daemon or _serves_an_emulator(t))]
    for thread in threads:
        thread.join(max(0.0, deadline - time.monotonic()))
    found = [_describe(t) for t in threads if t.is_alive()]
    children = _children() - before.children
    while children and time.monotonic() < deadline:
        time.sleep(0.05)
        children = _children() - before.children
    found += [f"a running process {pid} ({_command(pid)})" for pid in sorted(children)]
    tracker = _resource_tracker_fd()
    found += [f"file descriptor {fd} ({target})" for fd, target in sorted(_fds().items())
              if before.fds.get(fd) != target and fd != tracker
              and not any(p.search(target) for p in PROCESS_WIDE)]
    return found
