"""Plane patch areas against the occupied area of 2.5 cm cells, on the real scans (issue 15).

For every plane found in pcl/office1 and the three 3DTK scans prints the patch area
(boundary polygons traced on the image grid, outer rings minus holes), the area of the
2.5 cm and 5 cm cells of the plane that hold at least one of the region's projected
points, the convex hull of those points (the old outline), and the time to compute
every feature's geometry and covariance of the frame (median of repeats, cache cleared).
Usage::

    python scripts/patch_areas.py [--repeats 5] [--data-root PATH] [--all]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from rangeseg_o3d import Pipeline
from rangeseg_o3d.io.datasets import default_data_root, real_clouds
from rangeseg_o3d.patches import occupied_area, plane_basis
from _timing import median_seconds  # scripts/_timing.py (scripts/ is on sys.path)

SCANS = ("pcl_office1", "3dtk_scan000", "3dtk_scan001", "3dtk_scan002")


def hull_area(points: np.ndarray, normal: np.ndarray) -> float:
    from scipy.spatial import ConvexHull

    u, v = plane_basis(normal)
    return float(ConvexHull(np.stack([points @ u, points @ v], axis=1)).volume)


def geometry_seconds(result, repeats: int) -> float:
    def compute():
        for feat in result.features:
            feat._cache.clear()
            _ = feat.geometry, feat.covariance
    return median_seconds(compute, repeats)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--data-root", type=Path, default=None)
    parser.add_argument("--all", action="store_true", help="every real scan, not only office1 and 3DTK")
    args = parser.parse_args()
    items = [i for i in real_clouds(args.data_root or default_data_root())
             if args.all or i.name in SCANS]
    if not items:
        raise SystemExit("no real scan found (the shared data are absent)")
    for item in items:
        cloud = item.load()
        result = Pipeline(item.preset).run(cloud)
        rows = []
        for feat in result.features:
            if feat.kind != "plane":
                continue
            points = feat.source.points(feat.label, None)
            rows.append((feat.label, feat.n_pixels, feat.area, occupied_area(points, feat.model),
                         occupied_area(points, feat.model, 0.05), hull_area(points, feat.normal)))
        table = np.array(rows, dtype=float).reshape(-1, 6)
        area, occ, occ5, hull = table[:, 2:].sum(axis=0)
        ratio = table[:, 2] / table[:, 3]
        print(f"{item.name}: {len(rows)} planes; patch area {area:.2f} m2, occupied 2.5 cm cells "
              f"{occ:.2f} m2 (ratio {area / occ:.3f}; per plane {ratio.min():.2f}..{ratio.max():.2f}), "
              f"5 cm cells {occ5:.2f} m2 (ratio {area / occ5:.3f}), convex hulls {hull:.2f} m2 "
              f"(ratio {hull / occ:.2f}); geometry + covariance of all {len(result.features)} "
              f"features {geometry_seconds(result, args.repeats) * 1e3:.1f} ms")
        for label, n, a, o, o5, h in sorted(rows, key=lambda r: -r[3]):
            print(f"    plane {label:3d} {int(n):6d} px  area {a:6.3f}  occupied {o:6.3f} (5 cm {o5:6.3f})"
                  f"  ratio {a / o:5.2f}  hull {h:6.3f}")


if __name__ == "__main__":
    main()
