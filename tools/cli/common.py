"""What every robot command line shares: ``--port``, ``--json``, ``--timeout``,
``--priority``, and one mapping from errors to a message saying what to do next and an exit
status.

Exit statuses (every CLI built on :func:`run_cli`):

=====  ===================================================================================
0      done
1      the robot or the link: no such port, unplugged, no answer, refused (``HostError``)
2      the command line, or a request refused before anything was sent (``UsageError``)
3+     a CLI's own outcome (``armctl``: a move that did not settle)
130    interrupted (Ctrl-C, or SIGTERM: both stop the robot where it is, see
       :func:`interrupts_as_ctrl_c`; the message says what was held)
=====  ===================================================================================

``--timeout S`` is the link budget (s): how long the host waits for the link itself on top
of the wire times and the nodes' own deadlines.  Its default depends on the kind of link
(:data:`host.hand.session.LINK_BUDGET_S` for the hand: 30 ms in process, where the
simulation clock makes wire times exact; 100 ms over a serial port or pty, where a USB
adapter's 16 ms latency timer and a busy machine add up; 100 ms on CAN; 250 ms over the
network).  On the arm's bus it is the adapter latency added to each exchange's computed
wire time (:class:`host.arm.bus.DynamixelBus`: 0.2 ms in process, 100 ms otherwise).

``--priority realtime`` (the default) runs the command with real-time scheduling where Linux
allows it (root, ``CAP_SYS_NICE``, an ``rtprio`` limit: :mod:`host.scheduling`; priority
:data:`~host.scheduling.HOST_RT_PRIORITY`, below an emulator's pacing thread), silently
running on as it was where not: on a busy machine a normally scheduled host's 10 ms cycles
come 30-70 ms apart.  A command on an in-process link (``emu://``, the simulation clock,
which runs as fast as the CPU allows) never asks for it; ``--priority normal`` leaves it.
"""

from __future__ import annotations

import argparse
import copy
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from types import FrameType
from typing import Final

from host.errors import (
    HomingError,
    HostError,
    NodeError,
    ReplyTimeout,
    TransportError,
    UsageError,
)
from host.hand.session import Timeouts
from host.scheduling import HOST_RT_PRIORITY, PRIORITIES, priority_for
from host.transports.base import link_kind, schemes
from protocol.messages.boot_program import AUTOBOOT_WINDOW_US
from protocol.messages.common import TxnStatus
from tools.cli.launch import EXIT_INTERRUPTED
from tools.cli.numeric import number_above, read_negative_numbers
from tools.cli.output import EXIT_BROKEN_PIPE, checked_stdout, output_failed
from tools.errors import OutputError

EXIT_OK: Final = 0
EXIT_ROBOT: Final = 1
EXIT_USAGE: Final = 2
__all__ = ["EXIT_BROKEN_PIPE", "EXIT_INTERRUPTED", "EXIT_OK", "EXIT_ROBOT", "EXIT_USAGE",
           "add_common_arguments", "advice", "command_priority", "hand_timeouts",
           "options_anywhere", "parse", "port_help", "run", "run_cli", "unwritable"]


def port_help(what: str) -> str:
    """Help text of ``--port``: ``what`` it is, and the schemes known now."""
    return (f"{what}: a serial path (/dev/ttyACM0, a pty, ./robot/palm; ?baud=N) or a "
            f"transport URL; schemes: {', '.join(schemes())} (e.g. emu://hand/palm, "
            "can://slcan//dev/ttyACM0, socket://host:port)")


def unwritable(path: str) -> str | None:
    """Why an output file at ``path`` cannot be written (a directory, a folder that does
    not exist, no permission), or None; checked before a tool does anything, so a typo does
    not lose a recording or a campaign."""
    target = Path(path)
    folder = target.resolve().parent
    if target.is_dir():
        return "it is a directory: give a file name"
    if not folder.is_dir():
        return f"the directory for it is missing (no directory {folder}): create it, or " \
            "give another path"
    if not os.access(target if target.exists() else folder, os.W_OK):
        return "permission denied"
    return None


def add_common_arguments(parser: argparse.ArgumentParser, *, what: str,
                         timeout_default: str = "by link kind") -> None:
    """``--port`` (required), ``--json``, ``--timeout`` (dest ``link_timeout``, so a
    sub-command may have its own ``--timeout``) and ``--priority``."""
    parser.add_argument("--port", required=True, metavar="P", help=port_help(what))
    parser.add_argument("--json", action="store_true", help="print JSON instead of text")
    parser.add_argument("--timeout", dest="link_timeout", type=number_above(0, what="a time"),
                        default=None, metavar="S",
                        help="link budget (s) on top of wire times; raise it for slow USB "
                             f"adapters or a busy machine (default: {timeout_default})")
    parser.add_argument("--priority", choices=PRIORITIES, default="realtime",
                        help="real-time scheduling for the command where allowed (root, "
                             "CAP_SYS_NICE, an rtprio limit), never on emu://: steady cycles "
                             "on a busy machine (default: realtime)")


class _Required:
    """The default of a required option :func:`options_anywhere` accepts after the
    sub-command too (argparse's own check sees only the main parser): :func:`parse` refuses
    a command line that leaves it, as argparse would."""

    def __init__(self, action: argparse.Action) -> None:
        self.option = "/".join(action.option_strings)

    def __repr__(self) -> str:
        return f"<required {self.option}>"


def options_anywhere(parser: argparse.ArgumentParser) -> None:
    """Accept ``parser``'s options (``--port``, ``--json`` …) after its sub-command as well
    as before it (``armctl move --joints … --view`` as ``armctl --view move …``): each
    sub-parser gets a copy of each, under "options of <prog>", defaulting to what the main
    parser parsed.  A sub-command's own option of the same name (``move --timeout``) wins
    after the sub-command.  Call it once the sub-commands are added."""
    main_options = [a for a in parser._actions
                    if a.option_strings and not isinstance(a, argparse._HelpAction)]
    for action in main_options:
        if action.required:
            action.required = False
            action.default = _Required(action)
    for sub in parser._actions:
        if not isinstance(sub, argparse._SubParsersAction):
            continue
        for name, sub_parser in sub.choices.items():
            group = sub_parser.add_argument_group(
                f"options of {parser.prog} (also before {name})")
            for action in main_options:
                if any(o in sub_parser._option_string_actions for o in action.option_strings):
                    continue
                copied = copy.copy(action)
                copied.default = argparse.SUPPRESS  # not given here: the main parser's value
                copied.required = False
                group._add_action(copied)


def hand_timeouts(args: argparse.Namespace) -> Timeouts:
    """The hand session's timeouts for ``--port`` and ``--timeout``."""
    return Timeouts.for_url(args.port, args.link_timeout)


def advice(exc: HostError, port: str, prog: str, command: str | None = None) -> str:
    """The message for ``exc`` raised by ``prog``'s ``command``: what went wrong and what
    to do next."""
    if isinstance(exc, TransportError):
        return (f"cannot use {port}: {exc}\nCheck the path (ls /dev/ttyACM* /dev/ttyUSB*), "
                "the permissions (dialout group), that nothing else holds the port, or "
                "start the emulator (hil-emulator).")
    if isinstance(exc, ReplyTimeout):
        baud = " (and ?baud=N)" if link_kind(port) == "serial" else ""
        ping = "" if command == "ping" else f", try `{prog} --port {port} ping`"
        return (f"{exc}\nNothing answered in time: check the robot's power and cabling, "
                f"that {port} is its port{baud}{ping}, "
                "or give a slow adapter more time with --timeout S.")
    if isinstance(exc, HomingError):
        return f"homing failed: {exc}"
    if isinstance(exc, NodeError) and exc.status == TxnStatus.UNKNOWN_TYPE:
        return (f"{exc}\nThe node does not know this request: most likely it still runs its "
                f"bootloader (a board waits about {AUTOBOOT_WINDOW_US / 1e6:g} s after power-up "
                f"before it starts its "
                f"application). Wait a few seconds and retry; `{prog} --port {port} ping` "
                "shows what each node runs.")
    return str(exc)


def run(prog: str, port: str, body: Callable[[], int], *,
        usage: tuple[type[BaseException], ...] = (), hint: str = "",
        command: str | None = None) -> int:
    """Run ``body`` and map what it raises to a message on stderr and an exit status:
    :class:`UsageError` (and ``usage``: a CLI's own "refused before anything was
    touched") → 2, other :class:`HostError` → 1 (``hint``, if given, ends its message),
    ``OSError`` (a file, or standard output that cannot be written: one line) → 1, Ctrl-C
    or SIGTERM → 130 (:func:`interrupts_as_ctrl_c`), standard output closed by its reader
    → 141, quietly.  The notes a context manager added to the exception (``the arm: held
    where they were …``) end the message."""
    with checked_stdout():
        try:
            with interrupts_as_ctrl_c():
                status = body()
                sys.stdout.flush()  # a closed pipe shows here, not at the interpreter's exit
                return status
        except KeyboardInterrupt as exc:
            print(f"{prog}: interrupted" + "".join(f"; {n}" for n in _notes(exc)),
                  file=sys.stderr)
            return EXIT_INTERRUPTED
        except UsageError as exc:
            print(f"{prog}: error: {exc}", file=sys.stderr)
            return EXIT_USAGE
        except usage as exc:
            print(f"{prog}: {exc}", file=sys.stderr)
            return EXIT_USAGE
        except HostError as exc:
            print(f"{prog}: {advice(exc, port, prog, command)}"
                  + (f"\n{hint}." if hint else "")
                  + "".join(f"\n{n}" for n in _notes(exc)), file=sys.stderr)
            return EXIT_ROBOT
        except (BrokenPipeError, OutputError) as exc:
            return output_failed(prog, exc)  # closed pipe: quietly; else one line
        except OSError as exc:
            print(f"{prog}: {exc}", file=sys.stderr)
            return EXIT_ROBOT


def _notes(exc: BaseException) -> list[str]:
    """The notes the library added to ``exc`` on its way out (what a context manager did
    about it: ``the arm: held where they were …``)."""
    return [str(n) for n in getattr(exc, "__notes__", ())]


@contextmanager
def interrupts_as_ctrl_c() -> Iterator[None]:
    """Within the block SIGTERM is Ctrl-C: the first SIGINT or SIGTERM raises
    :class:`KeyboardInterrupt` (so the robot's context managers stop and hold it, and the
    tool exits 130), and any later one is ignored until the block is left, so a second
    Ctrl-C cannot cut the hold short.  Outside the main thread (where Python takes no
    signals) the block runs as it is."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    interrupted = False

    def handler(signum: int, frame: FrameType | None) -> None:
        nonlocal interrupted
        if not interrupted:
            interrupted = True
            raise KeyboardInterrupt(signal.Signals(signum).name)

    previous = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    except KeyboardInterrupt:
        interrupted = True  # raised elsewhere (a test, the terminal): later ones wait too
        raise
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


def parse(parser: argparse.ArgumentParser,
          argv: Sequence[str] | None) -> argparse.Namespace | int:
    """The parsed arguments, or the exit status argparse chose (0 for --help, 2 for a bad
    command line; its message is already on stderr)."""
    read_negative_numbers(parser)  # -1e-3 is a number, not an option
    try:
        args = parser.parse_args(argv)
        missing = [v.option for v in vars(args).values() if isinstance(v, _Required)]
        if missing:
            parser.error(f"the following arguments are required: {', '.join(missing)}")
        return args
    except SystemExit as exc:
        if exc.code is None:
            return EXIT_OK
        return exc.code if isinstance(exc.code, int) else EXIT_USAGE


def run_cli(parser: argparse.ArgumentParser, argv: Sequence[str] | None,
            body: Callable[[argparse.Namespace], int], *,
            usage: tuple[type[BaseException], ...] = (), hint: str = "") -> int:
    """Parse ``argv`` and :func:`run` ``body(args)``; the ``main`` of every robot CLI."""
    args = parse(parser, argv)
    if isinstance(args, int):
        return args
    with priority_for(command_priority(args.port, args.priority), HOST_RT_PRIORITY):
        return run(parser.prog, args.port, lambda: body(args), usage=usage, hint=hint,
                   command=getattr(args, "command", None))


def command_priority(port: str, priority: str) -> str:
    """The scheduling a command on ``port`` asks for with ``--priority`` ``priority``:
    ``"normal"`` on an in-process link (simulated time, as fast as the CPU allows: real time
    there would take a core from the machine and gain nothing), else ``priority``."""
    return "normal" if link_kind(port) == "in-process" else priority
