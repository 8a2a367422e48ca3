"""hil-fuzz: property-based, stateful fuzzing of a live target (emulator or real board).

    hil-fuzz --port emu://loose-finger/finger0 --target fmcb --examples 200 --seed 3
    hil-fuzz --port /dev/ttyUSB0 --target fmcb --seconds 600 --out findings/
    hil-fuzz replay findings/fmcb-seed3.json --port /dev/ttyUSB0

Prints "nothing found in N examples" (exit 0) or the minimal failing sequence, saved as a
reproducer in --out (exit 1).  ``replay`` exits 1 if the failure reproduces, else 0.  Both
exit 2 on a usage error, an unreadable reproducer, or a target that cannot be opened or
does not answer a ping before anything is sent (never taken for a finding), and 130 on
Ctrl-C (after saying what ran, and saving a failure found so far).  See docs/FUZZING.md.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence

from host.errors import HostError
from tools.cli.common import EXIT_INTERRUPTED
from tools.cli.numeric import number_above, read_negative_numbers
from tools.cli.output import guard_output
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
    budget.add_argument("--seconds", type=number_above(0),
                        help="fuzz for this long (wall clock; checked before each example, "
                        "so at most one example more)")
    budget.add_argument("--examples", type=number_above(0, int),
                        help="number of sequences sent (default 100)")
    parser.add_argument("--steps", type=number_above(0, int), default=12,
                        help="most steps per sequence")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--messages", nargs="+", metavar="GLOB",
                        help="focus on these messages (e.g. 'fmcb.param_*')")
    parser.add_argument("--out", default="fuzz-findings", help="where reproducers go")
    args = read_negative_numbers(parser).parse_args(argv)
    examples = None if args.seconds is not None else (args.examples or 100)
    try:
        result = run_campaign(args.target, args.port, examples=examples, seconds=args.seconds,
                              seed=args.seed, steps=args.steps, messages=args.messages)
    except (ValueError, HostError) as exc:
        print(f"hil-fuzz: {exc}", file=sys.stderr)
        return 2
    ran = f"{result.examples} examples ({result.steps_sent} steps, {result.seconds:.1f} s)"
    if result.link_error is not None:
        print(f"hil-fuzz: the link to the target failed after {ran}, nothing found before "
              f"that: {result.link_error}", file=sys.stderr)
        return 2
    if result.reproducer is None:
        if result.interrupted:
            print(f"interrupted: nothing found in {ran}")
            return EXIT_INTERRUPTED
        print(f"nothing found in {ran}")
        return 0
    rep = result.reproducer
    print(f"FAILURE on {rep.target}: {rep.failure}")
    print(f"minimal sequence ({len(rep.steps)} steps):" if not result.interrupted else
          f"sequence ({len(rep.steps)} steps; interrupted before it was fully shrunk):")
    for i, step in enumerate(rep.steps, 1):
        print(f"  {i}. {step}")
    try:
        path = rep.save(args.out)
    except OSError as exc:
        # The finding is not lost: the reproducer goes to stdout, to be saved by hand.
        print(f"hil-fuzz: cannot save the reproducer in {args.out}: {exc}; here it is (save "
              f"it as {rep.target}-seed{rep.seed}.json for hil-fuzz replay):", file=sys.stderr)
        print(json.dumps(rep.to_json(), indent=1))
    else:
        print(f"reproducer saved to {path}")
    return EXIT_INTERRUPTED if result.interrupted else 1


def _replay(argv: Sequence[str]) -> int:
    parser = argparse.ArgumentParser(prog="hil-fuzz replay",
                                     description="replay a reproducer against a target")
    parser.add_argument("file")
    parser.add_argument("--port", help="transport URL or serial port (default: the file's)")
    args = read_negative_numbers(parser).parse_args(argv)
    try:
        rep = Reproducer.load(args.file)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        print(f"hil-fuzz replay: {args.file}: not a readable reproducer ({exc}); give a file "
              f"hil-fuzz saved (--out, default fuzz-findings/TARGET-seedN.json)",
              file=sys.stderr)
        return 2
    try:
        failure = replay(rep, args.port)
    except (ValueError, HostError) as exc:
        print(f"hil-fuzz replay: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("hil-fuzz replay: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    if failure is None:
        print(f"does not reproduce ({len(rep.steps)} steps on {rep.target})")
        return 0
    print(f"reproduced: {failure}")
    return 1


@guard_output("hil-fuzz")
def main(argv: Sequence[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if args and args[0] == "replay":
        return _replay(args[1:])
    return _fuzz(args)


if __name__ == "__main__":
    sys.exit(main())
