"""Run a campaign's tasks on Dask: a local cluster of worker processes by default, or an existing scheduler.

Why processes, one thread each: the studies hold the GIL in numpy/numba code between short releases, so threads of
one process do not add up; a process per core does (the seed's sweep runs the same way: analysis/model/sweep.py).
Their BLAS, OpenMP and numba thread pools are set to one thread before they start (:func:`worker_env`), so two
workers on two cores use two cores, not 2 x N threads fighting over them; numba's cache directory is the one
``analysis/jit_cache.py`` chose for this process, so the workers load the kernels it compiled instead of compiling
them again.

Order: the largest logs are handed out first (a Dask priority), so a long log does not start last and leave the
other workers idle at the end (longest-processing-time-first). Rows come back as tasks finish (``progress``) and
are returned in the plan's order. A task whose worker died (killed, out of memory) is a row with exit 1 and the
reason; the other logs go on.
"""

from __future__ import annotations

import logging
import os
import uuid
import warnings
from collections.abc import Callable, Sequence
from typing import Any

from analysis.errors import BadInput, RuntimeFailure
from daq.studies.campaign.plan import Task
from daq.studies.campaign.tasks import empty_row, run_task

#: The thread pools a worker process must keep to one thread (numpy's BLAS: OpenBLAS or MKL; OpenMP; numba).
THREAD_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "VECLIB_MAXIMUM_THREADS",
               "NUMEXPR_NUM_THREADS", "NUMBA_NUM_THREADS")  # fmt: skip

Progress = Callable[[int, int, dict[str, Any]], None]  # (rows done, rows in all, the row just done)


def worker_env() -> dict[str, str]:
    """The environment a local worker process starts with (module docstring)."""
    from analysis.jit_cache import ENV, cache_dir

    return {**dict.fromkeys(THREAD_VARS, "1"), ENV: str(cache_dir())}


def default_workers(n_tasks: int) -> int:
    return max(1, min(n_tasks, os.cpu_count() or 1))


def run_here(tasks: Sequence[Task], progress: Progress | None = None) -> list[dict[str, Any]]:
    """The tasks one after another in this process (the benchmark's baseline; no Dask)."""
    rows = []
    for t in tasks:
        rows.append(run_task(t))
        if progress:
            progress(len(rows), len(tasks), rows[-1])
    return rows


def connect(scheduler: str | None, workers: int):
    """(client, cluster or None): a new local cluster of ``workers`` processes, or a client of ``scheduler``."""
    from distributed import Client, LocalCluster

    if scheduler is None:
        with warnings.catch_warnings():  # distributed's "port 8787 in use" for a dashboard nobody opens (as gvt sweep)
            warnings.filterwarnings("ignore", message="Port .* is already in use")
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                                   dashboard_address=None, silence_logs=logging.ERROR, env=worker_env())  # fmt: skip
        return Client(cluster), cluster
    if "://" not in scheduler and ":" not in scheduler:
        raise BadInput(f"--scheduler {scheduler!r}: give the scheduler's address, e.g. tcp://127.0.0.1:8786")
    try:
        client = Client(scheduler, timeout="10s")
    except (OSError, TimeoutError) as exc:
        raise RuntimeFailure(f"--scheduler {scheduler}: cannot reach a Dask scheduler there ({type(exc).__name__}: {exc}); "
                             "start one with `dask scheduler` and workers with `dask worker ADDRESS`") from None  # fmt: skip
    except ValueError as exc:
        raise BadInput(f"--scheduler {scheduler!r}: {exc}") from None
    try:
        client.wait_for_workers(1, timeout=30)
    except (OSError, TimeoutError):
        client.close()
        raise RuntimeFailure(f"--scheduler {scheduler}: the scheduler has no worker after 30 s; start one with "
                             f"`dask worker {scheduler} --nthreads 1`") from None  # fmt: skip
    return client, None


def lost_row(task: Task, exc: BaseException) -> dict[str, Any]:
    """The row of a task that did not come back (its worker died, or the cluster could not run it)."""
    row = empty_row(task)
    what = str(exc).splitlines()[0] if str(exc) else ""
    row.update(exit_code=1, error=f"the worker running it failed: {type(exc).__name__}: {what}")
    return row


def run_campaign(tasks: Sequence[Task], scheduler: str | None = None, workers: int | None = None,
                 progress: Progress | None = None) -> list[dict[str, Any]]:  # fmt: skip
    """Every task on the cluster; the rows in the tasks' order (module docstring)."""
    from distributed import as_completed

    if not tasks:
        return []
    client, cluster = connect(scheduler, workers or default_workers(len(tasks)))
    token = uuid.uuid4().hex[:8]
    try:
        futures = {}
        for t in tasks:
            size = os.path.getsize(t.log) if os.path.exists(t.log) else 0
            fut = client.submit(run_task, t, key=f"gvt-{t.verb}-{token}-{t.index}", priority=size, pure=False)
            futures[fut] = t
        rows: dict[int, dict[str, Any]] = {}
        for fut in as_completed(list(futures)):
            t = futures[fut]
            try:
                rows[t.index] = fut.result()
            except Exception as exc:  # a KilledWorker, a task the worker could not unpickle, ...
                rows[t.index] = lost_row(t, exc)
            fut.release()
            if progress:
                progress(len(rows), len(tasks), rows[t.index])
        return [rows[t.index] for t in tasks]
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
