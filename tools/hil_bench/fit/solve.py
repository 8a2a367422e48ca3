"""The fit: in stages, least squares over the replays' residuals, and the holding torques
from their slips.

The unknowns are the parameters asked for, each scaled by its nominal value
(:data:`hil_emulator.profile.PARAMETERS`; by its own scale where the nominal is 0), bounded by
its bounds and started at the nominal robot.  They are fitted in :data:`STAGES`, by kind,
each stage with the estimates of those before it and every later one nominal:

1. ``stiffness``: the elements' deflections under gravity and in the chirps, many counts;
2. ``bearing_friction``, ``damping``: a count or less each way of a slow ramp, seen once the
   stiffness no longer explains the deflections; a parameter of another kind joins this
   stage; then, with more than one of these stages, all their parameters together, from
   their estimates (a stiffness fitted while the friction was nominal is off by what the
   friction explains);
3. ``torque_constant``: a stepper's holding torque shows only in when its rotor lets go
   under a holding probe, a step the residuals take, not a slope; :mod:`.slip_onset`
   brackets it, with every other parameter at its estimate (the load a rotor holds at rest
   depends a little on them: the bearings' stiction carries a share of it).  The least
   squares leave out every sample after the recording's first slip (:class:`~.cases.Layout`),
   so they do not depend on it.

The residuals are :mod:`.cases`' (each fitted sample's error over its channel's tolerance,
every recording), minimised by :func:`scipy.optimize.least_squares` (trust region
reflective).  The replay is not differentiable (its channels are counts), so the Jacobian is
by forward differences with a step per kind (:data:`DIFF_STEPS`, a share of the nominal,
wide enough to move the channels by whole counts: 3 % for a stiffness, 30 % for a friction),
taken backwards at an upper bound.  Every point a Jacobian needs is replayed together with
the point itself (:class:`~.evaluate.Replayer`: this process, ``workers`` local processes,
or a Dask scheduler).  At the end one more Jacobian at the solution, over every
least-squares parameter together, gives their error bars (:mod:`.uncertainty`).
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np
from scipy.optimize import least_squares

from hil_emulator.profile import Parameter, RobotProfile, parameter
from tools.errors import ReplayRefused
from tools.hil_bench.fit import slip_onset
from tools.hil_bench.fit.cases import FitCase, Layout, check_parameters, load_case
from tools.hil_bench.fit.evaluate import Replayed, Replayer
from tools.hil_bench.fit.uncertainty import error_bars

#: The stages, by the parameters' kinds (the last part of their names), in order; a kind
#: not named goes with the friction.  The last is searched by slip onset, the rest least
#: squares.
STAGES: Final = (("stiffness",), ("bearing_friction", "damping"), ("torque_constant",))
#: The kinds found by slip onset rather than least squares.
SLIP_KINDS: Final = ("torque_constant",)
#: Finite-difference step of the Jacobian per kind (share of the scale); others: DIFF_STEP.
DIFF_STEPS: Final = {"stiffness": 0.03, "bearing_friction": 0.3, "damping": 0.3}
DIFF_STEP: Final = 0.03
#: At most this many Jacobians (iterations) per stage.
MAX_ITERATIONS: Final = 20
#: Relative change of the cost and of the parameters below which a stage has converged.
TOLERANCE: Final = 1e-3


def kind(name: str) -> str:
    """A parameter's kind: the last part of its name (``stiffness``)."""
    return name.rsplit(".", 1)[-1]


def scale(p: Parameter) -> float:
    """What ``p``'s unknown is a multiple of: its :attr:`~hil_emulator.parameter.Parameter.step`
    (its nominal, or a scale of its own where the nominal is 0: a sensor's rotation or
    offset), or its range where both are 0."""
    return abs(p.step) if p.step else p.high - p.low


@dataclass
class FittedParameter:
    """One parameter's estimate: ``value`` and its 1σ ``uncertainty`` in ``unit`` (infinite
    where ``observable`` is False: the recordings do not say), where it started
    (``nominal``), and how it was found (``method``: ``least squares``, ``slip onset``)."""

    name: str
    unit: str
    nominal: float
    value: float
    uncertainty: float
    observable: bool = True
    method: str = "least squares"


@dataclass
class FitResult:
    """What a fit found: the ``parameters``, the RMS of the normalised residuals before
    (nominal) and after, each fitted channel's RMS (its unit) before and after, the
    replays run, the iterations, CPU seconds (this process and its local workers) and how
    the stages ended (``message``)."""

    recordings: list[str]
    parameters: list[FittedParameter]
    rms_before: float
    rms_after: float
    channels_before: dict[str, float]
    channels_after: dict[str, float]
    within_after: bool
    replays: int
    iterations: int
    cpu_s: float
    message: str
    notes: list[str] = field(default_factory=list)

    @property
    def removed(self) -> float:
        """Share of the replay error (RMS) the fit removed (0..1; 0 when there was none)."""
        return 1.0 - self.rms_after / self.rms_before if self.rms_before > 0 else 0.0

    def profile(self) -> RobotProfile:
        """The robot profile of the estimates, with how they were found."""
        return RobotProfile(
            {p.name: p.value for p in self.parameters},
            {"by": "hil-bench fit", "recordings": self.recordings,
             "uncertainty": {p.name: _finite(p.uncertainty) for p in self.parameters},
             "rms_before": self.rms_before, "rms_after": self.rms_after})

    def as_json(self) -> dict[str, Any]:
        """The ``--json`` form."""
        return {"recordings": self.recordings,
                "parameters": {p.name: {"value": p.value, "uncertainty": _finite(p.uncertainty),
                                        "unit": p.unit, "nominal": p.nominal,
                                        "observable": p.observable, "method": p.method}
                               for p in self.parameters},
                "rms_before": self.rms_before, "rms_after": self.rms_after,
                "removed": self.removed, "within_after": self.within_after,
                "channels": {name: {"rms_before": self.channels_before[name],
                                    "rms_after": self.channels_after.get(name, 0.0)}
                             for name in self.channels_before},
                "replays": self.replays, "iterations": self.iterations,
                "cpu_s": self.cpu_s, "message": self.message, "notes": self.notes}


def _finite(x: float) -> float | None:
    """``x``, or None (JSON's null) for a parameter the recordings do not pin down."""
    return x if math.isfinite(x) else None


def _rms(r: np.ndarray) -> float:
    return float(math.sqrt(float(np.mean(r * r)))) if r.size else 0.0


def staged(names: Sequence[str]) -> list[list[str]]:
    """``names`` in their stages (:data:`STAGES`), empty stages left out, in order; with
    more than one least-squares stage, then all their parameters together (a stiffness
    fitted while the friction was nominal is off by what the friction explains: the joint
    stage, started from the stages' estimates, takes their correlation in)."""
    known = {k: i for i, kinds in enumerate(STAGES) for k in kinds}
    other = next(i for i, kinds in enumerate(STAGES) if "bearing_friction" in kinds)
    groups: list[list[str]] = [[] for _ in STAGES]
    for n in names:
        groups[known.get(kind(n), other)].append(n)
    out = [g for g in groups if g]
    squares = [g for g in out if kind(g[0]) not in SLIP_KINDS]
    if len(squares) > 1:  # all the least-squares ones again together, before the slips
        at = max(out.index(g) for g in squares) + 1
        out.insert(at, [n for g in squares for n in g])
    return out


class _Stage:
    """One least-squares stage: the unknowns ``names`` (scaled), the rest at ``fixed``;
    replays points in batches with their Jacobian's neighbours and remembers them."""

    def __init__(self, names: Sequence[str], fixed: Mapping[str, float], cases: Sequence[FitCase],
                 replayer: Replayer, layout: Layout) -> None:
        self.params = [parameter(n) for n in names]
        self.fixed, self.cases, self.replayer, self.layout = dict(fixed), cases, replayer, layout
        self.scales = np.array([scale(p) for p in self.params])
        self.upper = np.array([p.high for p in self.params]) / self.scales
        self.steps_of = np.array([DIFF_STEPS.get(kind(p.name), DIFF_STEP)
                                  for p in self.params])
        self.known: dict[tuple[float, ...], np.ndarray] = {}

    def values(self, x: np.ndarray) -> dict[str, float]:
        """The parameters' values at unknowns ``x``, with the fixed ones."""
        return {**self.fixed, **{p.name: float(s * xi) for p, s, xi in
                                 zip(self.params, self.scales, x, strict=True)}}

    def steps(self, x: np.ndarray) -> list[np.ndarray]:
        """The points of the Jacobian at ``x`` (one per unknown)."""
        out = []
        for i in range(len(x)):
            h = self.steps_of[i]
            point = x.copy()
            point[i] += h if x[i] + h <= self.upper[i] else -h
            out.append(point)
        return out

    def batch(self, points: Sequence[np.ndarray]) -> None:
        """Replay every point not yet known."""
        todo = [p for p in points if tuple(p) not in self.known]
        for point, channels in zip(todo, self.replayer.run([self.values(p) for p in todo]),
                                   strict=True):
            self.known[tuple(point)] = self.layout.vector(self.cases, channels)

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """The residuals at ``x`` (its Jacobian's points replayed alongside)."""
        self.batch([x, *self.steps(x)])
        return self.known[tuple(x)]

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """Forward differences at ``x``."""
        self.batch([x, *self.steps(x)])
        f0 = self.known[tuple(x)]
        return np.column_stack([(self.known[tuple(p)] - f0) / (p - x)[i]
                                for i, p in enumerate(self.steps(x))])


def _load(paths: Sequence[str], names: Sequence[str],
          tolerances: Sequence[tuple[str, float]]) -> list[FitCase]:
    cases = []
    for path in paths:
        try:
            cases.append(load_case(path, tolerances))
            check_parameters(cases[-1], names)
        except ReplayRefused as exc:
            raise ReplayRefused(f"{path}: {exc}") from None
    return cases


def fit(paths: Sequence[str], names: Sequence[str], *,
        tolerances: Sequence[tuple[str, float]] = (), workers: int | None = None,
        scheduler: Any = None, progress: Callable[[str], None] | None = None) -> FitResult:
    """Estimate parameters ``names`` (:data:`~hil_emulator.profile.PARAMETERS`) from the
    recordings at ``paths`` (module doc); ``tolerances`` as ``hil-bench replay``'s, over
    :data:`~tools.hil_bench.fit.cases.FIT_TOLERANCES`; replays on ``workers`` local
    processes (default one per core) or a Dask ``scheduler`` (an address or a Client);
    ``progress`` gets a line per iteration.  :class:`~hil_emulator.errors.EmulatorConfigError`
    for an unknown or repeated parameter, :class:`~tools.errors.ReplayRefused` for a
    recording it cannot replay."""
    from hil_emulator.errors import EmulatorConfigError

    params = {n: parameter(n) for n in names}
    if len(set(names)) != len(names) or not names:
        raise EmulatorConfigError("name each parameter once, at least one")
    cpu0, children0 = time.process_time(), os.times()
    cases = _load(paths, names, tolerances)
    notes = [f"{p}: recorded on an emulator with the profile {c.recorded_profile}; the fit "
             "starts from the nominal robot" for p, c in zip(paths, cases, strict=True)
             if c.recorded_profile]
    workers = workers or os.cpu_count() or 1
    say = progress or (lambda _line: None)
    estimates: dict[str, float] = {}
    fitted: dict[str, FittedParameter] = {}
    messages: list[str] = []
    iterations = 0
    with Replayer(paths, tolerances, cases, workers, scheduler) as replayer:
        first: list[Replayed] = replayer.run([{}])
        layout = Layout.of(cases, first[0])
        r0 = layout.vector(cases, first[0])
        for group in staged(names):
            if kind(group[0]) in SLIP_KINDS:
                for n in group:
                    found = slip_onset.search(replayer, params[n], estimates, first[0],
                                              workers, say)
                    estimates[n] = found.value
                    fitted[n] = FittedParameter(
                        n, params[n].unit, params[n].nominal, found.value,
                        found.uncertainty if found.observable else math.inf,
                        found.observable, "slip onset")
                    messages.append(f"{n}: slip onset bracketed in {found.rounds} rounds"
                                    if found.observable else
                                    f"{n}: no slip of its joint in the recordings")
                continue
            stage = _Stage(group, estimates, cases, replayer, layout)
            count = 0

            def jac(x: np.ndarray, stage: _Stage = stage, before: int = iterations
                    ) -> np.ndarray:
                nonlocal count
                count += 1
                shown = ", ".join(f"{p.name}={v:.4g}" for p, v in
                                  zip(stage.params, stage.scales * x, strict=True))
                say(f"fit: iteration {before + count}: RMS "
                    f"{_rms(stage.known[tuple(x)]):.4g} (of tolerance), {shown}")
                return stage.jacobian(x)

            x0 = np.array([estimates.get(p.name, p.nominal) for p in stage.params]
                          ) / stage.scales
            lower = np.array([p.low for p in stage.params]) / stage.scales
            solution = least_squares(stage.residuals, x0, jac=jac, bounds=(lower, stage.upper),
                                     method="trf", ftol=TOLERANCE, xtol=TOLERANCE,
                                     max_nfev=MAX_ITERATIONS, x_scale=1.0)
            iterations += count
            estimates.update({k: v for k, v in stage.values(np.asarray(solution.x)).items()
                              if k in group})
            messages.append(f"{', '.join(group)}: {solution.message}")
        squares = [n for n in names if n not in fitted]
        final = _Stage(squares, estimates, cases, replayer, layout)
        x = np.array([estimates[n] for n in squares]) / final.scales
        r = final.residuals(x) if squares else layout.vector(
            cases, replayer.run([estimates])[0])
        if squares:
            segments, tols = layout.segments(cases)
            bars = error_bars(final.jacobian(x), r, segments, tols, x)
            for i, n in enumerate(squares):
                p = params[n]
                # the optimiser stops once a step changes the parameters by less than
                # TOLERANCE, and below its finite-difference step the cost of counts is a
                # staircase it sees only as the secant over the step: the estimate is not
                # located better than either (the step as a uniform spread, step / √12)
                sigma = math.hypot(float(bars.sigma[i] * final.scales[i]),
                                   TOLERANCE * abs(estimates[n]),
                                   final.steps_of[i] * final.scales[i] / math.sqrt(12.0))
                fitted[n] = FittedParameter(n, p.unit, p.nominal, estimates[n], sigma,
                                            bool(bars.observable[i]))
        replays = replayer.replays
    children = os.times()
    cpu = (time.process_time() - cpu0 + children.children_user - children0.children_user
           + children.children_system - children0.children_system)
    return FitResult(list(paths), [fitted[n] for n in names], _rms(r0), _rms(r),
                     layout.channel_rms(cases, r0), layout.channel_rms(cases, r),
                     bool(np.all(np.abs(r) <= 1.0)), replays, iterations, cpu,
                     "; ".join(messages), notes)
