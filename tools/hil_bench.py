"""``hil-bench``: fault scenarios on the emulated robot, campaigns, reports.

    hil-bench run FILE… [--suite standard] [--seeds N|A,B,…] [--json OUT] [--report DIR]
                  [--workers N] [--scheduler tcp://HOST:8786]
    hil-bench list-faults [--json]
    hil-bench experiments ARGS…

``run`` runs each scenario (docs/HIL_BENCH.md) in fast mode on the in-process emulator: one
run per file × seed × ``campaign.vary`` combination, on ``--workers`` local processes or a
Dask scheduler (the same code path).  It prints one line per run and exits 0 only if every
assertion of every run holds (1 otherwise; 2 for a usage or scenario-file error).
``--json`` writes every result; ``--report`` a Markdown summary (opening with the pass rates
per fault class and per ``campaign.vary`` parameter value, and their bar charts), one JSON
per run and PNG plots around each fault.  ``list-faults`` prints the fault catalogue with parameters,
including those not implemented yet.  ``experiments`` hands its arguments to
``tools.bench_experiments``.
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
from collections.abc import Sequence
from typing import Any

from hil_emulator.errors import EmulatorError


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="hil-bench", description="Fault scenarios and "
                                     "campaigns on the emulated hand and arm.")
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run scenario files (or the standard suite)")
    run.add_argument("files", nargs="*", metavar="FILE", help="scenario TOML files")
    run.add_argument("--suite", choices=("standard",), help="add the built-in suite")
    run.add_argument("--seeds", metavar="N|A,B", help="N seeds 0..N-1, or a list of seeds "
                     "(default: each file's campaign.seeds or seed)")
    run.add_argument("--json", metavar="OUT", help="write every result to OUT (JSON)")
    run.add_argument("--report", metavar="DIR", help="write summary.md (pass rates per fault "
                     "class and parameter value, with bar charts), one JSON per run and "
                     "PNG plots around each fault into DIR")
    run.add_argument("--workers", type=int, default=1, metavar="N",
                     help="local processes (default 1: this process)")
    run.add_argument("--scheduler", metavar="ADDR",
                     help="a Dask distributed scheduler (tcp://127.0.0.1:8786) instead")
    lf = sub.add_parser("list-faults", help="the fault catalogue with parameters")
    lf.add_argument("--json", action="store_true", help="as JSON")
    # ``experiments`` takes its own options (--json, --report …), which argparse's REMAINDER
    # would refuse when they come first: main hands them over before parsing
    sub.add_parser("experiments", help="bench experiments (tools.bench_experiments): "
                   "hil-bench experiments [--json] [--report DIR] [--only NAME …] [--seed N]",
                   add_help=False)
    return parser


def _seeds(text: str | None) -> list[int] | None:
    if text is None:
        return None
    try:
        if "," in text:
            return [int(s) for s in text.split(",")]
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--seeds {text!r}: a count or a list") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"--seeds {text!r}: at least 1")
    return list(range(n))


def list_faults(as_json: bool) -> int:
    from hil_emulator.faults import catalogue

    entries = catalogue()
    if as_json:
        print(json.dumps(entries, indent=1))
        return 0
    for e in entries:
        mark = "" if e["implemented"] else "  [not yet implemented]"
        print(f"{e['name']}  ({e['entry_point'] or '-'}){mark}")
        print(f"    {e['summary']}")
        for p in e["parameters"]:  # type: ignore[attr-defined]
            print(f"    - {p['name']}: {p['type']} = {p['default']!r}")
    return 0


def run(args: argparse.Namespace) -> int:
    from tools.bench.campaign import expand, run_jobs
    from tools.bench.report import write_report
    from tools.bench.scenario import ScenarioError, standard_suite

    files = list(args.files)
    if args.suite == "standard":
        files += [str(p) for p in standard_suite()]
    if not files:
        print("hil-bench run: give scenario files or --suite standard", file=sys.stderr)
        return 2
    try:
        jobs = expand(files, _seeds(args.seeds), keep_trace=args.report is not None)
    except (ScenarioError, argparse.ArgumentTypeError, EmulatorError) as exc:
        print(f"hil-bench: {exc}", file=sys.stderr)
        return 2
    results = run_jobs(jobs, workers=args.workers, scheduler=args.scheduler)
    for r in results:
        failed = [a["id"] for a in r["assertions"] if not a["passed"]]
        verdict = "pass" if r["passed"] else f"FAIL ({', '.join(failed)})"
        print(f"{r['scenario']} seed {r['seed']}: {verdict}  [{r['sim_s']:.2f} s simulated, "
              f"{r['wall_s']:.1f} s wall]")
    if args.json:
        slim = [{k: v for k, v in r.items() if k != "trace"} for r in results]
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump(slim, f, indent=1)
    if args.report:
        write_report(results, args.report)
    passed = sum(r["passed"] for r in results)
    print(f"{passed} of {len(results)} runs passed")
    return 0 if passed == len(results) else 1


def experiments(argv: Sequence[str]) -> int:
    try:
        module: Any = importlib.import_module("tools.bench_experiments")
    except ModuleNotFoundError as exc:
        if exc.name != "tools.bench_experiments":
            raise
        print("hil-bench experiments: tools/bench_experiments.py is not installed in this "
              "tree (it is developed separately); nothing to run", file=sys.stderr)
        return 2
    return int(module.main(list(argv)) or 0)


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "experiments":
        return experiments(argv[1:])
    args = build_parser().parse_args(argv)
    if args.command == "list-faults":
        return list_faults(args.json)
    return run(args)


if __name__ == "__main__":
    raise SystemExit(main())
