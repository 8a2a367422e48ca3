"""Which build of the emulator's hot modules Python imports: the compiled core or the source.

The set-up builds a compiled core (mypyc C extensions written beside their sources, see
``tools/build_compiled.py``) where it can; Python imports an extension in preference to the
``.py`` beside it.  :func:`install` (called by each package that has compiled modules, before
any of them is imported) makes every module of :data:`PACKAGES` load from its source instead
when

* :data:`PURE_PYTHON_ENV` is set to anything but ``""`` or ``0`` (pure Python on request), or
* any extension is older than its source, or than any source of :data:`INLINED` (a stale
  build: the edit must count), in which case it says so once on standard error.

All or nothing: compiled modules check the types of each other's objects, so a mix of a
compiled and a source module of one build could fail.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType
from typing import Final

#: Set (to anything but "" or "0") to import every module from its source: pure Python.
PURE_PYTHON_ENV: Final = "LOWCOST_PURE_PYTHON"
#: The packages whose modules may be compiled.
PACKAGES: Final = ("protocol", "firmware_py", "hil_emulator")
ROOT: Final = Path(__file__).resolve().parent.parent
#: Packages whose ``Final`` constants mypyc copies into the compiled modules that use them
#: (robot numbers, addresses, control tables): an edit there makes the whole build stale,
#: compiled or not.
INLINED: Final = ("protocol",)


def pure_python_requested() -> bool:
    """True when :data:`PURE_PYTHON_ENV` asks for pure Python."""
    return os.environ.get(PURE_PYTHON_ENV, "") not in ("", "0")


def extensions(root: Path = ROOT) -> list[tuple[Path, Path]]:
    """(extension, its source) for every compiled module under :data:`PACKAGES`."""
    found = []
    suffixes = tuple(importlib.machinery.EXTENSION_SUFFIXES)
    for package in PACKAGES:
        for ext in (root / package).rglob("*.so"):
            if not ext.name.endswith(suffixes):
                continue
            source = ext.with_name(ext.name.split(".", 1)[0] + ".py")
            if source.is_file():
                found.append((ext, source))
    return found


def stale(root: Path = ROOT) -> list[Path]:
    """Sources edited since their extension was built, and sources of :data:`INLINED`
    edited since the oldest extension was."""
    found = extensions(root)
    edited = [source for ext, source in found if source.stat().st_mtime > ext.stat().st_mtime]
    if found:
        oldest = min(ext.stat().st_mtime for ext, _ in found)
        compiled = {source for _, source in found}
        edited += [source for package in INLINED for source in sorted((root / package).rglob("*.py"))
                   if source not in compiled and source.stat().st_mtime > oldest]
    return edited


class SourceFirst:
    """A meta-path finder: modules of :data:`PACKAGES` from their ``.py`` files."""

    def find_spec(self, name: str, path: Sequence[str] | None,
                  target: ModuleType | None = None) -> importlib.machinery.ModuleSpec | None:
        if name.split(".", 1)[0] not in PACKAGES or path is None:
            return None
        leaf = name.rpartition(".")[2]
        for entry in path:
            source = os.path.join(entry, leaf + ".py")
            if os.path.isfile(source):
                return importlib.util.spec_from_file_location(name, source)
        return None


_decided: list[bool] = []


def install() -> bool:
    """Decide once per process; True when modules load from source although extensions
    exist (requested or stale)."""
    if _decided:
        return _decided[0]
    found = extensions()
    old = stale() if found else []
    source_first = bool(found) and (pure_python_requested() or bool(old))
    if source_first:
        sys.meta_path.insert(0, SourceFirst())  # type: ignore[arg-type]
        if old and not pure_python_requested():
            names = ", ".join(str(p.relative_to(ROOT)) for p in old[:3])
            more = f" and {len(old) - 3} more" if len(old) > 3 else ""
            print(f"note: the compiled core is older than {names}{more}: running pure "
                  "Python (`make compiled` rebuilds it)", file=sys.stderr)
    _decided.append(source_first)
    return source_first
