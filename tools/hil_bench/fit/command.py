"""``hil-bench fit RECORDING.mcap… --params NAME… [--out PROFILE] [--json] [--workers N |
--scheduler ADDR] [--tolerance CHANNEL=VALUE …]``: estimate the parameters that best
reproduce the recordings, print each with its uncertainty (or that the recordings cannot
see it) and how much of the replay error the fit removed (a progress line per iteration on
standard error), write the robot profile to ``--out``.  ``--scheduler`` (also spelled
``--dask``) runs the replays on a Dask distributed scheduler, as ``hil-bench run`` does.  Exit 0 when the fit's emulator replays every recording within the tolerances
of the channels fitted, 1 when not, 2 for an unknown parameter, a recording it cannot
replay or bad arguments (one line saying why)."""

from __future__ import annotations

import argparse
import json
import os
import sys
from typing import TYPE_CHECKING, Any

from tools.cli.numeric import number_above
from tools.hil_bench.replay.command import tolerance

if TYPE_CHECKING:
    from tools.hil_bench.fit.solve import FitResult


def add_arguments(sub: Any) -> None:
    """The ``fit`` sub-command's parser."""
    p = sub.add_parser("fit", help="estimate the emulator's physical parameters from "
                       "recordings and write a robot profile")
    p.add_argument("recordings", nargs="+", metavar="RECORDING.mcap",
                   help="recordings of the robot (armctl excite, handctl excite, armctl "
                   "record); one session's recordings of its links joined by + "
                   "(arm.mcap+hand.mcap) are replayed together on one emulator")
    p.add_argument("--params", nargs="+", required=True, metavar="NAME",
                   help="the parameters to estimate (docs/EMULATOR.md, robot profiles), "
                   "e.g. arm.J2.stiffness, hand.finger1.f3.accel_rotation_x")
    p.add_argument("--out", metavar="PROFILE", help="write the robot profile (JSON) here")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--workers", type=number_above(1, int, inclusive=True, what="a number of "
                   "processes"), default=os.cpu_count() or 1, metavar="N",
                   help="processes replaying in parallel (default: one per core)")
    p.add_argument("--scheduler", "--dask", dest="scheduler", metavar="ADDR",
                   help="replay on a Dask distributed scheduler (tcp://127.0.0.1:8786) "
                   "instead of local processes")
    p.add_argument("--tolerance", action="append", type=tolerance, default=[],
                   metavar="CHANNEL=VALUE", help="a channel's tolerance (its unit): its "
                   "errors count in the fit divided by it; 0 leaves it out (default: "
                   "joint positions and deflections, 2 counts)")


def text_lines(result: FitResult) -> list[str]:
    """The fit as lines of text."""
    lines = [f"{p.name} = {p.value:.5g} ± {p.uncertainty:.2g} {p.unit} (nominal "
             f"{p.nominal:g}; {p.method})" if p.observable else
             f"{p.name} = {p.value:.5g} {p.unit} (nominal {p.nominal:g}): unobservable in "
             "these recordings" for p in result.parameters]
    lines.append(f"replay error (RMS over tolerance): {result.rms_before:.4g} before, "
                 f"{result.rms_after:.4g} after: {100 * result.removed:.1f} % removed; "
                 f"{result.replays} replays in {result.iterations} iterations, "
                 f"{result.cpu_s:.1f} CPU s")
    lines.append("the fitted emulator replays every recording within the tolerances"
                 if result.within_after else "the fitted emulator still parts from a "
                 "recording by more than a tolerance")
    lines.extend(result.notes)
    return lines


def run(args: argparse.Namespace) -> int:
    """Fit, print, write the profile; the exit status."""
    from hil_emulator.errors import EmulatorConfigError
    from tools.errors import ReplayRefused
    from tools.hil_bench.campaign import connect_scheduler
    from tools.hil_bench.fit.solve import fit

    def progress(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    try:
        scheduler = connect_scheduler(args.scheduler) if args.scheduler else None
    except ConnectionError as exc:
        print(f"hil-bench fit: {exc}", file=sys.stderr)
        return 2
    try:
        result = fit(args.recordings, args.params, tolerances=args.tolerance,
                     workers=args.workers, scheduler=scheduler, progress=progress)
    except (EmulatorConfigError, ReplayRefused) as exc:
        print(f"hil-bench fit: {exc}", file=sys.stderr)
        return 2
    finally:
        if scheduler is not None:
            scheduler.close()
    if args.out:
        try:
            result.profile().write(args.out)
        except OSError as exc:
            print(f"hil-bench fit: --out {args.out}: {exc.strerror or exc}", file=sys.stderr)
            return 2
    if args.json:
        print(json.dumps({**result.as_json(), "profile": args.out}, indent=1))
    else:
        print("\n".join(text_lines(result)))
    return 0 if result.within_after else 1
