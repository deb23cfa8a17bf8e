"""Segment a sequence of scans and log them all into one rerun recording, one step per scan.

With no input files, a few simulated LMS200 scans of the synthetic suite are used.

    python scripts/log_scan_sequence.py --save scans.rrd          # synthetic scans
    python scripts/log_scan_sequence.py a.npz b.pcd --spawn       # your own scans
    python scripts/log_scan_sequence.py --n-scans 3 --save s.rrd --png last.png

Every stage (range, residual, closing, edges, labels, points, fitted features, timings)
lands on the ``scan`` timeline at the scan's index; see rangeseg_o3d.viz.rerun_log.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from rangeseg_o3d.config import load_config, presets
from rangeseg_o3d.pipeline import Pipeline
from rangeseg_o3d.result import counted
from rangeseg_o3d.viz import add_rerun_arguments, finish_recording, recording_from_args
from rangeseg_o3d.viz import write_panel_png


def synthetic_scans(n_scans: int, seed: int):
    """(name, cloud) of the first ``n_scans`` simulated LMS200 scans of the suite."""
    from rangeseg_o3d.synthetic.lms200 import simulate_lms200
    from rangeseg_o3d.synthetic.suite import lms200_scenes

    for k, (name, scene) in enumerate(lms200_scenes()[:n_scans]):
        yield name, simulate_lms200(scene, seed=seed + k).cloud


def file_scans(paths: list[Path]):
    """(name, cloud) of each .npz / .pcd file."""
    from rangeseg_o3d import OrganizedCloud

    for path in paths:
        yield path.name, OrganizedCloud.load(path)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("inputs", nargs="*", type=Path, help=".npz or .pcd organized scans")
    parser.add_argument("--config", default="lms200",
                        help=f"preset ({', '.join(presets())}) or YAML file")
    parser.add_argument("--n-scans", type=int, default=4,
                        help="number of synthetic scans when no input is given")
    parser.add_argument("--seed", type=int, default=0, help="noise seed of the synthetic scans")
    add_rerun_arguments(parser)
    args = parser.parse_args(argv)
    if args.n_scans < 1:
        parser.error(f"--n-scans must be >= 1; got {args.n_scans}")

    pipeline = Pipeline(load_config(args.config))
    scans = file_scans(args.inputs) if args.inputs else synthetic_scans(args.n_scans, args.seed)
    rec = recording_from_args(args, application_id="rangeseg_sequence")
    if rec is None and not args.png:
        print("note: no --save/--spawn/--connect/--serve/--png given; segmenting only",
              file=sys.stderr)
    last = None
    for index, (name, cloud) in enumerate(scans):
        start = time.perf_counter()
        result = pipeline.run(cloud, recording=rec, scan_index=index)
        counts = result.counts()
        print(f"scan {index} {name}: {cloud.shape[0]}x{cloud.shape[1]}, "
              + ", ".join(counted(counts[k], k) for k in ("plane", "cylinder", "sphere"))
              + f", {counts['unfitted']} unfitted "
              f"({time.perf_counter() - start:.2f} s with logging)")
        last = (cloud, result)
    if args.png and last is not None:
        print(f"wrote {write_panel_png(args.png, *last)}")
    saved = finish_recording(args, rec)
    if saved is not None:
        print(f"wrote {saved}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
