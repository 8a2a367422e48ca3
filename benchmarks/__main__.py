"""``python -m benchmarks`` (``make bench``): run every benchmark, print rates and ratios.

Each ``bench_*`` module exposes ``run(quick) -> list[Result | Table]``; tables print after
the rates.  Ratios compare results of
the same group measured in this same run, so they hold on any machine.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
import time

import benchmarks
from benchmarks.harness import Result, Table


def _fmt(rate: float) -> str:
    for scale, suffix in ((1e9, "G"), (1e6, "M"), (1e3, "k")):
        if rate >= scale:
            return f"{rate / scale:8.2f}{suffix}"
    return f"{rate:9.1f}" if rate >= 10 or rate != rate else f"{rate:9.3f}"


def report(results: list[Result]) -> list[str]:
    """Table lines: group, name, value (a rate per second, or a figure in its unit where
    smaller is better), ratio to baseline, target met."""
    by_key = {(r.group, r.name): r for r in results}
    lines = [f"{'group':18s} {'name':34s} {'value':>10s} {'unit':6s} {'vs baseline':>14s}  target"]
    for r in results:
        ratio = ""
        if r.baseline and (r.group, r.baseline) in by_key:
            base = by_key[(r.group, r.baseline)].rate
            share = r.rate / base if base else 0.0
            digits = 2 if share < 10 else 1  # 0.96× is not 1.0×
            ratio = f"{share:8.{digits}f}× {r.baseline}" if base else ""
        target = ""
        if r.target is not None:
            bound = "≤" if r.at_most else "≥"
            target = f"{'met' if r.met else 'MISSED'} ({bound} {_fmt(r.target).strip()})"
        unit = r.unit if r.at_most else f"{r.unit}/s"
        lines.append(f"{r.group:18s} {r.name:34s} {_fmt(r.rate):>10s} {unit:6s} {ratio:>14s}  "
                     f"{target}{('  ' + r.note) if r.note else ''}")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks")
    parser.add_argument("--quick", action="store_true", help="shorter runs")
    parser.add_argument("only", nargs="*", help="module names (e.g. bench_framing)")
    args = parser.parse_args(argv)
    names = sorted(m.name for m in pkgutil.iter_modules(benchmarks.__path__)
                   if m.name.startswith("bench_"))
    if args.only:
        names = [n for n in names if n in args.only or n.removeprefix("bench_") in args.only]
    results: list[Result] = []
    tables: list[Table] = []
    for name in names:
        module = importlib.import_module(f"benchmarks.{name}")
        print(f"running {name} …", file=sys.stderr, flush=True)
        start = time.perf_counter()
        for item in module.run(quick=args.quick):
            (tables if isinstance(item, Table) else results).append(item)
        print(f"  {name}: {time.perf_counter() - start:.0f} s (wall)", file=sys.stderr, flush=True)
    print("\n".join(report(results)))
    for table in tables:
        print(f"\n{table.title}")
        print("\n".join(table.lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
