"""The ``rangeseg`` command line: segment, demo, compare, capture (argument types in
:mod:`.args`, the capture command in :mod:`.capture`)."""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import warnings
from pathlib import Path

import numpy as np

from .args import finite_float, positive_int

log = logging.getLogger(__name__)

__all__ = ["main", "add_config_arguments", "config_from_args"]


def add_config_arguments(parser: argparse.ArgumentParser, *, preset: bool = True,
                         units: bool = False) -> None:
    """The configuration options every command shares: ``--config``, ``--set`` (and ``--units``)."""
    if preset:
        parser.add_argument("--config", default="lms200", help="preset name or YAML path (default lms200)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="set one configuration value by dotted key, e.g. sensor.sigma0=0.01 or "
                             "refine.k_sigma=2.5 (repeatable)")
    if units:
        from ..sensor import UNIT_SCALES

        parser.add_argument("--units", choices=list(UNIT_SCALES), default=None,
                            help="unit of the inputs' coordinates, converted to metres "
                                 "(default: the preset's sensor.units)")


def config_from_args(args, source=None):
    """The configuration ``--config`` (or ``source``) names, with the ``--set`` overrides."""
    from ..config import load_config, parse_overrides

    return load_config(args.config if source is None else source,
                       overrides=parse_overrides(getattr(args, "overrides", None) or []))


def write_json(path: Path, payload: dict) -> None:
    """Write ``payload`` as JSON atomically."""
    from ..io.atomic import atomic_write

    with atomic_write(path, mode="w") as fh:
        json.dump(payload, fh, indent=2)


def _load_options(args) -> dict:
    """The reader options of ``segment`` (depth PNG intrinsics and scale) for every input."""
    intrinsics = getattr(args, "intrinsics", None)
    if intrinsics is not None and len(intrinsics) == 1:
        intrinsics = intrinsics[0]  # an Open3D PinholeCameraIntrinsic JSON file
    elif intrinsics is not None:
        try:
            intrinsics = [finite_float(v) for v in intrinsics]
        except argparse.ArgumentTypeError:
            raise ValueError(f"--intrinsics takes fx fy cx cy or one JSON file; got {intrinsics}") from None
    depth_scale = getattr(args, "depth_scale", None)
    return {"intrinsics": intrinsics, "depth_scale": 0.001 if depth_scale is None else depth_scale}


def _rerun_args(parser):
    try:
        from ..viz.rerun_log import add_rerun_arguments
    except ImportError:  # pragma: no cover - viz is part of the package
        return
    add_rerun_arguments(parser)


def _recording(args):
    from ..viz.rerun_log import recording_from_args

    return recording_from_args(args)


def _finish(args, rec, cloud=None, result=None, png=None):
    if png and cloud is not None and result is not None:
        from ..viz.panel import write_panel_png

        write_panel_png(png, cloud, result)
        print(f"wrote {png}")
    if rec is not None:
        from ..viz.rerun_log import finish_recording

        finish_recording(args, rec)


def _summary_path(args, plan) -> Path | None:
    if args.summary:
        return Path(args.summary)
    return plan.folder / "summary.jsonl" if plan.folder is not None else None


def _dask_or_none(args, n_tasks: int):
    import contextlib

    if not args.scheduler:
        return contextlib.nullcontext()
    from ..batch import dask_client

    return dask_client(args.scheduler, workers=min(args.jobs, n_tasks) if args.jobs else None)


def cmd_segment(args) -> int:
    """``rangeseg segment``: every input through :func:`rangeseg_o3d.batch.run_batch`."""
    import time

    from ..batch import Progress, plan_tasks, read_summary, run_batch, write_summary
    from ..cloud import set_max_grid_points

    config = config_from_args(args)
    set_max_grid_points(config.max_grid_points)  # loaders refuse bigger grids before allocating
    targets = {"labels": args.labels, "ply": args.ply, "panel": getattr(args, "png", None)}
    plan = plan_tasks(args.inputs, out=args.out, targets=targets)
    if args.resume and not any(task.outputs for task in plan.tasks):
        raise ValueError("--resume needs --out (or --labels/--ply): without output files nothing tells what is done")
    summary_path = _summary_path(args, plan)
    if summary_path is not None and summary_path.suffix != ".jsonl":
        raise ValueError(f"--summary must name a .jsonl file; got {summary_path}")
    previous = read_summary(summary_path) if args.resume and summary_path else {}
    single = len(plan.tasks) == 1
    rec = _recording(args)
    if rec is not None and (args.scheduler or (args.jobs or 1) > 1):
        print("note: rerun logging runs every input in this process (--jobs/--scheduler ignored)",
              file=sys.stderr)
    rows, start = [], time.perf_counter()
    progress = None
    try:
        with _dask_or_none(args, len(plan.tasks)) as client:
            batch = run_batch(None, config=config, plan=plan, jobs=args.jobs, units=args.units,
                              load_options=_load_options(args),
                              client=None if rec is not None else client, resume=args.resume,
                              tables=args.tables or single or args.out is None, recording=rec,
                              light_log=bool(getattr(args, "light", False)))
            progress = None if single else Progress(len(plan.tasks), bar=None if not args.quiet else False)
            for row in batch:
                if row.status == "skipped" and row.input in previous:
                    row_dict = {**previous[row.input], "status": "skipped"}
                else:
                    row_dict = row.row()
                rows.append(row_dict)
                if progress is not None:
                    progress.update(row)
                elif row.status == "failed":
                    print(f"error: {row.error}", file=sys.stderr)
                if row.table:
                    (progress.write if progress is not None else print)(row.table)
                if single and row.status == "ok":
                    for out in row.outputs:
                        print(f"wrote {out}")
    except KeyboardInterrupt:
        print(f"interrupted after {len(rows)} of {len(plan.tasks)} inputs"
              + ("; run again with --resume to do the rest" if plan.folder else ""), file=sys.stderr)
        return 130
    finally:
        if progress is not None:
            progress.close()
        if summary_path is not None and rows:
            written = write_summary(rows, summary_path)
            if not single:
                print("summary: " + ", ".join(str(p) for p in written))
        _finish(args, rec)
    failed = sum(r["status"] == "failed" for r in rows)
    if not single:
        elapsed = time.perf_counter() - start
        done = sum(r["status"] != "skipped" for r in rows)
        print(f"{len(rows)} inputs: {len(rows) - failed - (len(rows) - done)} ok, "
              f"{len(rows) - done} skipped, {failed} failed in {elapsed:.1f} s "
              f"({done / elapsed if elapsed > 0 else 0:.2f} files/s)")
    if failed:
        print(f"{failed} of {len(rows)} inputs failed", file=sys.stderr)
        return 1
    return 0


def cmd_demo(args) -> int:
    """``rangeseg demo``: a simulated LMS200 scan (a capture over serial ptys, or with
    ``--no-capture`` a ray-cast one) segmented and written to ``--out`` (scan, result, labels,
    panel); 0 on success. ValueError for a ``--faults`` rate outside [0, 1)."""
    from ..pipeline import Pipeline

    if not (math.isfinite(args.faults) and 0.0 <= args.faults < 1.0):
        raise ValueError(f"--faults must be a byte fault rate in [0, 1); got {args.faults}")
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    if args.no_capture:
        from ..synthetic.lms200 import simulate_lms200
        from ..synthetic.suite import default_scene

        cloud = simulate_lms200(default_scene(), seed=args.seed).cloud
        source = "simulated LMS200 scan of the default scene (ray-cast)"
    else:
        from ..acquisition.simulate import simulated_capture

        cloud = simulated_capture(faults=args.faults, seed=args.seed)
        source = "stop-and-go capture from the simulated LMS200 + PowerCube over serial ptys"
        if cloud.shape[1] == 181:
            # The paper's processing window: beams 25..155 deg of the 181 (1 deg steps).
            cloud = cloud.crop(cols=slice(25, 156))
    scan_path = cloud.save(out_dir / "scan.npz")
    pipeline = Pipeline(config_from_args(args))
    # The first run in a process loads the compiled kernels (about a second); the timings
    # shown are those of the run after it, which is what each further scan costs.
    first = pipeline.run(cloud).timings["total"]
    rec = _recording(args)
    result = pipeline.run(cloud, recording=rec, light_log=bool(getattr(args, "light", False)))
    print(result.table(title=f"demo: {source}\n{cloud!r}, preset {pipeline.config.name}"))
    print(f"(timings of a second run; the first, which loads the compiled kernels, took "
          f"{first * 1e3:.0f} ms)")
    payload = {"input": str(scan_path), "source": source,
               "config": pipeline.config.model_dump(), **result.to_dict()}
    write_json(out_dir / "result.json", payload)
    from ..io.atomic import atomic_write

    with atomic_write(out_dir / "labels.npy", mode="wb") as fh:
        np.save(fh, result.labels)
    print(f"wrote {scan_path}, {out_dir / 'result.json'}, {out_dir / 'labels.npy'}")
    _finish(args, rec, cloud, result, png=args.png or str(out_dir / "panel.png"))
    return 0


def _version() -> str:
    from importlib import metadata

    from .. import __version__

    try:
        return metadata.version("rangeseg_o3d")
    except metadata.PackageNotFoundError:  # run from a source tree that is not installed
        return __version__


def build_parser() -> argparse.ArgumentParser:
    """The ``rangeseg`` command line: its options and the subcommands ``segment``, ``demo``,
    ``capture`` and the others below."""
    parser = argparse.ArgumentParser(
        prog="rangeseg",
        description="Segment organized 3-D scans into planes, cylinders and spheres.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress")
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = parser.add_subparsers(dest="command", required=True)

    seg = sub.add_parser("segment", help="segment scans: .npz .pcd .3d, depth .png, KITTI .bin, "
                                             ".e57, ROS bags (files, folders, globs)")
    seg.add_argument("inputs", nargs="+",
                     help="input scans: files, folders (searched recursively) and glob patterns")
    add_config_arguments(seg, units=True)
    seg.add_argument("--out", help="result JSON (one input) or output folder (several)")
    seg.add_argument("--intrinsics", nargs="+", metavar="FX_FY_CX_CY_OR_JSON",
                     help="depth PNG inputs: fx fy cx cy (pixels), or Open3D's PinholeCameraIntrinsic JSON")
    seg.add_argument("--depth-scale", type=finite_float, default=None,
                     help="depth PNG inputs: metres per stored unit (default 0.001, millimetres)")
    seg.add_argument("--labels", help="per-pixel labels as a 16-bit PNG (one input) or folder (several)")
    seg.add_argument("--ply", help="labelled coloured points and the feature meshes as PLY "
                                   "(one input) or folder (several)")
    seg.add_argument("--jobs", type=positive_int, default=None,
                     help="worker processes (default: the cores available; 1 = this process)")
    seg.add_argument("--scheduler", default=None, metavar="local|tcp://HOST:PORT",
                     help="run on Dask: 'local' starts a LocalCluster of --jobs workers, an address "
                          "uses a running scheduler (needs the [dask] extra)")
    seg.add_argument("--resume", action="store_true", help="skip inputs whose outputs all exist")
    seg.add_argument("--summary", default=None, metavar="FILE.jsonl",
                     help="summary table, one row per input (default <out>/summary.jsonl; "
                          "a .parquet beside it when pyarrow is installed)")
    seg.add_argument("--tables", action="store_true",
                     help="print every input's feature table (default: only without --out or for one input)")
    seg.add_argument("--quiet", action="store_true", help="no progress bar, plain lines only")
    _rerun_args(seg)
    seg.set_defaults(func=cmd_segment)

    demo = sub.add_parser("demo", help="capture a simulated scan, segment it, print and write results")
    add_config_arguments(demo)
    demo.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    demo.add_argument("--seed", type=int, default=0)
    demo.add_argument("--faults", type=finite_float, default=0.0, help="byte fault rate on the simulated serial lines")
    demo.add_argument("--no-capture", action="store_true", help="ray-cast the scan directly, skip the serial simulators")
    _rerun_args(demo)
    demo.set_defaults(func=cmd_demo)

    for name, module, help_text in (
        ("compare", "rangeseg_o3d.evaluation.compare", "run every segmenter on the same scans and compare"),
        ("capture", "rangeseg_o3d.cli.capture", "capture a scan from an LMS200 on a PowerCube (or simulators)"),
    ):
        import importlib

        try:
            mod = importlib.import_module(module)
        except ImportError as exc:  # a missing optional part must not break the other commands
            log.debug("subcommand %s unavailable: %s", name, exc)
            continue
        p = sub.add_parser(name, help=help_text)
        mod.add_arguments(p)
        p.set_defaults(func=mod.run)
    return parser


def _show_warning(message, category, filename, lineno, file=None, line=None):
    # A user-facing warning (e.g. a unit problem) as one line, without the source location.
    print(f"warning: {message}", file=sys.stderr if file is None else file)


def main(argv=None) -> int:
    """Entry point of the ``rangeseg`` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    warnings.showwarning = _show_warning
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        return int(args.func(args) or 0)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
