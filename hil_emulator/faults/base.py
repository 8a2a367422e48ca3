"""What every fault is: one class with typed parameters, a seeded ``apply`` and a ``clear``.

A fault is a dataclass whose fields are its parameters (units in each field's docstring
comment); the class names its registry key (:attr:`Fault.name`), the emulator entry point it
acts through (:attr:`Fault.entry_point`) and a one-line summary.  Declaring a subclass with a
``name`` registers it in :data:`FAULTS`; that is all adding a fault takes (and its test).

``apply(emulator, rng)`` starts the fault, drawing any randomness it needs from ``rng`` (a
generator the :class:`~hil_emulator.faults.injector.FaultInjector` derives from the run's
seed, the plan entry and the occurrence, so a replay draws the same numbers);
``clear(emulator)`` ends it and restores what ``apply`` changed.  A fault instance keeps what
it needs to restore in private attributes, so one instance is applied and cleared in turn.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from typing import TYPE_CHECKING, Any, ClassVar, Final

import numpy as np

from hil_emulator.errors import FaultPlanError

if TYPE_CHECKING:
    from hil_emulator.emulator import Emulator

__all__ = ["ENTRY_POINTS", "FAULTS", "NOT_YET_IMPLEMENTED", "Fault", "make_fault"]

#: The emulator entry points a fault acts through.
ENTRY_POINTS: Final = ("line model", "node power", "plant force", "port", "node", "flash")

#: Every implemented fault by name (filled by subclassing :class:`Fault`).
FAULTS: dict[str, type[Fault]] = {}

#: Faults of the catalogue not implemented yet: name → what it would do.  ``hil-bench
#: list-faults`` prints them as such.  Empty: every fault of the catalogue is implemented.
NOT_YET_IMPLEMENTED: Final[dict[str, str]] = {}


@dataclasses.dataclass
class Fault:
    """Base of every fault.  Subclasses are dataclasses whose fields are the parameters."""

    name: ClassVar[str] = ""
    entry_point: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    #: True for a fault that acts once (a reset, a press of a button): nothing to clear.
    instantaneous: ClassVar[bool] = False

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if cls.__dict__.get("name"):
            if cls.entry_point not in ENTRY_POINTS:
                raise TypeError(f"fault {cls.name}: entry point {cls.entry_point!r} is not "
                                f"one of {ENTRY_POINTS}")
            if cls.name in FAULTS:
                raise TypeError(f"fault {cls.name!r} is declared twice")
            FAULTS[cls.name] = cls

    def apply(self, emulator: Emulator, rng: np.random.Generator) -> None:
        """Start the fault on ``emulator`` (randomness from ``rng`` only)."""
        raise NotImplementedError

    def clear(self, emulator: Emulator) -> None:
        """End the fault and restore what :meth:`apply` changed (nothing by default)."""

    def params(self) -> dict[str, Any]:
        """The parameters as plain data (what a plan file or the timeline holds)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.init}

    @classmethod
    def parameters(cls) -> list[tuple[str, str, Any]]:
        """(name, type, default or ``None`` when required) of each parameter."""
        hints = typing.get_type_hints(cls)
        out = []
        for f in dataclasses.fields(cls):
            if not f.init:
                continue
            default = f.default if f.default is not dataclasses.MISSING else None
            out.append((f.name, _type_name(hints[f.name]), default))
        return out


def _type_name(tp: Any) -> str:
    if isinstance(tp, type):
        return tp.__name__
    return str(tp).replace("typing.", "")


def _coerce(where: str, value: Any, tp: Any) -> Any:
    """``value`` checked against the annotation ``tp`` (int, float, str, bool, X | None)."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        options = typing.get_args(tp)
        if value is None and type(None) in options:
            return None
        for option in options:
            if option is type(None):
                continue
            try:
                return _coerce(where, value, option)
            except FaultPlanError:
                continue
        raise FaultPlanError(f"{where}: {value!r} is not a {_type_name(tp)}")
    if origin is typing.Literal:
        if value not in typing.get_args(tp):
            raise FaultPlanError(f"{where}: {value!r} is not one of {typing.get_args(tp)}")
        return value
    if tp is float and isinstance(value, int | float) and not isinstance(value, bool):
        return float(value)
    if tp is int and isinstance(value, int) and not isinstance(value, bool):
        return value
    if tp is bool and isinstance(value, bool):
        return value
    if tp is str and isinstance(value, str):
        return value
    raise FaultPlanError(f"{where}: {value!r} is not a {_type_name(tp)}")


def make_fault(name: str, params: dict[str, Any] | None = None, where: str = "fault") -> Fault:
    """The fault ``name`` with ``params`` checked (unknown, missing or mistyped parameters
    raise :class:`FaultPlanError` naming the key under ``where``)."""
    cls = FAULTS.get(name)
    if cls is None:
        hint = (" (in the catalogue, not implemented yet)" if name in NOT_YET_IMPLEMENTED
                else f"; known faults: {', '.join(sorted(FAULTS))}")
        raise FaultPlanError(f"{where}: unknown fault {name!r}{hint}")
    params = dict(params or {})
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(params) - set(fields))
    if unknown:
        raise FaultPlanError(f"{where}.params.{unknown[0]}: fault {name!r} has no parameter "
                             f"{unknown[0]!r}; it takes {', '.join(fields) or 'none'}")
    values = {}
    for key, f in fields.items():
        if key not in params:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise FaultPlanError(f"{where}.params.{key}: fault {name!r} needs {key!r}")
            continue
        values[key] = _coerce(f"{where}.params.{key}", params[key], hints[key])
    try:
        return cls(**values)
    except ValueError as exc:
        raise FaultPlanError(f"{where}: {exc}") from exc
