"""Grid search of region_growing's parameters on a synthetic suite (Hoover correct detections).

Used to choose configs/*_region_growing.yaml, so that the comparison is against a tuned
baseline. Each setting runs the whole pipeline (same fitter and refinement as the preset).

Run: python scripts/tune_region_growing.py --preset lms200 [--scans 10]
"""

import argparse
import itertools

from rangeseg_o3d.evaluation.compare import config_for
from rangeseg_o3d.evaluation import evaluate
from rangeseg_o3d.pipeline import Pipeline
from rangeseg_o3d.synthetic.suite import lms200_suite, rgbd_suite


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--preset", default="lms200", choices=["lms200", "rgbd_vga"])
    parser.add_argument("--scans", type=int, default=10)
    parser.add_argument("--smoothness", default="3,5,8,12,20,30")
    parser.add_argument("--curvature", default="0.02,0.05,0.1,1.0")
    parser.add_argument("--neighbours", default="30")
    parser.add_argument("--min-cluster", type=int, default=None)
    args = parser.parse_args()
    suite = (lms200_suite() if args.preset == "lms200" else rgbd_suite())[: args.scans]
    base = config_for(args.preset, "region_growing").model_dump()
    grid = itertools.product(
        [float(s) for s in args.smoothness.split(",")],
        [float(c) for c in args.curvature.split(",")],
        [int(k) for k in args.neighbours.split(",")],
    )
    for smooth, curv, k in grid:
        params = dict(base["segmenter"]["params"], smoothness_deg=smooth, curvature_threshold=curv,
                      n_neighbours=k, normal_neighbours=k)
        if args.min_cluster is not None:
            params["min_cluster_size"] = args.min_cluster
        data = dict(base, segmenter={"name": "region_growing", "params": params})
        pipe = Pipeline(data)
        totals = dict(n_truth=0, correct=0, over=0, under=0, missed=0, noise=0)
        false = 0
        for _, scan in suite:
            ev = evaluate(scan, pipe.run(scan.cloud))
            for key in totals:
                totals[key] += ev.hoover.counts()[key]
            false += ev.false_fittings
        print(f"smooth {smooth:5.1f} curv {curv:5.2f} k {k:3d}: {totals} false {false}", flush=True)


if __name__ == "__main__":
    main()
