"""Real-time scheduling of the thread that paces the simulation: asked for where allowed,
said once on standard error, normal where not (or with ``--priority normal``)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from typing import Any, TypeVar

import pytest

from hil_emulator.emulator import Emulator
from hil_emulator.ports.port_reader import PortReader
from host.scheduling import RT_PRIORITY, Scheduling, current, request_priority, rtprio_limit
from tests.hil_emulator.emulator_process import ROOT

ALLOWED = os.geteuid() == 0 or rtprio_limit() > 0
SETPRIV = shutil.which("setpriv")


T = TypeVar("T")


def _in_thread(fn: Callable[[], T]) -> T:
    """What ``fn`` returns, called in a new thread (scheduling is per thread)."""
    out: list[T] = []
    thread = threading.Thread(target=lambda: out.append(fn()))
    thread.start()
    thread.join()
    return out[0]


def test_normal_leaves_the_thread_as_it_is() -> None:
    got = _in_thread(lambda: request_priority("normal"))
    assert got == current() and not got.realtime
    assert got.describe() == "normal scheduling (--priority normal)"
    with pytest.raises(ValueError, match="realtime, normal"):
        request_priority("urgent")


@pytest.mark.skipif(not ALLOWED, reason="real-time scheduling is not allowed here")
def test_realtime_where_allowed_is_round_robin_for_that_thread_only() -> None:
    got = _in_thread(lambda: (request_priority("realtime"), current()))
    asked, seen = got
    assert (asked.policy, asked.priority) == ("SCHED_RR", RT_PRIORITY)
    assert seen == asked and asked.describe().startswith("real-time scheduling: SCHED_RR")
    assert not current().realtime  # this thread never asked
    assert os.sched_getscheduler(0) & os.SCHED_RESET_ON_FORK == 0


@pytest.mark.skipif(not ALLOWED, reason="real-time scheduling is not allowed here")
def test_a_run_gives_the_thread_its_scheduling_back_and_says_which_it_had() -> None:
    emulator = Emulator("arm", physics=False)
    said: list[str] = []
    emulator.pacer.on_notice = said.append
    stop = threading.Event()
    threading.Timer(0.3, stop.set).start()

    def run() -> tuple[str, bool]:
        emulator.run(stop, priority="realtime")
        return current().policy, bool(emulator.pacer.scheduling and emulator.pacer.scheduling.realtime)

    after, had = _in_thread(run)
    assert had and after == "SCHED_OTHER"
    assert said == [f"real-time scheduling: SCHED_RR priority {RT_PRIORITY} for the "
                    "simulation thread"]


def _command(*args: str, prefix: tuple[str, ...] = ()) -> tuple[list[str], dict[str, Any]]:
    proc = subprocess.run([*prefix, sys.executable, "-m", "tools.cli.serve_emulator", "--config",
                           "arm", "--no-physics", "--duration", "0.5", "--stats", *args],
                          cwd=ROOT, capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 0, proc.stderr
    lines = proc.stderr.strip().splitlines()
    stats = json.loads(lines[-1].split("stats: ", 1)[1])
    return lines[:-1], stats


@pytest.mark.skipif(not ALLOWED, reason="real-time scheduling is not allowed here")
def test_the_command_says_once_which_scheduling_it_got() -> None:
    lines, stats = _command()
    assert [line for line in lines if "scheduling" in line] == [
        f"hil-emulator: real-time scheduling: SCHED_RR priority {RT_PRIORITY} for the "
        "simulation thread"]
    assert stats["scheduling"] == "SCHED_RR"
    lines, stats = _command("--priority", "normal")
    assert "hil-emulator: normal scheduling (--priority normal)" in lines
    assert stats["scheduling"] == "SCHED_OTHER"


@pytest.mark.skipif(SETPRIV is None or os.geteuid() != 0 or rtprio_limit() > 0,
                    reason="needs setpriv and root to take CAP_SYS_NICE away")
def test_without_the_right_it_says_why_and_runs_on_normally() -> None:
    assert SETPRIV is not None
    lines, stats = _command(prefix=(SETPRIV, "--bounding-set=-sys_nice", "--"))
    told = [line for line in lines if "scheduling" in line]
    assert len(told) == 1 and told[0].startswith(
        "hil-emulator: normal scheduling (not allowed: needs CAP_SYS_NICE or an rtprio "
        "limit)"), told
    assert "docs/EMULATOR.md" in told[0]
    assert stats["scheduling"] == "SCHED_OTHER" and stats["sim_s"] > 0


@pytest.mark.skipif(not ALLOWED, reason="real-time scheduling is not allowed here")
def test_a_port_reader_started_by_the_real_time_thread_runs_real_time_too() -> None:
    """Linux does not pass SCHED_RR on to new threads (SCHED_RESET_ON_FORK); a reader left at
    normal priority could be preempted while it holds the interpreter's lock, and the pacing
    thread would wait behind it."""
    r, w = os.pipe()
    try:
        def start() -> tuple[Scheduling, Scheduling | None]:
            asked = request_priority("realtime")
            reader = PortReader(r, lambda: 4096, "test")
            os.write(w, b"x")
            deadline = time.monotonic() + 5.0
            while reader.queued == 0 and time.monotonic() < deadline:
                time.sleep(0.001)
            reader.stop()
            return asked, reader.scheduling

        asked, got = _in_thread(start)
        assert asked.realtime
        assert got == asked
        normal = PortReader(r, lambda: 4096, "normal")  # started by a normal thread
        os.write(w, b"y")
        deadline = time.monotonic() + 5.0
        while normal.queued == 0 and time.monotonic() < deadline:
            time.sleep(0.001)
        normal.stop()
        assert normal.scheduling is not None and not normal.scheduling.realtime
    finally:
        os.close(r)
        os.close(w)
