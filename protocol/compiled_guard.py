"""Which build of the emulator's hot modules Python imports: the compiled core or the source.

The set-up builds a compiled core (mypyc C extensions written beside their sources, and the
group's runtime library, see ``tools/build_compiled.py``) where it can, and records what it
was built from in :data:`RECORD_NAME` beside this module: the Python it was built for, the
runtime library, the compiled modules and a SHA-256 digest of every source the build read
(:func:`build_sources`).  Python imports an extension in preference to the ``.py`` beside
it.  :func:`install` (called by each package that has compiled modules, before any of them is
imported) decides once per process:

* the compiled core, whole, when the record matches what is on disk: the same Python, every
  recorded extension there and no other, the runtime library there and loadable (it is
  loaded from the build's own directory, so any interpreter of that Python importing these
  sources finds it: a second virtual environment's editable install, an IDE), and every
  source's digest as recorded;
* else every module of :data:`PACKAGES` from its source (pure Python), saying why in one
  line on standard error, with what rebuilds it for this kind of install (:func:`advice`) —
  or silently when :data:`PURE_PYTHON_ENV` asks for it, or when there is no build at all.

Staleness is by content, not by file times: a copy, a ``git checkout`` back and forth or a
``touch`` leave a build current; an edit of any source the build read makes it stale.  All or
nothing: compiled modules check the types of each other's objects, so a mix of a compiled and
a source module of one build could fail.
"""

from __future__ import annotations

import hashlib
import importlib.machinery
import importlib.util
import json
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType
from typing import Final

#: Set (to anything but "" or "0") to import every module from its source: pure Python.
PURE_PYTHON_ENV: Final = "LOWCOST_PURE_PYTHON"
#: Set by the first process of a command that said why the compiled core is not used, so
#: the processes it starts (the emulator's workers) do not say it again.
NOTED_ENV: Final = "LOWCOST_COMPILED_CORE_NOTED"
#: The packages whose modules may be compiled.
PACKAGES: Final = ("protocol", "firmware_py", "hil_emulator")
ROOT: Final = Path(__file__).resolve().parent.parent
#: Packages whose ``Final`` constants mypyc copies into the compiled modules that use them
#: (robot numbers, addresses, control tables): an edit there makes the whole build stale,
#: compiled or not.
INLINED: Final = ("protocol",)
#: What the build was made from (JSON, written by the build beside this module, relative to
#: the root: ``protocol/compiled_core.json``).
RECORD_NAME: Final = "protocol/compiled_core.json"
#: The record's layout; a record of another version counts as no record.
RECORD_VERSION: Final = 1
#: What :func:`problem` says where there is no build (nothing to say about it at run time).
NOT_BUILT: Final = "it is not built"
#: How many file names a note names before "and N more".
_NAMED: Final = 3


def pure_python_requested() -> bool:
    """True when :data:`PURE_PYTHON_ENV` asks for pure Python."""
    return os.environ.get(PURE_PYTHON_ENV, "") not in ("", "0")


def extension_suffix() -> str:
    """The file ending of this interpreter's own extensions (``.cpython-311-x86_64-linux-gnu.so``)."""
    return importlib.machinery.EXTENSION_SUFFIXES[0]


def extensions(root: Path = ROOT) -> list[tuple[Path, Path]]:
    """(extension, its source) for every extension this interpreter would import instead of
    a source of :data:`PACKAGES` (one built for another Python is not imported: not listed)."""
    found = []
    suffixes = tuple(importlib.machinery.EXTENSION_SUFFIXES)
    for package in PACKAGES:
        for ext in sorted([*(root / package).rglob("*.so"), *(root / package).rglob("*.pyd")]):
            stem = ext.name.split(".", 1)[0]
            source = ext.with_name(stem + ".py")
            if source.is_file() and ext.name.removeprefix(stem) in suffixes:
                found.append((ext, source))
    return found


def build_sources(root: Path, modules: Sequence[str]) -> list[str]:
    """Every source a build of ``modules`` (paths relative to ``root``) reads: the modules
    and the sources of :data:`INLINED`, relative to ``root``, sorted."""
    inlined = [path.relative_to(root).as_posix() for package in INLINED
               for path in (root / package).rglob("*.py")]
    return sorted(set(modules) | set(inlined))


def digest(path: Path) -> str:
    """SHA-256 of the file's bytes (hex); "" if it cannot be read."""
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return ""


def record(root: Path, modules: Sequence[str], runtime: str | None) -> dict[str, object]:
    """What a build of ``modules`` made now would record: this Python, the runtime library
    (its path relative to ``root``, None where mypyc made none) and every source's digest
    (:func:`build_sources`).  Taken before the build starts, so an edit made while it runs
    counts as an edit after it."""
    return {"version": RECORD_VERSION, "suffix": extension_suffix(), "runtime": runtime,
            "modules": sorted(modules),
            "sources": {name: digest(root / name) for name in build_sources(root, modules)}}


def write_record(root: Path, made: dict[str, object]) -> Path:
    """Write ``made`` (from :func:`record`) as the build's record; returns its path."""
    path = root / RECORD_NAME
    path.write_text(json.dumps(made, indent=1, sort_keys=True) + "\n", encoding="utf-8")
    return path


def read_record(root: Path = ROOT) -> dict[str, object] | None:
    """The build's record, or None (none, unreadable, of another layout)."""
    try:
        made = json.loads((root / RECORD_NAME).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(made, dict) or made.get("version") != RECORD_VERSION:
        return None
    return made


def _named(paths: Sequence[str]) -> str:
    more = f" and {len(paths) - _NAMED} more" if len(paths) > _NAMED else ""
    return ", ".join(paths[:_NAMED]) + more


def stale(root: Path = ROOT) -> list[str]:
    """The sources (relative to ``root``) whose content differs from what the build was made
    from: edited, removed, or new in a package of :data:`INLINED`; every extension's source
    where there is no record.  Empty for a current build (and where there is no build)."""
    found = extensions(root)
    made = read_record(root)
    if made is None:
        return [source.relative_to(root).as_posix() for _, source in found]
    recorded = made.get("sources")
    modules = made.get("modules")
    if not isinstance(recorded, dict) or not isinstance(modules, list):
        return [source.relative_to(root).as_posix() for _, source in found]
    now = build_sources(root, [str(m) for m in modules])
    return sorted({name for name in now if recorded.get(name) != digest(root / name)}
                  | {str(name) for name in recorded if name not in now})


def problem(root: Path = ROOT) -> str | None:
    """Why the build under ``root`` cannot be used whole (a few words), or None when it can:
    there is a build for this Python, and it is exactly what :data:`RECORD_NAME` records."""
    found = extensions(root)
    made = read_record(root)
    if not found:
        if made is not None and made.get("suffix") != extension_suffix():
            return (f"it was built for another Python ({made.get('suffix')}; this one is "
                    f"{extension_suffix()})")
        return NOT_BUILT
    if made is None:
        return f"it has no record of what it was built from, {RECORD_NAME}"
    if made.get("suffix") != extension_suffix():
        return f"its record is of a build for another Python ({made.get('suffix')})"
    listed = made.get("modules")
    modules = {str(m) for m in listed} if isinstance(listed, list) else set()
    have = {source.relative_to(root).as_posix() for _, source in found}
    if have - modules:
        return f"extensions not of its build are there ({_named(sorted(have - modules))})"
    if modules - have:
        return f"its extensions of {_named(sorted(modules - have))} are missing"
    runtime = made.get("runtime")
    if runtime is not None and not (root / str(runtime)).is_file():
        return f"its runtime library {runtime} is missing"
    edited = stale(root)
    if edited:
        return f"it was built from other versions of {_named(edited)}"
    return None


def advice(root: Path = ROOT) -> str:
    """What builds the compiled core under ``root`` anew, for the kind of install it is: a
    checkout (it has the Makefile, whose venv builds it), or a copy of the packages, or a
    checkout imported by another Python than the one it was built with."""
    made = read_record(root)
    if made is not None and made.get("suffix") != extension_suffix():
        return f"`python -m tools.build_compiled` in {root} with this Python builds one for it"
    if (root / "Makefile").is_file() and (root / "tools" / "build_compiled.py").is_file():
        return "`make compiled` rebuilds it"
    return (f"`python -m tools.build_compiled --root {root}` rebuilds it, "
            "`--clean` removes it")


def load_runtime(root: Path = ROOT) -> None:
    """Load the build's runtime library (mypyc's shared library of the group, which every
    compiled module imports as a top-level module) from the build's directory, so the
    compiled modules find it whatever ``sys.path`` holds.  Raises ImportError (or OSError)
    when it cannot be loaded."""
    made = read_record(root)
    runtime = made.get("runtime") if made is not None else None
    if runtime is None:
        return
    path = root / str(runtime)
    name = path.name.split(".", 1)[0]
    if name in sys.modules:
        return
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise ImportError(f"cannot load {path}")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise


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


def decide(root: Path = ROOT) -> str | None:
    """Whether the build under ``root`` is used: None for the compiled core (its runtime
    loaded), else the one line saying why not and what to do ("" when nothing needs saying:
    pure Python asked for, or no build at all)."""
    if pure_python_requested():
        return ""
    why = problem(root)
    if why is None:
        try:
            load_runtime(root)
        except (ImportError, OSError) as exc:
            why = f"its runtime library does not load: {str(exc).splitlines()[0][:120]}"
        else:
            return None
    if why == NOT_BUILT:
        return ""
    return f"note: the compiled core is not used ({why}): running pure Python ({advice(root)})"


_decided: list[bool] = []


def install() -> bool:
    """Decide once per process (:func:`decide`); True when modules load from source although
    extensions exist (pure Python asked for, or a build that cannot be used whole)."""
    if _decided:
        return _decided[0]
    line = decide()
    source_first = line is not None and bool(extensions())
    if source_first:
        sys.meta_path.insert(0, SourceFirst())  # type: ignore[arg-type]
    if line and not os.environ.get(NOTED_ENV):
        print(line, file=sys.stderr)
        os.environ[NOTED_ENV] = "1"  # the processes this one starts decide alike: quietly
    _decided.append(source_first)
    return source_first
