"""Plane patch areas against the occupied area of 2.5 cm cells, on the real scans (issue 15).

For every plane found in pcl/office1 and the three 3DTK scans prints the patch area
(boundary polygons traced on the image grid, outer rings minus holes), the area of the
2.5 cm and 5 cm cells of the plane that hold at least one of the region's projected
points, the convex hull of those points (the old outline), the sum of the pixels'
footprints on the plane (a yardstick that needs no cell size), and the time to compute
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


def _pixel_steps(uv: np.ndarray, mask: np.ndarray, axis: int) -> np.ndarray:
    """Per pixel, the in-plane step to the next pixel along ``axis`` (central difference
    where both neighbours are in the region, one-sided where one is, NaN where none is)."""
    fwd = np.full(uv.shape, np.nan)
    bwd = np.full(uv.shape, np.nan)
    ahead = [slice(None)] * 2
    behind = [slice(None)] * 2
    ahead[axis], behind[axis] = slice(1, None), slice(None, -1)
    pair = mask[tuple(ahead)] & mask[tuple(behind)]
    step = np.where(pair[..., None], uv[tuple(ahead)] - uv[tuple(behind)], np.nan)
    fwd[tuple(behind)] = step
    bwd[tuple(ahead)] = step
    return np.where(np.isnan(fwd), bwd, np.where(np.isnan(bwd), fwd, (fwd + bwd) / 2))


def footprint_area(source, label: int, normal: np.ndarray) -> float:
    """Sum of the region's pixel footprints on its plane: ``|du x dv|`` per pixel, from the
    in-plane steps to its grid neighbours; a pixel with no neighbour in a direction takes the
    region's median step in that direction. Needs no cell size, so it tells how much surface
    the pixels cover whatever the sampling density (the half pixel around the border included)."""
    box, mask = source.mask(label)
    u, v = plane_basis(normal)
    xyz = source.xyz[box]
    uv = np.stack([xyz @ u, xyz @ v], axis=-1)
    steps = []
    for axis in (1, 0):
        step = _pixel_steps(uv, mask, axis)[mask]
        missing = np.isnan(step[:, 0])
        if missing.all():
            return 0.0
        step[missing] = np.median(step[~missing], axis=0)
        steps.append(step)
    (du, dv) = steps
    return float(np.abs(du[:, 0] * dv[:, 1] - du[:, 1] * dv[:, 0]).sum())


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
                         occupied_area(points, feat.model, 0.05), hull_area(points, feat.normal),
                         footprint_area(feat.source, feat.label, feat.normal)))
        table = np.array(rows, dtype=float).reshape(-1, 7)
        area, occ, occ5, hull, foot = table[:, 2:].sum(axis=0)
        ratio = table[:, 2] / table[:, 3]
        print(f"{item.name}: {len(rows)} planes; patch area {area:.2f} m2, occupied 2.5 cm cells "
              f"{occ:.2f} m2 (ratio {area / occ:.3f}; per plane {ratio.min():.2f}..{ratio.max():.2f}), "
              f"5 cm cells {occ5:.2f} m2 (ratio {area / occ5:.3f}), convex hulls {hull:.2f} m2 "
              f"(ratio {hull / occ:.2f}), pixel footprints {foot:.2f} m2 (ratio {area / foot:.3f}); geometry + covariance of all {len(result.features)} "
              f"features {geometry_seconds(result, args.repeats) * 1e3:.1f} ms")
        for label, n, a, o, o5, h, f in sorted(rows, key=lambda r: -r[3]):
            print(f"    plane {label:3d} {int(n):6d} px  area {a:6.3f}  occupied {o:6.3f} (5 cm {o5:6.3f})"
                  f"  ratio {a / o:5.2f}  hull {h:6.3f}  footprints {f:6.3f} (ratio {a / f:5.2f})")


if __name__ == "__main__":
    main()
