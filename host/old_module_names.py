"""The flat module names of before the layout by concept, kept as deprecated aliases.

Until the host library and the emulator grouped their modules into folders by concept
(``host.arm.cycle``, ``hil_emulator.hand.rig`` …), each was a flat module
(``host.arm_cycle``, ``hil_emulator.hand_rig``).  :func:`install` makes every old name
import the module it became (the same module object, so ``isinstance`` and monkeypatching
see one module), with a :class:`DeprecationWarning` naming the new place.  Type checkers do
not follow the aliases: import the new names in code that is type-checked.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
import types
import warnings
from collections.abc import Mapping, Sequence


class _AliasLoader(importlib.abc.Loader):
    """Loads an old name as the module it moved to (it replaces itself in ``sys.modules``)."""

    def __init__(self, new: str) -> None:
        self.new = new

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> types.ModuleType:
        return types.ModuleType(spec.name)

    def exec_module(self, module: types.ModuleType) -> None:
        warnings.warn(f"{module.__name__} is now {self.new}: import it from there",
                      DeprecationWarning, stacklevel=2)
        sys.modules[module.__name__] = importlib.import_module(self.new)


class _AliasFinder(importlib.abc.MetaPathFinder):
    """Finds the old names of one package (``old dotted name`` → ``new dotted name``)."""

    def __init__(self, moved: Mapping[str, str]) -> None:
        self.moved = dict(moved)

    def find_spec(self, fullname: str, path: Sequence[str] | None = None,
                  target: types.ModuleType | None = None
                  ) -> importlib.machinery.ModuleSpec | None:
        new = self.moved.get(fullname)
        if new is None:
            return None
        return importlib.machinery.ModuleSpec(fullname, _AliasLoader(new))


def install(package: str, moved: Mapping[str, str]) -> None:
    """Let ``package.<old>`` import ``package.<new>`` for each ``old: new`` of ``moved``
    (names relative to ``package``); installing a package's table twice is harmless."""
    table = {f"{package}.{old}": f"{package}.{new}" for old, new in moved.items()}
    for finder in sys.meta_path:
        if isinstance(finder, _AliasFinder) and finder.moved == table:
            return
    sys.meta_path.append(_AliasFinder(table))
