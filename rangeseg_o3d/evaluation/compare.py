"""Method versus baselines: every segmenter on the same scans, in one process.

Each segmenter runs through :class:`~rangeseg_o3d.pipeline.Pipeline` with the scan's
preset; only ``config.segmenter`` is swapped, so the fitter and the refinement stage
are the same for all. Per segmenter and suite it reports the Hoover figures (synthetic
scans, T = 0.8), features found, under/over-segmentation, false fittings, the median
time per scan and the time ratio against ``residual_edges``; it writes a markdown
table and PNG plots, and times region growing alone from 10k to 300k points to show
that its time per point stays flat.

The Open3D segmenters find planes only (Open3D has no cylinder or sphere detector):
on scenes with cylinders and spheres they cannot score those regions.

Run as ``rangeseg compare`` or ``python scripts/compare.py``.
"""

from __future__ import annotations

import argparse
import io
import logging
import statistics
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = [
    "SEGMENTERS",
    "ScanCase",
    "ScanRun",
    "config_for",
    "collect_scans",
    "run_scan",
    "summarise",
    "markdown_table",
    "scaling_curve",
    "add_arguments",
    "run",
]

log = logging.getLogger(__name__)

SEGMENTERS = ("residual_edges", "region_growing", "o3d_planar_patches", "o3d_ransac_planes")
REFERENCE = "residual_edges"
PLANES_ONLY = frozenset({"o3d_planar_patches", "o3d_ransac_planes"})

#: Which sensor family's baseline settings a preset without its own uses.
_FAMILY = {"sick_3dtk": "lms200", "tls_andreashaus": "rgbd_vga"}
#: Open3D baselines per sensor family. RANSAC: 2 cm inlier band (PCL's organized
#: default), as many planes as a room scan shows, and a plane must be as big as the
#: preset's smallest region. Planar patches keep Open3D's defaults (auto sizes).
_OPEN3D_PARAMS = {
    "lms200": {"o3d_ransac_planes": dict(distance_threshold=0.02, max_planes=20, min_inliers=40)},
    "rgbd_vga": {"o3d_ransac_planes": dict(distance_threshold=0.02, max_planes=20, min_inliers=300)},
}
#: Points per frame for the region-growing scaling curve.
SCALING_POINTS = (10_000, 20_000, 50_000, 100_000, 200_000, 300_000)
_QUICK_SCALING_POINTS = (2_000, 5_000, 10_000)


@dataclass
class ScanCase:
    """One scan to segment: its suite, name, cloud, preset and (synthetic) ground truth."""

    suite: str
    name: str
    cloud: object
    preset: str
    truth: object | None = None  # SyntheticScan for synthetic scans


@dataclass
class ScanRun:
    """One segmenter on one scan: median time and what it found."""

    segmenter: str
    suite: str
    scan: str
    n_points: int
    seconds: float
    features: int
    kinds: dict
    segment_seconds: float = float("nan")  # the segmenter alone (Result.timings["segment"])
    hoover: dict | None = None  # Hoover counts (n_truth, correct, over, under, missed, noise)
    false_fittings: int | None = None
    error: str | None = None
    extra: dict = field(default_factory=dict)


def _family(preset: str) -> str:
    return _FAMILY.get(preset, preset)


def config_for(preset: str, segmenter: str, overrides=None):
    """The ``preset`` pipeline with its segmenter swapped for ``segmenter``.

    ``region_growing`` takes its parameters from ``configs/<preset>_region_growing.yaml``
    (or the sensor family's), the Open3D segmenters from this module's per-family table.
    The sensor (noise model) is the preset's, so the stages after segmentation see the
    same noise whichever segmenter runs. The preset's ``tile``
    belongs to the residual-edge method (its 3x3 window needs tile means on depth
    cameras); the baselines see the points as their users would: region growing with its
    own preset's tile (1: it thins the points on its voxel grid), Open3D's on raw points.
    ``overrides`` (dotted keys, or ``KEY=VALUE`` strings as ``--set`` takes them) are set
    over the result.
    """
    from ..config import load_config, parse_overrides, presets

    if overrides is not None and not isinstance(overrides, dict):
        overrides = parse_overrides(overrides)
    base = load_config(preset)
    if segmenter == base.segmenter.name:
        return load_config(base, overrides=overrides)
    tile = 1
    if segmenter == "region_growing":
        known = presets()
        name = next((f"{p}_region_growing" for p in (preset, _family(preset))
                     if f"{p}_region_growing" in known), None)
        own = load_config(name) if name else None
        params = own.segmenter.params if own else {}
        tile = own.tile if own else 1
    else:
        params = _OPEN3D_PARAMS.get(_family(preset), {}).get(segmenter, {})
    data = base.model_dump()
    # The refinement's region size and jump test follow the segmenter swapped in (they
    # were resolved from the preset's segmenter); the sensor stays the preset's.
    for key in ("min_region_size", "jump_ratio", "jump_min"):
        data["refine"][key] = None
    data["segmenter"] = {"name": segmenter, "params": dict(params)}
    data["tile"] = tile
    data["name"] = f"{base.name}+{segmenter}"
    return load_config(data, overrides=overrides)


def collect_scans(*, quick: bool = False, real: bool = True, data_root=None) -> list[ScanCase]:
    """The synthetic suites (LMS200 70x131, RGB-D 640x480) and the real clouds present.

    ``quick`` keeps one small scan of each synthetic suite (the RGB-D one rendered at
    160 x 120) and no real data, for tests.
    """
    from ..synthetic.suite import lms200_scenes, lms200_suite, rgbd_scenes, rgbd_suite

    cases = []
    if quick:
        from ..synthetic.depth_camera import simulate_depth_camera
        from ..synthetic.lms200 import simulate_lms200

        name, scene = lms200_scenes()[0]
        cases.append(ScanCase("lms200", name, None, "lms200", simulate_lms200(scene, seed=0)))
        name, scene = rgbd_scenes()[0]
        small = simulate_depth_camera(scene, width=160, height=120, fx=131.25, fy=131.25,
                                      cx=79.5, cy=59.5, seed=0)
        cases.append(ScanCase("rgbd", name, None, "rgbd_vga", small))
    else:
        cases += [ScanCase("lms200", n, None, "lms200", s) for n, s in lms200_suite()]
        cases += [ScanCase("rgbd", n, None, "rgbd_vga", s) for n, s in rgbd_suite()]
    for case in cases:
        case.cloud = case.truth.cloud
    if real and not quick:
        from ..io.datasets import real_clouds

        for item in real_clouds(data_root):
            try:
                cloud = item.load()
            except (OSError, ValueError) as exc:
                log.warning("skipping %s: %s", item.name, exc)
                continue
            cases.append(ScanCase("real", item.name, cloud, item.preset))
    return cases


def _median_time(func, repeats: int, stage: str | None = None):
    # Median wall time of func(); with ``stage``, also the median of out.timings[stage].
    times, stages, out = [], [], None
    for _ in range(max(1, repeats)):
        start = time.perf_counter()
        out = func()
        times.append(time.perf_counter() - start)
        if stage is not None:
            stages.append(out.timings.get(stage, float("nan")))
    if stage is None:
        return statistics.median(times), out
    return statistics.median(times), statistics.median(stages), out


def run_scan(pipeline, case: ScanCase, *, repeats: int = 3) -> ScanRun:
    """Run ``pipeline`` on ``case`` ``repeats`` times; score the last result if there is truth."""
    from .metrics import evaluate

    name = pipeline.segmenter.name
    try:
        seconds, seg_seconds, result = _median_time(lambda: pipeline.run(case.cloud), repeats, "segment")
    except (ValueError, RuntimeError) as exc:  # one failing scan must not end the comparison
        log.warning("%s failed on %s: %s", name, case.name, exc)
        return ScanRun(name, case.suite, case.name, case.cloud.n_valid, float("nan"), 0, {},
                       error=str(exc))
    counts = result.counts()
    run_ = ScanRun(name, case.suite, case.name, case.cloud.n_valid, seconds,
                   len(result.features), counts, segment_seconds=seg_seconds)
    if case.truth is not None:
        ev = evaluate(case.truth, result)
        run_.hoover = ev.hoover.counts()
        run_.false_fittings = ev.false_fittings
    return run_


_HOOVER_KEYS = ("n_truth", "correct", "over", "under", "missed", "noise")


def summarise(runs: list[ScanRun]) -> list[dict]:
    """One row per (suite, segmenter): summed counts, median time, ratio to residual_edges."""
    rows = []
    keys = sorted({(r.suite, r.segmenter) for r in runs},
                  key=lambda k: (k[0], SEGMENTERS.index(k[1]) if k[1] in SEGMENTERS else 99, k[1]))
    medians = {}
    for suite, seg in keys:
        mine = [r for r in runs if r.suite == suite and r.segmenter == seg]
        times = [r.seconds for r in mine if r.error is None]
        seg_times = [r.segment_seconds for r in mine if r.error is None]
        row = {
            "suite": suite,
            "segmenter": seg,
            "scans": len(mine),
            "failed": sum(r.error is not None for r in mine),
            "median_points": int(np.median([r.n_points for r in mine])),
            "features": sum(r.features for r in mine),
            "median_ms": 1e3 * statistics.median(times) if times else float("nan"),
            "median_segment_ms": 1e3 * statistics.median(seg_times) if seg_times else float("nan"),
        }
        scored = [r for r in mine if r.hoover is not None]
        if scored:
            for key in _HOOVER_KEYS:
                row[key] = sum(r.hoover[key] for r in scored)
            row["correct_pct"] = 100.0 * row["correct"] / row["n_truth"] if row["n_truth"] else float("nan")
            row["false_fittings"] = sum(r.false_fittings for r in scored)
        medians[(suite, seg)] = (row["median_ms"], row["median_segment_ms"])
        rows.append(row)
    for row in rows:
        ref, ref_seg = medians.get((row["suite"], REFERENCE), (None, None))
        row["time_ratio"] = row["median_ms"] / ref if ref and ref > 0 else float("nan")
        row["segment_ratio"] = (row["median_segment_ms"] / ref_seg if ref_seg and ref_seg > 0
                                else float("nan"))
    return rows


def _fmt(value, spec: str = "") -> str:
    if value is None:
        return "-"
    if isinstance(value, float) and np.isnan(value):
        return "n/a"
    return format(value, spec)


def markdown_table(rows: list[dict]) -> str:
    """The summary rows as a markdown table (Hoover columns '-' where there is no truth)."""
    head = ("| suite | segmenter | scans | median points | truth regions | correct | correct % | over "
            "| under | missed | noise | features | false fittings | median ms/scan | time / residual_edges "
            "| segmenter ms/scan | segmenter time / residual_edges |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        name = r["segmenter"] + (" (planes only)" if r["segmenter"] in PLANES_ONLY else "")
        if r["failed"]:
            name += f" ({r['failed']} failed)"
        cells = [r["suite"], name, r["scans"], r["median_points"], r.get("n_truth"), r.get("correct"),
                 _fmt(r.get("correct_pct"), ".1f"), r.get("over"), r.get("under"), r.get("missed"),
                 r.get("noise"), r["features"], r.get("false_fittings"), _fmt(r["median_ms"], ".1f"),
                 _fmt(r["time_ratio"], ".1f"), _fmt(r["median_segment_ms"], ".1f"),
                 _fmt(r["segment_ratio"], ".1f")]
        lines.append("| " + " | ".join(_fmt(c) for c in cells) + " |")
    return "\n".join(lines)


def scaling_curve(points=SCALING_POINTS, *, repeats: int = 3, params: dict | None = None,
                  seed: int = 0) -> list[tuple[int, float]]:
    """Median seconds of region growing alone on synthetic depth frames of ~``points`` points.

    The office scene of the RGB-D suite is rendered at the resolution that gives each
    point count (focal length scaled with it, so the view is the same).
    Returns ``(n_valid, seconds)`` pairs.
    """
    from ..segmenters.region_growing import segment_region_growing
    from ..synthetic.depth_camera import simulate_depth_camera
    from ..synthetic.suite import rgbd_scenes

    scene = rgbd_scenes()[0][1]
    params = params or {}
    probe = simulate_depth_camera(scene, width=64, height=48, fx=52.5, fy=52.5, cx=31.5, cy=23.5, seed=seed)
    valid_fraction = max(probe.cloud.n_valid / (64 * 48), 0.05)
    out = []
    for target in points:
        scale = np.sqrt(target / valid_fraction / (640 * 480))
        width, height = max(8, round(640 * scale)), max(6, round(480 * scale))
        scan = simulate_depth_camera(scene, width=width, height=height, fx=525 * scale, fy=525 * scale,
                                     cx=(width - 1) / 2, cy=(height - 1) / 2, seed=seed)
        seconds, _ = _median_time(lambda: segment_region_growing(scan.cloud, **params), repeats)
        out.append((scan.cloud.n_valid, seconds))
        log.info("scaling: %d points %.3f s", scan.cloud.n_valid, seconds)
    return out


# -- plots and files ------------------------------------------------------------------

def _write_bytes(path: Path, data: bytes) -> None:
    from ..io.atomic import atomic_write

    with atomic_write(path, "wb") as fh:
        fh.write(data)


def _save_figure(fig, path: Path) -> None:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110, bbox_inches="tight")
    _write_bytes(path, buffer.getvalue())


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_time_vs_points(runs: list[ScanRun], path: Path) -> None:
    """Log-log scatter of time per scan against valid points: whole pipeline | segmenter alone."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for ax, attr, title in ((axes[0], "seconds", "Pipeline.run (segment + fit + refine)"),
                            (axes[1], "segment_seconds", "segmentation stage alone")):
        for seg in dict.fromkeys(r.segmenter for r in runs):
            mine = [r for r in runs if r.segmenter == seg and r.error is None]
            ax.scatter([r.n_points for r in mine], [1e3 * getattr(r, attr) for r in mine], label=seg, s=22)
        ax.set(xscale="log", yscale="log", xlabel="valid points per scan", ylabel="ms per scan (median)",
               title=title)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    _save_figure(fig, path)
    plt.close(fig)


def plot_quality(rows: list[dict], path: Path) -> None:
    """Grouped bars of the Hoover counts per segmenter, one panel per synthetic suite."""
    plt = _pyplot()
    suites = [s for s in dict.fromkeys(r["suite"] for r in rows) if any("correct" in r for r in rows if r["suite"] == s)]
    fig, axes = plt.subplots(1, max(1, len(suites)), figsize=(6 * max(1, len(suites)), 4.2), squeeze=False)
    metrics = ("correct", "over", "under", "missed", "noise", "false_fittings")
    for ax, suite in zip(axes[0], suites):
        mine = [r for r in rows if r["suite"] == suite]
        width = 0.8 / max(1, len(mine))
        x = np.arange(len(metrics))
        for k, r in enumerate(mine):
            ax.bar(x + k * width, [r.get(m, 0) for m in metrics], width, label=r["segmenter"])
        ax.set_xticks(x + width * (len(mine) - 1) / 2, metrics, rotation=20)
        truth = mine[0].get("n_truth", 0)
        ax.set(title=f"{suite}: Hoover T=0.8 ({truth} truth regions)", ylabel="regions")
        ax.legend(fontsize=8)
    _save_figure(fig, path)
    plt.close(fig)


def plot_scaling(curve: list[tuple[int, float]], path: Path) -> None:
    """Region growing's time per point against points per frame."""
    plt = _pyplot()
    n = np.array([c[0] for c in curve], dtype=float)
    us = 1e6 * np.array([c[1] for c in curve]) / n
    fig, ax = plt.subplots(figsize=(6.5, 4.0))
    ax.plot(n, us, "o-")
    ax.set(xscale="log", xlabel="valid points per frame", ylabel="µs per point (median)",
           title="region_growing: time per point", ylim=(0, 1.2 * us.max()))
    ax.grid(True, which="both", alpha=0.3)
    _save_figure(fig, path)
    plt.close(fig)


def _scaling_text(curve) -> str:
    lines = ["| points | median s | µs per point |", "|---|---|---|"]
    lines += [f"| {n} | {s:.3f} | {1e6 * s / n:.2f} |" for n, s in curve]
    per_point = [s / n for n, s in curve]
    lines.append(f"\nmax / min time per point: {max(per_point) / min(per_point):.2f}")
    return "\n".join(lines)


def _targets_text(rows: list[dict], curve) -> str:
    lines = []
    by = {(r["suite"], r["segmenter"]): r for r in rows}
    for suite, what in (("lms200", "70x131 scan"), ("rgbd", "640x480 frame")):
        ref, rg = by.get((suite, REFERENCE)), by.get((suite, "region_growing"))
        if not (ref and rg):
            continue
        quality = ref.get("correct", 0) >= rg.get("correct", 0)
        for label, key in (("whole pipeline", "median_ms"), ("segmenter alone", "median_segment_ms")):
            speed = rg[key] / ref[key] if ref[key] > 0 else float("nan")
            met = speed >= 20 and quality
            lines.append(
                f"- {what} ({suite}), {label}: residual_edges is {speed:.1f}x faster than "
                f"region_growing; correct detections {ref.get('correct')} vs {rg.get('correct')} -> "
                f"target (>= 20x, correct at least as high) {'MET' if met else 'NOT MET'}"
            )
    if curve and len(curve) >= 2:
        per_point = [s / n for n, s in curve]
        lines.append(
            f"- region_growing time per point from {curve[0][0]} to {curve[-1][0]} points: "
            f"{1e6 * per_point[0]:.2f} -> {1e6 * per_point[-1]:.2f} µs "
            f"(max/min {max(per_point) / min(per_point):.2f})"
        )
    return "\n".join(lines)


def _per_scan_table(runs: list[ScanRun]) -> str:
    lines = ["| suite | scan | segmenter | points | ms | features | correct / truth | false fittings |",
             "|---|---|---|---|---|---|---|---|"]
    for r in runs:
        hoover = f"{r.hoover['correct']} / {r.hoover['n_truth']}" if r.hoover else "-"
        ms = "failed" if r.error else f"{1e3 * r.seconds:.1f}"
        lines.append(f"| {r.suite} | {r.scan} | {r.segmenter} | {r.n_points} | {ms} | {r.features} "
                     f"| {hoover} | {_fmt(r.false_fittings)} |")
    return "\n".join(lines)


# -- command line ---------------------------------------------------------------------

def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``rangeseg compare`` / ``scripts/compare.py``."""
    parser.add_argument("--quick", action="store_true",
                        help="tiny suite (two small synthetic scans, no real data, short scaling curve)")
    parser.add_argument("--repeats", type=int, default=3, help="runs per scan; the median is reported (default 3)")
    parser.add_argument("--out-dir", default="docs/benchmarks", help="where compare.md and the PNGs go")
    parser.add_argument("--segmenters", default=",".join(SEGMENTERS),
                        help=f"comma-separated segmenters (default {','.join(SEGMENTERS)})")
    parser.add_argument("--no-real", action="store_true", help="skip the real clouds in ../shared/data")
    parser.add_argument("--no-scaling", action="store_true", help="skip the region-growing scaling curve")
    parser.add_argument("--data-root", default=None, help="shared data folder (default <repo>/../shared/data)")
    from ..cli import add_config_arguments

    add_config_arguments(parser, preset=False)


def run(args: argparse.Namespace) -> int:
    """Run the comparison; print the table; write compare.md and the plots. Returns 0."""
    from ..pipeline import Pipeline
    from ..registry import available

    segmenters = [s.strip() for s in args.segmenters.split(",") if s.strip()]
    known = available("segmenter")
    unknown = [s for s in segmenters if s not in known]
    if unknown or not segmenters:
        raise ValueError(f"--segmenters must name known segmenters ({', '.join(known)}); got {args.segmenters!r}")
    if args.repeats < 1:
        raise ValueError(f"--repeats must be >= 1; got {args.repeats}")
    out_dir = Path(args.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)

    cases = collect_scans(quick=args.quick, real=not args.no_real, data_root=args.data_root)
    runs: list[ScanRun] = []
    pipelines: dict[tuple[str, str], Pipeline] = {}
    for case in cases:
        for seg in segmenters:
            key = (case.preset, seg)
            if key not in pipelines:
                pipelines[key] = Pipeline(config_for(case.preset, seg, overrides=args.overrides))
            runs.append(run_scan(pipelines[key], case, repeats=args.repeats))
            print(f"  {case.suite:7s} {case.name:24s} {seg:20s} "
                  f"{_fmt(1e3 * runs[-1].seconds, '.1f'):>9s} ms  features {runs[-1].features}", flush=True)
    rows = summarise(runs)
    table = markdown_table(rows)

    curve = []
    if not args.no_scaling and "region_growing" in segmenters:
        # The raw algorithm on every point: the voxel grid would hide how the kNN scales.
        rg_params = dict(config_for("rgbd_vga", "region_growing").segmenter.params, voxel_size=None)
        curve = scaling_curve(_QUICK_SCALING_POINTS if args.quick else SCALING_POINTS,
                              repeats=args.repeats, params=rg_params)

    targets = _targets_text(rows, curve)
    print()
    print(table)
    if curve:
        print()
        print(_scaling_text(curve))
    if targets:
        print()
        print(targets)

    plot_time_vs_points(runs, out_dir / "time_vs_points.png")
    plot_quality(rows, out_dir / "quality.png")
    parts = [
        "# Segmenter comparison",
        "",
        f"Command: `rangeseg compare{' --quick' if args.quick else ''} --repeats {args.repeats}`; "
        "Hoover T = 0.8, ground-truth regions >= 60 pixels; times are medians of the repeats "
        "(ms/scan: segmentation + fitting + refinement, one Pipeline.run; segmenter ms/scan: "
        "the segmentation stage alone, Result.timings['segment']). "
        "The Open3D segmenters find planes only.",
        "",
        table,
        "",
        "![time per scan](time_vs_points.png)",
        "",
        "![quality](quality.png)",
    ]
    if curve:
        plot_scaling(curve, out_dir / "region_growing_scaling.png")
        parts += ["", "## region_growing scaling", "",
                  "Region growing alone (rgbd_vga_region_growing parameters, voxel grid off) on the "
                  "office scene rendered at growing resolutions.", "", _scaling_text(curve), "",
                  "![scaling](region_growing_scaling.png)"]
    if targets:
        parts += ["", "## Targets", "", targets]
    parts += ["", "## Per scan", "", _per_scan_table(runs), ""]
    _write_bytes(out_dir / "compare.md", "\n".join(parts).encode("utf-8"))
    print(f"\nwrote {out_dir / 'compare.md'} and PNG plots in {out_dir}")
    return 0


def main(argv=None) -> int:
    """``python -m rangeseg_o3d.evaluation.compare`` / ``scripts/compare.py``."""
    parser = argparse.ArgumentParser(prog="compare", description=__doc__.split("\n\n")[0])
    add_arguments(parser)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
