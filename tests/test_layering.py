"""The dependency rule of docs/ARCHITECTURE.md, checked by parsing every import.

Two towers on one ground floor: ``protocol`` at the bottom; the device tower
(``firmware_py``) and the host tower (``host``, then ``bootloader``) on it, never importing
each other; the emulator (``hil_emulator``) and the ``tools`` where they meet.  Imports inside
functions (and under ``TYPE_CHECKING``) count too: a lazy import is still a dependency.

Inside the host library, the facades (:data:`FACADES`: ``host.arm.facade``,
``host.hand.facade``) sit on top of their helpers: no module of ``host`` but the package's
public names imports a facade (a helper takes a small ``Protocol`` of what it uses:
``host.arm.interface``, ``host.hand.interface``).  Each room (a folder by concept,
:data:`ROOMS`) imports only what its rule allows.

No modules import each other round a circle inside any package (:data:`CYCLE_FREE`: all
of them); between packages the rule above already allows none, so none remains anywhere.
"""

from __future__ import annotations

import ast
import shutil
import sys
from collections.abc import Mapping
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
    # rerun (and its pyarrow, the columns the view sends): the live browser view
    # (host.view.live), imported only when a view is asked for
    "host": Rule(("host", "protocol"),
                 ("serial", "can", "dynamixel_sdk", "numpy", "scipy", "mcap", "mcap_protobuf",
                  "rerun", "pyarrow")),
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


# ----------------------------------------------------------------------------- inside a package

#: The facades of the host library: what programs use, built on helpers that never import
#: them back.
#: (A helper imports a sibling by its full name, ``import host.arm.kinematics as …``: through
#: the package, ``from host.arm import …`` reaches the facade's names.)
FACADES = ("host.arm.facade", "host.hand.facade", "host.arm", "host.hand")

# ------------------------------------------------------------------------------------ the rooms

#: The host library's top: what every room may import.
HOST_TOP = ("host.errors", "host.code_names", "host.scheduling", "host.old_module_names")
#: Each room (a folder by concept) -> what of its own package it may import besides itself
#: (by dotted prefix); a package's top-level modules are not a room (docs/ARCHITECTURE.md).
ROOMS: dict[str, tuple[str, ...]] = {
    "host.transports": HOST_TOP,
    "host.recording": HOST_TOP,
    "host.estimation": HOST_TOP,
    # the view draws what the hand and the arm show it (their interfaces and kinematics)
    "host.view": (*HOST_TOP, "host.recording", "host.hand", "host.arm"),
    "host.hand": (*HOST_TOP, "host.transports", "host.estimation", "host.recording",
                  "host.view"),
    # the arm, like the hand, loads its calibration through estimation's calibration_file
    "host.arm": (*HOST_TOP, "host.transports", "host.estimation", "host.recording",
                 "host.view"),
    "hil_emulator.lines": (),
    "hil_emulator.ports": ("hil_emulator.errors",),
    "hil_emulator.hand": ("hil_emulator.errors", "hil_emulator.plant", "hil_emulator.ports",
                          "hil_emulator.lines"),
    "hil_emulator.arm": ("hil_emulator.errors", "hil_emulator.plant", "hil_emulator.ports",
                         "hil_emulator.lines"),
}
#: Outside the view's room, only the facades (and the package's public names) import it:
#: the view sits beside the hand and the arm, and their helpers never draw.
VIEW = "host.view"
VIEW_IMPORTERS = ("host", "host.arm.facade", "host.hand.facade")


def _under(module: str, prefix: str) -> bool:
    return module == prefix or module.startswith(prefix + ".")


def room_violations(graph: Mapping[str, set[str]]) -> list[str]:
    """``module -> target (room: rule)`` for every import the rooms' rules forbid."""
    out = []
    for module, targets in sorted(graph.items()):
        room = next((r for r in ROOMS if _under(module, r)), None)
        for target in sorted(targets):
            if room is not None and not _under(target, room) and not any(
                    _under(target, allowed) for allowed in ROOMS[room]):
                out.append(f"{module} -> {target} ({room} may import "
                           f"{', '.join(ROOMS[room]) or 'nothing of its package'})")
            elif (_under(target, VIEW) and not _under(module, VIEW)
                  and module not in VIEW_IMPORTERS):
                out.append(f"{module} -> {target} (only {', '.join(VIEW_IMPORTERS)} "
                           "import the view)")
    return out


@pytest.mark.parametrize("package", ["host", "hil_emulator"])
def test_each_room_imports_only_what_its_rule_allows(package: str) -> None:
    assert room_violations(import_graph(package)) == []


#: A forbidden import planted in each room (a copy of the package), and the view imported by
#: a helper: the rule must name each.
PLANTED = {
    "host.transports": "host.arm.state",
    "host.recording": "host.hand.state",
    "host.estimation": "host.arm.kinematics",
    "host.view": "host.transports.base",
    "host.hand": "host.arm.state",
    "host.arm": "host.hand.state",
    "hil_emulator.lines": "hil_emulator.errors",
    "hil_emulator.ports": "hil_emulator.plant",
    "hil_emulator.hand": "hil_emulator.arm.plant",
    "hil_emulator.arm": "hil_emulator.hand.rig",
}


@pytest.mark.parametrize("room", sorted(ROOMS))
def test_the_room_rule_sees_a_planted_violation(room: str, tmp_path: Path) -> None:
    assert sorted(PLANTED) == sorted(ROOMS)
    package = room.split(".")[0]
    shutil.copytree(ROOT / package, tmp_path / package,
                    ignore=shutil.ignore_patterns("*.so", "__pycache__"))
    probe = tmp_path / Path(*room.split(".")) / "_layering_probe.py"
    probe.write_text(f"def later() -> None:\n    import {PLANTED[room]}\n", encoding="utf-8")
    found = room_violations(import_graph(package, tmp_path))
    assert len(found) == 1
    assert found[0].startswith(f"{room}._layering_probe -> {PLANTED[room]} ({room} may import")


def test_the_room_rule_sees_a_helper_importing_the_view(tmp_path: Path) -> None:
    shutil.copytree(ROOT / "host", tmp_path / "host",
                    ignore=shutil.ignore_patterns("*.so", "__pycache__"))
    (tmp_path / "host" / "arm" / "_layering_probe.py").write_text(
        "from host.view.live import RobotView\n", encoding="utf-8")
    assert room_violations(import_graph("host", tmp_path)) == [
        "host.arm._layering_probe -> host.view.live (only host, host.arm.facade, "
        "host.hand.facade import the view)"]
#: Packages whose modules import no circle of each other: every one.
CYCLE_FREE = OURS


def module_name(path: Path, root: Path = ROOT) -> str:
    """``host/arm/facade.py`` -> ``host.arm.facade``; a package's ``__init__.py`` -> the package."""
    parts = path.relative_to(root).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph(package: str, root: Path = ROOT) -> dict[str, set[str]]:
    """Each module of ``package`` -> the modules of ``package`` it imports, by any import
    statement (in a function, under ``TYPE_CHECKING``); ``from host import arm_gate`` names
    the module ``host.arm.gate`` (and the package ``host``, whose ``__init__`` runs first)."""
    modules = {module_name(p, root): p for p in sorted((root / package).rglob("*.py"))}
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        here = name if path.name == "__init__.py" else name.rpartition(".")[0]
        found: set[str] = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                found.update(alias.name for alias in node.names)
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = here.split(".")[: len(here.split(".")) - node.level + 1]
                    base = ".".join([*up, node.module] if node.module else up)
                found.add(base)
                found.update(f"{base}.{alias.name}" for alias in node.names)
        graph[name] = {m for m in found if m in modules and m != name}
    return graph


def facade_importers(graph: Mapping[str, set[str]],
                     facades: tuple[str, ...] = FACADES) -> list[str]:
    """``module -> facade`` for every module of the graph that imports a facade."""
    return [f"{module} -> {target}" for module, targets in sorted(graph.items())
            for target in sorted(targets & set(facades))
            if module not in facades and module != "host"]


def import_cycles(graph: Mapping[str, set[str]]) -> list[list[str]]:
    """The import circles of ``graph``: each strongly connected set of two or more modules,
    sorted (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(out)


def test_no_host_module_imports_a_facade() -> None:
    """The facades import their helpers, never the other way round."""
    assert facade_importers(import_graph("host")) == []


@pytest.mark.parametrize("package", CYCLE_FREE)
def test_no_import_cycle_inside_the_package(package: str) -> None:
    assert import_cycles(import_graph(package)) == []


def test_the_checker_sees_a_facade_import_and_a_cycle(tmp_path: Path) -> None:
    """Both checks can fail: a helper importing its facade inside a function, and a circle
    closed by ``import host.arm.right`` under ``TYPE_CHECKING`` and a relative import."""
    arm = tmp_path / "host" / "arm"
    arm.mkdir(parents=True)
    (tmp_path / "host" / "__init__.py").write_text("", encoding="utf-8")
    (arm / "__init__.py").write_text("", encoding="utf-8")
    (arm / "facade.py").write_text("from host.arm import helper\n", encoding="utf-8")
    (arm / "helper.py").write_text(
        "def later():\n    from host.arm.facade import Arm\n", encoding="utf-8")
    (arm / "left.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import host.arm.right\n",
        encoding="utf-8")
    (arm / "right.py").write_text("from .left import x\n", encoding="utf-8")
    graph = import_graph("host", tmp_path)
    assert facade_importers(graph) == ["host.arm.helper -> host.arm.facade"]
    assert import_cycles(graph) == [["host.arm.facade", "host.arm.helper"],
                                    ["host.arm.left", "host.arm.right"]]


def test_the_cycle_check_sees_a_circle_closed_inside_a_function(tmp_path: Path) -> None:
    """A circle closed by a lazy import (the usual dodge), one through a package's
    ``__init__`` and one under ``TYPE_CHECKING`` are all found, each named by its modules."""
    package = tmp_path / "hil_emulator"
    (package / "faults").mkdir(parents=True)
    (package / "__init__.py").write_text("", encoding="utf-8")
    (package / "emulator.py").write_text("from hil_emulator import tap\n", encoding="utf-8")
    (package / "tap.py").write_text(
        "def later():\n    from hil_emulator.emulator import Emulator\n", encoding="utf-8")
    (package / "faults" / "__init__.py").write_text("from . import arm\n", encoding="utf-8")
    (package / "faults" / "arm.py").write_text("from hil_emulator.faults import targets\n",
                                               encoding="utf-8")
    (package / "faults" / "targets.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import hil_emulator.pacing\n",
        encoding="utf-8")
    (package / "pacing.py").write_text("import hil_emulator.faults.targets\n", encoding="utf-8")
    assert import_cycles(import_graph("hil_emulator", tmp_path)) == [
        ["hil_emulator.emulator", "hil_emulator.tap"],
        ["hil_emulator.faults", "hil_emulator.faults.arm"],
        ["hil_emulator.faults.targets", "hil_emulator.pacing"]]


def test_no_module_is_named_after_one_of_our_packages() -> None:
    """``import hil_emulator`` and ``tools.hil_emulator`` would name two things (the
    ``hil-emulator`` command is ``tools.cli.serve_emulator``; the node's boot program is
    ``firmware_py.boot_program``, not a second ``bootloader``)."""
    clashes = [str(path.relative_to(ROOT)) for package in OURS
               for path in (ROOT / package).rglob("*")
               if path.stem in OURS and (path.suffix == ".py" or path.is_dir())]
    assert clashes == []
