"""Segment a simulated SICK LMS200 scan (the paper's sensor) and print the features found.

    python examples/segment_lms200_scan.py [--seed 0]

The scan comes from the built-in simulator (a room with a box, a cylinder and a sphere,
70 x 131 pixels); the ``lms200`` preset segments it and fits a plane, cylinder or sphere
to every region.
"""

import argparse

import rangeseg_o3d as rs
from rangeseg_o3d.synthetic.lms200 import simulate_lms200
from rangeseg_o3d.synthetic.suite import default_scene


def describe(feature) -> str:
    """One line per feature: its kind, size and parameters."""
    if feature.kind == "plane":
        shape = f"normal {feature.normal.round(3).tolist()} d {feature.d:.3f} m"
    elif feature.kind == "sphere":
        shape = f"center {feature.center.round(3).tolist()} radius {feature.radius:.3f} m"
    else:
        shape = (f"axis {feature.axis.round(3).tolist()} point {feature.point.round(3).tolist()} "
                 f"radius {feature.radius:.3f} m")
    return (f"{feature.label:3d} {feature.kind:8s} {feature.n_pixels:5d} px  rms {1000 * feature.rms:.1f} mm  "
            f"{shape}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0, help="noise seed of the simulated scan")
    args = parser.parse_args()

    scan = simulate_lms200(default_scene(), seed=args.seed)
    result = rs.Pipeline("lms200").run(scan.cloud)
    print(f"{scan.cloud.shape[0]} x {scan.cloud.shape[1]} scan: {len(result.features)} features, "
          f"{len(result.unfitted)} regions unfitted, {1000 * result.timings['total']:.1f} ms")
    for feature in result.features:
        print(describe(feature))
    for region in result.unfitted:
        print(f"{region.label:3d} unfitted {region.n_pixels:5d} px  {region.reason}")


if __name__ == "__main__":
    main()
