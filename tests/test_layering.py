"""The dependency rule of docs/ARCHITECTURE.md, checked by parsing every import.

Two towers on one ground floor: ``protocol`` at the bottom; the device tower
(``firmware_py``) and the host tower (``host``, then ``bootloader``) on it, never importing
each other; the emulator (``hil_emulator``) and the ``tools`` where they meet.  Imports inside
functions count too: a lazy import is still a dependency.
"""

from __future__ import annotations

import ast
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
OURS = ("protocol", "firmware_py", "hil_emulator", "host", "bootloader", "tools")
STDLIB = frozenset(sys.stdlib_module_names)


@dataclass(frozen=True)
class Rule:
    """What one package may import: our packages (by dotted prefix) and third-party ones."""

    ours: tuple[str, ...]
    third_party: tuple[str, ...] | None  # None: anything installed


RULES: dict[str, Rule] = {
    "protocol": Rule(("protocol",), ("construct", "crcmod", "numpy", "hypothesis")),
    # mypy_extensions: @mypyc_attr on the classes programs subclass (the compiled core)
    "firmware_py": Rule(("firmware_py", "protocol"), ("numpy", "mypy_extensions")),
    # rerun: the live browser view (host.view), imported only when a view is asked for
    "host": Rule(("host", "protocol"),
                 ("serial", "can", "dynamixel_sdk", "numpy", "mcap", "mcap_protobuf", "rerun")),
    "bootloader": Rule(("bootloader", "host", "protocol"),
                       ("serial", "can", "numpy", "cryptography", "intelhex", "elftools",
                        "nacl")),
    "hil_emulator": Rule(("hil_emulator", "firmware_py", "protocol", "host"), None),
    "tools": Rule(OURS, None),
}
#: The firmware proper sees only its HAL: the simulated HAL and board factories live in
#: ``firmware_py.sim``, which firmware modules outside it never import.
SIM_PACKAGE = "firmware_py.sim"


def imports_of(path: Path) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import statement in ``path``."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    package = ".".join(path.relative_to(ROOT).with_suffix("").parts[:-1])
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.extend((node.lineno, alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                module = ".".join([*base, node.module] if node.module else base)
            else:
                module = node.module or ""
            found.append((node.lineno, module))
    return found


def violations(package: str) -> list[str]:
    """Every import in ``package`` that its rule forbids, as ``file:line: module``."""
    rule = RULES[package]
    out = []
    for path in sorted((ROOT / package).rglob("*.py")):
        in_sim = path.relative_to(ROOT).as_posix().startswith(SIM_PACKAGE.replace(".", "/"))
        for line, module in imports_of(path):
            top = module.split(".")[0]
            where = f"{path.relative_to(ROOT)}:{line}: {module}"
            if top in OURS:
                if not any(module == p or module.startswith(p + ".") for p in rule.ours):
                    out.append(where)
                elif (package == "firmware_py" and not in_sim
                      and (module == SIM_PACKAGE or module.startswith(SIM_PACKAGE + "."))):
                    out.append(where + " (firmware proper importing the simulation)")
            elif top in STDLIB or top == "__future__":
                continue
            elif rule.third_party is not None and top not in rule.third_party:
                out.append(where)
    return out


@pytest.mark.parametrize("package", sorted(RULES))
def test_package_imports_only_what_the_layering_allows(package: str) -> None:
    assert violations(package) == []


def test_the_checker_sees_a_forbidden_import(tmp_path: Path) -> None:
    """The check can fail: a relative and an absolute import are both resolved."""
    probe = ROOT / "protocol" / "_layering_probe.py"
    probe.write_text("from firmware_py import hal\nfrom .framing import encode_frame\n",
                     encoding="utf-8")
    try:
        found = violations("protocol")
    finally:
        probe.unlink()
    assert found == ["protocol/_layering_probe.py:1: firmware_py"]


def test_repository_text_never_points_outside_the_repository() -> None:
    """Code and docs stand on their own: no paths into a sibling checkout."""
    offenders = []
    for path in ROOT.rglob("*"):
        if (path.suffix not in {".py", ".md", ".toml", ".cfg", ".txt"}
                or any(part.startswith(".") for part in path.relative_to(ROOT).parts)
                or path == Path(__file__).resolve()):
            continue
        text = path.read_text(encoding="utf-8", errors="replace")
        for needle in ("../shared", "shared/reference", "shared/DESIGN", "the issue"):
            if needle in text:
                offenders.append(f"{path.relative_to(ROOT)}: {needle}")
    assert offenders == []
