"""One exception tree per package: every public exception class a package defines derives
from its package's base, is listed in its ``errors.py``, and no two packages (nor two
modules) define one of the same name."""

from __future__ import annotations

import importlib
import pkgutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Each package's base, from its errors.py.
BASES = {
    "protocol": "ProtocolError",
    "firmware_py": "FirmwareError",
    "hil_emulator": "EmulatorError",
    "host": "HostError",
    "bootloader": "FlashError",
    "tools": "ToolError",
}


def _modules(package: str) -> list[str]:
    names = [package]
    for info in pkgutil.walk_packages([str(ROOT / package)], prefix=package + "."):
        if info.name.rsplit(".", 1)[-1] != "__main__":  # running it is not importing it
            names.append(info.name)
    return names


def _defined_exceptions(package: str) -> list[type[BaseException]]:
    found: list[type[BaseException]] = []
    for name in _modules(package):
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:  # an optional extra (rerun, atheris) not installed
            if exc.name is not None and exc.name.split(".")[0] in BASES:
                raise
            continue
        for value in vars(module).values():
            if (isinstance(value, type) and issubclass(value, Exception)
                    and value.__module__ == name and not value.__name__.startswith("_")):
                found.append(value)
    return found


@pytest.mark.process_wide("importing host's view modules starts rerun's runtime, kept for the "
                          "process")
@pytest.mark.parametrize("package", sorted(BASES))
def test_every_exception_of_a_package_is_in_its_tree_and_listed(package: str) -> None:
    base = getattr(importlib.import_module(f"{package}.errors"), BASES[package])
    listed = (ROOT / package / "errors.py").read_text(encoding="utf-8")
    outside = [f"{c.__module__}.{c.__name__}" for c in _defined_exceptions(package)
               if not issubclass(c, base)]
    unlisted = [f"{c.__module__}.{c.__name__}" for c in _defined_exceptions(package)
                if c.__name__ not in listed]
    assert outside == [] and unlisted == []


def test_no_two_exceptions_share_a_name() -> None:
    seen: dict[str, str] = {}
    clashes = []
    for package in BASES:
        for cls in _defined_exceptions(package):
            where = f"{cls.__module__}.{cls.__name__}"
            if seen.setdefault(cls.__name__, where) != where:
                clashes.append(f"{seen[cls.__name__]} and {where}")
    assert clashes == []


def test_missing_accelerometers_are_the_robots_state_not_a_usage_error() -> None:
    from host.errors import HostError, UsageError
    from host.estimation.closed_form import NoAccelerationError

    assert issubclass(NoAccelerationError, HostError)
    assert not issubclass(NoAccelerationError, UsageError)
