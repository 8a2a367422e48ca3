"""``flash-all-fingers``: flash the fmcb, f2 and f3 of every finger, four fingers at once.

::

    flash-all-fingers --port /dev/ttyACM0 --fmcb fmcb.img --f2 f2.img --f3 f3.img
    flash-all-fingers --port emu://hand/palm --f2 f2.img --fingers 0,2 --dry-run
    flash-all-fingers --port P --fmcb fmcb.img --all-or-nothing --json --key signing.pub
    flash-all-fingers --port P --rollback            # every node back to its previous image

Nodes with two image slots are updated through them by default: each new image is written
into every secondary slot while the applications keep running, verified by its on-node hash,
then every node swaps (down for that one reboot), is checked (identify, version, its sensors
answer) and confirmed; if any node fails its check, every node of the update goes back to
its previous image (``--no-fleet-rollback``: only that node).  ``--keep-trial`` leaves the
new images unconfirmed, so that the next reset of a node reverts it.  Nodes still on the
one-slot layout (an older bootloader) are flashed in their bootloader as before
(``--one-slot`` flashes every node that way); the report's ``layout`` says which.

Every image is checked before anything is touched (exists, parses, right board, signed with
``--key`` when given), and the palm and every finger must answer.  A node already holding
its image is skipped unless ``--force``; an interrupted run is resumed by running again.
Progress goes to stderr; the table (or ``--json``) to stdout, also when the run stops early
(Ctrl-C, the link lost), ending with what to do next when not every node verified.  Exit 0
only if every node ends verified and running the requested version; 1 if not (or the link
failed: run again to resume); 2 for a bad command line or a plan refused before touching
anything (an image, a key, a finger not answering, a port that does not open); 130 when
interrupted.
``--timeout S`` sets the link budget (default by link kind, see :mod:`tools.cli.common`).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TextIO

from bootloader.batch import RunReport, new_reports, run_plan, run_rollback, settle
from bootloader.errors import FlashError, PlanError
from bootloader.node_session import NodeReport, NodeState
from bootloader.plan import FlashPlan, make_plan, rollback_plan
from bootloader.signing import load_public_key
from host.errors import HostError, TransportError
from host.hand.session import HandSession
from host.transports.base import open_transport
from protocol.topology import FINGER_BOARDS
from tools.cli.common import EXIT_ROBOT, EXIT_USAGE, add_common_arguments, hand_timeouts, run_cli
from tools.cli.output import guard_output

#: Not every node ended verified (or the link failed mid-run).
EXIT_FAILED = EXIT_ROBOT
__all__ = ["EXIT_FAILED", "EXIT_USAGE", "main"]


def _fingers(text: str) -> list[int]:
    try:
        return [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected finger indices like 0,1,2,3"
                                         ) from None


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="flash-all-fingers", description=__doc__.split("\n\n")[0])
    add_common_arguments(p, what="the palm's port")
    for board in FINGER_BOARDS:
        p.add_argument(f"--{board.app}", type=Path, help=f"image for the {board.role}s")
    p.add_argument("--fingers", type=_fingers, default=[], help="e.g. 0,1,2,3 (default all)")
    p.add_argument("--force", action="store_true", help="rewrite even matching images")
    p.add_argument("--dry-run", action="store_true", help="print the plan, touch nothing")
    p.add_argument("--all-or-nothing", action="store_true",
                   help="stage and verify every node, activate only if all verified")
    p.add_argument("--key", type=Path, help="public key the nodes require signatures from")
    p.add_argument("--no-fleet-rollback", action="store_true",
                   help="a node failing its check after the swap goes back alone; the "
                   "others keep the new image")
    p.add_argument("--keep-trial", action="store_true",
                   help="leave the new images unconfirmed: the next reset of a node reverts "
                   "it (to test the rollback path)")
    p.add_argument("--rollback", action="store_true",
                   help="no images: every node goes back to its previous image")
    p.add_argument("--one-slot", action="store_true",
                   help="flash every node in its bootloader (the one-slot way)")
    return p


def plan_from_args(args: argparse.Namespace) -> FlashPlan:
    """The checked plan the command line asks for (raises :class:`FlashError`)."""
    if args.rollback:
        given = [f"--{b.app}" for b in FINGER_BOARDS if getattr(args, b.app) is not None]
        given += [f"--{n.replace('_', '-')}" for n in ("keep_trial", "no_fleet_rollback",
                                                         "one_slot", "force", "all_or_nothing")
                  if getattr(args, n)]
        if given:
            raise PlanError(f"--rollback takes no {' '.join(given)}: it puts every node back "
                            "on the image it ran before")
        return rollback_plan(args.fingers)
    images = {b.board_type: getattr(args, b.app) for b in FINGER_BOARDS
              if getattr(args, b.app) is not None}
    key = load_public_key(args.key) if args.key is not None else None
    return make_plan(images, args.fingers, force=args.force,
                     all_or_nothing=args.all_or_nothing, public_key=key,
                     slots=not args.one_slot, fleet_rollback=not args.no_fleet_rollback,
                     keep_trial=args.keep_trial)


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
    """The end-of-run table: node, before → after, bytes, retries, time, layout, time the
    node was down (its swap to its new application; ``-`` flashed the one-slot way or not
    swapped), result."""
    rows = [("node", "version", "bytes", "retries", "time", "layout", "down", "result")]
    for r in report.nodes:
        before = r.version_before or (f"{r.partly_written} partly written"
                                      if r.partly_written else "?")
        down = f"{r.downtime_s:.2f} s" if r.downtime_s is not None else "-"
        rows.append((r.job.name, f"{before} → {r.version or '?'}",
                     str(r.bytes_written), str(r.retries), f"{r.seconds:.2f} s", r.layout,
                     down,
                     r.result + (f": {r.error}" if r.error and r.result == "failed" else "")))
    widths = [max(len(row[i]) for row in rows) for i in range(7)]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=False)) + "  " + row[7]
             for row in rows]
    stopped = f"{report.stopped}: " if report.stopped else ""
    lines.append(f"total {report.total_seconds:.2f} s; {stopped}"
                 f"{'all nodes verified' if report.ok else 'NOT all nodes verified'}")
    if report.next_step:
        lines.append(f"next: {report.next_step}.")
    return "\n".join(lines)


def _print_report(report: RunReport, as_json: bool) -> None:
    print(json.dumps(report.to_dict()) if as_json else table(report), flush=True)


def _run(args: argparse.Namespace) -> int:
    plan = plan_from_args(args)
    if args.dry_run and args.rollback:
        lines = [f"finger {f}: every node back to the image in its secondary slot"
                 for f in plan.fingers]
        print(json.dumps({"dry_run": True, "plan": lines}) if args.json else "\n".join(lines))
        return 0
    if args.dry_run:
        lines = plan.describe()
        print(json.dumps({"dry_run": True, "plan": lines}) if args.json else "\n".join(lines))
        return 0
    try:
        transport = open_transport(args.port)
    except TransportError as exc:
        raise PlanError(f"{exc}; nothing was touched.\nCheck the path (ls /dev/ttyACM* "
                        "/dev/ttyUSB*), that nothing else holds the port (another "
                        "flash-all-fingers, handctl, a terminal), or start the emulator "
                        "(hil-emulator).") from exc
    reports = new_reports(plan)
    with HandSession(transport, timeouts=hand_timeouts(args)) as session:
        started = session.now()
        fingers = ",".join(str(f) for f in plan.fingers)
        print(f"checking the palm and fingers {fingers} (nothing is touched until they "
              "answer; a hand just switched on takes a few seconds)", file=sys.stderr,
              flush=True)
        try:
            run = run_rollback if args.rollback else run_plan
            report = run(session, plan, on_change=progress_printer(sys.stderr),  # type: ignore[arg-type]
                         reports=reports)
        except (KeyboardInterrupt, HostError) as exc:
            # Ctrl-C or the link lost mid-run: what every node got to, then the message.
            touched = any(r.state != NodeState.PENDING for r in reports.values())
            if touched or args.json:
                why = "interrupted" if isinstance(exc, KeyboardInterrupt) else f"link lost: {exc}"
                settled = settle(reports, started, session.now(), why)
                settled.rollback = args.rollback
                _print_report(settled, args.json)
            raise
    _print_report(report, args.json)
    return 0 if report.ok else EXIT_FAILED


@guard_output("flash-all-fingers")
def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``flash-all-fingers``; returns the exit status."""
    return run_cli(_parser(), argv, _run, usage=(FlashError,),
                   hint="run flash-all-fingers again to resume")


if __name__ == "__main__":
    sys.exit(main())
