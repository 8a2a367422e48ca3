"""What every test shares: how ``make test`` shares the machine between tests, the
hypothesis profile, and the check that no test leaves anything behind.

``make test`` runs the suite on two pytest-xdist workers (``-n 2``), scheduled by
:func:`scope_of`:

* every test file runs whole on one worker, in its own order (a module's tests share
  module-scoped fixtures, such as one emulator, and some build on the state the test before
  left), except the files of :data:`SPREAD_FILES`, whose tests are independent of each
  other and long (the slot update's 200-case campaign, in shards): each of their tests is
  a unit of its own, for whichever worker is free;
* the files of :data:`WALL_CLOCK_FILES` (tests that hold wall-clock timing over real ptys,
  start the emulator as a process, load the machine with more than one CPU-bound process
  of their own — CPU hogs, local worker processes — or measure speed) form one unit,
  :data:`WALL_CLOCK_GROUP`, run on one worker, one test at a time.  So each of them has at
  most one other test beside it, an in-process simulation on the other worker: the "one
  other CPU-bound process" every such test is written to stand (their timing bounds come
  from what the emulator reports, not from an idle machine's margins).  A file whose tests
  time nothing and run one CPU-bound process at a time stays out, however long it takes:
  beside a wall-clock test it is that one other process (the compiled core's tests start a
  compiler, mypy or pip and wait for it; hil-fuzz's run on the in-process emulator, by its
  link's simulated clock).

xdist hands out the units in this order: the wall-clock group (one worker's serial chain,
the run's longest unit), then the files of :data:`LONG_FILES` (the longest files, longest
first, so that none of them is left to finish alone at the end), then the rest, the largest
(by number of tests) first, and the one-test units last.  Without xdist (``pytest`` alone,
``TEST_WORKERS=0``) the hook is never called.

Every test, and every module's fixtures, must leave no descriptor (a pty, a socket, a pipe,
a file), no non-daemon thread and no running emulator (on a thread or as a process)
behind: :func:`_leaves_nothing_behind` fails the test that did, naming what
(:mod:`tests.leaks`).

Hypothesis runs under the profile :data:`HYPOTHESIS_PROFILE`: no per-example deadline and no
"too slow" health check, which measure the machine (a loaded two-core machine takes
seconds where an idle one takes milliseconds), not the code under test.  A ``@settings``
without its own ``deadline`` inherits it.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any, Final

import pytest
from hypothesis import HealthCheck, settings

from tests import leaks

#: Measuring where the time goes: ``pytest --cpu-durations=N`` (:mod:`tests.cpu_durations`).
pytest_plugins = ["tests.cpu_durations"]

#: The hypothesis settings profile every test runs under (registered and loaded here).
HYPOTHESIS_PROFILE: Final = "any-machine"
settings.register_profile(HYPOTHESIS_PROFILE, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.load_profile(HYPOTHESIS_PROFILE)

#: The one scheduling unit of the tests in :data:`WALL_CLOCK_FILES`.
WALL_CLOCK_GROUP: Final = "wall-clock"

#: Test files (relative to ``tests/``) whose tests run one at a time on one worker.
WALL_CLOCK_FILES: Final = frozenset({
    "hil_emulator/test_emulator_over_the_wire.py",
    "hil_emulator/test_hil_emulator_command.py",
    "hil_emulator/test_realtime_loop.py",
    "hil_emulator/ports/test_pty_port.py",
    "hil_emulator/ports/test_port_reader.py",
    "hil_emulator/test_scheduling.py",
    "hil_emulator/ports/test_slcan_adapter.py",
    "hil_emulator/faults/test_fault_control.py",
    "hil_emulator/faults/test_host_link_faults.py",
    "host/transports/test_transports.py",
    "tools/test_handctl.py",
    "tools/test_handbus.py",
    "tools/test_cli_common.py",
    "tools/test_cli_help.py",
    "tools/test_hil_bench.py",
    "tools/test_demo_realtime.py",
    "benchmarks/test_benchmarks.py",
})


#: Test files (relative to ``tests/``) whose tests are each a scheduling unit of their own.
SPREAD_FILES: Final = frozenset({
    "bootloader/test_slot_campaign.py",
})


#: The test files (relative to ``tests/``) of most CPU time outside the wall-clock group,
#: longest first (``pytest --cpu-durations=N`` measures them): handed out before the others.
LONG_FILES: Final = (
    "tools/test_armctl_killed_with_a_reader.py",
    "tools/test_build_compiled.py",
    "tools/test_fit_hand.py",
    "tools/test_demo.py",
    "tools/test_hil_fuzz.py",
    "tools/test_bench_experiments.py",
    "host/arm/test_arm_interrupt_moments.py",
)


def scope_of(nodeid: str) -> str:
    """The scheduling unit of the test ``nodeid`` (``tests/<file>::<name>[params]``): its
    file, :data:`WALL_CLOCK_GROUP` for the files of :data:`WALL_CLOCK_FILES`, the test
    itself for those of :data:`SPREAD_FILES`."""
    path = nodeid.split("::", 1)[0]
    if path.removeprefix("tests/") in WALL_CLOCK_FILES:
        return WALL_CLOCK_GROUP
    return nodeid if path.removeprefix("tests/") in SPREAD_FILES else path


def handed_out(unit: str, tests: int) -> tuple[int, int, int]:
    """The order xdist hands out the unit ``unit`` (of :func:`scope_of`) of ``tests``
    tests in, as a sort key: the wall-clock group, :data:`LONG_FILES` in their order, the
    other units by number of tests (most first)."""
    if unit == WALL_CLOCK_GROUP:
        return (0, 0, 0)
    path = unit.split("::", 1)[0].removeprefix("tests/")
    if path in LONG_FILES and "::" not in unit:
        return (1, LONG_FILES.index(path), 0)
    return (2, 0, -tests)


@pytest.hookimpl(optionalhook=True)  # an xdist hook: unknown (and unused) without xdist
def pytest_xdist_make_scheduler(config: pytest.Config, log: Any) -> Any:
    """Whole units (:func:`scope_of`) to whichever worker is free, the largest (most tests)
    first."""
    from xdist.scheduler import LoadScopeScheduling

    class UnitScheduling(LoadScopeScheduling):  # type: ignore[misc]
        def _split_scope(self, nodeid: str) -> str:
            return scope_of(nodeid)

        def _assign_work_unit(self, node: Any) -> None:
            if not getattr(self, "_ordered", False):  # the whole queue is there by now
                ordered = sorted(self.workqueue.items(),
                                 key=lambda unit: handed_out(unit[0], len(unit[1])))
                self.workqueue.clear()
                self.workqueue.update(ordered)
                self._ordered = True
            super()._assign_work_unit(node)

    return UnitScheduling(config, log)


@pytest.fixture(autouse=True)
def _calibration_files_apart(tmp_path_factory: pytest.TempPathFactory,
                             monkeypatch: pytest.MonkeyPatch) -> None:
    """No test reads or writes the user's calibration files: each test's default calibration
    directory ($LOWCOST_CALIBRATION_DIR, host.estimation.calibration_file) is its own, empty."""
    monkeypatch.setenv("LOWCOST_CALIBRATION_DIR", str(tmp_path_factory.mktemp("calibration")))


@pytest.fixture(autouse=True)
def _leaves_nothing_behind(request: pytest.FixtureRequest) -> Iterator[None]:
    """Fail the test that leaves a descriptor (a pty, a socket, a file), a non-daemon thread or
    a running emulator behind (:mod:`tests.leaks`); its module's fixtures are checked when
    the module ends."""
    yield from _check(request, "")


@pytest.fixture(scope="module", autouse=True)
def _module_leaves_nothing_behind(request: pytest.FixtureRequest) -> Iterator[None]:
    """The same check over a whole module: what its module-scoped fixtures leave behind."""
    yield from _check(request, "the module's fixtures ")


_REPORTED: set[str] = set()


def _check(request: pytest.FixtureRequest, whose: str) -> Iterator[None]:
    before = leaks.snapshot()
    yield
    found = [x for x in leaks.leaked(before) if x not in _REPORTED]
    if request.scope == "function" and request.node.get_closest_marker("process_wide"):
        # A test that starts a server its library keeps for the life of the process (rerun's
        # web viewer) says so with ``@pytest.mark.process_wide("why")``: its descriptors
        # are not counted, now or later.
        _REPORTED.update(x for x in found if x.startswith("file descriptor "))
        found = [x for x in found if x not in _REPORTED]
    if found:
        _REPORTED.update(found)
        pytest.fail(f"{whose}left behind: " + "; ".join(found), pytrace=False)
