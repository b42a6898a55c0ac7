"""Where the per-layer work of a stage runs: here, in order (no Dask import); here on a few threads (the
command line's default: :class:`Threads`); or on a Dask cluster (``dask.distributed``: a local one of N
processes, or any existing one by address).

Stages see one small interface, :class:`Executor`:

* ``map(fn, items, **shared)`` — ``[fn(item, **shared) for item in items]``; each shared input is
  sent to the cluster once (as a task of its own, copied between workers), not once per task;
  results come back in order;
* ``share(value)`` / ``submit(fn, *args, **kwargs)`` / ``gather(futures)`` — a task graph for work
  whose tasks depend on each other (a sequential fold next to parallel per-layer tasks): in-process,
  ``submit`` runs the call at once and returns its value, so both executors give the same results.
  ``lane`` places a task (:data:`LANES`): the links of a sequential chain on one worker, which nothing
  ahead of the chain then delays, and the work the chain waits for on the others.

Tasks are retried on another worker when theirs dies (``retries``); a shared input lost with its
workers is made again from its task. Which executor runs a stage never changes its
result: the executor is an execution option, not a :class:`~curvslice.pipeline.Settings` field.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor, as_completed
from contextlib import contextmanager
from typing import Any

from curvslice.errors import CurvsliceError

#: Times a task is re-run after its worker died or it raised (a lost worker, not a bug, is the case).
RETRIES = 3

#: Dask settings of the local clusters of ``--workers N`` (their scheduler and the workers' processes,
#: which get the config from their nannies). Without them the workers of the bunny's tool-path stage
#: spent 1.34× the CPU of the in-process run and the scheduler (in the client's process) 0.2× more,
#: measured side by side on layers 40-70 (benchmarks/SCALING.md); with them 1.09× and 0.1×:
#: * MALLOC_TRIM_THRESHOLD_, which Dask sets in its workers, pins glibc's mmap threshold at 128 KiB:
#:   every mid-size numpy temporary of a layer's task is then mapped and zero-filled anew (+30 % CPU
#:   measured on the kitten's tool-paths); workers of a short run keep glibc's default instead;
#: * the workers' statistical profiler samples the task thread's stack every 10 ms (the dashboard's
#:   profile, which a run without dashboard never shows) and takes the GIL from the task each time;
#: * memory and system monitors poll every 0.1-0.5 s: once a second is enough for tasks of 0.1-2 s;
#: * work stealing moves a queued task to an idle worker even against its lane (:data:`LANES`: loose
#:   restrictions do not stop it): it put prepares on the chain worker, where the next fold then waited
#:   16 s behind them (bunny, two workers, load 10); without it, a worker idles rather than take
#:   another lane's task, and the per-layer maps need no stealing (Dask queues their tasks on the
#:   scheduler until a worker is free);
#: * every process checks its event loop's health every 20 ms (``admin.tick``, which only times how late
#:   the check comes, for a warning after 3 s): an idle two-worker cluster burnt 0.023 CPU s per wall
#:   second in its workers and 0.020 in the client (the scheduler), 0.006 and 0.008 with a check a second
#:   -- on this shared machine, where a run takes minutes of wall time, the larger share of Dask's cost.
LOCAL_CLUSTER_CONFIG = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
                        "distributed.worker.profile.enabled": False,
                        "distributed.worker.memory.monitor-interval": "1s",
                        "distributed.admin.system-monitor.interval": "1s",
                        "distributed.scheduler.work-stealing": False,
                        "distributed.admin.tick.interval": "1s"}


#: Where :meth:`DaskExecutor.submit` places a task: ``any`` worker (Dask decides); ``chain``, the one
#: worker that runs the links of a sequential chain (the first by address), so that no other task started
#: there holds up the next link -- a worker never interrupts a task, and Dask would otherwise place each
#: link where its largest input lies, often behind another task; ``apart``, the others (what the chain
#: waits for, so that it is ready in time). Preferences only: a worker that left is not waited for.
LANES = ("any", "chain", "apart")


class InProcess:
    """Every task runs here, at once, in submission order."""

    workers = 1

    def map(self, fn: Callable, items: Iterable, progress=None, **shared: Any) -> list:
        out = []
        for item in items:
            out.append(fn(item, **shared))
            if progress is not None:
                progress.update(1)
        return out

    def share(self, value: Any) -> Any:
        return value

    def submit(self, fn: Callable, *args: Any, priority: int = 0, lane: str = "any", **kwargs: Any) -> Any:
        return fn(*args, **kwargs)

    def gather(self, futures: Sequence, progress=None) -> list:
        if progress is not None:
            progress.update(len(futures))
        return list(futures)


class Threads:
    """Tasks on ``threads`` threads of this process (``concurrent.futures``): numpy, scipy's KD-trees and
    SuperLU release the GIL in their loops, so two layers' tasks share two cores (the bunny 1.0's tool-paths:
    51 -> 42 s wall in the benchmark on this 2-core machine, for 3-10 % more CPU; the same arrays bit for bit),
    without the start-up, copies and memory of worker processes. ``submit`` takes futures as arguments and
    waits for them inside the task: the pool starts tasks in submission order and a task only waits for ones
    submitted before it, which are then running or done, so no task waits for a queued one. Priorities and
    lanes are Dask's; here the order of submission is the order of start (submitting the chain's folds
    between other layers' tasks gained nothing: the GIL, not the order, bounds two threads)."""

    def __init__(self, threads: int):
        self.workers = threads
        self.pool = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="curvslice")

    def map(self, fn: Callable, items: Iterable, progress=None, **shared: Any) -> list:
        return self.gather([self.pool.submit(fn, item, **shared) for item in items], progress)

    def share(self, value: Any) -> Any:
        return value

    def submit(self, fn: Callable, *args: Any, priority: int = 0, lane: str = "any", **kwargs: Any) -> Future:
        return self.pool.submit(_resolved, fn, args, kwargs)

    def gather(self, futures: Sequence, progress=None) -> list:
        if progress is not None:
            for _ in as_completed(futures):
                progress.update(1)
        return [f.result() for f in futures]

    def close(self, cancel: bool = False) -> None:
        """Stop the threads once their tasks are done (``cancel``: the queued ones are dropped, a running
        one ends first -- what an interrupt or an error in the caller does)."""
        self.pool.shutdown(wait=not cancel, cancel_futures=cancel)


def _resolved(fn: Callable, args: tuple, kwargs: dict) -> Any:
    """``fn(*args, **kwargs)`` with every future among them replaced by its result."""
    def value(v: Any) -> Any:
        return v.result() if isinstance(v, Future) else v

    return fn(*[value(a) for a in args], **{k: value(v) for k, v in kwargs.items()})


def default_threads() -> int:
    """Threads of an in-process run when none are asked for: the cores this process may use, at most
    :data:`MAX_THREADS`."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(cores, MAX_THREADS))


#: Most threads an in-process run takes by default: the tasks hold the GIL between numpy calls, and on this
#: 2-core machine a third thread made the bunny's tool-paths slower (43 -> 46 s wall, 59 -> 65 CPU s) --
#: more cores scale with Dask's worker processes (``--workers``), not with threads.
MAX_THREADS = 2


class DaskExecutor:
    """Tasks on the workers of a ``dask.distributed`` client."""

    def __init__(self, client: Any, retries: int = RETRIES):
        self.client, self.retries = client, retries
        self._workers: list[str] | None = None  # the cluster's workers when a lane was first asked for

    @property
    def workers(self) -> int:
        return len(self.client.scheduler_info(n_workers=-1)["workers"])

    def map(self, fn: Callable, items: Iterable, progress=None, **shared: Any) -> list:
        shared = {k: self.share(v) for k, v in shared.items()}
        futures = [self.submit(fn, item, **shared) for item in items]
        return self.gather(futures, progress)

    def share(self, value: Any) -> Any:
        # A task that returns the value, not client.scatter: scattered data has no recipe, and the
        # scheduler's memory manager drops broadcast replicas, so a killed worker can take the last copy
        # and every task needing it with it. This one is sent to the scheduler once, copied from worker
        # to worker as tasks need it, and re-run if every holder dies.
        with warnings.catch_warnings():  # Dask's hint to scatter large objects instead: see above
            warnings.filterwarnings("ignore", message="Sending large graph", category=UserWarning)
            return self.client.submit(_value, value, pure=False, retries=self.retries)

    def submit(self, fn: Callable, *args: Any, priority: int = 0, lane: str = "any", **kwargs: Any) -> Any:
        workers = self._lane(lane)
        return self.client.submit(fn, *args, retries=self.retries, pure=False, priority=priority, workers=workers,
                                  allow_other_workers=workers is not None, **kwargs)

    def _lane(self, lane: str) -> list[str] | None:
        """The workers of ``lane`` (:data:`LANES`), ``None`` for any; one worker alone takes every lane. The
        workers are asked once (a round trip to the scheduler): one that left later is only a preference."""
        if lane not in LANES:
            raise CurvsliceError(f"unknown lane {lane!r} (one of {', '.join(LANES)})")
        if lane == "any":
            return None
        if self._workers is None:
            self._workers = sorted(self.client.scheduler_info(n_workers=-1)["workers"])
        if len(self._workers) < 2:
            return None
        return self._workers[:1] if lane == "chain" else self._workers[1:]

    def gather(self, futures: Sequence, progress=None) -> list:
        if progress is not None:
            from dask.distributed import as_completed

            for _ in as_completed(futures):
                progress.update(1)
        return self.client.gather(list(futures))


def query_threads(points: int) -> int:
    """Threads of one KD-tree query of ``points`` points (``cKDTree.query(..., workers=query_threads(len(x)))``):
    ``OMP_NUM_THREADS`` when set -- Dask's nannies set it to 1 in their worker processes, which share the cores
    between them already (Dask's guidance: no more threads than cores) -- else every core (-1, as in-process),
    but one for fewer than :data:`THREADED_QUERY` points. Each query's threads are started and joined anew: the
    bunny's folds of layers 41-62 took 7.25 CPU s on a worker with two threads per query, 6.43 with one
    (in-process 7.0-7.2, where the second core is free to take them)."""
    value = os.environ.get("OMP_NUM_THREADS", "")
    if value.isdigit() and int(value) > 0:
        return int(value)
    return -1 if points >= THREADED_QUERY else 1


#: Fewest points of a KD query worth threads (:func:`query_threads`): starting and joining two threads cost
#: 0.2 ms CPU per query, the whole search of 200 points. Of the bunny's 6,461 tool-path queries (1.0 mm), nine in
#: ten have fewer points (median 123), a tenth of all points; one thread for every query took 2.6 of its 61 CPU s less
#: (load 2.3-3.2).
THREADED_QUERY = 4096


def _value(value: Any) -> Any:
    return value


Executor = InProcess | Threads | DaskExecutor


@contextmanager
def open_executor(workers: int | None = None, scheduler: str | None = None,
                  retries: int = RETRIES, threads: int | None = None) -> Iterator[Executor]:
    """In-process without ``workers`` or ``scheduler``: on ``threads`` threads (:class:`Threads`; default
    :func:`default_threads`), in order for one; ``workers``: a local cluster of that many single-threaded
    worker processes (on 127.0.0.1, no dashboard); ``scheduler``: the cluster at that address
    (``tcp://host:8786``, e.g. of ``dask scheduler`` + ``dask worker``)."""
    if workers is not None and scheduler is not None:
        raise CurvsliceError("give either a number of local workers or a scheduler address, not both")
    if threads is not None and (workers is not None or scheduler is not None):
        raise CurvsliceError("threads are for a run in this process: give them without Dask workers or a scheduler")
    if threads is not None and threads < 1:
        raise CurvsliceError(f"the number of threads must be at least 1 (got {threads})")
    if workers is None and scheduler is None:
        count = default_threads() if threads is None else threads
        if count == 1:
            yield InProcess()
            return
        pool = Threads(count)
        try:
            yield pool
        except BaseException:
            pool.close(cancel=True)
            raise
        pool.close()
        return
    from dask.distributed import Client, LocalCluster

    if scheduler is not None:
        cluster = None
        try:
            client = Client(scheduler, timeout="20s")
        except OSError as exc:
            raise CurvsliceError(f"no Dask scheduler at {scheduler} ({exc})") from None
    else:
        if workers < 1:
            raise CurvsliceError(f"the number of workers must be at least 1 (got {workers})")
        import dask

        with dask.config.set(LOCAL_CLUSTER_CONFIG):
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                                   dashboard_address=None)
        client = Client(cluster)
    try:
        yield DaskExecutor(client, retries)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
