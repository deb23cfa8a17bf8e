"""Median time of a k-nearest-neighbour query: scipy cKDTree vs Open3D's nns, for region growing.

Run: python scripts/bench_knn.py [--points 300000] [--k 31] [--repeats 3]
"""

import argparse

import numpy as np
from _timing import median_seconds  # scripts/_timing.py (scripts/ is on sys.path)


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--points", type=int, default=300_000)
    parser.add_argument("--k", type=int, default=31)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    # a depth-frame-like surface: a wavy sheet sampled on a grid
    side = int(np.sqrt(args.points))
    u, v = np.meshgrid(np.linspace(-1, 1, side), np.linspace(-1, 1, side))
    pts = np.stack([u, v, 2 + 0.1 * np.sin(3 * u) + rng.normal(0, 0.002, u.shape)], -1).reshape(-1, 3)

    from scipy.spatial import cKDTree

    def scipy_knn():
        cKDTree(pts).query(pts, k=args.k, workers=-1)

    import open3d as o3d

    def o3d_knn():
        t = o3d.core.Tensor(pts)
        nns = o3d.core.nns.NearestNeighborSearch(t)
        nns.knn_index()
        nns.knn_search(t, args.k)

    print(f"{len(pts)} points, k={args.k}, median of {args.repeats}")
    print(f"scipy cKDTree(workers=-1): {median_seconds(scipy_knn, args.repeats):.3f} s")
    print(f"open3d core.nns knn:       {median_seconds(o3d_knn, args.repeats):.3f} s")


if __name__ == "__main__":
    main()
