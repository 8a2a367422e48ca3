"""Campaigns: scenarios × seeds × parameter values, run in parallel by one code path.

:func:`expand` turns scenario files into jobs (plain data: the scenario table with its seed
and overrides set), :func:`run_job` runs one (a module-level function, so a process pool or
a Dask worker can import it), and :func:`run_jobs` runs them in this process, on local
processes (``concurrent.futures``), or on a Dask distributed scheduler
(``tcp://127.0.0.1:8786``, or a ``dask.distributed.Client``).  The results are the same
whichever ran them (only ``wall_s`` differs).
"""

from __future__ import annotations

import itertools
import multiprocessing
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from tools.bench.runner import run_scenario
from tools.bench.scenario import load_scenario, parse_scenario, with_overrides

Job = dict[str, Any]


def expand(paths: Sequence[str | Path], seeds: Sequence[int] | None = None,
           keep_trace: bool = False) -> list[Job]:
    """One job per scenario file × seed (``seeds``, else the file's ``campaign.seeds``,
    else its ``seed``) × combination of its ``campaign.vary`` values."""
    jobs: list[Job] = []
    for path in paths:
        scenario = load_scenario(path)  # checks the file before anything runs
        run_seeds = list(seeds) if seeds else list(scenario.campaign.get("seeds",
                                                                         [scenario.seed]))
        vary: dict[str, list[Any]] = scenario.campaign.get("vary", {})
        keys = sorted(vary)
        for seed in run_seeds:
            for values in itertools.product(*(vary[k] for k in keys)):
                overrides = dict(zip(keys, values, strict=True))
                raw = with_overrides(scenario.raw, seed, overrides)
                parse_scenario(raw, str(path))  # every point checked before any runs
                jobs.append({"raw": raw, "source": str(path), "keep_trace": keep_trace,
                             "overrides": overrides})
    return jobs


def run_job(job: Job) -> dict[str, Any]:
    """Run one job; its result, with the overrides it ran with."""
    result = run_scenario(job["raw"], job["source"], keep_trace=job["keep_trace"])
    result["overrides"] = job.get("overrides", {})
    return result


def run_jobs(jobs: Sequence[Job], workers: int = 1, scheduler: Any = None
             ) -> list[dict[str, Any]]:
    """Results of ``jobs`` in their order: in this process (``workers`` 1), on ``workers``
    local processes, or on a Dask scheduler (an address or a ``Client``)."""
    if scheduler is not None:
        from dask.distributed import Client

        client = scheduler if isinstance(scheduler, Client) else Client(scheduler)
        try:
            futures = client.map(run_job, list(jobs), pure=False)
            return list(client.gather(futures))
        finally:
            if client is not scheduler:
                client.close()
    if workers <= 1 or len(jobs) <= 1:
        return [run_job(j) for j in jobs]
    context = multiprocessing.get_context("spawn")  # MuJoCo and threads: no fork
    with ProcessPoolExecutor(max_workers=workers, mp_context=context) as pool:
        return list(pool.map(run_job, jobs))


def comparable(result: dict[str, Any]) -> dict[str, Any]:
    """``result`` without the fields that vary between equal runs (wall time)."""
    return {k: v for k, v in result.items() if k != "wall_s"}
