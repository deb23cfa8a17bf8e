"""Benchmark the pipeline: Hoover figures, parameter errors, Table 1 columns and stage timings.

Runs ``Pipeline(load_config("configs/lms200.yaml"))`` over the synthetic LMS200 suite, the
``rgbd_vga`` preset over the synthetic RGB-D suite, and each real cloud found in
``<repo>/../shared/data`` with the preset its loader names. Timings are medians of
``--repeats`` runs per scan (a suite's scans in turn, round after round) on one
thread (OpenMP/BLAS/numba env vars and OpenCV set to 1
before anything heavy is imported). Hoover figures at T = 0.8 over ground-truth regions of
at least 60 pixels.

Run: python scripts/benchmark.py [--repeats 20] [--quick] [--no-real] [--no-refine] [--json OUT]

``--cpu-stages`` (with any mode) times the stages in the process's CPU time: on a machine
that other jobs share, wall time per stage is mostly their load.

The sensor matrix (``--matrix``): every sensor of :mod:`rangeseg_o3d.synthetic.matrix`
(nodding lasers at 1, 0.5, 0.25 deg; range noise 2-20 mm; spinning lidars 32 x 1024 to
128 x 2048; Kinect 640 x 480; stereo 1280 x 720; an ABW-like tabletop), each on several
independent random scenes drawn from ``--seed``, segmented by the sensor's preset with
``residual_edges`` and with ``region_growing`` (same scans, same fitting and refinement),
plus the ABW images in ../shared/data/abw scored with SegComp's rules (overlaps over all
pixels, every labelled region counted). One table; a JSON in docs/benchmarks/matrix.json
for a full run (else with --json only).

The real frames (``--frames``): the six real 640 x 480 frames alone, each stage's median
per frame, and ``OrganizedCloud.from_depth`` on the CAPE frame.

Run: python scripts/benchmark.py --frames [--repeats 20]

The same frames for other programs (``--export-frames DIR``): each frame's points as raw
float32 and a manifest of sizes and intrinsics (see :func:`export_frames`), nothing timed;
docs/benchmarks.md times CAPE and PEAC on them.

Run: python scripts/benchmark.py --export-frames DIR

Run: python scripts/benchmark.py --matrix [--quick] [--sensor NAME ...] [--matrix-repeats 5]
     [--rg-repeats 1 | --no-baseline] [--seed 0] [--json OUT] [--surfaces] [--connected-truth]

``--connected-truth`` scores the simulated rows SegComp's way, as the ABW images are: each
4-connected patch of a surface its own truth region (a simulated table split by an object
standing on it is otherwise one surface; ABW's hand labels give each patch its own id).

``--surfaces`` also lists, per scan, every surface not correctly detected (missed, over-
or under-segmented) with where its pixels went: the regions holding them (label, kind,
pixels, fraction of that region on the surface) and how many are in no region.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS",
             "NUMBA_NUM_THREADS", "VECLIB_MAXIMUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from rangeseg_o3d.config import load_config  # noqa: E402
from rangeseg_o3d.evaluation import evaluate, surface_breakdown  # noqa: E402
from rangeseg_o3d.pipeline import Pipeline  # noqa: E402
from rangeseg_o3d.synthetic.suite import lms200_suite, rgbd_suite  # noqa: E402

TOLERANCE = 0.8
MIN_REGION = 60
TARGETS = {
    "percent_correct_min": 90.0,
    "false_fittings_max": 0,
    "normal_error_deg_max": 0.5,
    "radius_error_cm_max": 1.0,
    "lms200_ms_max": 5.0,
    "vga_ms_max": 50.0,
}


def _single_thread() -> None:
    try:
        import cv2

        cv2.setNumThreads(1)
    except ImportError:
        pass


def timed_runs(pipeline: Pipeline, cloud, repeats: int):
    """Run once to warm up (its result is returned), then ``repeats`` times.

    Returns
    -------
    result, {stage: median seconds}, median wall seconds per run, median CPU seconds per
    run (the process's own time: on a shared machine it moves far less than wall time).
    """
    return interleaved_runs(pipeline, [cloud], repeats)[0]


def interleaved_runs(pipeline: Pipeline, clouds: list, repeats: int) -> list[tuple]:
    """:func:`timed_runs` for several clouds, timed in ``repeats`` rounds of one run each.

    A stall of the host (a virtual machine's neighbours) then slows one run of every
    scan it overlaps instead of every run of one scan, and the medians stay apart from it.
    """
    results = [pipeline.run(cloud) for cloud in clouds]
    per_stage: list[dict[str, list[float]]] = [{} for _ in clouds]
    wall: list[list[float]] = [[] for _ in clouds]
    cpu: list[list[float]] = [[] for _ in clouds]
    for _ in range(repeats):
        for i, cloud in enumerate(clouds):
            start, start_cpu = time.perf_counter(), time.process_time()
            res = pipeline.run(cloud)
            wall[i].append(time.perf_counter() - start)
            cpu[i].append(time.process_time() - start_cpu)
            for stage, seconds in res.timings.items():
                per_stage[i].setdefault(stage, []).append(seconds)
    return [(result, {k: statistics.median(v) for k, v in stages.items()}, statistics.median(times),
             statistics.median(cpu_times))
            for result, stages, times, cpu_times in zip(results, per_stage, wall, cpu)]


def _median(values) -> float | None:
    values = np.asarray(values, dtype=float)
    return float(np.median(values)) if values.size else None


def synthetic_rows(suite, pipeline: Pipeline, repeats: int) -> list[dict]:
    rows = []
    timed = interleaved_runs(pipeline, [scan.cloud for _, scan in suite], repeats)
    for (name, scan), (result, stages, wall, cpu) in zip(suite, timed):
        ev = evaluate(scan, result, tolerance=TOLERANCE, min_region=MIN_REGION)
        rows.append({
            "name": name,
            "shape": list(scan.cloud.shape),
            "hoover": ev.hoover.counts() | {"percent_correct": ev.hoover.percent_correct},
            "table1": ev.table1(),
            "unfitted_correct": len(ev.unfitted_correct),
            "missed_kinds": sorted(scan.truth[k].kind for k in ev.hoover.missed),
            "errors": {
                "normal_error_deg": ev.errors("normal_error_deg", "plane").tolist(),
                "offset_error_m": ev.errors("offset_error", "plane").tolist(),
                "sphere_radius_error_m": ev.errors("radius_error", "sphere").tolist(),
                "cylinder_radius_error_m": ev.errors("radius_error", "cylinder").tolist(),
                "cylinder_axis_error_deg": ev.errors("axis_error_deg", "cylinder").tolist(),
                "center_error_m": ev.errors("center_error").tolist(),
            },
            "stage_ms": {k: 1000 * v for k, v in stages.items()},
            "wall_ms": 1000 * wall,
            "cpu_ms": 1000 * cpu,
        })
    return rows


def summarise(rows: list[dict], time_target_ms: float) -> dict:
    """Totals over a suite and whether each target is met."""
    counts = {k: sum(r["hoover"][k] for r in rows)
              for k in ("n_truth", "n_machine", "correct", "over", "under", "missed", "noise")}
    errs = {k: [v for r in rows for v in r["errors"][k]] for k in rows[0]["errors"]} if rows else {}
    radius = errs.get("sphere_radius_error_m", []) + errs.get("cylinder_radius_error_m", [])
    features = sum(r["table1"]["features"] for r in rows)
    false_fittings = sum(r["table1"]["false_fittings"] for r in rows)
    pct = 100.0 * counts["correct"] / counts["n_truth"] if counts["n_truth"] else float("nan")
    normal = _median(errs.get("normal_error_deg", []))
    radius_cm = _median(np.asarray(radius) * 100)
    worst_ms = max((r["stage_ms"].get("total", r["wall_ms"]) for r in rows), default=float("nan"))
    summary = {
        "scans": len(rows),
        "hoover": counts | {"percent_correct": pct},
        "table1": {
            "features": features,
            "under": counts["under"],
            "under_pct": 100.0 * counts["under"] / features if features else float("nan"),
            "over": counts["over"],
            "over_pct": 100.0 * counts["over"] / features if features else float("nan"),
            "false_fittings": false_fittings,
        },
        "median_normal_error_deg": normal,
        "median_offset_error_cm": None if not errs.get("offset_error_m") else 100 * _median(errs["offset_error_m"]),
        "median_sphere_radius_error_cm": None if not errs.get("sphere_radius_error_m") else 100 * _median(errs["sphere_radius_error_m"]),
        "median_cylinder_radius_error_cm": None if not errs.get("cylinder_radius_error_m") else 100 * _median(errs["cylinder_radius_error_m"]),
        "median_radius_error_cm": radius_cm,
        "median_cylinder_axis_error_deg": _median(errs.get("cylinder_axis_error_deg", [])),
        "median_scan_ms": _median([r["stage_ms"].get("total", r["wall_ms"]) for r in rows]),
        "median_scan_cpu_ms": _median([r["cpu_ms"] for r in rows]),
        "worst_scan_ms": worst_ms,
    }
    summary["targets"] = {
        "percent_correct>=90": pct >= TARGETS["percent_correct_min"],
        "false_fittings==0": false_fittings <= TARGETS["false_fittings_max"],
        "median_normal_error<=0.5deg": normal is not None and normal <= TARGETS["normal_error_deg_max"],
        "median_radius_error<=1cm": radius_cm is not None and radius_cm <= TARGETS["radius_error_cm_max"],
        f"every_scan<={time_target_ms:g}ms": worst_ms <= time_target_ms,
    }
    return summary


#: The six real 640 x 480 depth frames (issue 14's comparison with CAPE, PEAC and PCL).
VGA_FRAMES = ("cape_tunnel", "pcl_table_scene_mug", "pcl_milk_cartoon", "pcl_office1", "pcl_frame_laptop",
              "peac_stairs")


def real_rows(repeats: int, limit: int | None, names=None) -> list[dict]:
    try:
        from rangeseg_o3d.io.datasets import real_clouds
    except ImportError as exc:
        print(f"real data: skipped (rangeseg_o3d.io.datasets unavailable: {exc})")
        return []
    clouds = real_clouds()
    if names is not None:
        clouds = [c for c in clouds if c.name in names]
    if limit is not None:
        clouds = clouds[:limit]
    rows, pipelines = [], {}
    for item in clouds:
        try:
            if item.preset not in pipelines:
                pipelines[item.preset] = Pipeline(load_config(item.preset))
            cloud = item.load()
        except Exception as exc:  # report and go on: one bad file must not stop the benchmark
            rows.append({"name": item.name, "preset": item.preset, "error": f"{type(exc).__name__}: {exc}"})
            continue
        result, stages, wall, cpu = timed_runs(pipelines[item.preset], cloud, repeats)
        rows.append({
            "name": item.name,
            "preset": item.preset,
            "shape": list(cloud.shape),
            "counts": result.counts(),
            "largest": [
                {"kind": f.kind, "n_pixels": f.n_pixels, "rms_mm": 1000 * f.rms,
                 **({"radius_m": float(f.radius)} if f.kind != "plane" else {})}
                for f in sorted(result.features, key=lambda f: -f.n_pixels)[:6]
            ],
            "stage_ms": {k: 1000 * v for k, v in stages.items()},
            "wall_ms": 1000 * wall,
            "cpu_ms": 1000 * cpu,
        })
    return rows


#: Header of the manifest :func:`export_frames` writes.
EXPORT_MANIFEST_HEADER = "# name rows cols fx fy cx cy  (<name>.xyz: float32 little-endian, rows x cols x 3, metres, NaN = no return)"


def export_frames(directory, items) -> Path:
    """Write real frames for programs outside Python: ``<name>.xyz`` and ``frames.txt``.

    ``items`` are :class:`rangeseg_o3d.io.datasets.RealCloud` (anything with ``name`` and
    ``load()``). Each frame's points are written as they load (the loaders' own unit and
    validity conversions), as raw little-endian float32, row-major ``rows x cols x 3``,
    metres, all three coordinates NaN where the sensor had no return. ``frames.txt`` has
    one line ``name rows cols fx fy cx cy`` per frame (``nan`` intrinsics when the cloud
    carries no pinhole geometry). Files are written atomically.

    Returns
    -------
    Path of the manifest.

    Raises
    ------
    ValueError
        If ``directory`` exists and is not a directory, or a name has whitespace or a path
        separator (the manifest is whitespace-separated).
    """
    from rangeseg_o3d.geometry import PinholeGeometry
    from rangeseg_o3d.io.atomic import atomic_write

    directory = _export_directory(directory)
    directory.mkdir(parents=True, exist_ok=True)
    lines = [EXPORT_MANIFEST_HEADER]
    for item in items:
        name = str(item.name)
        if not name or any(ch.isspace() or ch in "/\\" for ch in name):
            raise ValueError(f"frame names must be non-empty without spaces or slashes; got {name!r}")
        cloud = item.load()
        with atomic_write(directory / f"{name}.xyz", "wb") as fh:
            fh.write(np.ascontiguousarray(cloud.xyz, dtype="<f4").tobytes())
        geometry = cloud.geometry if isinstance(cloud.geometry, PinholeGeometry) else None
        intrinsics = ((geometry.fx, geometry.fy, geometry.cx, geometry.cy) if geometry is not None
                      else (float("nan"),) * 4)
        rows, cols = cloud.shape
        lines.append(f"{name} {rows} {cols} " + " ".join(repr(float(v)) for v in intrinsics))
    manifest = directory / "frames.txt"
    with atomic_write(manifest, "w", encoding="utf-8") as fh:
        fh.write("\n".join(lines) + "\n")
    return manifest


def _export_directory(directory) -> Path:
    # the export's target as a Path; ValueError when it exists and is not a directory
    directory = Path(directory)
    if directory.exists() and not directory.is_dir():
        raise ValueError(f"--export-frames expects a directory; {directory} is a file")
    return directory


def run_export(directory: Path) -> int:
    """``--export-frames``: the six real VGA frames present, for the C++ peers' drivers."""
    from rangeseg_o3d.io.datasets import real_clouds

    _export_directory(directory)  # a bad target is an error whether or not the frames are here
    items = [item for item in real_clouds() if item.name in VGA_FRAMES]
    if not items:
        print("no real 640x480 frame found in ../shared/data: nothing exported")
        return 1
    manifest = export_frames(directory, items)
    print(f"wrote {len(items)} frames ({', '.join(item.name for item in items)}) and {manifest}")
    return 0


# -- printing ---------------------------------------------------------------------------
def _fmt(value, spec=".2f") -> str:
    return "-" if value is None or (isinstance(value, float) and np.isnan(value)) else format(value, spec)


def print_synthetic(title: str, rows: list[dict], summary: dict) -> None:
    print(f"\n== {title}: Hoover T={TOLERANCE}, regions >= {MIN_REGION} px; times = median of runs, ms ==")
    head = (f"{'scene':<20}{'GT':>4}{'cor':>5}{'over':>5}{'undr':>5}{'miss':>5}{'nois':>5}{'%cor':>7}"
            f"{'feat':>5}{'FF':>4}{'n_err°':>8}{'r_err cm':>9}{'total':>8}  stages")
    print(head)
    for r in rows:
        h, t = r["hoover"], r["table1"]
        e = r["errors"]
        radius = e["sphere_radius_error_m"] + e["cylinder_radius_error_m"]
        stages = " ".join(f"{k}={v:.1f}" for k, v in r["stage_ms"].items() if k != "total")
        print(f"{r['name']:<20}{h['n_truth']:>4}{h['correct']:>5}{h['over']:>5}{h['under']:>5}{h['missed']:>5}"
              f"{h['noise']:>5}{_fmt(h['percent_correct'], '.1f'):>7}{t['features']:>5}{t['false_fittings']:>4}"
              f"{_fmt(_median(e['normal_error_deg']), '.3f'):>8}"
              f"{_fmt(None if not radius else 100 * _median(radius), '.2f'):>9}"
              f"{_fmt(r['stage_ms'].get('total', r['wall_ms']), '.1f'):>8}  {stages}")
        if r["missed_kinds"] or r["unfitted_correct"]:
            print(f"{'':<20}missed: {', '.join(r['missed_kinds']) or '-'}; correct but unfitted: {r['unfitted_correct']}")
    s, h, t = summary, summary["hoover"], summary["table1"]
    print(f"{'TOTAL':<20}{h['n_truth']:>4}{h['correct']:>5}{h['over']:>5}{h['under']:>5}{h['missed']:>5}"
          f"{h['noise']:>5}{_fmt(h['percent_correct'], '.1f'):>7}{t['features']:>5}{t['false_fittings']:>4}"
          f"{_fmt(s['median_normal_error_deg'], '.3f'):>8}{_fmt(s['median_radius_error_cm'], '.2f'):>9}"
          f"{_fmt(s['median_scan_ms'], '.1f'):>8}  (worst scan {_fmt(s['worst_scan_ms'], '.1f')} ms; "
          f"CPU time median {_fmt(s['median_scan_cpu_ms'], '.2f')} ms)")
    print(f"Table 1: features {t['features']}, under-segmentation {t['under']} ({_fmt(t['under_pct'], '.1f')} %), "
          f"over-segmentation {t['over']} ({_fmt(t['over_pct'], '.1f')} %), false fittings {t['false_fittings']}")
    print(f"medians: plane normal {_fmt(s['median_normal_error_deg'], '.3f')} deg, plane offset "
          f"{_fmt(s['median_offset_error_cm'])} cm, sphere radius {_fmt(s['median_sphere_radius_error_cm'])} cm, "
          f"cylinder radius {_fmt(s['median_cylinder_radius_error_cm'])} cm, cylinder axis "
          f"{_fmt(s['median_cylinder_axis_error_deg'], '.2f')} deg")
    print("targets: " + ", ".join(f"{k} {'MET' if ok else 'NOT MET'}" for k, ok in s["targets"].items()))


def print_real(rows: list[dict]) -> None:
    print("\n== real clouds (no ground truth): features per kind, median times in ms ==")
    for r in rows:
        if "error" in r:
            print(f"{r['name']:<22}{r['preset']:<16}ERROR {r['error']}")
            continue
        c = r["counts"]
        largest = ", ".join(
            f"{f['kind']}({f['n_pixels']}px{', r=%.3f m' % f['radius_m'] if 'radius_m' in f else ''})"
            for f in r["largest"])
        stages = " ".join(f"{k}={v:.1f}" for k, v in r["stage_ms"].items() if k != "total")
        print(f"{r['name']:<22}{r['preset']:<16}{'x'.join(map(str, r['shape'])):>9} planes {c['plane']:>3} "
              f"cyl {c['cylinder']:>2} sph {c['sphere']:>2} unfitted {c['unfitted']:>3} "
              f"total {r['stage_ms'].get('total', r['wall_ms']):.1f} cpu {r['cpu_ms']:.1f}  {stages}")
        print(f"{'':<22}largest: {largest}")



# -- the sensor matrix ---------------------------------------------------------------------
#: Which region-growing preset gives the baseline's segmenter parameters, per sensor family.
REGION_GROWING_PRESET = {"nodding": "lms200_region_growing", "noise": "lms200_region_growing",
                         "spinning": "lms200_region_growing", "depth": "rgbd_vga_region_growing",
                         "tabletop": "rgbd_vga_region_growing", "abw": "rgbd_vga_region_growing"}
#: Size classes (pixels) of the ABW surfaces for the correct rate by size.
ABW_SIZE_BINS = (0, 500, 2000, 8000)
#: ABW images: voxel grid of the baseline at the blocks' scale (the rooms' 3 cm would merge faces).
ABW_REGION_GROWING = {"voxel_size": 0.004}


def matrix_configs(preset: str, facts: dict | None, family: str, rg_params: dict):
    """The residual-edge and region-growing configurations of one sensor row.

    The sensor's facts (noise model, grid spacing) go into the preset's ``sensor:``
    section (``facts=None``: the preset's own, as for the real ABW camera); region growing
    swaps the segmenter only (parameters from its family's ``*_region_growing`` preset,
    that preset's tile), keeping the sensor, the fitter and the refinement (whose region
    size and jump test are then its own defaults, as region growing has none).
    """
    overrides = {f"sensor.{key}": value for key, value in (facts or {}).items()}
    base = load_config(preset, overrides=overrides).model_dump()
    base["name"] = f"{preset}@matrix"
    residual = load_config(base)
    own = load_config(REGION_GROWING_PRESET[family])
    grow = residual.model_dump()
    grow["segmenter"] = {"name": "region_growing", "params": {**own.segmenter.params, **rg_params}}
    grow["tile"] = own.tile
    for key in ("min_region_size", "jump_ratio", "jump_min"):
        grow["refine"][key] = None
    grow["name"] = f"{preset}@matrix+region_growing"
    return residual, load_config(grow)


def _plane_normal(points: np.ndarray) -> np.ndarray:
    centred = points - points.mean(axis=0)
    return np.linalg.svd(centred, full_matrices=False)[2][-1]


def score_abw(image, result, tolerance: float = TOLERANCE) -> dict:
    """SegComp figures of one ABW image; plane normal errors against each correctly
    detected surface's least-squares plane of its labelled points (ABW has no models)."""
    from rangeseg_o3d.evaluation import hoover

    score = hoover(image.truth_ids, result.labels, tolerance=tolerance, min_region=1,
                   count_unlabelled=True)
    by_label = {int(f.label): f for f in result.features}
    errors, false_fittings = [], 0
    xyz = image.cloud.xyz
    for truth_id, label in score.correct.items():
        feature = by_label.get(label)
        if feature is None:
            continue
        if feature.kind != "plane":
            false_fittings += 1
            continue
        points = xyz[(image.truth_ids == truth_id) & image.cloud.valid]
        if len(points) >= 3:
            cos = abs(float(_plane_normal(points) @ feature.model.normal))
            errors.append(float(np.degrees(np.arccos(min(1.0, cos)))))
    surfaces = surface_breakdown(image.truth_ids, result.labels, score,
                                 kinds={int(f.label): f.kind for f in result.features})
    sizes = np.bincount(image.truth_ids.ravel())
    by_size = {}
    for lo, hi in zip(ABW_SIZE_BINS, ABW_SIZE_BINS[1:] + (None,)):
        ids = [k for k in range(1, sizes.size) if sizes[k] >= lo and (hi is None or sizes[k] < hi)]
        by_size[f"{lo}-{hi or ''}"] = [sum(k in score.correct for k in ids), len(ids)]
    return {"hoover": score.counts(), "false_fittings": false_fittings, "normal_errors_deg": errors,
            "by_size": by_size, "surfaces": surfaces}


def score_synthetic(scan, result) -> dict:
    ev = evaluate(scan, result, tolerance=TOLERANCE, min_region=MIN_REGION)
    surfaces = surface_breakdown(scan.truth_ids, result.labels, ev.hoover,
                                 kinds={int(f.label): f.kind for f in result.features})
    return {"hoover": ev.hoover.counts(), "false_fittings": ev.false_fittings,
            "normal_errors_deg": ev.errors("normal_error_deg", "plane").tolist(), "surfaces": surfaces}


def run_method(config, clouds: list, repeats: int) -> tuple[list, list[float]]:
    """Results and median total seconds per cloud (warm-up run scored, then ``repeats`` timed)."""
    timed = interleaved_runs(Pipeline(config), clouds, repeats)
    return [r for r, *_ in timed], [stages.get("total", wall) for _, stages, wall, _ in timed]


def method_summary(scores: list[dict], seconds: list[float]) -> dict:
    """Totals over a row's scans: counts, % correct, per-scan means, FF, median normal error, ms."""
    keys = ("n_truth", "n_machine", "correct", "over", "under", "missed", "noise")
    totals = {k: sum(s["hoover"][k] for s in scores) for k in keys}
    n = max(len(scores), 1)
    normal = [e for s in scores for e in s["normal_errors_deg"]]
    by_size = {}
    for s in scores:
        for size, (correct, total) in s.get("by_size", {}).items():
            have = by_size.setdefault(size, [0, 0])
            have[0] += correct
            have[1] += total
    return {
        "by_size": by_size,
        "scans": len(scores),
        **totals,
        "percent_correct": 100.0 * totals["correct"] / totals["n_truth"] if totals["n_truth"] else float("nan"),
        "per_scan": {k: totals[k] / n for k in ("over", "under", "missed", "noise")},
        "false_fittings": sum(s["false_fittings"] for s in scores),
        "median_normal_error_deg": _median(normal),
        "median_ms": 1000 * statistics.median(seconds) if seconds else float("nan"),
        "ms": [1000 * t for t in seconds],
        "scan_percent_correct": [100.0 * s["hoover"]["correct"] / s["hoover"]["n_truth"]
                                 if s["hoover"]["n_truth"] else float("nan") for s in scores],
    }


def matrix_row(name, description, preset, family, facts, rg_params, items, score,
               repeats, rg_repeats, surfaces: bool = False) -> dict:
    """Both methods on the same ``items`` (anything ``score(item, result)`` takes; ``.cloud``);
    ``rg_repeats = 0`` leaves region growing out. With ``surfaces`` each method also keeps,
    per scan, the surfaces not correctly detected (``surface_breakdown``; printed by
    :func:`print_surfaces`)."""
    residual, grow = matrix_configs(preset, facts, family, rg_params)
    clouds = [item.cloud for item in items]
    row = {"sensor": name, "description": description, "preset": preset,
           "sensor_facts": facts, "shape": list(clouds[0].shape) if clouds else None}
    methods = [("residual_edges", residual, repeats)] + ([("region_growing", grow, rg_repeats)] if rg_repeats else [])
    for method, config, reps in methods:
        results, seconds = run_method(config, clouds, reps)
        scores = [score(i, r) for i, r in zip(items, results)]
        row[method] = method_summary(scores, seconds)
        if surfaces:
            row[method]["surfaces"] = [{"scan": getattr(item, "name", str(k)), "surfaces": s["surfaces"]}
                                       for k, (item, s) in enumerate(zip(items, scores))]
    if "region_growing" in row:
        re_ms, rg_ms = row["residual_edges"]["median_ms"], row["region_growing"]["median_ms"]
        row["speed_ratio"] = rg_ms / re_ms if re_ms > 0 else float("nan")
    return row


def as_connected_patches(scan):
    """``scan`` with its truth relabelled one id per 4-connected patch
    (:func:`rangeseg_o3d.evaluation.connected_patches`), each patch carrying its surface's model."""
    from dataclasses import replace

    from rangeseg_o3d.evaluation import connected_patches

    patches, origin = connected_patches(scan.truth_ids)
    truth = {patch: scan.truth[int(surface)] for patch, surface in enumerate(origin.tolist()) if patch}
    return replace(scan, truth_ids=patches, truth=truth)


def sensor_matrix(*, seed: int, quick: bool, only: list[str] | None, repeats: int, rg_repeats: int,
                  abw_limit: int | None = None, surfaces: bool = False, connected_truth: bool = False) -> list[dict]:
    """Every sensor row (or those in ``only``; ``"abw"`` names the ABW images), in order;
    ``surfaces``: see :func:`matrix_row`; ``connected_truth``: the simulated scans scored
    on :func:`as_connected_patches` (SegComp's rule, which the ABW truth follows)."""
    from rangeseg_o3d.synthetic.matrix import SENSORS, matrix_rng

    known = [s.name for s in SENSORS] + ["abw"]
    for name in only or []:
        if name not in known:
            raise SystemExit(f"--sensor {name!r} is not a row of the matrix; known: {', '.join(known)}")
    rows = []
    for spec in SENSORS:
        if only and spec.name not in only:
            continue
        count = spec.quick_scans if quick else spec.scans
        start = time.perf_counter()
        scans = [spec.simulate(matrix_rng(seed, spec.draws, k), quick) for k in range(count)]
        if connected_truth:
            scans = [as_connected_patches(scan) for scan in scans]
        print(f"  {spec.name}: {count} scans of {'x'.join(map(str, scans[0].cloud.shape))} simulated "
              f"in {time.perf_counter() - start:.1f} s", flush=True)
        rows.append(matrix_row(spec.name, spec.description, spec.preset, spec.family, spec.sensor_facts(quick),
                               spec.region_growing, scans, score_synthetic, repeats, rg_repeats, surfaces))
    if not only or "abw" in only:
        from rangeseg_o3d.io.abw import abw_images, load_abw

        paths = abw_images()
        if quick or abw_limit:
            paths = paths[: abw_limit or 2]
        if not paths:
            print("  abw: skipped (no ../shared/data/abw images)")
        else:
            images = [load_abw(p) for p in paths]
            rows.append(matrix_row("abw", f"{len(images)} ABW images (SegComp rules, every labelled surface)",
                                   "abw", "abw", None, ABW_REGION_GROWING, images,
                                   score_abw, repeats, rg_repeats, surfaces))
    return rows


def print_matrix(rows: list[dict]) -> None:
    print(f"\n== sensor matrix: Hoover T={TOLERANCE} (synthetic: truth regions >= {MIN_REGION} px, "
          "mixed/no-return pixels don't care; abw: SegComp rules, every labelled region); "
          "over/under/missed/noise per scan; FF = false fittings; n_err = median plane normal "
          "error; ms = median of per-scan median totals; ratio = region growing ms / residual_edges ms ==")
    width = max([19] + [len(row["sensor"]) + 1 for row in rows])  # (kinect_real_640x480: 19 characters)
    head = (f"{'sensor':<{width}}{'preset':<17}{'scans':>5}{'GT':>5} | {'method':<6}{'%cor':>6}{'over':>6}"
            f"{'undr':>6}{'miss':>6}{'nois':>6}{'FF':>4}{'n_err°':>8}{'ms':>9}")
    print(head)
    for row in rows:
        preset = row["preset"]
        for i, method in enumerate(m for m in ("residual_edges", "region_growing") if m in row):
            m = row[method]
            lead = (f"{row['sensor']:<{width}}{preset:<17}{m['scans']:>5}{m['n_truth']:>5}" if i == 0
                    else f"{'':<{width}}{'':<17}{'':>5}{'':>5}")
            p = m["per_scan"]
            tail = f"  x{row['speed_ratio']:.1f}" if i == 1 else ""
            print(f"{lead} | {'RE' if i == 0 else 'RG':<6}{_fmt(m['percent_correct'], '.1f'):>6}"
                  f"{p['over']:>6.2f}{p['under']:>6.2f}{p['missed']:>6.2f}{p['noise']:>6.2f}"
                  f"{m['false_fittings']:>4}{_fmt(m['median_normal_error_deg'], '.3f'):>8}"
                  f"{_fmt(m['median_ms'], '.1f'):>9}{tail}")
            if m["by_size"]:
                print(f"{'':<{width + 27}} | {'':<6}correct by size (px): " + ", ".join(
                    f"{size}: {c}/{n}" for size, (c, n) in m["by_size"].items()))
    print("RE = residual_edges, RG = region_growing (same scans, same fitter and refinement)")


def print_surfaces(rows: list[dict]) -> None:
    """Per scan, each surface a method did not detect correctly and where its pixels went:
    ``label+kind:pixels(share of that region)``, label 0 = in no region (``--surfaces``)."""
    print("\n== surfaces not correctly detected: truth id, pixels, status -> largest shares "
          "label+kind:pixels(fraction of that region on the surface); 0 = in no region ==")
    for row in rows:
        for method in (m for m in ("residual_edges", "region_growing") if m in row):
            for scan in row[method].get("surfaces", []):
                print(f"{row['sensor']} {'RE' if method == 'residual_edges' else 'RG'} scan {scan['scan']}: "
                      f"{len(scan['surfaces'])} not correct")
                for s in scan["surfaces"]:
                    parts = ", ".join(f"{label}{kind[:1]}:{pixels}({share:.2f})"
                                      for label, kind, pixels, share in s["parts"])
                    print(f"  gt{s['truth_id']:<4}{s['pixels']:>7} px {s['status']:<7}-> {parts}")


def code_version() -> str:
    """The commit benchmarked (``+dirty`` with uncommitted changes), or "unknown" outside git."""
    import subprocess

    try:
        out = subprocess.run(["git", "-C", str(REPO), "describe", "--always", "--dirty=+dirty", "--abbrev=7"],
                             capture_output=True, text=True, timeout=10, check=True)
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return out.stdout.strip() or "unknown"


def from_depth_ms(repeats: int) -> tuple[float, float] | None:
    """Median and fastest ms of ``OrganizedCloud.from_depth`` on the CAPE tunnel frame
    (16-bit PNG, mm); the fastest run is what the pass costs when the host lets it run."""
    from rangeseg_o3d.cloud import OrganizedCloud
    from rangeseg_o3d.io.datasets import default_data_root

    png = default_data_root() / "cape" / "depth_0.png"
    if not png.is_file():
        return None
    import cv2

    depth = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
    OrganizedCloud.from_depth(depth, 575.93, 576.41, 315.15, 230.59, depth_scale=0.001)  # warm (compiled)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        OrganizedCloud.from_depth(depth, 575.93, 576.41, 315.15, 230.59, depth_scale=0.001)
        times.append(time.perf_counter() - start)
    return 1000 * statistics.median(times), 1000 * min(times)


def run_frames(args) -> int:
    """The six real VGA frames, every stage (per-frame medians), and from_depth on the CAPE frame."""
    _single_thread()
    warnings.simplefilter("ignore", RuntimeWarning)
    repeats = 3 if args.quick else args.repeats
    print(f"real 640x480 frames: {repeats} timed runs each (after one warm-up), one thread; "
          f"code {code_version()}")
    rows = real_rows(repeats, None, names=VGA_FRAMES)
    if not rows:
        print("no real 640x480 frame found in ../shared/data")
    else:
        print_real(rows)
        done = [r for r in rows if "error" not in r]
        if done:
            totals = [r["stage_ms"].get("total", r["wall_ms"]) for r in done]
            cpus = [r["cpu_ms"] for r in done]
            print(f"whole pipeline, median per frame: {min(totals):.1f} - {max(totals):.1f} ms "
                  f"over {len(done)} frames (issue 14 target <= 8 ms); CPU time "
                  f"{min(cpus):.1f} - {max(cpus):.1f} ms")
    runs = max(10 * repeats, 100)
    ms = from_depth_ms(runs)
    if ms is not None:
        print(f"OrganizedCloud.from_depth on cape/depth_0.png (640x480 uint16): {ms[0]:.2f} ms median of "
              f"{runs}, fastest {ms[1]:.2f} ms (target <= 1 ms)")
    if args.json:
        from rangeseg_o3d.io.atomic import atomic_write

        with atomic_write(args.json, "w", encoding="utf-8") as fh:
            json.dump({"code": code_version(), "repeats": repeats, "frames": rows,
                       "from_depth_ms": None if ms is None else {"median": ms[0], "fastest": ms[1]}},
                      fh, indent=1, default=float)
        print(f"\nwrote {args.json}")
    return 0


def run_matrix(args, parser) -> int:
    if args.no_baseline:
        args.rg_repeats = 0
    for flag in ("matrix_repeats", "rg_repeats") if not args.no_baseline else ("matrix_repeats",):
        if getattr(args, flag) < 1:
            parser.error(f"--{flag.replace('_', '-')} must be >= 1; got {getattr(args, flag)}")
    _single_thread()
    warnings.simplefilter("ignore", RuntimeWarning)
    repeats = 2 if args.quick else args.matrix_repeats
    print(f"sensor matrix: seed {args.seed}, {'quick, ' if args.quick else ''}{repeats} timed runs per scan "
          f"(residual_edges), {args.rg_repeats} (region_growing), one thread; code {code_version()}"
          + ("; simulated truth as connected patches (--connected-truth)" if args.connected_truth else ""), flush=True)
    rows = sensor_matrix(seed=args.seed, quick=args.quick, only=args.sensor, repeats=repeats,
                         rg_repeats=args.rg_repeats, surfaces=args.surfaces,
                         connected_truth=args.connected_truth)
    print_matrix(rows)
    if args.surfaces:
        print_surfaces(rows)
    out = args.json
    if out is None and not args.quick and not args.sensor and not args.no_baseline and not args.connected_truth:
        out = REPO / "docs" / "benchmarks" / "matrix.json"
    if out is not None:
        from rangeseg_o3d.io.atomic import atomic_write

        report = {"code": code_version(), "seed": args.seed, "quick": args.quick, "repeats": repeats,
                  "connected_truth": args.connected_truth,
                  "rg_repeats": args.rg_repeats,
                  "tolerance": TOLERANCE, "min_region": MIN_REGION, "rows": rows}
        with atomic_write(out, "w", encoding="utf-8") as fh:
            json.dump(report, fh, indent=1, default=float)
        print(f"\nwrote {out}")
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=20, help="timed runs per scan (median); default 20")
    parser.add_argument("--quick", action="store_true",
                        help="3 repeats, 3 LMS200 scenes, 1 RGB-D scene, 2 real clouds")
    parser.add_argument("--no-real", action="store_true", help="skip the real clouds in ../shared/data")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path, help="write every figure to this JSON file")
    parser.add_argument("--no-refine", action="store_true",
                        help="the paper's pipeline alone: segmentation and first fits, refinement off")
    parser.add_argument("--frames", action="store_true",
                        help="only the six real 640x480 frames (every stage) and from_depth's time")
    parser.add_argument("--export-frames", type=Path, metavar="DIR",
                        help="write the six real 640x480 frames as raw float32 + frames.txt to DIR "
                             "(for timing other programs on them) and stop")
    parser.add_argument("--matrix", action="store_true",
                        help="the sensor matrix (both methods, every sensor, ABW) instead of the suites")
    parser.add_argument("--sensor", action="append", metavar="NAME",
                        help="only this row of the matrix (repeatable; 'abw' for the ABW images); implies --matrix")
    parser.add_argument("--matrix-repeats", type=int, default=5,
                        help="timed runs per scan of residual_edges in the matrix; default 5")
    parser.add_argument("--rg-repeats", type=int, default=1,
                        help="timed runs per scan of region_growing in the matrix; default 1")
    parser.add_argument("--no-baseline", action="store_true",
                        help="matrix: residual_edges only (region growing takes most of the run's time)")
    parser.add_argument("--connected-truth", action="store_true",
                        help="matrix: score the simulated rows with each 4-connected patch of a surface as its "
                             "own truth region (SegComp's rule, as on the ABW images)")
    parser.add_argument("--surfaces", action="store_true",
                        help="matrix: also list, per scan, every surface not correctly detected and "
                             "where its pixels went (kept in --json too)")
    parser.add_argument("--cpu-stages", action="store_true",
                        help="time every stage (and 'total') in the process's CPU time instead of wall "
                             "time: on a machine shared with other jobs a stage's wall time holds its waits "
                             "for a core")
    args = parser.parse_args(argv)
    if args.cpu_stages:
        from rangeseg_o3d.timing import set_clock

        set_clock(time.process_time)
        print("stage times (and totals) in CPU time of this process (--cpu-stages)")
    if args.repeats < 1:
        parser.error(f"--repeats must be >= 1; got {args.repeats}")
    if args.export_frames is not None:
        try:
            return run_export(args.export_frames)
        except ValueError as exc:
            parser.error(str(exc))
    if args.matrix or args.sensor:
        return run_matrix(args, parser)
    if args.frames:
        return run_frames(args)
    repeats = 3 if args.quick else args.repeats
    _single_thread()
    warnings.simplefilter("ignore", RuntimeWarning)

    lms = lms200_suite(seed=args.seed)
    rgbd = rgbd_suite(seed=args.seed)
    if args.quick:
        lms, rgbd = lms[:3], rgbd[:1]
    print(f"benchmark: {len(lms)} LMS200 scans, {len(rgbd)} RGB-D frames, {repeats} timed runs each, one thread")
    def preset(name):
        config = load_config(REPO / "configs" / f"{name}.yaml")
        if args.no_refine:
            config = config.model_copy(update={"refine": config.refine.model_copy(update={"enabled": False})})
        return Pipeline(config)

    if args.no_refine:
        print("refinement off (the paper's pipeline: segmentation and first fits)")
    lms_rows = synthetic_rows(lms, preset("lms200"), repeats)
    lms_summary = summarise(lms_rows, TARGETS["lms200_ms_max"])
    print_synthetic("synthetic LMS200 70x131 (configs/lms200.yaml)", lms_rows, lms_summary)
    rgbd_rows = synthetic_rows(rgbd, preset("rgbd_vga"), repeats)
    rgbd_summary = summarise(rgbd_rows, TARGETS["vga_ms_max"])
    print_synthetic("synthetic RGB-D 640x480 (configs/rgbd_vga.yaml)", rgbd_rows, rgbd_summary)
    real = [] if args.no_real else real_rows(repeats, 2 if args.quick else None)
    if real:
        print_real(real)

    if args.json:
        from rangeseg_o3d.io.atomic import atomic_write

        report = {
            "repeats": repeats,
            "tolerance": TOLERANCE,
            "min_region": MIN_REGION,
            "targets": TARGETS,
            "lms200": {"scenes": lms_rows, "summary": lms_summary},
            "rgbd": {"scenes": rgbd_rows, "summary": rgbd_summary},
            "real": real,
        }
        with atomic_write(args.json, "w", encoding="utf-8") as fh:
            json.dump(report, fh, indent=1, default=float)
        print(f"\nwrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
