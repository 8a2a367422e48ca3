"""The compiled core: build (or remove) mypyc C extensions of the emulator's hot modules.

``python -m tools.build_compiled [--setup] [--clean] [--list] [--build-dir DIR] [--root DIR]``

mypyc compiles each module in :data:`COMPILED_MODULES` into a C extension written next to
its ``.py`` (``scheduler.cpython-311-x86_64-linux-gnu.so`` beside ``scheduler.py``), which
Python imports instead of the source, and their runtime library (``<hash>__mypyc.*.so``, at
the root); the build records what it was made from (the digest of every source it read,
:data:`protocol.compiled_guard.RECORD_NAME`), which decides at import time whether it is
current.  ``make compiled`` builds it; by default
(``COMPILED_CORE=no`` skips it) the set-up (``make install``, so every ``make`` target) runs
``--setup``: it builds the core where a C compiler exists, saying so in one line, and falls
back to pure Python with one line where it cannot; with ``LOWCOST_PURE_PYTHON=1`` it removes
any build and stays pure Python, and the same variable makes a process import the sources
although a build exists
(:mod:`protocol.compiled_guard`, which also ignores a build made from other sources, saying
so in one line).
``--clean`` (``make clean-compiled``) removes every extension.  Behaviour is the same either
way (the traffic digest of ``python -m tools.traffic_record`` is identical); only the speed
differs.  See the performance section of docs/EMULATOR.md.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import shutil
import sys
import sysconfig
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Final

from protocol import compiled_guard
from protocol.compiled_guard import (
    PURE_PYTHON_ENV,
    RECORD_NAME,
    extension_suffix,
    pure_python_requested,
    record,
    write_record,
)
from tools.cli.output import guard_output
from tools.errors import BuildError

#: The modules compiled, as paths relative to the repository root; declared once here.
#: Not protocol/manchester.py: its work is numpy's, and its public functions take what numpy
#: takes (array-likes, truthy flags), which a compiled signature would refuse with TypeError.
COMPILED_MODULES: Final[tuple[str, ...]] = (
    # the clock, the HAL and its in-memory implementation, and the wire formats
    "firmware_py/scheduler.py",
    "firmware_py/hal.py",
    "firmware_py/sim/virtual_hal.py",
    "firmware_py/sim/virtual_ports.py",
    "firmware_py/sim/virtual_drives.py",
    "firmware_py/sim/virtual_sensors.py",
    "protocol/crc.py",
    "protocol/framing.py",
    "protocol/stream.py",
    "protocol/dynamixel.py",
    "protocol/flat_codec.py",
    "protocol/catalogue.py",
    "protocol/topology.py",
    "protocol/sensor_counts.py",
    "protocol/control_tables.py",
    # the hand nodes' firmware (HandNode and every program built on it)
    "firmware_py/hand_node.py",
    "firmware_py/node_request.py",
    "firmware_py/boot_program.py",
    "firmware_py/fmcb.py",
    "firmware_py/fmcb_control.py",
    "firmware_py/current_governor.py",
    "firmware_py/phalange.py",
    "firmware_py/palm.py",
    "firmware_py/palm_router.py",
    # the arm nodes' firmware
    "firmware_py/dynamixel_slave.py",
    "firmware_py/arm_stepper.py",
    "firmware_py/stepper_settle.py",
    "firmware_py/rx64.py",
    # the buses and the plant
    "hil_emulator/lines/rs485_bus.py",
    "hil_emulator/plant.py",
    "hil_emulator/hand/finger_plant.py",
    "hil_emulator/hand/sensors.py",
    "hil_emulator/arm/plant.py",
    "hil_emulator/arm/actuators.py",
)

#: mypy options of the compile (as pyproject's [tool.mypy]).
_MYPY_FLAGS: Final = ("--ignore-missing-imports", "--explicit-package-bases",
                      "--python-version", "3.11")

#: The repository root (the directory holding ``protocol/``, ``firmware_py/`` …).
ROOT: Final = Path(__file__).resolve().parent.parent


def compiled_files(root: Path = ROOT) -> list[Path]:
    """Every built extension under the packages of ``root`` (what ``--clean`` removes)."""
    found: list[Path] = []
    for module in COMPILED_MODULES:
        source = root / module
        found += sorted(source.parent.glob(f"{source.stem}.*.so"))
        found += sorted(source.parent.glob(f"{source.stem}.*.pyd"))
    # An extension of a module no longer listed (an update dropped it) would still be
    # imported in preference to its source: every extension beside a source of ours counts.
    from protocol.compiled_guard import extensions

    found += [ext for ext, _source in extensions(root)]
    # mypyc's shared library of the group: beside a lone module, else at the root.
    found += _runtime_libraries(root)
    record = root / RECORD_NAME
    if record.is_file():
        found.append(record)
    return sorted(set(found))


def _runtime_libraries(root: Path) -> list[Path]:
    """mypyc's shared library of the group: beside a lone module, else at the root."""
    found: list[Path] = []
    for folder in {root, *((root / module).parent for module in COMPILED_MODULES)}:
        found += sorted(folder.glob("*__mypyc.*.so"))
    return found


def loaded_compiled() -> list[str]:
    """The modules of :data:`COMPILED_MODULES` this process imported as C extensions.

    Imports each (they are the emulator's own modules, cheap to import); an empty list means
    the pure-Python default is in use.
    """
    import importlib

    names = [module.removesuffix(".py").replace("/", ".") for module in COMPILED_MODULES]
    loaded = []
    for name in names:
        origin = getattr(importlib.import_module(name), "__file__", None) or ""
        if not origin.endswith(".py"):
            loaded.append(name)
    return loaded


def _site_packages() -> Path:
    """The running interpreter's site-packages (the set-up runs as the venv's python)."""
    return Path(sysconfig.get_paths()["platlib"])


def _unlink_shared_libraries(root: Path, site: Path) -> list[Path]:
    """Remove the links into ``root`` that earlier versions of the set-up made in
    site-packages for the runtime library (:mod:`protocol.compiled_guard` now loads it from
    the build's directory), and any such link whose library is gone."""
    removed = []
    for link in sorted(site.glob("*__mypyc.*.so")):
        if link.is_symlink() and (Path(os.readlink(link)).parent == root.resolve()
                                  or not link.exists()):
            link.unlink()
            removed.append(link)
    return removed


def _remove_from_wheel_build(root: Path) -> list[Path]:
    """Remove the extensions earlier versions of the build left in ``build/lib``, the
    directory setuptools builds the project's wheel in (a wheel would carry them, for a
    Python and sources they may not fit); returns what was removed."""
    removed = sorted((root / "build" / "lib").rglob("*.so"))
    for path in removed:
        path.unlink()
    return removed


def clean(root: Path = ROOT, build_dir: Path | None = None) -> list[Path]:
    """Remove the built extensions, their links in site-packages and the build directory;
    returns what was removed."""
    removed = compiled_files(root)
    for path in removed:
        path.unlink()
    removed += _unlink_shared_libraries(root, _site_packages())
    build = build_dir if build_dir is not None else root / "build"
    if build.is_dir():
        shutil.rmtree(build)
        removed.append(build)
    return removed


def build(root: Path = ROOT, build_dir: Path | None = None,
          modules: Sequence[str] = COMPILED_MODULES) -> list[Path]:
    """Compile ``modules`` (paths relative to ``root``) in place; returns the extensions.

    Raises :class:`BuildError` if mypyc or the C compiler is missing or fails.  mypy finds
    modules on ``sys.path`` too: call it from a process whose path holds no other copy of
    the packages (``python -m tools.build_compiled`` from ``root``).
    """
    try:
        from mypyc.build import mypycify
        from setuptools import Distribution
        from setuptools.errors import CCompilerError
    except ImportError as exc:  # pragma: no cover - mypy (with mypyc) is a test dependency
        raise BuildError(f"mypyc is not installed: {exc}") from exc
    if shutil.which(os.environ.get("CC", "cc")) is None and shutil.which("gcc") is None:
        raise BuildError("no C compiler (cc or gcc) on PATH")
    build_path = (build_dir if build_dir is not None else root / "build").resolve()
    (root / RECORD_NAME).unlink(missing_ok=True)  # no record while the build is partial
    _remove_from_wheel_build(root)
    made = record(root, modules, None)  # the sources as the build reads them
    here = Path.cwd()
    os.chdir(root)  # mypyc names the modules from paths relative to the working directory
    try:
        # The type-check options are pyproject's [tool.mypy] (a fresh type check of these
        # modules needs them, check_untyped_defs among them), plus the few that matter.
        config = ["--config-file", "pyproject.toml"] if (root / "pyproject.toml").is_file() else []
        extensions = mypycify([*config, *_MYPY_FLAGS, *modules], only_compile_paths=list(modules),
                              opt_level="3", target_dir=str(build_path / "mypyc"))
        # A bare Distribution: setuptools must not read pyproject.toml for this.
        dist = Distribution({"name": "lowcost_compiled", "ext_modules": extensions})
        command = dist.get_command_obj("build_ext")
        command.inplace = True  # type: ignore[attr-defined]
        command.build_temp = str(build_path / "temp")  # type: ignore[attr-defined]
        # Not build/lib: setuptools builds a wheel of the project there (pip install .),
        # and would pack whatever extensions it found in it (build_ext leaves a copy).
        command.build_lib = str(build_path / "mypyc-lib")  # type: ignore[attr-defined]
        dist.run_command("build_ext")
    except (SystemExit, CCompilerError) as exc:  # distutils may report it by exiting
        raise BuildError(f"the C build failed: {exc}") from exc
    except Exception as exc:
        raise BuildError(f"mypyc failed: {exc}") from exc
    finally:
        os.chdir(here)
    suffix = extension_suffix()
    runtimes = [lib for lib in _runtime_libraries(root) if lib.name.endswith(suffix)]
    made["runtime"] = runtimes[0].relative_to(root).as_posix() if runtimes else None
    write_record(root, made)
    return compiled_files(root)


def build_sources(root: Path = ROOT) -> list[str]:
    """The compiled modules and the sources of :data:`~protocol.compiled_guard.INLINED`
    (relative to ``root``): what the build's record has the digest of, and make's
    prerequisites of the set-up's step."""
    return compiled_guard.build_sources(root, COMPILED_MODULES)


def is_current(root: Path = ROOT, modules: Sequence[str] = COMPILED_MODULES) -> bool:
    """True when ``modules`` are built under ``root`` for this Python, and the build is
    usable whole and made from the sources as they are now (:mod:`protocol.compiled_guard`)."""
    made = compiled_guard.read_record(root)
    return (made is not None and made.get("modules") == sorted(modules)
            and compiled_guard.problem(root) is None)


@contextlib.contextmanager
def _output_to(log: Path) -> Iterator[None]:
    """Standard output and error of this process and its children (the C compiler) go to
    ``log`` for the duration."""
    log.parent.mkdir(parents=True, exist_ok=True)
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    with open(log, "wb") as out:
        os.dup2(out.fileno(), 1)
        os.dup2(out.fileno(), 2)
        try:
            yield
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])


def setup(root: Path = ROOT, build_dir: Path | None = None,
          modules: Sequence[str] = COMPILED_MODULES) -> str:
    """The set-up's step: build the compiled core (``modules``) unless pure Python is asked
    for or it is built and fresh already; never fails (any error of the build leaves pure
    Python).  Returns the one line it printed."""
    _unlink_shared_libraries(root, _site_packages())  # what an earlier set-up left
    _remove_from_wheel_build(root)
    if pure_python_requested():
        clean(root, build_dir)
        line = f"compiled core: not built ({PURE_PYTHON_ENV} is set): the emulator runs pure Python"
    elif is_current(root, modules):
        line = "compiled core: built already and up to date"
    else:
        print("compiled core: building it with mypyc (once; a few minutes on 2 cores; "
              f"{PURE_PYTHON_ENV}=1 skips it) ...", flush=True)
        started = time.monotonic()
        log = (build_dir if build_dir is not None else root / "build") / "compiled-core.log"
        try:
            with _output_to(log):
                build(root, build_dir, modules)
        except Exception as exc:  # a BuildError, or mypyc/setuptools failing another way
            clean(root, build_dir)
            reason = str(exc).splitlines()[0][:200] if str(exc) else type(exc).__name__
            line = (f"compiled core: cannot be built here ({reason}; see {log}): the emulator "
                    "runs pure Python")
        else:
            line = (f"compiled core: built in {time.monotonic() - started:.0f} s; the emulator "
                    "uses it")
    print(line, flush=True)
    return line


@guard_output("build_compiled")
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tools.build_compiled")
    parser.add_argument("--clean", action="store_true", help="remove the extensions")
    parser.add_argument("--setup", action="store_true",
                        help="as the set-up does: build where possible, else say so and "
                             "go on (exit 0)")
    parser.add_argument("--list", action="store_true", help="print the compiled modules")
    parser.add_argument("--sources", action="store_true",
                        help="print every source the build depends on: the compiled modules "
                             "and the sources whose constants it copies (make's prerequisites)")
    parser.add_argument("--root", type=Path, default=ROOT, help="repository root")
    parser.add_argument("--build-dir", type=Path, default=None,
                        help="intermediate files (default: ROOT/build)")
    parser.add_argument("--only", nargs="+", default=None, metavar="MODULE",
                        help="compile only these of the listed modules (paths as --list prints)")
    args = parser.parse_args(argv)
    modules = tuple(args.only) if args.only else COMPILED_MODULES
    unknown = sorted(set(modules) - set(COMPILED_MODULES))
    if unknown:
        print(f"build_compiled: not in the compiled core's list: {', '.join(unknown)} "
              "(see --list)", file=sys.stderr)
        return 2
    if args.list:
        print("\n".join(COMPILED_MODULES))
        return 0
    if args.sources:
        print("\n".join(build_sources(args.root)))
        return 0
    if args.setup:
        setup(args.root, args.build_dir)
        return 0
    if args.clean:
        for path in clean(args.root, args.build_dir):
            print(f"removed {path}")
        return 0
    try:
        built = build(args.root, args.build_dir, modules)
    except BuildError as exc:
        print(f"build_compiled: {exc}", file=sys.stderr)
        return 1
    for path in built:
        print(f"built {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
