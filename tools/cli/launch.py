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
from typing import Any, Final

EXIT_INTERRUPTED: Final = 130
"""Exit status after Ctrl-C or SIGTERM (128 + SIGINT, as a shell reports a process that a
Ctrl-C ended)."""


def launch(prog: str, module: str, argv: list[str] | None = None) -> int:
    """Import ``module`` (a ``tools`` module with ``main(argv) -> int``) and run its ``main``
    (on ``argv``, or the command line's arguments when None),
    with Ctrl-C and SIGTERM taken as an interruption from now on: the first raises
    :class:`KeyboardInterrupt`, later ones are ignored (a second Ctrl-C cannot cut the
    one-line exit short). ``main`` installs its own handlers (:func:`tools.cli.common.run`
    holds the robot on Ctrl-C) and restores these when it returns. Returns the exit
    status: ``main``'s, or :data:`EXIT_INTERRUPTED` with ``PROG: interrupted`` on stderr.
    When ``main`` returns, the handlers found on entry are back (a caller in the same
    process, such as a test, keeps its own), except for the installed command itself
    (``argv`` None), which exits next: a Ctrl-C that late is ignored (it used to end the
    finished program by the signal, as if its work had been cut short)."""
    interrupted = False
    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}

    def handler(signum: int, frame: FrameType | None) -> None:
        nonlocal interrupted
        if not interrupted:
            interrupted = True
            raise KeyboardInterrupt(signal.Signals(signum).name)

    hook = sys.unraisablehook

    def quiet(unraisable: Any) -> None:
        """A Ctrl-C that lands in a callback Python cannot raise from (a weak reference's,
        as the import system's module locks use) is printed as "Exception ignored in …"
        with a traceback; the interruption is taken all the same (``interrupted``)."""
        if not (interrupted and isinstance(unraisable.exc_value, KeyboardInterrupt)):
            hook(unraisable)

    for sig in previous:
        signal.signal(sig, handler)
    sys.unraisablehook = quiet
    try:
        main: Callable[[list[str] | None], int] = importlib.import_module(module).main
        if interrupted:  # swallowed on the way (an optional import's ``except ImportError``)
            raise KeyboardInterrupt
        status = main(argv)
    except KeyboardInterrupt:
        interrupted = True
    except BaseException:
        # An interruption may come out as another exception: numpy turns one inside its
        # C extensions' import into an ImportError.  After this handler fired, it is that.
        if not interrupted:
            _restore(previous, hook)
            raise
    else:
        if argv is None:  # the command's own process, which exits with this status next
            interrupted = True  # a Ctrl-C now finds the work done: ignored, not a kill
        else:
            _restore(previous, hook)
        return status
    print(f"{prog}: interrupted", file=sys.stderr)
    return EXIT_INTERRUPTED


def _restore(handlers: dict[signal.Signals, Any], hook: Any) -> None:
    """Put back the signal handlers and the unraisable-exception hook ``launch`` found on
    entry."""
    for sig, old in handlers.items():
        signal.signal(sig, old)
    sys.unraisablehook = hook


def armctl(argv: list[str] | None = None) -> int:
    """``armctl`` (:mod:`tools.cli.armctl`)."""
    return launch("armctl", "tools.cli.armctl", argv)


def handctl(argv: list[str] | None = None) -> int:
    """``handctl`` (:mod:`tools.cli.handctl`)."""
    return launch("handctl", "tools.cli.handctl", argv)


def handbus(argv: list[str] | None = None) -> int:
    """``handbus`` (:mod:`tools.cli.handbus`)."""
    return launch("handbus", "tools.cli.handbus", argv)


def hil_emulator(argv: list[str] | None = None) -> int:
    """``hil-emulator`` (:mod:`tools.cli.serve_emulator`)."""
    return launch("hil-emulator", "tools.cli.serve_emulator", argv)


def hil_fuzz(argv: list[str] | None = None) -> int:
    """``hil-fuzz`` (:mod:`tools.cli.hil_fuzz`)."""
    return launch("hil-fuzz", "tools.cli.hil_fuzz", argv)


def fwimage(argv: list[str] | None = None) -> int:
    """``fwimage`` (:mod:`tools.cli.fwimage`)."""
    return launch("fwimage", "tools.cli.fwimage", argv)


def flash_all_fingers(argv: list[str] | None = None) -> int:
    """``flash-all-fingers`` (:mod:`tools.cli.flash_all_fingers`)."""
    return launch("flash-all-fingers", "tools.cli.flash_all_fingers", argv)


def hil_bench(argv: list[str] | None = None) -> int:
    """``hil-bench`` (:mod:`tools.hil_bench.cli`)."""
    return launch("hil-bench", "tools.hil_bench.cli", argv)


def robot_view(argv: list[str] | None = None) -> int:
    """``robot-view`` (:mod:`tools.cli.robot_view`)."""
    return launch("robot-view", "tools.cli.robot_view", argv)
