"""Campaigns: scenarios × seeds × parameter values, run in parallel by one code path.

:func:`expand` turns scenario files into jobs (plain data: the scenario table with its seed
and overrides set), :func:`run_job` runs one (a module-level function, so a process pool or
a Dask worker can import it), and :func:`run_jobs` runs them in this process, on local
processes (``concurrent.futures``), or on a Dask distributed scheduler
(``tcp://127.0.0.1:8786``, or a ``dask.distributed.Client``).  The results are the same
whichever ran them (only ``wall_s`` differs).
"""

from __future__ import annotations

import gc
import itertools
import multiprocessing
import socket
import threading
from collections.abc import Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from hil_emulator.profile import RobotProfile
from tools.hil_bench.runner import run_scenario
from tools.hil_bench.scenario import find_scenario, load_scenario, parse_scenario, with_overrides

Job = dict[str, Any]


def expand(paths: Sequence[str | Path], seeds: Sequence[int] | None = None,
           keep_trace: bool = False, fixed: dict[str, Any] | None = None,
           profile: RobotProfile | None = None) -> list[Job]:
    """One job per scenario file × seed (``seeds``, else the file's ``campaign.seeds``,
    else its ``seed``) × combination of its ``campaign.vary`` values.  ``fixed`` (dotted
    path → value, ``hil-bench run --set``) sets those keys in every job: a key the file
    varies takes only that value.  ``profile`` (``hil-bench run --profile``): every job's
    robot, carried as its values (a Dask worker need not see the file)."""
    carried = None if profile is None else {"parameters": dict(profile.values),
                                            "source": profile.source}
    jobs: list[Job] = []
    for name in paths:
        path = find_scenario(name)
        scenario = load_scenario(path)  # checks the file before anything runs
        run_seeds = list(seeds) if seeds else list(scenario.campaign.get("seeds",
                                                                         [scenario.seed]))
        vary: dict[str, list[Any]] = {**scenario.campaign.get("vary", {}),
                                      **{k: [v] for k, v in (fixed or {}).items()}}
        keys = sorted(vary)
        for seed in run_seeds:
            for values in itertools.product(*(vary[k] for k in keys)):
                overrides = dict(zip(keys, values, strict=True))
                raw = with_overrides(scenario.raw, seed, overrides)
                parse_scenario(raw, str(path))  # every point checked before any runs
                jobs.append({"raw": raw, "source": str(path), "keep_trace": keep_trace,
                             "overrides": overrides, "profile": carried})
    return jobs


def run_job(job: Job) -> dict[str, Any]:
    """Run one job; its result, with the overrides it ran with."""
    carried = job.get("profile")
    profile = None if carried is None else RobotProfile(carried["parameters"],
                                                        source=carried["source"])
    result = run_scenario(job["raw"], job["source"], keep_trace=job["keep_trace"],
                          profile=profile)
    result["overrides"] = job.get("overrides", {})
    return result


def run_jobs(jobs: Sequence[Job], workers: int = 1, scheduler: Any = None
             ) -> list[dict[str, Any]]:
    """Results of ``jobs`` in their order: in this process (``workers`` 1), on ``workers``
    local processes, or on a Dask scheduler (an address or a ``Client``)."""
    return list(iter_jobs(jobs, workers, scheduler))


def iter_jobs(jobs: Sequence[Job], workers: int = 1, scheduler: Any = None
              ) -> Iterator[dict[str, Any]]:
    """:func:`run_jobs` one result at a time, in the jobs' order, each as soon as it and
    those before it are done (what ``hil-bench run`` prints as it goes).  Closing the
    iterator early (Ctrl-C in the caller) cancels the jobs not started."""
    if scheduler is not None:
        from dask.distributed import Client

        client = scheduler if isinstance(scheduler, Client) else Client(scheduler)
        futures = client.map(run_job, list(jobs), pure=False)
        try:
            for future in futures:
                yield future.result()
        finally:
            client.cancel(futures)
            if client is not scheduler:
                client.close()
        return
    if workers <= 1 or len(jobs) <= 1:
        for job in jobs:
            yield run_job(job)
        return
    context = multiprocessing.get_context("spawn")  # MuJoCo and threads: no fork
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=context)
    finished = False
    try:
        yield from pool.map(run_job, jobs)
        finished = True
    finally:
        pool.shutdown(wait=finished, cancel_futures=not finished)


#: How long a ``--scheduler`` may take to connect before hil-bench gives up (s).
SCHEDULER_TIMEOUT_S = 10.0


def _refused(address: str) -> OSError | None:
    """Why nothing listens at the ``tcp://HOST:PORT`` ``address`` (a refused or unreachable
    port, said at once rather than after :data:`SCHEDULER_TIMEOUT_S`), or None: something
    does, or the address is not a plain TCP one (Dask's own client judges those)."""
    parts = urlsplit(address)
    if parts.scheme != "tcp" or parts.hostname is None:
        return None
    try:
        port = parts.port
    except ValueError:
        return None
    if port is None:
        return None
    try:
        socket.create_connection((parts.hostname, port), timeout=SCHEDULER_TIMEOUT_S).close()
    except OSError as exc:
        return exc
    return None


def connect_scheduler(address: str) -> Any:
    """A Dask client of the scheduler at ``address`` (``hil-bench run`` and ``fit``'s
    ``--scheduler``); :class:`ConnectionError` saying what to do when there is none (checked
    before anything runs).

    A TCP port where nothing listens is found with a plain socket first: a
    ``distributed.Client`` whose constructor failed is left to the garbage collector, and
    its ``__del__`` (closing its event loop under a lock) can deadlock the thread the
    collector happens to run in (seen: a test process hung for minutes).  What a failed
    client leaves is collected here, at once, where no lock of its is held."""
    from dask.distributed import Client

    why: BaseException | None = _refused(address)
    if why is None:
        made: list[Any] = []
        failed: list[BaseException] = []

        def make() -> None:
            try:
                made.append(Client(address, timeout=f"{SCHEDULER_TIMEOUT_S}s"))
            except (OSError, ValueError, TimeoutError) as exc:
                failed.append(exc)

        # A port that takes the connection and never answers Dask's handshake holds the
        # client's constructor whatever its timeout: given up on here, on a daemon thread.
        maker = threading.Thread(target=make, name="dask-connect", daemon=True)
        maker.start()
        maker.join(2 * SCHEDULER_TIMEOUT_S + 1.0)
        if made:
            return made[0]
        why = failed[0] if failed else TimeoutError(
            f"no Dask handshake within {2 * SCHEDULER_TIMEOUT_S + 1.0:g} s")
        gc.collect()
    raise ConnectionError(
        f"--scheduler {address}: no Dask scheduler there ({why}); start one "
        f"(dask scheduler --host 127.0.0.1, and dask worker tcp://127.0.0.1:8786), or "
        f"use --workers N for local processes")


def comparable(result: dict[str, Any]) -> dict[str, Any]:
    """``result`` without the fields that vary between equal runs (wall time)."""
    return {k: v for k, v in result.items() if k != "wall_s"}
