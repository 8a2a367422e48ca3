"""Ctrl-C while an installed command is still importing: one line and exit 130, no traceback.

The commands are run as a user runs them, through their console scripts in the virtual
environment (``[project.scripts]`` → :mod:`tools.cli.launch`). The moments of the SIGINT
are set on the child's own clock, never the wall clock: first the moment its handler is in
place (its SIGTERM disposition in ``/proc/PID/status`` turns to "caught": the first line of
the project's code ran), then after it has used given amounts of CPU time since, which on a
busy machine takes longer but lands at the same point of its start-up.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

BIN = Path(sys.executable).parent
TICK_S = 1 / os.sysconf("SC_CLK_TCK")
#: A child asleep this long (s, wall clock) without using CPU is waiting, its start-up over.
WAITING_S = 2.0


def _stat(pid: int) -> tuple[str, float]:
    """The process's state letter and CPU time (s, user + system)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return fields[0], (int(fields[11]) + int(fields[12])) * TICK_S


def _catches_sigterm(pid: int) -> bool:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("SigCgt:"):
            return bool(int(line.split()[1], 16) & (1 << (signal.SIGTERM - 1)))
    return False


def interrupt(command: list[str], cpu_s: float, after_handler: bool = True) -> tuple[int, str]:
    """Start ``command``, wait (polling /proc) until it has used ``cpu_s`` seconds of CPU
    (counted from when its handler is installed if ``after_handler``, else from its
    start), send SIGINT; its exit status and stderr."""
    script = BIN / command[0]
    assert script.exists(), f"{script}: run `make install` (the console scripts)"
    proc = subprocess.Popen([str(script), *command[1:]], stdin=subprocess.DEVNULL,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        while after_handler and not _catches_sigterm(proc.pid):
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.001)  # a poll, not a bound: leave the CPU to the child
        state, start = _stat(proc.pid)
        cpu = start
        # a child whose start-up took less CPU than asked (a warm cache, the compiled core)
        # ends it waiting on the port: its CPU stops growing, and the SIGINT lands there
        idle_since, last = time.monotonic(), cpu
        while state != "Z" and cpu < start + cpu_s:
            state, cpu = _stat(proc.pid)
            if cpu != last:
                idle_since, last = time.monotonic(), cpu
            elif state == "S" and time.monotonic() - idle_since > WAITING_S:
                break
            time.sleep(0.001)
        assert state != "Z", f"{command[0]} ended before the SIGINT: {proc.communicate()}"
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode, err


@pytest.fixture()
def silent_port() -> Iterator[str]:
    """A pty nothing answers on."""
    leader, follower = os.openpty()
    yield os.ttyname(follower)
    os.close(follower)
    os.close(leader)


@pytest.mark.parametrize(("cpu_s", "after_handler"), [
    (0.0, True), (0.03, True), (0.1, True), (0.2, True),
    # from the start: Python's own start-up (site) takes about 0.03 s of CPU (more the first
    # time after an install, when it compiles the editable install's finder)
    (0.12, False), (0.2, False), (0.3, False)])
def test_armctl_interrupted_at_any_moment_of_its_start_is_one_line(
        silent_port: str, cpu_s: float, after_handler: bool) -> None:
    """From the handler's first moment through the imports (numpy, MuJoCo, construct: about
    0.3 s of CPU): one line, exit 130 (Ctrl-C later in the run: test_armctl_killed.py)."""
    status, err = interrupt(["armctl", "--port", silent_port, "--timeout", "60", "ping"],
                            cpu_s, after_handler)
    assert "Traceback" not in err
    assert status == 130, err
    assert err.splitlines()[0] == "armctl: interrupted"


@pytest.mark.slow
@pytest.mark.parametrize("command", [
    ["handctl", "--port", "PORT", "--timeout", "60", "ping"],
    ["flash-all-fingers", "--port", "PORT", "--timeout", "60", "--dry-run"],
    ["hil-emulator", "--config", "full"],
    ["hil-bench", "list-scenarios"],
])
def test_every_command_interrupted_while_importing_is_one_line(
        silent_port: str, command: list[str]) -> None:
    status, err = interrupt([silent_port if a == "PORT" else a for a in command], 0.1,
                            after_handler=False)
    assert "Traceback" not in err
    assert (status, err) == (130, f"{command[0]}: interrupted\n")


def test_the_entry_module_imports_only_the_standard_library() -> None:
    """The handler is in place before anything heavy loads: importing the entry module
    loads none of the project's libraries nor numpy, MuJoCo or construct."""
    heavy = {"numpy", "mujoco", "construct", "serial", "can", "protocol", "firmware_py",
             "hil_emulator", "host", "bootloader"}
    out = subprocess.run(
        [sys.executable, "-c", "import sys, tools.cli.launch; "
         "print(' '.join(sorted({m.split('.')[0] for m in sys.modules})))"],
        capture_output=True, text=True, check=True).stdout.split()
    assert heavy.isdisjoint(out), heavy & set(out)


def test_a_ctrl_c_after_the_command_finished_does_not_end_it_by_the_signal(
        tmp_path: Path) -> None:
    """A Ctrl-C between ``main`` returning and the process exiting (``armctl move`` whose
    move had just settled) ended it by SIGINT: status -2 and a traceback, though its work
    was done.  The installed command (``argv`` None) now exits with ``main``'s status."""
    (tmp_path / "finished.py").write_text("def main(argv):\n    return 0\n")
    code = ("import os, signal, sys, time, tools.cli.launch as launch; "
            f"sys.path.insert(0, {str(tmp_path)!r}); "
            "status = launch.launch('finished', 'finished'); "
            "os.kill(os.getpid(), signal.SIGINT); time.sleep(0.2); sys.exit(status)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60)
    assert (done.returncode, done.stderr) == (0, "")


def test_a_ctrl_c_inside_a_weak_reference_callback_is_still_one_line(tmp_path: Path) -> None:
    """A Ctrl-C that lands while the import system runs a weak reference's callback (its
    module locks' clean-up: seen once in 175 interrupted starts beside a CPU hog) cannot
    raise there: Python printed "Exception ignored in …" and a traceback before the one
    line.  The interruption is taken all the same, and nothing else is printed."""
    (tmp_path / "slow_start.py").write_text(
        "import os, signal, weakref\n"
        "class Thing:\n"
        "    pass\n"
        "def gone(_ref):\n"
        "    os.kill(os.getpid(), signal.SIGINT)\n"
        "    for _ in range(1000):  # the handler runs here, inside the callback\n"
        "        pass\n"
        "thing = Thing()\n"
        "ref = weakref.ref(thing, gone)\n"
        "del thing\n"
        "def main(argv):\n"
        "    return 0\n")
    code = ("import sys; sys.path.insert(0, sys.argv[1]); from tools.cli.launch import launch; "
            "sys.exit(launch('slow', 'slow_start', []))")
    run = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True,
                         text=True, timeout=60)
    assert (run.returncode, run.stderr) == (130, "slow: interrupted\n")
