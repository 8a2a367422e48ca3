"""Rows of the view gathered per entity and sent to rerun as columns, a batch at a time.

Every rerun logging call costs about the same whatever it carries (0.05–0.1 ms of CPU in
the Python SDK, and again in its Rust threads to batch, encode and send), so the view does
not call rerun per state: :class:`Columns` keeps each entity's rows (a time and one value
per component) and :meth:`Columns.flush` sends each entity's rows as one
``send_columns`` chunk, built straight as Arrow arrays with the component descriptors of
rerun's own archetypes (taken once, below).  A chunk carries only the ``time`` timeline
(s, the link's clock), so the page shows that clock.

Component kinds (what one row's value is):

==================  =================================================================
:data:`SCALARS`     a sequence of numbers (None: NaN, a gap in the series)
:data:`POSITIONS`   points, k×3 (m): one instance per point
:data:`STRIPS`      polylines, n×k×3 (m): one instance per polyline
:data:`TRANSLATION` a point, 3 (m)
:data:`MAT3X3`      a rotation, 3×3
:data:`TEXT`        a string; :data:`LEVEL` a rerun text-log level
==================  =================================================================
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from itertools import accumulate
from typing import Any, Final

import numpy as np
import pyarrow as pa
import rerun as rr

#: The time line every row is on (s, the link's clock).
TIMELINE: Final = "time"
#: An entity's rows are sent when they reach this many, whatever the caller's flushing.
MAX_ROWS: Final = 256


class _Batch:
    """An Arrow array as rerun's component batches give theirs."""

    __slots__ = ("array",)

    def __init__(self, array: pa.Array) -> None:
        self.array = array

    def as_arrow_array(self) -> pa.Array:
        return self.array


@dataclass(frozen=True, eq=False)
class Component:
    """One component: its descriptor and how a list of rows' values becomes (one Arrow
    array of every instance, the number of instances in each row)."""

    descriptor: rr.ComponentDescriptor
    encode: Callable[[list[Any]], tuple[pa.Array, list[int]]]


def _template(archetype: rr.AsComponents) -> list[tuple[rr.ComponentDescriptor, pa.DataType]]:
    """(descriptor, Arrow type) of each component ``archetype`` logs, in order."""
    return [(batch.component_descriptor(), batch.as_arrow_array().type)
            for batch in archetype.as_component_batches()]


_ORIGIN: Final = [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]
((_SCALARS, _), ) = _template(rr.Scalars.from_fields(scalars=[0.0]))
((_STRIPS, _STRIPS_TYPE), ) = _template(rr.LineStrips3D.from_fields(strips=[_ORIGIN]))
((_POSITIONS, _POINT_TYPE), ) = _template(rr.Points3D.from_fields(positions=_ORIGIN))
((_TRANSLATION, _), (_MAT3X3, _MAT3X3_TYPE)) = _template(
    rr.Transform3D(translation=_ORIGIN[0], mat3x3=np.eye(3)))
((_TEXT, _TEXT_TYPE), (_LEVEL, _LEVEL_TYPE)) = _template(
    rr.TextLog("", level=rr.TextLogLevel.INFO))


def _fixed(values: np.ndarray, kind: pa.DataType) -> pa.Array:
    """``values`` (any shape) as float32 fixed-size lists of ``kind``."""
    flat = pa.array(np.ascontiguousarray(values, dtype=np.float32).ravel())
    return pa.FixedSizeListArray.from_arrays(flat, type=kind)


def _scalars(rows: list[Sequence[Any]]) -> tuple[pa.Array, list[int]]:
    flat = [np.nan if v is None else v for row in rows for v in row]
    return pa.array(flat, type=pa.float64()), [len(row) for row in rows]


def _points(rows: list[np.ndarray]) -> tuple[pa.Array, list[int]]:
    points = [np.asarray(row).reshape(-1, 3) for row in rows]
    return _fixed(np.concatenate(points), _POINT_TYPE), [len(p) for p in points]


def _matrices(rows: list[np.ndarray]) -> tuple[pa.Array, list[int]]:
    # rerun's Mat3x3 is column-major
    return _fixed(np.array([np.asarray(m).T for m in rows]), _MAT3X3_TYPE), [1] * len(rows)


def _strips(rows: list[np.ndarray]) -> tuple[pa.Array, list[int]]:
    polylines = [np.asarray(row) for row in rows]
    sizes = [k for p in polylines for k in [p.shape[1]] * p.shape[0]]
    offsets = pa.array(np.fromiter(accumulate(sizes, initial=0), np.int32, len(sizes) + 1))
    points = _fixed(np.concatenate([p.reshape(-1, 3) for p in polylines]), _POINT_TYPE)
    return (pa.ListArray.from_arrays(offsets, points, type=_STRIPS_TYPE),
            [len(p) for p in polylines])


def _strings(kind: pa.DataType) -> Callable[[list[Any]], tuple[pa.Array, list[int]]]:
    return lambda rows: (pa.array([str(r) for r in rows], type=kind), [1] * len(rows))


SCALARS: Final = Component(_SCALARS, _scalars)
POSITIONS: Final = Component(_POSITIONS, _points)
STRIPS: Final = Component(_STRIPS, _strips)
TRANSLATION: Final = Component(_TRANSLATION, _points)
MAT3X3: Final = Component(_MAT3X3, _matrices)
TEXT: Final = Component(_TEXT, _strings(_TEXT_TYPE))
LEVEL: Final = Component(_LEVEL, _strings(_LEVEL_TYPE))


class _Rows:
    """One entity's rows not sent yet."""

    __slots__ = ("components", "times", "values")

    def __init__(self, components: tuple[Component, ...]) -> None:
        self.components = components
        self.times: list[float] = []
        self.values: list[list[Any]] = [[] for _ in components]


class Columns:
    """Rows for ``recording``, sent per entity by :meth:`flush` (or when an entity has
    :data:`MAX_ROWS`); the ``background`` entities only when a flush sends everything.
    Safe to call from several threads."""

    def __init__(self, recording: rr.RecordingStream, max_rows: int = MAX_ROWS,
                 background: frozenset[str] = frozenset()) -> None:
        self.rec = recording
        self.max_rows = max_rows
        self.background = background
        self._pending: dict[str, _Rows] = {}
        self._lock = threading.Lock()

    def row(self, path: str, t: float, *cells: tuple[Component, Any]) -> None:
        """One row of entity ``path`` at time ``t`` (s): each cell a component and its
        value; an entity's rows always carry the same components, in the same order."""
        with self._lock:
            rows = self._pending.get(path)
            if rows is None:
                rows = self._pending[path] = _Rows(tuple(c for c, _ in cells))
            rows.times.append(t)
            for column, (_, value) in zip(rows.values, cells, strict=True):
                column.append(value)
            if len(rows.times) >= self.max_rows:
                self._send(path, self._pending.pop(path))

    @property
    def pending(self) -> int:
        """Rows waiting to be sent."""
        return sum(len(rows.times) for rows in self._pending.values())

    def flush(self, everything: bool = True) -> None:
        """Send each entity's rows, one ``send_columns`` call each (``everything`` False:
        not the background entities')."""
        with self._lock:
            for path in [p for p in self._pending if everything or p not in self.background]:
                self._send(path, self._pending.pop(path))

    def _send(self, path: str, rows: _Rows) -> None:
        columns = []
        for component, values in zip(rows.components, rows.values, strict=True):
            array, lengths = component.encode(values)
            offsets = np.fromiter(accumulate(lengths, initial=0), np.int32, len(lengths) + 1)
            columns.append(rr.ComponentColumn(component.descriptor, _Batch(array),
                                              offsets=offsets))
        # to the µs (the simulation clock's step, and what survives an MCAP round trip), in ns
        micros = np.round(np.maximum(0.0, np.asarray(rows.times, dtype=float)) * 1e6)
        times = (micros.astype(np.int64) * 1000).astype("timedelta64[ns]")
        self.rec.send_columns(path, indexes=[rr.TimeColumn(TIMELINE, duration=times)],
                              columns=columns)
