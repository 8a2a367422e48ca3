"""The browser view on the command line, one way for handctl, armctl and the demo.

``--view`` (every command) serves a live view of the robot while the command runs and
prints its address (``view: http://127.0.0.1:9090/?url=…``) on stderr; ``--view-port N``
chooses the web page's port (the data's is N+1).  ``watch`` is a session that
only reads the robot and draws it, until ``--seconds`` pass or Ctrl-C.  Nothing here needs
rerun-sdk unless a view is asked for (:mod:`host.view.live`).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

from host.view.live import WEB_PORT, RobotView
from tools.cli.numeric import number_above

__all__ = ["WATCH_HELP", "add_view_arguments", "add_watch_command", "port_number", "view_spec",
           "watch", "watch_arguments"]


def port_number(text: str) -> int:
    """A TCP port for the page, 0..65534 (its data goes on the next; 0: any free ports)."""
    try:
        port = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a port number") from None
    if not 0 <= port <= 65534:
        raise argparse.ArgumentTypeError(f"port {port}: give 0..65534 (0: any free port)")
    return port


def add_view_arguments(parser: argparse.ArgumentParser) -> None:
    """``--view`` and ``--view-port``."""
    parser.add_argument("--view", action="store_true",
                        help="serve a live view of the robot in a browser while this runs "
                             "(prints its address; needs rerun-sdk, the 'view' extra)")
    parser.add_argument("--view-port", type=port_number, default=WEB_PORT, metavar="N",
                        help=f"the view's web page port (default {WEB_PORT}; its data on N+1)")


#: The ``watch`` sub-command's help line.
WATCH_HELP = "only read the robot and draw it in a browser view (prints its address) until Ctrl-C"


def watch_arguments(default_rate: float) -> Callable[[argparse.ArgumentParser], None]:
    """What adds the ``watch`` sub-command's ``--rate`` (default ``default_rate``, Hz) and
    ``--seconds`` to its parser."""
    def add(watch_cmd: argparse.ArgumentParser) -> None:
        watch_cmd.add_argument("--rate", type=number_above(0, what="a rate (Hz)"),
                               default=default_rate, metavar="HZ",
                               help=f"states read per second (default {default_rate:g})")
        watch_cmd.add_argument("--seconds", type=number_above(0, what="a time (s)"),
                               default=None, metavar="S",
                               help="stop after this long (s; default: until Ctrl-C)")

    return add


def add_watch_command(sub: Any, default_rate: float) -> None:
    """The ``watch`` sub-command: ``--rate`` and ``--seconds``."""
    watch_arguments(default_rate)(sub.add_parser("watch", help=WATCH_HELP))


def view_spec(args: argparse.Namespace) -> RobotView | int | None:
    """What ``view=`` gets for these arguments: the web port when ``--view`` (or ``watch``)
    asks for a view, else None."""
    if getattr(args, "view", False) or getattr(args, "command", None) == "watch":
        return int(args.view_port)
    return None


def watch(read: Callable[[], Any], now: Callable[[], float], sleep: Callable[[float], None],
          rate_hz: float, seconds: float | None) -> int:
    """Call ``read`` ``rate_hz`` times a second on the link's clock (``now``/``sleep``) for
    ``seconds`` (None: until interrupted); the number of reads."""
    start = now()
    count = 0
    while seconds is None or count / rate_hz <= seconds:
        wait = start + count / rate_hz - now()
        if wait > 0:
            sleep(wait)
        read()
        count += 1
    return count
