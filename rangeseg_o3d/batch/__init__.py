"""Segment many scans: in this process, on a pool of local processes, or on a Dask cluster.

>>> from rangeseg_o3d.batch import run_batch
>>> for row in run_batch(["scans/"], config="rgbd_vga", out="results/", jobs=2):  # doctest: +SKIP
...     print(row.input, row.status, row.planes)

:func:`run_batch` checks the inputs and the output places at once (a ValueError before
any work), then returns an iterator of :class:`InputSummary` rows in the order the
inputs finish. Each input's result file is ``<out>/<name>.json``, where ``name`` keeps
inputs from different folders apart (:func:`output_names`); its content depends only
on the input and the configuration, so every engine writes the same bytes.
"""

from __future__ import annotations

import contextlib
import logging
import os
from typing import Iterator

from .engines import MAX_ATTEMPTS, available_cores, run_dask, run_pool, run_serial
from .inputs import LOADERS, check_regular_file, expand_inputs, input_suffixes, load_scan, output_names
from .plan import BatchPlan, plan_tasks, prepare_outputs
from .report import Progress, read_summary, write_summary
from .task import (InputSummary, InputTask, SegmentOptions, describe_error, result_payload,
                   segment_input)

__all__ = [
    "run_batch",
    "dask_client",
    "InputSummary",
    "InputTask",
    "SegmentOptions",
    "BatchPlan",
    "plan_tasks",
    "prepare_outputs",
    "segment_input",
    "result_payload",
    "describe_error",
    "expand_inputs",
    "output_names",
    "check_regular_file",
    "load_scan",
    "run_serial",
    "run_pool",
    "run_dask",
    "available_cores",
    "Progress",
    "write_summary",
    "read_summary",
    "LOADERS",
    "input_suffixes",
    "MAX_ATTEMPTS",
]

log = logging.getLogger(__name__)

#: Seconds to wait for a running Dask scheduler to answer.
CONNECT_TIMEOUT_S = 10.0


def run_batch(inputs, *, config=None, out=None, outputs=("json",), jobs: int | None = None,
              client=None, resume: bool = False, units: str | None = None,
              load_options: dict | None = None,
              keep_results: bool = False, keep_stages: bool = False, tables: bool = False,
              targets: dict | None = None, recording=None, plan: BatchPlan | None = None,
              light_log: bool = False) -> Iterator[InputSummary]:
    """Segment every input; an iterator of per-input summaries, in completion order.

    Parameters
    ----------
    inputs : files, folders (searched recursively) and glob patterns.
    config : a PipelineConfig, preset name, YAML path or dict (default lms200).
    out : output folder (or, for one input, a ``.json`` file); None writes nothing.
    outputs : output kinds written per input into ``out`` (``"json"``, ``"labels"``,
        ``"ply"``, ``"panel"``).
    jobs : worker processes on this machine (default: the cores available); 1 runs in
        this process.
    client : a ``dask.distributed.Client``; the inputs run on its workers (``jobs`` unused).
    resume : inputs whose output files all exist are not run (``status="skipped"``).
    units : unit of the inputs' coordinates (``"m"``, ``"cm"``, ``"mm"``, ...); None takes
        the configuration's ``sensor.units``.
    load_options : other keyword arguments for the scan loader.
    keep_results : put each input's Result in its summary (``.result``), without the
        intermediate images unless ``keep_stages``.
    tables : put the readable feature table in each summary (``.table``).
    targets : ``{kind: file or folder}`` for further outputs (see :func:`plan_tasks`).
    recording : a rerun recording to log every scan to (runs in this process).
    light_log : log no intermediate images to ``recording`` (see ``log_scan(light=True)``).
    plan : a plan made beforehand (then ``inputs``, ``out``, ``outputs``, ``targets``
        are not used).

    Raises
    ------
    ValueError
        Before any work: no input, a pattern matching nothing, an invalid configuration,
        an output folder that is missing, not writable or ambiguous.
    """
    from ..config import load_config

    options = SegmentOptions(config=load_config(config), units=units,
                             load_options=dict(load_options or {}),
                             keep_result=keep_results, keep_stages=keep_stages, table=tables,
                             light_log=light_log)
    if plan is None:
        plan = plan_tasks(inputs, out=out, outputs=outputs, targets=targets)
    prepare_outputs(plan)
    if jobs is not None and int(jobs) < 1:
        raise ValueError(f"jobs must be at least 1; got {jobs}")
    return _iterate(plan.tasks, options, jobs=jobs, client=client, resume=resume,
                    recording=recording)


def _iterate(tasks, options, *, jobs, client, resume, recording) -> Iterator[InputSummary]:
    todo = []
    for task in tasks:
        if resume and task.outputs_exist():
            yield InputSummary(index=task.index, input=task.path, name=task.name,
                               status="skipped", outputs=[p for _, p in task.outputs])
        else:
            todo.append(task)
    if not todo:
        return
    if client is not None:
        yield from run_dask(todo, options, client)
        return
    jobs = min(int(jobs or available_cores()), len(todo))
    if jobs == 1 or recording is not None:
        yield from run_serial(todo, options, recording=recording)
    else:
        yield from run_pool(todo, options, jobs)


@contextlib.contextmanager
def dask_client(scheduler: str, *, workers: int | None = None):
    """A ``dask.distributed.Client`` for ``--scheduler``: ``"local"`` starts a LocalCluster
    of ``workers`` single-threaded worker processes (default: the cores available);
    an address (``tcp://HOST:PORT``) connects to a running scheduler. Closed on exit.

    Raises
    ------
    ValueError
        dask.distributed is not installed (the ``[dask]`` extra), or no scheduler answers.
    """
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise ValueError("--scheduler needs dask.distributed: pip install 'rangeseg_o3d[dask]'") from None
    if not logging.getLogger().isEnabledFor(logging.INFO):
        # distributed logs every connection at INFO; keep the progress readable (-v shows it)
        logging.getLogger("distributed").setLevel(logging.WARNING)
    if scheduler == "local":
        import dask

        n = workers or available_cores()
        # Dask starts workers with MALLOC_TRIM_THRESHOLD_=65536, which makes glibc map and
        # zero fresh pages for every large array: 0.12-0.13 instead of 0.09 CPU s per VGA
        # frame (scripts/bench_batch.py). Our workers allocate frame-sized arrays in a loop.
        spawn_env = dask.config.get("distributed.nanny.pre-spawn-environ")
        environ = {k: v for k, v in spawn_env.items() if k != "MALLOC_TRIM_THRESHOLD_"}
        # An earlier cluster in this process left Dask's value in os.environ (its nannies
        # write it there); the workers would inherit it. A value of the user's stays.
        leaked = os.environ.get("MALLOC_TRIM_THRESHOLD_")
        if leaked is not None and leaked == str(spawn_env.get("MALLOC_TRIM_THRESHOLD_")):
            del os.environ["MALLOC_TRIM_THRESHOLD_"]
        else:
            leaked = None
        # Nor the statistical profiler's stack sampling every 10 ms: it is for the dashboard,
        # which this cluster does not serve.
        try:
            with dask.config.set({"distributed.nanny.pre-spawn-environ": environ,
                                  "distributed.worker.profile.enabled": False}):
                cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                       dashboard_address=None)
        finally:
            if leaked is not None:
                os.environ["MALLOC_TRIM_THRESHOLD_"] = leaked
        try:
            with Client(cluster) as client:
                yield client
        finally:
            cluster.close()
        return
    try:
        client = Client(scheduler, timeout=f"{CONNECT_TIMEOUT_S}s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise ValueError(f"no Dask scheduler answers at {scheduler} ({exc})") from None
    try:
        yield client
    finally:
        client.close()
