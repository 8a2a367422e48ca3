"""The MuJoCo plant: one model, stepped on the firmware's simulation clock.

The plant is built procedurally with :class:`mujoco.MjSpec` (:func:`new_spec` gives the
world: options, gravity, floor, light), then compiled once.  *Parts* (the hand's fingers, the
arm's joints, …) each own a disjoint set of degrees of freedom and implement
:class:`PlantPart`.  Every :data:`TICK_US` of simulation time, :meth:`Plant.tick`:

1. zeroes ``data.qfrc_applied``,
2. calls every part's :meth:`PlantPart.before_step` (firmware commands in the HALs →
   generalised forces in N·m / N),
3. advances the physics by ``substeps`` × ``timestep_s``,
4. calls every part's :meth:`PlantPart.after_step` (physics state → sensors, hall states,
   encoder counts, currents in the HALs).

:meth:`Plant.attach` schedules that on a :class:`~firmware_py.scheduler.Scheduler`, so
firmware timers and physics share one clock.  Parts draw every random number from the
generator they were given, so a seeded run is repeatable.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Final, Protocol

import mujoco
import numpy as np

from firmware_py.scheduler import Scheduler, TimerHandle
from hil_emulator.errors import PlantError

#: Physics tick period (µs): parts exchange commands and sensors with the firmware at 1 kHz.
TICK_US: Final = 1_000
#: Default integration step (s) and substeps per tick (one 1 ms step per 1 ms tick).
DEFAULT_TIMESTEP_S: Final = 0.001
DEFAULT_SUBSTEPS: Final = 1


class PlantPart(Protocol):
    """One piece of the plant wired to firmware HALs (a finger module, the arm, …)."""

    def bind(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """Resolve names to ids in the compiled ``model``; keep ``data`` for the steps."""

    def before_step(self, dt_s: float) -> None:
        """Read the firmware's commands and write forces for the next ``dt_s`` seconds."""

    def after_step(self, dt_s: float) -> None:
        """Write sensor readings for the firmware after ``dt_s`` seconds of physics."""


def rint(value: float) -> int:
    """``value`` rounded to the nearest integer, ties to even: ``round(value)`` (and
    ``np.rint``), and the same errors for NaN and infinities.  Written out because the
    compiled core calls ``round`` as a Python function but ``math.floor`` as C; run from
    source, ``rint`` *is* ``float.__round__`` (below), the faster there."""
    whole = math.floor(value)
    rest = value - whole  # exact
    if rest > 0.5 or (rest == 0.5 and whole & 1):
        return whole + 1
    return whole


#: True when this module runs from its source (pure Python), not compiled by mypyc.
_FROM_SOURCE: Final = __file__.endswith(".py")
if _FROM_SOURCE:
    # float's own __round__ (the values are floats): ``round`` looks the method up at
    # every call, which costs twice the rounding.
    rint = float.__round__  # type: ignore[assignment]  # noqa: F811


def new_spec(name: str = "hil") -> mujoco.MjSpec:
    """An empty world: 1 ms step (implicitfast), gravity −9.81 m/s² along z, a floor, a light."""
    spec = mujoco.MjSpec()
    spec.modelname = name
    spec.option.timestep = DEFAULT_TIMESTEP_S
    spec.option.gravity = [0.0, 0.0, -9.81]
    spec.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE,
                            size=[2.0, 2.0, 0.05], rgba=[0.8, 0.8, 0.8, 1.0])
    spec.worldbody.add_light(name="sun", pos=[0.0, 0.0, 3.0], dir=[0.0, 0.0, -1.0])
    return spec


class Plant:
    """A compiled model, its data, and the parts that connect it to the firmware."""

    def __init__(self, spec: mujoco.MjSpec, parts: Sequence[PlantPart],
                 substeps: int = DEFAULT_SUBSTEPS) -> None:
        try:
            self.model = spec.compile()
        except Exception as exc:  # mujoco raises ValueError with the compiler's message
            raise PlantError(f"the plant model does not compile: {exc}") from exc
        self.data = mujoco.MjData(self.model)
        self.parts = list(parts)
        self.substeps = int(substeps)
        self.ticks = 0
        mujoco.mj_forward(self.model, self.data)
        for part in self.parts:
            part.bind(self.model, self.data)
        self._dt_s = self.model.opt.timestep * self.substeps
        self._timer: TimerHandle | None = None
        # Bound once: the tick's attribute lookups and MjData's view making cost more than
        # the work at 1 kHz (MjData's buffers are fixed for its lifetime).
        self._qfrc_applied = self.data.qfrc_applied
        self._before_steps = [part.before_step for part in self.parts]
        self._after_steps = [part.after_step for part in self.parts]

    @property
    def time_s(self) -> float:
        """Physics time (s)."""
        return float(self.data.time)

    def tick(self) -> None:
        """One exchange with the firmware and ``substeps`` integration steps."""
        model, data, dt = self.model, self.data, self._dt_s
        self._qfrc_applied.fill(0.0)
        for before_step in self._before_steps:
            before_step(dt)
        for _ in range(self.substeps):
            mujoco.mj_step(model, data)
        for after_step in self._after_steps:
            after_step(dt)
        self.ticks += 1
        if self.ticks % 1000 == 0 and not np.isfinite(data.qpos).all():
            raise PlantError(f"the physics diverged at t = {data.time:.3f} s")

    def attach(self, scheduler: Scheduler, period_us: int = TICK_US) -> TimerHandle:
        """Tick every ``period_us`` on ``scheduler`` (the period must match the step)."""
        expected = round(self._dt_s * 1e6)
        if period_us != expected or not math.isclose(self._dt_s * 1e6, expected):
            raise PlantError(f"tick period {period_us} µs does not match the physics step "
                             f"({self._dt_s * 1e6:g} µs)")
        self._timer = scheduler.call_every(period_us, self.tick)
        return self._timer
