"""Dump labels and every feature's parameters for the suites and real clouds; compare two dumps.

A refactoring that must not change behaviour is checked by dumping before and after and
comparing bit for bit:

    PYTHONPATH=. python scripts/compare_outputs.py dump before.npz    # on the old tree
    PYTHONPATH=. python scripts/compare_outputs.py dump after.npz     # on the new tree
    python scripts/compare_outputs.py compare before.npz after.npz    # exit 1 on any difference

Cases: the synthetic LMS200 suite under ``lms200`` and ``lms200_region_growing``, the
synthetic RGB-D suite under ``rgbd_vga`` and ``rgbd_vga_region_growing``, every real
cloud of :func:`rangeseg_o3d.io.datasets.real_clouds` under its preset (the depth-camera
ones also under ``rgbd_vga_region_growing``), and the ``rangeseg compare`` configurations
(each segmenter swapped into the preset) on the first LMS200 scan, a simulated spinning
lidar room under ``spinning_lidar`` and the ABW images under ``abw``. Each case stores its
labels and the JSON of its features and unfitted regions (Python's float repr round-trips
exactly).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))


def _cases(real: bool):
    """Yield ``(case name, config, cloud)``."""
    from rangeseg_o3d.synthetic.suite import lms200_suite, rgbd_suite

    lms = lms200_suite(seed=0)
    for preset in ("lms200", "lms200_region_growing"):
        for name, scan in lms:
            yield f"lms200/{preset}/{name}", preset, scan.cloud
    rgbd = rgbd_suite(seed=0)
    for preset in ("rgbd_vga", "rgbd_vga_region_growing"):
        for name, scan in rgbd:
            yield f"rgbd/{preset}/{name}", preset, scan.cloud
    from rangeseg_o3d.evaluation.compare import config_for

    for segmenter in ("region_growing", "o3d_planar_patches"):
        yield f"compare/lms200+{segmenter}/{lms[0][0]}", config_for("lms200", segmenter), lms[0][1].cloud
    from rangeseg_o3d.synthetic.scene import Scene, box, room
    from rangeseg_o3d.synthetic.spinning import simulate_spinning_lidar

    spinning_room = Scene([room(x=(-6, 8), y=(-5, 4), z=(-1.7, 2.5), first_id=1),
                           box((3.0, 1.5, -1.2), (1.0, 1.0, 1.0), first_id=10)])
    yield ("spinning/spinning_lidar/room_box",
           "spinning_lidar", simulate_spinning_lidar(spinning_room, noise_sigma=0.015, seed=0).cloud)
    if not real:
        return
    from rangeseg_o3d.io.datasets import real_clouds

    from rangeseg_o3d.io.abw import abw_images, load_abw

    for path in abw_images():
        yield f"abw/abw/{path.stem}", "abw", load_abw(path).cloud
    for item in real_clouds():
        cloud = item.load()
        yield f"real/{item.preset}/{item.name}", item.preset, cloud
        if item.preset == "rgbd_vga":
            yield f"real/rgbd_vga_region_growing/{item.name}", "rgbd_vga_region_growing", cloud


def dump(path: Path, *, real: bool) -> None:
    """Run every case and write labels + features to ``path``."""
    from rangeseg_o3d.pipeline import Pipeline

    arrays = {}
    pipelines = {}
    for case, config, cloud in _cases(real):
        key = config if isinstance(config, str) else config.name
        if key not in pipelines:
            pipelines[key] = Pipeline(config)
        result = pipelines[key].run(cloud)
        summary = {"features": [f.to_dict() for f in result.features],
                   "unfitted": [u.to_dict() for u in result.unfitted]}
        arrays[f"{case}/labels"] = result.labels
        arrays[f"{case}/features"] = np.asarray(json.dumps(summary, default=_plain))
        counts = result.counts()
        print(f"{case}: {len(result.features)} features {counts}", flush=True)
    np.savez_compressed(path, **arrays)
    print(f"wrote {path} ({len(arrays) // 2} cases)")


def _plain(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def compare(before: Path, after: Path) -> int:
    """Print every case whose labels or features differ; returns the number of differences."""
    with np.load(before) as a, np.load(after) as b:
        keys_a, keys_b = set(a.files), set(b.files)
        differences = 0
        for key in sorted(keys_a ^ keys_b):
            print(f"only in {'before' if key in keys_a else 'after'}: {key}")
            differences += 1
        for key in sorted(keys_a & keys_b):
            if key.endswith("/labels"):
                same = a[key].shape == b[key].shape and np.array_equal(a[key], b[key])
                detail = "" if same else f" ({int(np.count_nonzero(a[key] != b[key]))} pixels differ)" \
                    if a[key].shape == b[key].shape else " (shapes differ)"
            else:
                same = str(a[key]) == str(b[key])
                detail = ""
            if not same:
                print(f"differs: {key}{detail}")
                differences += 1
        cases = len(keys_a & keys_b) // 2
    print(f"{cases} cases compared (labels and features), {differences} differences")
    return differences


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    d = sub.add_parser("dump", help="run every case, write an .npz")
    d.add_argument("out", type=Path)
    d.add_argument("--no-real", action="store_true", help="synthetic suites only")
    c = sub.add_parser("compare", help="compare two dumps")
    c.add_argument("before", type=Path)
    c.add_argument("after", type=Path)
    args = parser.parse_args(argv)
    if args.command == "dump":
        dump(args.out, real=not args.no_real)
        return 0
    return 1 if compare(args.before, args.after) else 0


if __name__ == "__main__":
    sys.exit(main())
