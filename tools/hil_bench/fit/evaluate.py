"""Replaying candidate parameters, many at once: in this process, on local processes or on
a Dask cluster, by one code path.

A *job* is plain data: the recordings' paths, the tolerances and one set of parameter
values (name → value in its unit; every other parameter nominal).  :func:`replay_job`, a
module-level function a process pool or a Dask worker imports, reads the recordings once per
process (:func:`cases_for`) and replays each against a new emulator with those values.
:class:`Replayer` sends a batch of jobs to wherever it was told and counts the replays.
The results are the same whichever ran them: a replay is deterministic for its seed.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Mapping, Sequence
from concurrent.futures import Executor, ProcessPoolExecutor
from typing import Any

from tools.hil_bench.fit.cases import FitCase, load_case, replay_case
from tools.hil_bench.replay.compare import Channel

#: One job: the recordings' paths, the tolerances (CHANNEL, VALUE) and the values.
Job = tuple[tuple[str, ...], tuple[tuple[str, float], ...], dict[str, float]]
#: One job's result: per recording, its channels by name.
Replayed = list[dict[str, Channel]]

#: The cases this process has read, by (paths, tolerances): one entry, the last asked.
_CASES: dict[tuple[tuple[str, ...], tuple[tuple[str, float], ...]], list[FitCase]] = {}


def cases_for(paths: Sequence[str], tolerances: Sequence[tuple[str, float]]
              ) -> list[FitCase]:
    """The cases of ``paths``, read once per process."""
    key = (tuple(paths), tuple(tolerances))
    if key not in _CASES:
        _CASES.clear()
        _CASES[key] = [load_case(p, tolerances) for p in paths]
    return _CASES[key]


def replay_job(job: Job) -> Replayed:
    """Replay every recording of ``job`` with its values (what a worker runs)."""
    paths, tolerances, values = job
    return [replay_case(case, values) for case in cases_for(paths, tolerances)]


class Replayer:
    """Runs jobs of the recordings ``paths`` (their ``cases``, already read here) in this
    process (``workers`` 1), on ``workers`` spawned local processes (MuJoCo does not survive
    a fork), or on a Dask ``scheduler`` (an address or a ``dask.distributed.Client``); a
    context manager that shuts what it started down."""

    def __init__(self, paths: Sequence[str], tolerances: Sequence[tuple[str, float]],
                 cases: Sequence[FitCase], workers: int = 1, scheduler: Any = None) -> None:
        self.paths, self.tolerances = tuple(paths), tuple(tolerances)
        self.cases = list(cases)
        self.replays = 0
        self._pool: Executor | None = None
        self._client: Any = None
        self._own_client = False
        if scheduler is not None:
            from dask.distributed import Client

            self._own_client = not isinstance(scheduler, Client)
            self._client = Client(scheduler) if self._own_client else scheduler
        elif workers > 1:
            self._pool = ProcessPoolExecutor(max_workers=workers,
                                             mp_context=multiprocessing.get_context("spawn"))
        self.parallel = self._client is not None or self._pool is not None

    def run(self, points: Sequence[Mapping[str, float]]) -> list[Replayed]:
        """Each set of values in ``points`` replayed against every recording, in order."""
        jobs: list[Job] = [(self.paths, self.tolerances, dict(p)) for p in points]
        self.replays += len(jobs) * len(self.cases)
        if self._client is not None:
            futures = self._client.map(replay_job, jobs, pure=False)
            return list(self._client.gather(futures))
        if self._pool is not None and len(jobs) > 1:
            return list(self._pool.map(replay_job, jobs))
        return [[replay_case(case, job[2]) for case in self.cases] for job in jobs]

    def close(self) -> None:
        """Shut down the pool or the client this replayer started (idempotent)."""
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None
        if self._client is not None and self._own_client:
            self._client.close()
        self._client = None

    def __enter__(self) -> Replayer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
