"""The ``rangeseg`` command line: segment, demo, compare, capture."""

from __future__ import annotations

import argparse
import json
import logging
import sys
import warnings
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

__all__ = ["main", "format_table", "add_config_arguments", "config_from_args"]


def add_config_arguments(parser: argparse.ArgumentParser, *, preset: bool = True,
                         units: bool = False) -> None:
    """The configuration options every command shares: ``--config``, ``--set`` (and ``--units``)."""
    if preset:
        parser.add_argument("--config", default="lms200", help="preset name or YAML path (default lms200)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="set one configuration value by dotted key, e.g. sensor.sigma0=0.01 or "
                             "refine.k_sigma=2.5 (repeatable)")
    if units:
        from .sensor import UNIT_SCALES

        parser.add_argument("--units", choices=list(UNIT_SCALES), default=None,
                            help="unit of the inputs' coordinates, converted to metres "
                                 "(default: the preset's sensor.units)")


def config_from_args(args, source=None):
    """The configuration ``--config`` (or ``source``) names, with the ``--set`` overrides."""
    from .config import load_config, parse_overrides

    return load_config(args.config if source is None else source,
                       overrides=parse_overrides(getattr(args, "overrides", None) or []))


def format_table(result, *, title: str = "") -> str:
    """A readable table of a Result's features and unfitted regions, with timings."""
    lines = [title] if title else []
    lines.append(f"{'label':>5}  {'kind':<8} {'pixels':>6} {'rms mm':>7}  parameters")
    for f in result.features:
        if f.kind == "plane":
            params = f"n=({f.normal[0]:+.3f}, {f.normal[1]:+.3f}, {f.normal[2]:+.3f}) d={f.d:+.3f} m"
        elif f.kind == "sphere":
            c = f.center
            params = f"c=({c[0]:+.3f}, {c[1]:+.3f}, {c[2]:+.3f}) r={f.radius:.3f} m"
        else:
            a, p = f.axis, f.point
            params = (f"axis=({a[0]:+.3f}, {a[1]:+.3f}, {a[2]:+.3f}) "
                      f"p=({p[0]:+.3f}, {p[1]:+.3f}, {p[2]:+.3f}) r={f.radius:.3f} m")
        lines.append(f"{f.label:>5}  {f.kind:<8} {f.n_pixels:>6} {f.rms * 1e3:>7.2f}  {params}")
    for u in result.unfitted:
        lines.append(f"{u.label:>5}  {'unfitted':<8} {u.n_pixels:>6} {'':>7}  {u.reason}")
    counts = result.counts()
    lines.append(
        f"{counts['plane']} planes, {counts['cylinder']} cylinders, {counts['sphere']} spheres, "
        f"{counts['unfitted']} unfitted"
    )
    lines.append("timings: " + ", ".join(f"{k} {v * 1e3:.2f} ms" for k, v in result.timings.items()))
    return "\n".join(lines)


def write_json(path: Path, payload: dict) -> None:
    """Write ``payload`` as JSON atomically."""
    from .io.atomic import atomic_write

    with atomic_write(path, mode="w") as fh:
        json.dump(payload, fh, indent=2)


def _load_input(path: Path, units: str = "m", args=None):
    # ``units``: of .npz/.pcd coordinates; 3DTK's .3d files are cm by format.
    from .io.readers import load_input

    intrinsics = getattr(args, "intrinsics", None)
    if intrinsics is not None and len(intrinsics) == 1:
        intrinsics = intrinsics[0]  # an Open3D PinholeCameraIntrinsic JSON file
    elif intrinsics is not None:
        try:
            intrinsics = [float(v) for v in intrinsics]
        except ValueError:
            raise ValueError(f"--intrinsics takes fx fy cx cy or one JSON file; got {intrinsics}") from None
    depth_scale = getattr(args, "depth_scale", None)
    return load_input(path, units=units, intrinsics=intrinsics,
                      depth_scale=0.001 if depth_scale is None else depth_scale)


def _rerun_args(parser):
    try:
        from .viz.rerun_log import add_rerun_arguments
    except ImportError:  # pragma: no cover - viz is part of the package
        return
    add_rerun_arguments(parser)


def _recording(args):
    from .viz.rerun_log import recording_from_args

    return recording_from_args(args)


def _finish(args, rec, cloud=None, result=None, png=None):
    if png and cloud is not None and result is not None:
        from .viz.panel import write_panel_png

        write_panel_png(png, cloud, result)
        print(f"wrote {png}")
    if rec is not None:
        from .viz.rerun_log import finish_recording

        finish_recording(args, rec)


def _output_path(option: str | None, path: Path, suffix: str, n_inputs: int) -> Path | None:
    """Where one input's output goes: the file named (one input), else ``<folder>/<stem><suffix>``."""
    if option is None:
        return None
    if n_inputs == 1 and Path(option).suffix.lower() == suffix:
        return Path(option)
    Path(option).mkdir(parents=True, exist_ok=True)
    return Path(option) / f"{path.stem}{suffix}"


def _segment_one(pipeline, path: Path, outputs: dict, args, rec, index: int) -> bool:
    try:
        cloud = _load_input(path, args.units or pipeline.sensor.units, args)
        result = pipeline.run(cloud, recording=rec, scan_index=index)
    except (ValueError, OSError) as exc:
        print(f"error: {path}: {exc}", file=sys.stderr)
        return False
    print(format_table(result, title=f"{path} ({cloud.shape[0]}x{cloud.shape[1]}, "
                                     f"{cloud.n_valid} valid points, preset {pipeline.config.name})"))
    from .io.export import write_outputs

    for written in write_outputs(result, cloud, json_path=outputs.get("out"),
                                 labels_path=outputs.get("labels"), ply_path=outputs.get("ply"),
                                 input=str(path), config=pipeline.config.model_dump(),
                                 **({} if cloud.pose is None else {"pose": cloud.pose.tolist()})):
        print(f"wrote {written}")
    png = getattr(args, "png", None)
    if png:
        png_path = Path(png) if index == 0 else Path(png).with_name(f"{Path(png).stem}_{index}.png")
        from .viz.panel import write_panel_png

        write_panel_png(png_path, cloud, result)
        print(f"wrote {png_path}")
    return True


def cmd_segment(args) -> int:
    from .pipeline import Pipeline

    pipeline = Pipeline(config_from_args(args))
    inputs = [Path(p) for p in args.inputs]
    rec = _recording(args)
    ok = 0
    for i, path in enumerate(inputs):
        outputs = {name: _output_path(getattr(args, name), path, suffix, len(inputs))
                   for name, suffix in (("out", ".json"), ("labels", ".png"), ("ply", ".ply"))}
        ok += _segment_one(pipeline, path, outputs, args, rec, i)
    _finish(args, rec)
    if ok < len(inputs):
        print(f"{len(inputs) - ok} of {len(inputs)} inputs failed", file=sys.stderr)
        return 1
    return 0


def cmd_demo(args) -> int:
    from .pipeline import Pipeline

    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    if args.no_capture:
        from .synthetic.lms200 import simulate_lms200
        from .synthetic.suite import default_scene

        cloud = simulate_lms200(default_scene(), seed=args.seed).cloud
        source = "simulated LMS200 scan of the default scene (ray-cast)"
    else:
        from .acquisition.simulate import simulated_capture

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
    result = pipeline.run(cloud, recording=rec)
    print(format_table(result, title=f"demo: {source}\n{cloud!r}, preset {pipeline.config.name}"))
    print(f"(timings of a second run; the first, which loads the compiled kernels, took "
          f"{first * 1e3:.0f} ms)")
    payload = {"input": str(scan_path), "source": source,
               "config": pipeline.config.model_dump(), **result.to_dict()}
    write_json(out_dir / "result.json", payload)
    from .io.atomic import atomic_write

    with atomic_write(out_dir / "labels.npy", mode="wb") as fh:
        np.save(fh, result.labels)
    print(f"wrote {scan_path}, {out_dir / 'result.json'}, {out_dir / 'labels.npy'}")
    _finish(args, rec, cloud, result, png=args.png or str(out_dir / "panel.png"))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="rangeseg",
        description="Segment organized 3-D scans into planes, cylinders and spheres.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress")
    sub = parser.add_subparsers(dest="command", required=True)

    seg = sub.add_parser("segment", help="segment scans: .npz .pcd .3d, depth .png, KITTI .bin, "
                                             ".e57, ROS bags")
    seg.add_argument("inputs", nargs="+", help="input scans")
    add_config_arguments(seg, units=True)
    seg.add_argument("--out", help="result JSON (one input) or output folder (several)")
    seg.add_argument("--intrinsics", nargs="+", metavar="FX_FY_CX_CY_OR_JSON",
                     help="depth PNG inputs: fx fy cx cy (pixels), or Open3D's PinholeCameraIntrinsic JSON")
    seg.add_argument("--depth-scale", type=float, default=None,
                     help="depth PNG inputs: metres per stored unit (default 0.001, millimetres)")
    seg.add_argument("--labels", help="per-pixel labels as a 16-bit PNG (one input) or folder (several)")
    seg.add_argument("--ply", help="labelled coloured points and the feature meshes as PLY "
                                   "(one input) or folder (several)")
    _rerun_args(seg)
    seg.set_defaults(func=cmd_segment)

    demo = sub.add_parser("demo", help="capture a simulated scan, segment it, print and write results")
    add_config_arguments(demo)
    demo.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    demo.add_argument("--seed", type=int, default=0)
    demo.add_argument("--faults", type=float, default=0.0, help="byte fault rate on the simulated serial lines")
    demo.add_argument("--no-capture", action="store_true", help="ray-cast the scan directly, skip the serial simulators")
    _rerun_args(demo)
    demo.set_defaults(func=cmd_demo)

    for name, module, help_text in (
        ("compare", "rangeseg_o3d.compare", "run every segmenter on the same scans and compare"),
        ("capture", "rangeseg_o3d.acquisition.cli", "capture a scan from an LMS200 on a PowerCube (or simulators)"),
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


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
