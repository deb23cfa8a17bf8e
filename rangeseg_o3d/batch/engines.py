"""Engines that run :func:`.task.segment_input` over tasks and yield rows as they complete.

- :func:`run_serial`: in this process, in order (rerun logging needs this process).
- :func:`run_pool`: a pool of worker processes on this machine; each builds its Pipeline
  and loads the compiled kernels once, in its initializer.
- :func:`run_dask`: a ``dask.distributed`` Client; the workers read the inputs and write
  the outputs themselves, the client receives summary rows only.

A worker process that dies (killed, out of memory) does not stop a run: the inputs it
held are run again on another worker, up to :data:`MAX_ATTEMPTS` times in all, then
reported as failed.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
import uuid
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Iterable, Iterator

from .task import InputSummary, InputTask, SegmentOptions, segment_input, warm_worker, worker_pipeline

__all__ = ["run_serial", "run_pool", "run_dask", "available_cores", "MAX_ATTEMPTS"]

log = logging.getLogger(__name__)

#: Attempts per input when its worker dies under it (a Dask scheduler's allowed-failures + 1).
MAX_ATTEMPTS = 3


def available_cores() -> int:
    """The cores this process may run on (its CPU affinity), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def _lost(task: InputTask, attempts: int) -> InputSummary:
    return InputSummary(index=task.index, input=task.path, name=task.name, status="failed",
                        error=f"{task.path}: its worker process died {attempts} times while "
                              "segmenting it")


def run_serial(tasks: Iterable[InputTask], options: SegmentOptions, *,
               recording=None) -> Iterator[InputSummary]:
    """Run every task in this process, in order."""
    pipeline = None
    for task in tasks:
        if pipeline is None:
            pipeline = worker_pipeline(options.config)
        yield segment_input(task, options, pipeline, recording=recording)


# -- a pool of local processes -------------------------------------------------------

_OPTIONS: SegmentOptions | None = None


def _init_pool_worker(options: SegmentOptions, warm: bool) -> None:
    global _OPTIONS
    # Ctrl-C is the parent's to handle (it stops the pool); workers print no tracebacks.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _OPTIONS = options
    if warm:
        warm_worker(options.config)


def _pool_task(task: InputTask) -> InputSummary:
    return segment_input(task, _OPTIONS)


def _pool_context():
    # fork starts workers in milliseconds and re-imports nothing; elsewhere spawn.
    methods = multiprocessing.get_all_start_methods()
    return multiprocessing.get_context("fork" if "fork" in methods else "spawn")


def run_pool(tasks: Iterable[InputTask], options: SegmentOptions, jobs: int, *,
             warm: bool = True) -> Iterator[InputSummary]:
    """Run the tasks on ``jobs`` worker processes; yield each row as it completes.

    Each worker builds its Pipeline and (``warm``) loads the kernels once when it starts.
    At most ``2 * jobs`` tasks are queued at a time, so a run of 100,000 inputs holds
    few futures. If a worker dies, the pool is rebuilt; the inputs that were in flight
    are run again one at a time, so that the one that kills its worker is known: it is
    reported as failed after :data:`MAX_ATTEMPTS` deaths, the others complete.
    """
    pending = list(tasks)[::-1]  # pop() from the end = in order
    suspects: list[InputTask] = []  # in flight when a worker died: run alone
    deaths: dict[int, int] = {}
    while pending or suspects:
        with ProcessPoolExecutor(max_workers=jobs, mp_context=_pool_context(),
                                 initializer=_init_pool_worker, initargs=(options, warm)) as pool:
            running: dict = {}
            broken = False
            try:
                yield from _drain(pool, pending, suspects, running, jobs)
            except BrokenProcessPool:
                broken = True
            except BaseException:  # Ctrl-C, or the caller stopped iterating: drop the queue
                pool.shutdown(wait=True, cancel_futures=True)
                raise

            if not broken:
                continue
            lost = list(running.values())
            if len(lost) == 1:  # it was alone: it is the one that killed its worker
                task = lost[0]
                deaths[task.index] = deaths.get(task.index, 0) + 1
                if deaths[task.index] >= MAX_ATTEMPTS:
                    yield _lost(task, deaths[task.index])
                    lost = []
            log.warning("a worker process died with %d input(s) in flight; restarting the pool",
                        len(running))
            suspects.extend(sorted(lost, key=lambda t: -t.index))


def _drain(pool, pending, suspects, running, jobs) -> Iterator[InputSummary]:
    # Keep 2 * jobs tasks queued (a suspect runs alone); raises BrokenProcessPool when a
    # worker died, with the lost tasks still in ``running``.
    while pending or suspects or running:
        if suspects and not running:
            task = suspects.pop()
            running[pool.submit(_pool_task, task)] = task
        while pending and not suspects and len(running) < 2 * jobs:
            task = pending.pop()
            running[pool.submit(_pool_task, task)] = task
        done, _ = wait(running, return_when=FIRST_COMPLETED)
        for future in sorted(done, key=lambda f: f.exception() is not None):
            error = future.exception()
            if error is not None:
                raise error  # segment_input does not raise: a dead worker, or a bug
            del running[future]
            yield future.result()


# -- Dask ---------------------------------------------------------------------------

def _dask_task(task: InputTask, options: SegmentOptions) -> InputSummary:
    # Runs on a Dask worker: its Pipeline is built once per process (worker_pipeline).
    return segment_input(task, options)


def _dask_warm(options: SegmentOptions) -> float:
    return warm_worker(options.config)


def run_dask(tasks: Iterable[InputTask], options: SegmentOptions, client, *,
             warm: bool = True) -> Iterator[InputSummary]:
    """Run the tasks on a ``dask.distributed`` Client; yield each row as it completes.

    The workers must see the input paths and the output folder (a shared file system)
    and have this package installed. The options travel once (scattered); a task is a
    path and its output names. A worker lost mid-task has its tasks rescheduled by the
    scheduler (``distributed.scheduler.allowed-failures``); a task that kills workers
    past that limit is reported as failed.
    """
    from distributed import as_completed
    from distributed.client import FutureCancelledError
    from distributed.scheduler import KilledWorker

    tasks = list(tasks)
    if warm:
        client.run(_dask_warm, options)
    [remote_options] = client.scatter([options], broadcast=True, hash=False)
    run_id = uuid.uuid4().hex[:12]
    futures = {client.submit(_dask_task, task, remote_options, key=f"rangeseg-{run_id}-{task.index}",
                             pure=False): task for task in tasks}
    try:
        for future in as_completed(futures):
            task = futures[future]
            try:
                yield future.result()
            except (KilledWorker, FutureCancelledError) as exc:
                yield _lost(task, MAX_ATTEMPTS) if isinstance(exc, KilledWorker) else InputSummary(
                    index=task.index, input=task.path, name=task.name, status="failed",
                    error=f"{task.path}: cancelled ({exc})")
            future.release()
    finally:
        client.cancel(list(futures))
