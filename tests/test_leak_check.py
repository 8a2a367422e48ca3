"""The suite's own rules (tests/conftest.py): the leak check names what a test leaves behind,
and the scheduling lists name files that exist."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from hil_emulator.emulator import Emulator
from tests import conftest, leaks
from tests.hil_emulator.emulator_thread import serving

TESTS = Path(__file__).resolve().parent


def test_a_descriptor_left_open_is_named_and_one_closed_is_not() -> None:
    before = leaks.snapshot()
    master, slave = os.openpty()
    try:
        found = leaks.leaked(before)
        assert any(f"file descriptor {master} (/dev/ptmx)" == x for x in found), found
        assert any(f"file descriptor {slave} (/dev/pts/" in x for x in found), found
    finally:
        os.close(master)
        os.close(slave)
    assert leaks.leaked(before) == []


def test_a_non_daemon_thread_still_running_is_named() -> None:
    before = leaks.snapshot()
    release = threading.Event()
    thread = threading.Thread(target=release.wait, name="forgotten")
    thread.start()
    try:
        assert leaks.leaked(before, grace_s=0.1) == ["a non-daemon thread 'forgotten'"]
    finally:
        release.set()
        thread.join()
    assert leaks.leaked(before) == []


def test_an_emulator_left_running_on_a_thread_is_named() -> None:
    emulator = Emulator("arm", physics=False)
    with serving(emulator, ports=False) as run:
        before = leaks.snapshot()
        found = leaks.leaked(leaks.Snapshot(before.fds, before.threads - {run.thread},
                                            before.children), grace_s=0.1)
        assert found == [f"a running emulator (thread {run.thread.name!r} still in "
                         "Emulator.run)"]


def test_a_process_still_running_is_named() -> None:
    before = leaks.snapshot()
    with subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()"],
                          stdin=subprocess.PIPE) as child:
        try:
            found = leaks.leaked(before, grace_s=0.1)
            assert any(x.startswith(f"a running process {child.pid} (") for x in found), found
        finally:
            child.kill()
    assert leaks.leaked(before) == []


@pytest.mark.parametrize("listed", sorted(conftest.WALL_CLOCK_FILES | conftest.SPREAD_FILES
                                              | set(conftest.LONG_FILES)))
def test_every_file_the_scheduling_names_exists(listed: str) -> None:
    assert (TESTS / listed).is_file(), f"tests/conftest.py names {listed}, which is gone"
