"""hil-fuzz: property-based, stateful fuzzing of a live target (emulator or real board).

    hil-fuzz --port emu://loose-finger/finger0 --target fmcb --examples 200 --seed 3
    hil-fuzz --port /dev/ttyUSB0 --target fmcb --seconds 600 --out findings/
    hil-fuzz replay findings/fmcb-seed3.json --port /dev/ttyUSB0

Prints "nothing found in N examples" (exit 0) or the minimal failing sequence, saved as a
reproducer in --out (exit 1).  ``replay`` exits 1 if the failure reproduces, else 0.
See docs/FUZZING.md.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from host.errors import HostError
from tools.fuzz.campaign import replay, run_campaign
from tools.fuzz.steps import Reproducer
from tools.fuzz.targets import TARGETS


def _fuzz(argv: Sequence[str]) -> int:
    parser = argparse.ArgumentParser(
        prog="hil-fuzz", description=__doc__.split("\n")[0],
        epilog="hil-fuzz replay FILE [--port P]: replay a saved reproducer (exit 1 if the "
               "failure reproduces); see hil-fuzz replay --help")
    parser.add_argument("--port", help="transport URL or serial port (default: the "
                        "emulator in process that has the target)")
    parser.add_argument("--target", required=True, choices=sorted(TARGETS))
    budget = parser.add_mutually_exclusive_group()
    budget.add_argument("--seconds", type=float, help="fuzz for this long (wall clock)")
    budget.add_argument("--examples", type=int, help="number of sequences (default 100)")
    parser.add_argument("--steps", type=int, default=12, help="most steps per sequence")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--messages", nargs="+", metavar="GLOB",
                        help="focus on these messages (e.g. 'fmcb.param_*')")
    parser.add_argument("--out", default="fuzz-findings", help="where reproducers go")
    args = parser.parse_args(argv)
    examples = None if args.seconds is not None else (args.examples or 100)
    try:
        result = run_campaign(args.target, args.port, examples=examples, seconds=args.seconds,
                              seed=args.seed, steps=args.steps, messages=args.messages)
    except ValueError as exc:
        print(f"hil-fuzz: {exc}", file=sys.stderr)
        return 2
    except HostError as exc:
        print(f"hil-fuzz: {exc}", file=sys.stderr)
        return 1
    if result.reproducer is None:
        print(f"nothing found in {result.examples} examples ({result.steps_sent} steps, "
              f"{result.seconds:.1f} s)")
        return 0
    rep = result.reproducer
    path = rep.save(args.out)
    print(f"FAILURE on {rep.target}: {rep.failure}")
    print(f"minimal sequence ({len(rep.steps)} steps):")
    for i, step in enumerate(rep.steps, 1):
        print(f"  {i}. {step}")
    print(f"reproducer saved to {path}")
    return 1


def _replay(argv: Sequence[str]) -> int:
    parser = argparse.ArgumentParser(prog="hil-fuzz replay",
                                     description="replay a reproducer against a target")
    parser.add_argument("file")
    parser.add_argument("--port", help="transport URL or serial port (default: the file's)")
    args = parser.parse_args(argv)
    try:
        rep = Reproducer.load(args.file)
        failure = replay(rep, args.port)
    except (OSError, ValueError, KeyError) as exc:
        print(f"hil-fuzz: {exc}", file=sys.stderr)
        return 2
    except HostError as exc:
        print(f"hil-fuzz: {exc}", file=sys.stderr)
        return 1
    if failure is None:
        print(f"does not reproduce ({len(rep.steps)} steps on {rep.target})")
        return 0
    print(f"reproduced: {failure}")
    return 1


def main(argv: Sequence[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if args and args[0] == "replay":
        return _replay(args[1:])
    return _fuzz(args)


if __name__ == "__main__":
    sys.exit(main())
