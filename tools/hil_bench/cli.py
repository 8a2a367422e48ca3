"""``hil-bench``: fault scenarios on the emulated robot, campaigns, reports.

    hil-bench run FILE|NAME… [--suite standard] [--seeds N|A,B,… | --seed N]
                  [--set KEY=VALUE …] [--profile FILE] [--json OUT] [--report DIR]
                  [--workers N] [--scheduler tcp://HOST:8786]
    hil-bench list-scenarios [--json]
    hil-bench list-faults [--json]
    hil-bench replay RECORDING.mcap [--json] [--tolerance CHANNEL=VALUE …] [--seed N]
                  [--sensors ideal|realistic] [--profile FILE|none] [--report DIR]
    hil-bench fit RECORDING.mcap… --params NAME… [--out PROFILE] [--json] [--workers N]
                  [--scheduler ADDR] [--tolerance CHANNEL=VALUE …]
    hil-bench experiments ARGS…

``run`` runs each scenario (docs/HIL_BENCH.md) in fast mode on the in-process emulator: one
run per file × seed × ``campaign.vary`` combination, on ``--workers`` local processes or a
Dask scheduler (the same code path).  It prints one line per run and exits 0 only if every
assertion of every run holds (1 otherwise; 2 for a usage or scenario-file error; 130 after
Ctrl-C, with the runs finished so far printed, written to ``--json`` and reported).  A
failed run prints the command that runs it alone (``--seed``, ``--set``).
``--json`` writes every result; ``--report`` a Markdown summary (opening with the pass rates
per fault class and per ``campaign.vary`` parameter value, and their bar charts), one JSON
per run and PNG plots around each fault.  ``list-scenarios`` prints the built-in
scenarios (a NAME ``run`` takes instead of a file).  ``list-faults`` prints the fault catalogue with parameters,
including those not implemented yet.  ``replay`` drives an emulator with a recording's host
bytes and compares its answers with the recorded robot's (:mod:`tools.hil_bench.replay`);
``fit`` estimates the physical parameters that best reproduce recordings and writes a robot
profile (:mod:`tools.hil_bench.fit`).
``experiments`` hands its arguments to
``tools.experiments.dissertation``.
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hil_emulator.errors import EmulatorError
from tools.cli.common import EXIT_INTERRUPTED, unwritable
from tools.cli.numeric import number_above, read_negative_numbers
from tools.cli.output import guard_output


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="hil-bench", description="Fault scenarios and "
                                     "campaigns on the emulated hand and arm.")
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run scenario files (or the standard suite)")
    run.add_argument("files", nargs="*", metavar="FILE|NAME",
                     help="scenario TOML files, or names of built-in scenarios "
                     "(hil-bench list-scenarios)")
    run.add_argument("--suite", choices=("standard",), help="add the built-in suite")
    seeds = run.add_mutually_exclusive_group()
    seeds.add_argument("--seeds", metavar="N|A,B", help="N seeds 0..N-1, or a list of seeds "
                       "(default: each file's campaign.seeds or seed)")
    seeds.add_argument("--seed", type=_SEED, metavar="N",
                       help="this one seed (what a failed run prints to reproduce it)")
    run.add_argument("--set", action="append", type=_setting, default=[],
                     metavar="KEY=VALUE", help="set a scenario key by its dotted path "
                     "(faults.0.params.probability=0.2; VALUE as in TOML, else text); a key "
                     "the file's campaign.vary varies takes only this value")
    run.add_argument("--profile", metavar="FILE", help="a robot profile (JSON, hil-bench fit "
                     "--out): every run's emulator has its physical parameters")
    run.add_argument("--json", metavar="OUT", help="write every result to OUT (JSON)")
    run.add_argument("--report", metavar="DIR", help="write summary.md (pass rates per fault "
                     "class and parameter value, with bar charts), one JSON per run and "
                     "PNG plots around each fault into DIR")
    run.add_argument("--workers", type=_WORKERS, default=1, metavar="N",
                     help="local processes (default 1: this process)")
    run.add_argument("--scheduler", metavar="ADDR",
                     help="a Dask distributed scheduler (tcp://127.0.0.1:8786) instead")
    ls = sub.add_parser("list-scenarios", help="the built-in scenarios (--suite standard)")
    ls.add_argument("--json", action="store_true", help="as JSON")
    lf = sub.add_parser("list-faults", help="the fault catalogue with parameters")
    lf.add_argument("--json", action="store_true", help="as JSON")
    from tools.hil_bench.fit.command import add_arguments as add_fit
    from tools.hil_bench.replay.command import add_arguments

    add_arguments(sub)
    add_fit(sub)
    # ``experiments`` takes its own options (--json, --report …), which argparse's REMAINDER
    # would refuse when they come first: main hands them over before parsing
    sub.add_parser("experiments", help="bench experiments (tools.experiments.dissertation): "
                   "hil-bench experiments [--json] [--report DIR] [--only NAME …] [--seed N]",
                   add_help=False)
    return parser


#: ``--seed``: one seed, an integer >= 0; ``--workers``: a number of processes >= 1.
_SEED = number_above(0, int, inclusive=True, what="a seed")
_WORKERS = number_above(1, int, inclusive=True, what="a number of processes")


def _setting(text: str) -> tuple[str, Any]:
    """An argparse type: ``KEY=VALUE``, VALUE read as a TOML value (``0.2``, ``true``,
    ``[1, 2]``, ``"x"``), else kept as text."""
    key, sep, value = text.partition("=")
    if not sep or not key.strip():
        raise argparse.ArgumentTypeError(f"{text!r}: KEY=VALUE, e.g. "
                                         f"faults.0.params.probability=0.2")
    try:
        parsed: Any = tomllib.loads(f"v = {value}")["v"]
    except tomllib.TOMLDecodeError:
        parsed = value
    return key.strip(), parsed


def run_line(result: dict[str, Any]) -> str:
    """The line ``run`` prints for one result (its overrides by their last key)."""
    from tools.hil_bench.report import override_texts

    failed = [a["id"] for a in result["assertions"] if not a["passed"]]
    verdict = "pass" if result["passed"] else f"FAIL ({', '.join(failed)})"
    where = "".join(f" {k}" for k in override_texts(result))
    return (f"{result['scenario']} seed {result['seed']}{where}: {verdict}  "
            f"[{result['sim_s']:.2f} s simulated, {result['wall_s']:.1f} s wall]")


def unchecked_failures(result: dict[str, Any]) -> list[tuple[str, str]]:
    """The actions of a run that failed while no assertion looks at them (``action_ok``,
    ``action_fails``, ``flash_verified``, ``cleared_by``): (id, error).  They do not fail
    the run, but a scenario whose actions all failed should not read as a plain pass."""
    checked = {a["params"].get(key) for a in result["assertions"]
               for key in ("action", "cleared_by")}
    return [(name, str(a.get("error", ""))) for name, a in result["actions"].items()
            if not a["ok"] and name not in checked]


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


def list_scenarios(as_json: bool) -> int:
    from tools.hil_bench.scenario import load_scenario, standard_suite

    entries: list[dict[str, Any]] = []
    for path in standard_suite():
        sc = load_scenario(path)
        entries.append({"name": path.stem, "config": sc.config, "physics": sc.physics,
                        "faults": list(dict.fromkeys(e.fault.name for e in sc.faults)),
                        "description": sc.description, "path": str(path)})
    if as_json:
        print(json.dumps(entries, indent=1))
        return 0
    for e in entries:
        print(f"{e['name']}  ({e['config']}{'' if e['physics'] else ', no physics'}; "
              f"faults: {', '.join(e['faults']) or '-'})")
        print(f"    {e['description']}")
    return 0


def _writable(args: argparse.Namespace) -> str | None:
    """Why ``--json`` or ``--report`` cannot be written (checked, and the report's
    directory made, before anything runs, so a typo does not lose a campaign), or None."""
    if args.json and (problem := unwritable(args.json)):
        return f"--json {args.json}: {problem}"
    if args.report:
        try:
            Path(args.report).mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            return f"--report {args.report}: cannot make that directory: {exc.strerror}"
    return None


def run(args: argparse.Namespace) -> int:
    from hil_emulator.profile import load_profile
    from tools.hil_bench.campaign import connect_scheduler, expand, iter_jobs
    from tools.hil_bench.report import reproduce_command, write_report
    from tools.hil_bench.scenario import ScenarioError, standard_suite

    files = list(args.files)
    if args.suite == "standard":
        files += [str(p) for p in standard_suite()]
    if not files:
        print("hil-bench run: give scenario files or names (hil-bench list-scenarios), or "
              "--suite standard", file=sys.stderr)
        return 2
    try:
        seeds = [args.seed] if args.seed is not None else _seeds(args.seeds)
        profile = load_profile(args.profile) if args.profile else None
        jobs = expand(files, seeds, keep_trace=args.report is not None,
                      fixed=dict(args.set), profile=profile)
    except (ScenarioError, argparse.ArgumentTypeError, EmulatorError) as exc:
        print(f"hil-bench: {exc}", file=sys.stderr)
        return 2
    if problem := _writable(args):
        print(f"hil-bench: {problem}", file=sys.stderr)
        return 2
    try:
        scheduler = connect_scheduler(args.scheduler) if args.scheduler else None
    except ConnectionError as exc:
        print(f"hil-bench: {exc}", file=sys.stderr)
        return 2
    results: list[dict[str, Any]] = []
    interrupted = False
    try:
        for r in iter_jobs(jobs, workers=args.workers, scheduler=scheduler):
            results.append(r)
            print(run_line(r), flush=True)
            for name, error in unchecked_failures(r):
                print(f"    note: action {name} failed (no assertion checks it): {error}",
                      flush=True)
            if not r["passed"]:
                print(f"    reproduce: {reproduce_command(r)}", flush=True)
    except KeyboardInterrupt:
        interrupted = True
        print(f"hil-bench: interrupted: {len(results)} of {len(jobs)} runs finished; "
              f"what they measured is kept", file=sys.stderr)
    finally:
        if scheduler is not None:
            scheduler.close()
    if args.json:
        slim = [{k: v for k, v in r.items() if k != "trace"} for r in results]
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump(slim, f, indent=1)
    if args.report:
        write_report(results, args.report, planned=len(jobs))
    passed = sum(r["passed"] for r in results)
    if interrupted:
        print(f"{passed} of {len(results)} runs passed (interrupted: {len(jobs) - len(results)}"
              f" of {len(jobs)} not run)")
        return EXIT_INTERRUPTED
    print(f"{passed} of {len(results)} runs passed")
    return 0 if passed == len(results) else 1


def experiments(argv: Sequence[str]) -> int:
    try:
        module: Any = importlib.import_module("tools.experiments.dissertation")
    except ModuleNotFoundError as exc:
        if exc.name != "tools.experiments.dissertation":
            raise
        print("hil-bench experiments: tools/experiments/dissertation.py is not installed in this "
              "tree (it is developed separately); nothing to run", file=sys.stderr)
        return 2
    return int(module.main(list(argv)) or 0)


@guard_output("hil-bench")
def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "experiments":
        return experiments(argv[1:])
    args = read_negative_numbers(build_parser()).parse_args(argv)
    if args.command == "list-faults":
        return list_faults(args.json)
    if args.command == "list-scenarios":
        return list_scenarios(args.json)
    if args.command == "replay":
        from tools.hil_bench.replay.command import run as replay

        return replay(args)
    if args.command == "fit":
        from tools.hil_bench.fit.command import run as fit

        return fit(args)
    return run(args)


if __name__ == "__main__":
    raise SystemExit(main())
