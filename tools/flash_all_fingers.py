"""``flash-all-fingers``: flash the fmcb, f2 and f3 of every finger, four fingers at once.

::

    flash-all-fingers --port /dev/ttyACM0 --fmcb fmcb.img --f2 f2.img --f3 f3.img
    flash-all-fingers --port emu://hand/palm --f2 f2.img --fingers 0,2 --dry-run
    flash-all-fingers --port P --fmcb fmcb.img --all-or-nothing --json --key signing.pub

Every image is checked before anything is touched (exists, parses, right board, signed with
``--key`` when given), and the palm and every finger must answer.  A node already holding
its image is skipped unless ``--force``; an interrupted run is resumed by running again.
Progress goes to stderr; the table (or ``--json``) to stdout.  Exit 0 only if every node
ends verified and running the requested version; 1 if not; 2 for a bad command line or a
plan refused before touching anything.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TextIO

from bootloader.batch import RunReport, run_plan
from bootloader.errors import FlashError
from bootloader.node_session import NodeReport, NodeState
from bootloader.plan import FlashPlan, make_plan
from bootloader.signing import load_public_key
from host.errors import HostError
from host.hand_session import HandSession
from host.transport import open_transport
from protocol.image import BoardType

EXIT_FAILED = 1
EXIT_USAGE = 2


def _fingers(text: str) -> list[int]:
    try:
        return [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected finger indices like 0,1,2,3"
                                         ) from None


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="flash-all-fingers", description=__doc__.split("\n\n")[0])
    p.add_argument("--port", required=True, help="the palm's serial port or a transport URL")
    p.add_argument("--fmcb", type=Path, help="image for the motor boards")
    p.add_argument("--f2", type=Path, help="image for the proximal phalanges")
    p.add_argument("--f3", type=Path, help="image for the distal phalanges")
    p.add_argument("--fingers", type=_fingers, default=[], help="e.g. 0,1,2,3 (default all)")
    p.add_argument("--force", action="store_true", help="rewrite even matching images")
    p.add_argument("--dry-run", action="store_true", help="print the plan, touch nothing")
    p.add_argument("--all-or-nothing", action="store_true",
                   help="stage and verify every node, activate only if all verified")
    p.add_argument("--key", type=Path, help="public key the nodes require signatures from")
    p.add_argument("--json", action="store_true", help="print one JSON object at the end")
    return p


def plan_from_args(args: argparse.Namespace) -> FlashPlan:
    """The checked plan the command line asks for (raises :class:`FlashError`)."""
    images = {board: path for board, path in ((BoardType.FMCB, args.fmcb),
              (BoardType.F2, args.f2), (BoardType.F3, args.f3)) if path is not None}
    key = load_public_key(args.key) if args.key is not None else None
    return make_plan(images, args.fingers, force=args.force,
                     all_or_nothing=args.all_or_nothing, public_key=key)


def progress_printer(stream: TextIO) -> object:
    """A state-change callback writing one line per change of a node."""

    def on_change(report: NodeReport) -> None:
        extra = ""
        if report.state == NodeState.WRITING and report.blocks_total:
            extra = f" ({report.blocks_total} blocks)"
        elif report.state == NodeState.FAILED:
            extra = f": {report.error}"
        print(f"{report.job.name}: {report.state.value}{extra}", file=stream, flush=True)

    return on_change


def table(report: RunReport) -> str:
    """The end-of-run table: node, before → after, bytes, retries, time, result."""
    rows = [("node", "version", "bytes", "retries", "time", "result")]
    for r in report.nodes:
        rows.append((r.job.name, f"{r.version_before or '?'} → {r.version or '?'}",
                     str(r.bytes_written), str(r.retries), f"{r.seconds:.2f} s",
                     r.result + (f": {r.error}" if r.error and r.result == "failed" else "")))
    widths = [max(len(row[i]) for row in rows) for i in range(5)]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=False)) + "  " + row[5]
             for row in rows]
    lines.append(f"total {report.total_seconds:.2f} s; "
                 f"{'all nodes verified' if report.ok else 'NOT all nodes verified'}")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``flash-all-fingers``; returns the exit status."""
    args = _parser().parse_args(argv)
    try:
        plan = plan_from_args(args)
    except FlashError as exc:
        print(f"flash-all-fingers: {exc}", file=sys.stderr)
        return EXIT_USAGE
    if args.dry_run:
        lines = plan.describe()
        if args.json:
            print(json.dumps({"dry_run": True, "plan": lines}))
        else:
            print("\n".join(lines))
        return 0
    try:
        transport = open_transport(args.port)
    except HostError as exc:
        print(f"flash-all-fingers: cannot open {args.port}: {exc}", file=sys.stderr)
        return EXIT_USAGE
    on_change = progress_printer(sys.stderr)
    with HandSession(transport) as session:
        try:
            report = run_plan(session, plan, on_change=on_change)  # type: ignore[arg-type]
        except FlashError as exc:
            print(f"flash-all-fingers: {exc}", file=sys.stderr)
            return EXIT_USAGE
        except HostError as exc:
            print(f"flash-all-fingers: the link failed: {exc}; run again to resume",
                  file=sys.stderr)
            return EXIT_FAILED
    if args.json:
        print(json.dumps(report.to_dict()))
    else:
        print(table(report))
    return 0 if report.ok else EXIT_FAILED


if __name__ == "__main__":
    sys.exit(main())
