"""robot-view: replay MCAP recordings of the hand and arm in the browser view.

::

    robot-view replay demo-output/arm.mcap demo-output/hand.mcap   # serve, print the address
    robot-view replay arm.mcap --save arm.rrd                       # a rerun file instead

The recorders' JSON channels (``/arm/state``, ``/hand/state``, ``/hand/events``; the bus
counters where recorded) go through the same drawing as a live view
(:class:`host.view.render.Renderer`), merged by log time, so a session looks as it did
live.  Serving, it keeps the page up until Ctrl-C (or ``--seconds``).  Exit 1 for a file
that is not an MCAP recording, 2 for bad arguments, 130 when interrupted.
"""

from __future__ import annotations

import argparse
import heapq
import json
import sys
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from host.errors import ViewUnavailable
from host.view.live import WEB_PORT, RobotView
from protocol.robot import DEFAULT_HAND_LAYOUT, HAND_LAYOUTS
from tools.cli.numeric import number_above, read_negative_numbers
from tools.cli.output import guard_output
from tools.cli.view import port_number
from tools.errors import NotARecording

EXIT_OK, EXIT_ERROR, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130


def messages(path: Path, topics: Sequence[str]) -> Iterator[tuple[float, str, dict[str, Any]]]:
    """``(t, topic, payload)`` of every JSON message on ``topics`` in the MCAP file
    ``path``, in the order they were logged; ``t`` is the link's clock (s: the message's
    publish time, the simulation's in process), as the live view drew it (log times are
    the wall clock)."""
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as stream:
            reader = make_reader(stream)
            for _schema, channel, message in reader.iter_messages(topics=list(topics),
                                                                   log_time_order=True):
                if channel.message_encoding == "json":
                    yield message.publish_time / 1e9, channel.topic, json.loads(message.data)
    except (McapError, ValueError, EOFError) as exc:
        raise NotARecording(f"{path}: not an MCAP recording of this project ({exc})") from exc


def replay(view: RobotView, paths: Sequence[Path]) -> int:
    """Draw every recorded message of ``paths`` in ``view`` in time order; how many."""
    from host.view.render import TOPICS

    count = 0
    merged = heapq.merge(*(messages(p, TOPICS) for p in paths), key=lambda m: m[0])
    for t, topic, payload in merged:
        view.renderer.message(topic, t, payload)
        count += 1
    view.renderer.flush()
    view.rec.flush()
    return count


def make_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="robot-view", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    rep = sub.add_parser("replay", help="draw MCAP recordings (arm and/or hand) in a view")
    rep.add_argument("files", nargs="+", type=Path, metavar="FILE.mcap")
    rep.add_argument("--layout", choices=sorted(HAND_LAYOUTS), default=DEFAULT_HAND_LAYOUT,
                     help="the hand's layout (default %(default)s)")
    rep.add_argument("--save", type=Path, default=None, metavar="FILE.rrd",
                     help="write a rerun file instead of serving a page")
    rep.add_argument("--view-port", type=port_number, default=WEB_PORT, metavar="N",
                     help=f"the page's port (default {WEB_PORT}; its data on N+1)")
    rep.add_argument("--seconds", type=number_above(0, what="a time (s)"), default=None,
                     metavar="S", help="stop serving after this long (default: Ctrl-C)")
    return parser


@guard_output("robot-view")
def main(argv: Sequence[str] | None = None) -> int:
    """Run robot-view; returns the exit status."""
    args = read_negative_numbers(make_parser()).parse_args(argv)
    for path in args.files:
        if not path.is_file():
            print(f"robot-view: {path}: no such file", file=sys.stderr)
            return EXIT_USAGE
    try:
        view = RobotView(serve=args.save is None, web_port=args.view_port, save=args.save,
                         layout=args.layout)
        with view:
            if view.address:
                print(f"view: {view.address}", file=sys.stderr, flush=True)
            count = replay(view, args.files)
            print(f"{count} messages replayed", flush=True)
            if view.address:
                deadline = None if args.seconds is None else time.monotonic() + args.seconds
                while deadline is None or time.monotonic() < deadline:
                    time.sleep(0.2)
    except (NotARecording, ViewUnavailable) as exc:
        print(f"robot-view: {exc}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
