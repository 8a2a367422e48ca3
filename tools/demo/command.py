"""``python -m tools.demo``: the command (options, the one verdict line, the exit status) over
:mod:`tools.demo.script` (in process) and :mod:`tools.demo.realtime` (``--realtime``)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from hil_emulator.imperfections import SENSOR_MODES
from tools.cli.numeric import read_negative_numbers
from tools.cli.output import guard_output
from tools.cli.view import add_view_arguments
from tools.demo import realtime, script
from tools.demo.plan import DEMO_SENSORS
from tools.errors import DemoFailed

#: The command's one-line description (the first paragraph of the script's docs).
DESCRIPTION = (script.__doc__ or "").split("\n\n")[0]


@guard_output("demo")
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="demo", description=DESCRIPTION)
    parser.add_argument("--out", type=Path, default=Path("demo-output"),
                        help="where the report and recordings go (default ./demo-output)")
    parser.add_argument("--seed", type=int, default=0, help="the emulator's seed")
    parser.add_argument("--sensors", choices=SENSOR_MODES, default=DEMO_SENSORS,
                        help="the robot's sensors: realistic (as built, the default; the demo calibrates "
                             "the hand first) or ideal (exact, nothing to calibrate)")
    parser.add_argument("--profile", type=Path, metavar="FILE",
                        help="a robot profile (JSON, hil-bench fit --out): the emulated "
                             "robot has its physical parameters")
    parser.add_argument("--arm-calibration", metavar="PATH",
                        help="the arm's calibration file (armctl calibrate's) the Cartesian "
                             "moves use (default: this arm's, named by its serial, when there "
                             "is one; 'none': the CAD model)")
    parser.add_argument("--realtime", action="store_true",
                        help="run against a hil-emulator subprocess through its ptys, "
                             "paced to the wall clock")
    add_view_arguments(parser)
    args = read_negative_numbers(parser).parse_args(argv)
    if args.profile is not None:
        from hil_emulator.errors import EmulatorConfigError
        from hil_emulator.profile import load_profile

        try:
            load_profile(args.profile)  # a bad file is one line, before anything starts
        except EmulatorConfigError as exc:
            parser.error(str(exc))
    if args.arm_calibration not in (None, "none") and not Path(args.arm_calibration).is_file():
        parser.error(f"--arm-calibration {args.arm_calibration}: no such file")
    args.out.mkdir(parents=True, exist_ok=True)
    try:
        ok, text = (realtime.run_realtime if args.realtime else script.run_inprocess)(
            args.out, args.seed, args.view_port if args.view else None, args.sensors,
            args.profile, arm_calibration=args.arm_calibration)
    except DemoFailed as exc:
        ok, text = False, f"{exc.step}: {exc}"
    except KeyboardInterrupt:
        ok, text = False, "interrupted"
    except Exception as exc:  # noqa: BLE001 - a demo reports, it does not crash
        ok, text = False, f"{type(exc).__name__}: {exc}"
    print(f"demo: OK ({text})" if ok else f"demo: FAILED ({text})", flush=True)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
