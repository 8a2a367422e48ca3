"""The installed commands' entry points: Ctrl-C from the first line of the project's code on.

Each command's ``main`` lives in a module that imports numpy, MuJoCo, construct and the
host library, which takes about a second of CPU. A Ctrl-C in that second used to be a
Python ``KeyboardInterrupt`` traceback. The console scripts (``[project.scripts]``) start
here instead: this module imports only the standard library, installs a SIGINT and SIGTERM
handler first, then imports the command's module and runs its ``main``. A Ctrl-C (or
SIGTERM) before ``main`` takes over is one line, ``armctl: interrupted``, and exit status
130, as it is later in the run; nothing has touched the robot by then.

What remains is Python's own start-up before this module runs (about 20–30 ms of CPU:
the interpreter, ``site`` and, in an editable install, its import finder): a Ctrl-C there
ends the process by the signal or with Python's own message, before any of the project's
code ran.
"""

from __future__ import annotations

import importlib
import signal
import sys
from collections.abc import Callable
from types import FrameType
from typing import Final

EXIT_INTERRUPTED: Final = 130
"""Exit status after Ctrl-C or SIGTERM (128 + SIGINT, as a shell reports a process that a
Ctrl-C ended)."""


def launch(prog: str, module: str) -> int:
    """Import ``module`` (a ``tools`` module with ``main() -> int``) and run its ``main``,
    with Ctrl-C and SIGTERM taken as an interruption from now on: the first raises
    :class:`KeyboardInterrupt`, later ones are ignored (a second Ctrl-C cannot cut the
    one-line exit short). ``main`` installs its own handlers (:func:`tools.cli.common.run`
    holds the robot on Ctrl-C) and restores these when it returns. Returns the exit
    status: ``main``'s, or :data:`EXIT_INTERRUPTED` with ``PROG: interrupted`` on stderr."""
    interrupted = False

    def handler(signum: int, frame: FrameType | None) -> None:
        nonlocal interrupted
        if not interrupted:
            interrupted = True
            raise KeyboardInterrupt(signal.Signals(signum).name)

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, handler)
    try:
        main: Callable[[], int] = importlib.import_module(module).main
        if interrupted:  # swallowed on the way (an optional import's ``except ImportError``)
            raise KeyboardInterrupt
        return main()
    except KeyboardInterrupt:
        interrupted = True
    except BaseException:
        # An interruption may come out as another exception: numpy turns one inside its
        # C extensions' import into an ImportError.  After this handler fired, it is that.
        if not interrupted:
            raise
    print(f"{prog}: interrupted", file=sys.stderr)
    return EXIT_INTERRUPTED


def armctl() -> int:
    """``armctl`` (:mod:`tools.cli.armctl`)."""
    return launch("armctl", "tools.cli.armctl")


def handctl() -> int:
    """``handctl`` (:mod:`tools.cli.handctl`)."""
    return launch("handctl", "tools.cli.handctl")


def handbus() -> int:
    """``handbus`` (:mod:`tools.cli.handbus`)."""
    return launch("handbus", "tools.cli.handbus")


def hil_emulator() -> int:
    """``hil-emulator`` (:mod:`tools.cli.serve_emulator`)."""
    return launch("hil-emulator", "tools.cli.serve_emulator")


def hil_fuzz() -> int:
    """``hil-fuzz`` (:mod:`tools.cli.hil_fuzz`)."""
    return launch("hil-fuzz", "tools.cli.hil_fuzz")


def fwimage() -> int:
    """``fwimage`` (:mod:`tools.cli.fwimage`)."""
    return launch("fwimage", "tools.cli.fwimage")


def flash_all_fingers() -> int:
    """``flash-all-fingers`` (:mod:`tools.cli.flash_all_fingers`)."""
    return launch("flash-all-fingers", "tools.cli.flash_all_fingers")


def hil_bench() -> int:
    """``hil-bench`` (:mod:`tools.hil_bench.cli`)."""
    return launch("hil-bench", "tools.hil_bench.cli")


def robot_view() -> int:
    """``robot-view`` (:mod:`tools.cli.robot_view`)."""
    return launch("robot-view", "tools.cli.robot_view")
