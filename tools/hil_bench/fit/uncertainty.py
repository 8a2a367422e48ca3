"""Error bars of the least-squares parameters, and which ones the recordings cannot see.

At the solution the fit's residuals ``r`` (each sample's error over its channel's tolerance)
and their Jacobian ``J`` (finite differences, the parameters in their scaled unknowns) give
the linearised covariance ``s² · τ · (JᵀJ)⁻¹``:

* ``s²`` is the residuals' variance, ``Σr² / (m − n)``, but never below what the channels'
  resolution alone gives: a reading is a whole count, so even a perfect model differs from
  the robot by a rounding of up to half a count, variance ``1/12`` count², over the
  tolerance squared (:data:`QUANTUM`);
* ``τ = (1 + ρ) / (1 − ρ)`` counts the samples' correlation: consecutive samples of a
  channel are not independent (a model error lasts many cycles), and ``ρ``, the residuals'
  lag-1 autocorrelation pooled over the channels, says by how much fewer independent ones
  there are (the variance of a mean of an AR(1) series; 1 for white residuals).

A parameter whose column of ``J`` is zero (no replay moved a channel) or whose 1σ is more
than :data:`UNOBSERVABLE_SHARE` of its value is *unobservable*: the recordings cannot say
what it is, and no number is given for its uncertainty.  The rest of the covariance is taken
over the observable parameters only.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np

#: A channel's resolution in its unit (encoder counts, position units).
QUANTUM: Final = 1.0
#: A parameter whose 1σ exceeds this share of its value is reported unobservable.
UNOBSERVABLE_SHARE: Final = 0.5
#: Largest lag-1 autocorrelation used (τ at most 199).
_RHO_MAX: Final = 0.99


@dataclass(frozen=True)
class ErrorBars:
    """Per parameter its 1σ in the scaled unknowns (``sigma``; infinity where
    ``observable`` is False), and what went into them: the residual variance ``s2`` and
    the correlation factor ``tau``."""

    sigma: np.ndarray
    observable: np.ndarray
    s2: float
    tau: float


def correlation_factor(residuals: np.ndarray, segments: Sequence[int]) -> float:
    """``τ`` (module doc) of ``residuals`` laid out as consecutive channels of
    ``segments`` samples each."""
    num = den = 0.0
    at = 0
    for n in segments:
        part = residuals[at:at + n]
        at += n
        if n > 1:
            num += float(np.dot(part[:-1], part[1:]))
        den += float(np.dot(part, part))
    rho = min(max(num / den, 0.0), _RHO_MAX) if den > 0 else 0.0
    return (1.0 + rho) / (1.0 - rho)


def error_bars(jacobian: np.ndarray, residuals: np.ndarray, segments: Sequence[int],
               tolerances: Sequence[float], x: np.ndarray) -> ErrorBars:
    """The error bars (module doc) of the unknowns ``x`` from the ``jacobian`` and the
    ``residuals`` at ``x``; ``segments`` and ``tolerances``: each channel's number of
    samples and tolerance, in the residuals' order."""
    m, n = jacobian.shape
    floor = sum(k * (QUANTUM / tol) ** 2 / 12.0 for k, tol in zip(segments, tolerances,
                                                                   strict=True))
    s2 = max(float(np.dot(residuals, residuals)) / max(1, m - n), floor / max(1, m))
    tau = correlation_factor(residuals, segments)
    observable = np.linalg.norm(jacobian, axis=0) > 0
    sigma = np.full(n, math.inf)
    for _ in range(n):  # drop the unobservable until the rest are all observable
        cols = np.flatnonzero(observable)
        if cols.size == 0:
            break
        sub = jacobian[:, cols]
        jtj = sub.T @ sub
        if np.linalg.matrix_rank(jtj) < cols.size:
            weakest = cols[int(np.argmin(np.linalg.norm(sub, axis=0)))]
            observable[weakest] = False
            continue
        sigma[:] = math.inf
        sigma[cols] = np.sqrt(np.clip(np.diag(np.linalg.inv(jtj)) * s2 * tau, 0.0, None))
        vague = cols[sigma[cols] > UNOBSERVABLE_SHARE * np.abs(x[cols])]
        if vague.size == 0:
            break
        observable[vague] = False
    sigma[~observable] = math.inf
    return ErrorBars(sigma, observable, s2, tau)
