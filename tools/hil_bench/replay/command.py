"""``hil-bench replay RECORDING.mcap… [--json] [--tolerance CHANNEL=VALUE …] [--seed N]
[--sensors ideal|realistic] [--profile FILE|none] [--report DIR]``: exit 0 when every channel is within its
tolerance, 1 when one is not (a line naming them), 2 for a recording it cannot replay (a
line saying why) or bad arguments."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from hil_emulator.imperfections import SENSOR_MODES
from tools.cli.numeric import number_above


def tolerance(text: str) -> tuple[str, float]:
    """An argparse type: ``CHANNEL=VALUE``, VALUE a number >= 0."""
    name, sep, value = text.partition("=")
    try:
        number = float(value)
    except ValueError:
        number = -1.0
    if not sep or not name.strip() or not number >= 0:
        raise argparse.ArgumentTypeError(f"{text!r}: CHANNEL=VALUE with VALUE a number >= 0, "
                                         f"e.g. present_position=2")
    return name.strip(), number


def add_arguments(sub: Any) -> None:
    """The ``replay`` sub-command's parser."""
    p = sub.add_parser("replay", help="replay a recording against the emulator and say where "
                       "they differ")
    p.add_argument("recording", metavar="RECORDING.mcap", nargs="+",
                   help="a recording (armctl record, handctl record, make demo), or one "
                   "session's recordings of its links (make demo's arm.mcap and hand.mcap), "
                   "replayed together on one emulator")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--tolerance", action="append", type=tolerance, default=[],
                   metavar="CHANNEL=VALUE", help="a channel's tolerance in its unit (CHANNEL "
                   "a full name, a pattern with *, or a field name for every node); default 0")
    p.add_argument("--seed", type=number_above(0, int, inclusive=True, what="a seed"),
                   metavar="N", help="the emulator's seed (default: the recording's)")
    p.add_argument("--sensors", choices=SENSOR_MODES,
                   help="the emulator's sensors (default: the recording's)")
    p.add_argument("--profile", metavar="FILE|none", help="the emulator's robot profile "
                   "(hil-bench fit --out), or none for the nominal robot (default: the "
                   "recording's)")
    p.add_argument("--report", metavar="DIR", help="write replay.md, replay.json and plots "
                   "into DIR")


def run(args: argparse.Namespace) -> int:
    """Replay, print, report; the exit status."""
    from tools.errors import ReplayRefused
    from tools.hil_bench.replay.report import as_json, text_lines, write_report
    from tools.hil_bench.replay.session import replay

    if args.report:
        try:
            Path(args.report).mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            print(f"hil-bench replay: --report {args.report}: cannot make that directory: "
                  f"{exc.strerror}", file=sys.stderr)
            return 2
    try:
        profile = None if args.profile is None else (
            "" if args.profile.lower() == "none" else args.profile)
        result = replay(args.recording, tolerances=args.tolerance, seed=args.seed,
                        sensors=args.sensors, profile=profile)
    except ReplayRefused as exc:
        print(f"hil-bench replay: {' + '.join(args.recording)}: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(as_json(result), indent=1))
    else:
        print("\n".join(text_lines(result)))
    if args.report:
        write_report(result, args.report)
    if not result.within and args.json:
        from tools.hil_bench.replay.report import summary_line

        print(summary_line(result), file=sys.stderr)
    return 0 if result.within else 1
