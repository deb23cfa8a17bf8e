"""One input of a batch: read it, segment it, write its outputs, return its summary row.

:func:`segment_input` is the whole per-input job; every engine (in this process, a
pool of processes, a Dask cluster) calls it and nothing else, so an output or an input
option added here works under all of them. It never raises for a bad input: the error
becomes the row's ``error``.
"""

from __future__ import annotations

import json
import os
import socket
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

from ..config import PipelineConfig
from .inputs import load_scan

__all__ = ["InputTask", "SegmentOptions", "InputSummary", "OUTPUT_WRITERS", "segment_input",
           "result_payload", "describe_error", "worker_pipeline", "warm_worker", "portable_result"]


@dataclass(frozen=True)
class InputTask:
    """One input file and the files its outputs go to.

    index : position in the batch (rows are reported in this order at the end).
    path : the input as given (it is also written into the result file).
    name : the input's distinct output name (see :func:`.inputs.output_names`).
    outputs : ``(kind, path)`` pairs, a kind of :data:`OUTPUT_WRITERS` each.
    """

    index: int
    path: str
    name: str
    outputs: tuple[tuple[str, str], ...] = ()

    def outputs_exist(self) -> bool:
        """True when every output file is there (they are written atomically: complete)."""
        return bool(self.outputs) and all(os.path.isfile(p) for _, p in self.outputs)


@dataclass(frozen=True)
class SegmentOptions:
    """What every worker needs besides the task: picklable, sent once per worker.

    config : the resolved pipeline configuration.
    units : unit of the inputs' coordinates (``"cm"``, ...); None takes the
        configuration's ``sensor.units``.
    load_options : other keyword arguments for the scan loader.
    keep_result : return the :class:`~rangeseg_o3d.result.Result` with the summary.
    keep_stages : keep the intermediate images in that Result (several MB per VGA
        frame; off by default so that results cross process boundaries cheaply).
    table : return the readable feature table with the summary.
    light_log : log no intermediate images to the rerun recording (``--light``).
    """

    config: PipelineConfig
    units: str | None = None
    load_options: dict = field(default_factory=dict)
    keep_result: bool = False
    keep_stages: bool = False
    table: bool = False
    light_log: bool = False


@dataclass
class InputSummary:
    """What one input gave: one row of the batch's summary table.

    ``status`` is ``"ok"``, ``"failed"`` (``error`` says why) or ``"skipped"`` (resumed:
    its outputs were there). Times are seconds: reading, the pipeline, writing, all, and
    the CPU time the worker process spent on it (``cpu_s``; less than ``total_s`` when
    the machine is shared).
    ``result`` and ``table`` are filled only when asked for; they are not part of the row.
    """

    index: int
    input: str
    name: str
    status: str = "ok"
    error: str | None = None
    height: int | None = None
    width: int | None = None
    n_valid: int | None = None
    planes: int | None = None
    cylinders: int | None = None
    spheres: int | None = None
    unfitted: int | None = None
    read_s: float | None = None
    segment_s: float | None = None
    write_s: float | None = None
    total_s: float | None = None
    cpu_s: float | None = None
    worker: str | None = None
    outputs: list[str] = field(default_factory=list)
    stage_timings: dict[str, float] = field(default_factory=dict)
    result: Any = field(default=None, repr=False, compare=False)
    table: str | None = field(default=None, repr=False, compare=False)

    @property
    def ok(self) -> bool:
        return self.status != "failed"

    def row(self) -> dict:
        """The summary row: every field but ``result`` and ``table``."""
        data = asdict(replace(self, result=None, table=None))
        del data["result"], data["table"]
        return data


def result_payload(input_path: str, config: PipelineConfig, result, pose=None) -> dict:
    """The content of a result file: input, configuration, the scan's pose (if it has
    one) and the Result, no timings.

    Timings vary from run to run and go to the summary table instead, so that the same
    input and configuration give the same file byte for byte on any engine.
    """
    body = result.to_dict()
    body.pop("timings", None)
    head = {"input": str(input_path), "config": config.model_dump(mode="json")}
    if pose is not None:
        head["pose"] = pose.tolist()
    return {**head, **body}


def _write_json(path: Path, *, input_path, config, cloud, result) -> None:
    from ..io.atomic import atomic_write

    # One line: json's C encoder serves only indent=None, 3x faster than indent=2 on a
    # VGA frame's record (its plane boundaries make it ~0.7 MB); json.tool pretty-prints.
    with atomic_write(path, mode="w") as fh:
        json.dump(result_payload(input_path, config, result), fh)
        fh.write("\n")


def _write_panel(path: Path, *, input_path, config, cloud, result) -> None:
    from ..viz.panel import write_panel_png

    write_panel_png(path, cloud, result)


def _write_labels(path: Path, *, input_path, config, cloud, result) -> None:
    from ..io.export import write_labels_png

    write_labels_png(result.labels, path)


def _write_ply(path: Path, *, input_path, config, cloud, result) -> None:
    from ..io.export import write_ply

    write_ply(path, result, cloud)


#: Output kinds: name -> writer(path, *, input_path, config, cloud, result), atomic.
OUTPUT_WRITERS: dict[str, Callable[..., None]] = {
    "json": _write_json, "labels": _write_labels, "ply": _write_ply, "panel": _write_panel}
#: The file suffix of each output kind (in an output folder: ``<name><suffix>``).
OUTPUT_SUFFIXES: dict[str, str] = {"json": ".json", "labels": ".png", "ply": ".ply", "panel": ".png"}


def describe_error(exc: BaseException, path) -> str:
    """A one-line message for a failed input that names its path exactly once."""
    if isinstance(exc, OSError) and exc.strerror:
        text = exc.strerror
        other = exc.filename if exc.filename not in (None, str(path), os.fspath(path)) else None
        if other is not None:
            text = f"{text}: {other}"
    else:
        text = str(exc).strip() or "(no message)"
        if not isinstance(exc, (ValueError, OSError)):
            # Not one of our own error types: the type tells what went wrong (EOFError, ...).
            text = f"{type(exc).__name__}: {text}"
    text = " ".join(text.split())  # one line
    return text if str(path) in text else f"{path}: {text}"


_PIPELINES: dict[str, Any] = {}


def worker_pipeline(config: PipelineConfig):
    """The process's Pipeline for ``config``: built once per process and configuration."""
    from ..pipeline import Pipeline

    key = config.model_dump_json()
    if key not in _PIPELINES:
        _PIPELINES[key] = Pipeline(config)
    return _PIPELINES[key]


def _warm_cloud():
    """A 120 x 160 depth-camera view of a wall, a floor, a sphere and a cylinder, computed
    in closed form (no ray caster to import): every kind of kernel runs on it."""
    import numpy as np

    from ..cloud import OrganizedCloud

    focal = 131.25
    x, y = np.meshgrid((np.arange(160) - 79.5) / focal, (np.arange(120) - 59.5) / focal)
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = np.minimum(3.0, np.where(y > 0, 0.8 / y, np.inf))  # wall z = 3, floor y = 0.8
        # sphere: centre (0.4, 0.2, 2), radius 0.35; rays (x, y, 1)
        a, b = x * x + y * y + 1.0, 0.4 * x + 0.2 * y + 2.0
        disc = b * b - a * (0.4**2 + 0.2**2 + 2.0**2 - 0.35**2)
        depth = np.where(disc > 0, np.minimum(depth, (b - np.sqrt(disc)) / a), depth)
        # vertical cylinder (axis along y): centre x = -0.6, z = 2.2, radius 0.25
        a, b = x * x + 1.0, -0.6 * x + 2.2
        disc = b * b - a * (0.6**2 + 2.2**2 - 0.25**2)
        depth = np.where(disc > 0, np.minimum(depth, (b - np.sqrt(disc)) / a), depth)
    depth = depth + np.random.default_rng(0).normal(0.0, 1e-3, depth.shape)
    return OrganizedCloud(np.stack([x * depth, y * depth, depth], axis=-1))


def warm_worker(config: PipelineConfig) -> float:
    """Build the process's Pipeline and load its compiled kernels; returns seconds.

    Runs the pipeline once on a small synthetic frame, so that the first real input's
    timings do not include loading the kernels (about a second per process).
    """
    start = time.perf_counter()
    pipeline = worker_pipeline(config)
    try:
        pipeline.run(_warm_cloud())
    except ValueError:  # a configuration this frame does not suit: the kernels load later
        pass
    return time.perf_counter() - start


def segment_input(task: InputTask, options: SegmentOptions, pipeline=None, *,
                  recording=None) -> InputSummary:
    """Read, segment and write one input; never raises for a bad input.

    Parameters
    ----------
    task : the input and its output files.
    options : the configuration and what to return.
    pipeline : a Pipeline built from ``options.config``; None uses the process's own
        (:func:`worker_pipeline`).
    recording : optional rerun recording; the scan is logged at ``task.index``.

    Returns
    -------
    InputSummary
        ``status="failed"`` with the error message if anything went wrong.
    """
    row = InputSummary(index=task.index, input=task.path, name=task.name,
                       worker=f"{socket.gethostname()}:{os.getpid()}")
    start, cpu_start = time.perf_counter(), time.process_time()
    try:
        if pipeline is None:
            pipeline = worker_pipeline(options.config)
        units = options.units or pipeline.sensor.units
        cloud = load_scan(task.path, units=units, **options.load_options)
        row.height, row.width = (int(n) for n in cloud.shape)
        row.n_valid = int(cloud.n_valid)
        row.read_s = time.perf_counter() - start
        result = pipeline.run(cloud, recording=recording, scan_index=task.index,
                              light_log=options.light_log)
        row.segment_s = time.perf_counter() - start - row.read_s
        for kind, out in task.outputs:
            Path(out).parent.mkdir(parents=True, exist_ok=True)  # names like a/scan
            OUTPUT_WRITERS[kind](Path(out), input_path=task.path, config=options.config,
                                 cloud=cloud, result=result)
        row.write_s = time.perf_counter() - start - row.read_s - row.segment_s
    except Exception as exc:  # any failure of one input is that input's error, the batch goes on
        row.status, row.error = "failed", describe_error(exc, task.path)
        row.total_s = time.perf_counter() - start
        row.cpu_s = time.process_time() - cpu_start
        return row
    counts = result.counts()
    row.planes, row.cylinders, row.spheres, row.unfitted = (
        counts["plane"], counts["cylinder"], counts["sphere"], counts["unfitted"])
    row.outputs = [out for _, out in task.outputs]
    row.stage_timings = {k: float(v) for k, v in result.timings.items()}
    row.total_s = time.perf_counter() - start
    row.cpu_s = time.process_time() - cpu_start
    if options.table:
        row.table = result.table(title=(
            f"{task.path} ({row.height}x{row.width}, {row.n_valid} valid points, "
            f"preset {options.config.name})"))
    if options.keep_result:
        row.result = portable_result(result, keep_stages=options.keep_stages)
    return row


def portable_result(result, *, keep_stages: bool = False):
    """``result`` made cheap to send to another process: no intermediate images unless
    ``keep_stages``, and features that no longer point at the scan's points.

    Each feature's patch geometry and covariance are computed here (if the result file
    did not already) and kept, so they read the same on the receiving side.
    """
    features = [replace(f, source=None, _cache={"geometry": f.geometry, "covariance": f.covariance})
                for f in result.features]
    return replace(result, features=features, stages=result.stages if keep_stages else {})
