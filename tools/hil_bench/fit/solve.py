"""The fit: :func:`scipy.optimize.least_squares` over the replays' residuals.

The unknowns are the parameters asked for, each as ``1 + (value − nominal) / step`` with
``step`` its :attr:`~hil_emulator.parameter.Parameter.step` (:data:`hil_emulator.profile.PARAMETERS`;
the nominal value itself unless the parameter says otherwise, so mostly a multiple of the
nominal; a sensor's offset, nominally 0, in shares of its own scale), bounded by its bounds
and started at 1 (the nominal robot).  The residuals are :mod:`.cases`' (each fitted sample's error over its
channel's tolerance, every recording).  The replay is not differentiable (its channels are
counts), so the Jacobian is by forward differences with a step of :data:`DIFF_STEP` (a
share of the parameter's step, wide enough to span several counts), taken backwards at an upper
bound.  Every point a Jacobian needs is replayed together with the point itself, in
parallel over ``workers`` processes (:class:`concurrent.futures.ProcessPoolExecutor`,
spawned: MuJoCo is not forked); with one worker, in this process.

Each parameter's uncertainty is the 1σ of the linearised fit at the solution:
``sqrt(diag((JᵀJ)⁻¹)) · s`` with ``s² = Σr² / (m − n)`` (m residuals, n parameters), in
the parameter's unit; a parameter the recordings do not move has an infinite uncertainty.
"""

from __future__ import annotations

import math
import multiprocessing
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Executor, ProcessPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np
from scipy.optimize import least_squares

from hil_emulator.profile import PARAMETERS, RobotProfile, parameter
from tools.errors import ReplayRefused
from tools.hil_bench.fit import cases as fit_cases
from tools.hil_bench.fit.cases import FitCase, Layout, check_parameters, load_case
from tools.hil_bench.replay.compare import Channel

#: Finite-difference step of the Jacobian (share of each parameter's nominal value).
DIFF_STEP: Final = 0.03
#: At most this many Jacobians (iterations) per fit.
MAX_ITERATIONS: Final = 20
#: Relative change of the cost and of the parameters below which the fit has converged.
TOLERANCE: Final = 1e-3


@dataclass
class FittedParameter:
    """One parameter's estimate: ``value`` and its 1σ ``uncertainty`` in ``unit``, where it
    started (``nominal``)."""

    name: str
    unit: str
    nominal: float
    value: float
    uncertainty: float


@dataclass
class FitResult:
    """What a fit found: the ``parameters``, the RMS of the normalised residuals before
    (nominal) and after, each fitted channel's RMS (its unit) before and after, the
    replays run, the iterations, CPU seconds (this process and its workers) and how
    scipy ended (``message``)."""

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
                                        "unit": p.unit, "nominal": p.nominal}
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


def _value(name: str, x: float) -> float:
    """Parameter ``name``'s value (its unit) at the fit's unknown ``x`` (module doc)."""
    p = PARAMETERS[name]
    return float(p.nominal + p.step * (x - 1.0))


def _values(names: Sequence[str], x: np.ndarray) -> dict[str, float]:
    return {n: _value(n, float(xi)) for n, xi in zip(names, x, strict=True)}


class _Evaluator:
    """Replays points (multiples of nominal) in batches and remembers them."""

    def __init__(self, names: Sequence[str], cases: Sequence[FitCase],
                 pool: Executor | None, upper: np.ndarray) -> None:
        self.names, self.cases, self.pool, self.upper = list(names), list(cases), pool, upper
        self.layout: Layout | None = None
        self.known: dict[tuple[float, ...], np.ndarray] = {}
        self.replays = 0

    def steps(self, x: np.ndarray) -> list[np.ndarray]:
        """The points of the Jacobian at ``x`` (one per parameter)."""
        out = []
        for i in range(len(x)):
            h = DIFF_STEP if x[i] + DIFF_STEP <= self.upper[i] else -DIFF_STEP
            point = x.copy()
            point[i] += h
            out.append(point)
        return out

    def batch(self, points: Sequence[np.ndarray]) -> None:
        """Replay every point not yet known, in parallel."""
        todo = [p for p in points if tuple(p) not in self.known]
        values = [_values(self.names, p) for p in todo]
        replayed: list[list[dict[str, Channel]]]
        if self.pool is None:
            replayed = [[fit_cases.replay_case(c, v) for c in self.cases] for v in values]
        else:
            replayed = list(self.pool.map(fit_cases.replay_all, values))
        self.replays += len(todo) * len(self.cases)
        for point, channels in zip(todo, replayed, strict=True):
            if self.layout is None:
                self.layout = Layout.of(self.cases, channels)
            self.known[tuple(point)] = self.layout.vector(self.cases, channels)

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """The residuals at ``x`` (its Jacobian's points replayed alongside)."""
        self.batch([x, *self.steps(x)])
        return self.known[tuple(x)]

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """Forward differences at ``x``."""
        self.batch([x, *self.steps(x)])
        f0 = self.known[tuple(x)]
        columns = [(self.known[tuple(p)] - f0) / (p - x)[i]
                   for i, p in enumerate(self.steps(x))]
        return np.column_stack(columns)


def _rms(r: np.ndarray) -> float:
    return float(math.sqrt(float(np.mean(r * r)))) if r.size else 0.0


def fit(paths: Sequence[str], names: Sequence[str], *,
        tolerances: Sequence[tuple[str, float]] = (), workers: int | None = None,
        progress: Callable[[str], None] | None = None) -> FitResult:
    """Estimate parameters ``names`` (:data:`~hil_emulator.profile.PARAMETERS`) from the
    recordings at ``paths`` (module doc); ``tolerances`` as ``hil-bench replay``'s, over
    :data:`~tools.hil_bench.fit.cases.FIT_TOLERANCES`; ``progress`` gets one line per
    iteration.  :class:`~hil_emulator.errors.EmulatorConfigError` for an unknown or repeated
    parameter, :class:`~tools.errors.ReplayRefused` for a recording it cannot replay."""
    from hil_emulator.errors import EmulatorConfigError

    params = [parameter(n) for n in names]
    if len(set(names)) != len(names) or not names:
        raise EmulatorConfigError("name each parameter once, at least one")
    cpu0, children0 = time.process_time(), os.times()
    cases = []
    for path in paths:
        try:
            cases.append(load_case(path, tolerances))
            check_parameters(cases[-1], names)
        except ReplayRefused as exc:
            raise ReplayRefused(f"{path}: {exc}") from None
    notes = [f"{p}: recorded on an emulator with the profile {c.recorded_profile}; the fit "
             "starts from the nominal robot" for p, c in zip(paths, cases, strict=True)
             if c.recorded_profile]
    lower = np.array([1.0 + (p.low - p.nominal) / p.step for p in params])
    upper = np.array([1.0 + (p.high - p.nominal) / p.step for p in params])
    workers = workers or os.cpu_count() or 1
    pool: ProcessPoolExecutor | None = None
    if workers > 1:
        pool = ProcessPoolExecutor(max_workers=workers,
                                   mp_context=multiprocessing.get_context("spawn"),
                                   initializer=fit_cases.init_worker,
                                   initargs=(list(paths), list(tolerances)))
    try:
        evaluator = _Evaluator(names, cases, pool, upper)
        x0 = np.ones(len(names))
        r0 = evaluator.residuals(x0)
        iterations = 0

        def jac(x: np.ndarray) -> np.ndarray:
            nonlocal iterations
            iterations += 1
            if progress is not None:
                shown = ", ".join(f"{n}={v:.4g}" for n, v in _values(names, x).items())
                progress(f"fit: iteration {iterations}: RMS {_rms(evaluator.known[tuple(x)]):.4g}"
                         f" (of tolerance), {shown}")
            return evaluator.jacobian(x)

        solution = least_squares(evaluator.residuals, x0, jac=jac, bounds=(lower, upper),
                                 method="trf", ftol=TOLERANCE, xtol=TOLERANCE,
                                 max_nfev=MAX_ITERATIONS, x_scale=1.0)
        x = np.asarray(solution.x)
        r = evaluator.residuals(x)
        jacobian = evaluator.jacobian(x)
        replays = evaluator.replays
    finally:
        if pool is not None:
            pool.shutdown()
    m, n = r.size, len(names)
    scale2 = float(np.sum(r * r)) / max(1, m - n)
    jtj = jacobian.T @ jacobian
    sigma = np.full(n, math.inf)
    if np.linalg.matrix_rank(jtj) == n:
        sigma = np.sqrt(np.clip(np.diag(np.linalg.inv(jtj)) * scale2, 0.0, None))
    fitted = [FittedParameter(p.name, p.unit, p.nominal, _value(p.name, float(xi)),
                              float(p.step * si))
              for p, xi, si in zip(params, x, sigma, strict=True)]
    layout = evaluator.layout
    assert layout is not None
    children = os.times()
    cpu = (time.process_time() - cpu0 + children.children_user - children0.children_user
           + children.children_system - children0.children_system)
    return FitResult(list(paths), fitted, _rms(r0), _rms(r), layout.channel_rms(cases, r0),
                     layout.channel_rms(cases, r), bool(np.all(np.abs(r) <= 1.0)), replays,
                     iterations, cpu, str(solution.message), notes)

