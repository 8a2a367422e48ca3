"""Where the suite's time goes, measured as CPU time: ``pytest --cpu-durations=N``.

``--durations`` reports wall time, which on a loaded machine measures the load as much as the
test.  This plugin records, for each test's set-up, call and tear-down (module-scoped
fixtures count in the set-up of the module's first test and the tear-down of its last):

* ``wall``: seconds of wall time;
* ``cpu``: CPU seconds (user + system) of the process running the test, all its threads
  (an in-process emulator's included);
* ``children``: CPU seconds of the child processes that ended and were waited for meanwhile
  (``resource.getrusage(RUSAGE_CHILDREN)``: an emulator or CLI started as a process).

It then prints the ``N`` tests of most CPU (process + children) with their wall time, the
files of most CPU, and each xdist worker's totals (its busy wall time and its CPU: the two
workers' balance, and the longer one is the run's critical path).  ``--cpu-durations-json=PATH``
also writes every test's figures to ``PATH``, one JSON object a line as each test ends (a run
cut short keeps what it measured).  Without these options the plugin
measures nothing.
"""

from __future__ import annotations

import json
import os
import resource
import time
from collections import defaultdict
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from typing import Final

import pytest

#: The key of a phase's figures in a report's ``user_properties`` (how they travel from an
#: xdist worker to the controller).
PROPERTY: Final = "cpu_durations"


@dataclass
class Figures:
    """One test's time in seconds, over its set-up, call and tear-down."""

    nodeid: str
    worker: str
    wall: float = 0.0
    cpu: float = 0.0
    children: float = 0.0

    @property
    def total_cpu(self) -> float:
        """CPU seconds of the process and of its children."""
        return self.cpu + self.children


def pytest_addoption(parser: pytest.Parser) -> None:
    """``--cpu-durations=N`` and ``--cpu-durations-json=PATH``."""
    group = parser.getgroup("cpu-durations", "CPU time per test")
    group.addoption("--cpu-durations", type=int, default=None, metavar="N",
                    help="print the N tests of most CPU time (process and children), the files "
                         "of most and each worker's totals")
    group.addoption("--cpu-durations-json", default=None, metavar="PATH",
                    help="write every test's wall, CPU and children's CPU seconds to PATH "
                         "(JSON lines, as the tests end)")


def _enabled(config: pytest.Config) -> bool:
    return (config.getoption("--cpu-durations") is not None
            or config.getoption("--cpu-durations-json") is not None)


def _clocks() -> tuple[float, float, float]:
    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (time.perf_counter(), own.ru_utime + own.ru_stime,
            children.ru_utime + children.ru_stime)


@contextmanager
def _measured(item: pytest.Item, when: str) -> Iterator[None]:
    if not _enabled(item.config):
        yield
        return
    before = _clocks()
    try:
        yield
    finally:
        after = _clocks()
        wall, cpu, children = (b - a for a, b in zip(before, after, strict=True))
        item.user_properties.append(
            (PROPERTY, {"when": when, "wall": wall, "cpu": cpu, "children": children,
                        "worker": os.environ.get("PYTEST_XDIST_WORKER", "main")}))


@pytest.hookimpl(wrapper=True)
def pytest_runtest_setup(item: pytest.Item) -> Iterator[None]:
    """Measure the set-up (the phase's figures go with its report)."""
    with _measured(item, "setup"):
        return (yield)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item: pytest.Item) -> Iterator[None]:
    """Measure the call."""
    with _measured(item, "call"):
        return (yield)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_teardown(item: pytest.Item) -> Iterator[None]:
    """Measure the tear-down."""
    with _measured(item, "teardown"):
        return (yield)


class _Collector:
    """The controller's (or the only process's) tally of the phases' figures."""

    def __init__(self, path: str | None) -> None:
        self.tests: dict[str, Figures] = {}
        self.path = path
        if path:
            open(path, "w", encoding="utf-8").close()

    @pytest.hookimpl
    def pytest_runtest_logreport(self, report: pytest.TestReport) -> None:
        # a report carries the item's properties so far: count only this phase's
        for key, value in report.user_properties:
            if key != PROPERTY or not isinstance(value, dict) or value["when"] != report.when:
                continue
            figures = self.tests.setdefault(report.nodeid,
                                            Figures(report.nodeid, str(value["worker"])))
            figures.wall += value["wall"]
            figures.cpu += value["cpu"]
            figures.children += value["children"]
        if report.when == "teardown" and report.nodeid in self.tests and self.path:
            # one line per test as it ends: a run cut short keeps what it measured
            with open(self.path, "a", encoding="utf-8") as out:
                out.write(json.dumps(asdict(self.tests[report.nodeid])) + "\n")

    @pytest.hookimpl
    def pytest_terminal_summary(self, terminalreporter: pytest.TerminalReporter,
                                config: pytest.Config) -> None:
        tests = list(self.tests.values())
        count = config.getoption("--cpu-durations")
        if count is None:
            return
        write = terminalreporter.write_line
        terminalreporter.section("CPU time (seconds: wall, process CPU, children's CPU)")
        for t in sorted(tests, key=lambda t: -t.total_cpu)[:count]:
            write(f"{t.wall:8.1f} {t.cpu:8.1f} {t.children:8.1f}  {t.worker:5} {t.nodeid}")
        files: dict[str, list[float]] = defaultdict(lambda: [0.0, 0.0, 0.0])
        for t in tests:
            tally = files[t.nodeid.split("::", 1)[0]]
            tally[0] += t.wall
            tally[1] += t.cpu
            tally[2] += t.children
        write("files:")
        for name, (wall, cpu, children) in sorted(files.items(),
                                                  key=lambda f: -(f[1][1] + f[1][2]))[:count]:
            write(f"{wall:8.1f} {cpu:8.1f} {children:8.1f}  {name}")
        workers: dict[str, list[float]] = defaultdict(lambda: [0.0, 0.0, 0.0, 0.0])
        for t in tests:
            tally = workers[t.worker]
            tally[0] += t.wall
            tally[1] += t.cpu
            tally[2] += t.children
            tally[3] += 1
        write("workers (busy wall, CPU, children's CPU, tests):")
        for name, (wall, cpu, children, n) in sorted(workers.items()):
            write(f"{wall:8.1f} {cpu:8.1f} {children:8.1f}  {name} ({int(n)} tests)")


def pytest_configure(config: pytest.Config) -> None:
    """Tally the figures where the reports arrive (not on an xdist worker)."""
    if _enabled(config) and not hasattr(config, "workerinput"):
        config.pluginmanager.register(_Collector(config.getoption("--cpu-durations-json")),
                                      "cpu-durations-collector")
