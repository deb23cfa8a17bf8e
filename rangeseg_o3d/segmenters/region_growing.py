"""Smoothness-constraint region growing: the baseline the paper compares against.

Rabbani, van den Heuvel & Vosselman (2006), "Segmentation of point clouds using
smoothness constraint", as implemented by PCL's ``pcl::RegionGrowing``. It ignores the
grid: it works on the valid points of an :class:`~rangeseg_o3d.cloud.OrganizedCloud`
through k nearest neighbours and maps the labels back to the (H, W) grid.

Algorithm (PCL semantics)
-------------------------
1. kNN of every point (scipy ``cKDTree``; measured as fast as Open3D's ``core.nns``
   with ``scripts/bench_knn.py``, and it keeps Open3D out of the import).
2. Normal and curvature per point by PCA of its ``normal_neighbours`` nearest points
   (the point included, as PCL's ``NormalEstimation``):
   curvature = l0 / (l0 + l1 + l2), l0 the smallest eigenvalue; 0 when all are 0.
3. Seeds in order of increasing curvature. A region grows from its seed across the
   ``n_neighbours`` neighbours whose unoriented normals differ by less than
   ``smoothness_deg`` (``|n_i . n_j| >= cos(theta)``); a point joins the region if it
   passes that test, and it grows the region further only if its curvature is at most
   ``curvature_threshold``. Points taken by a region stay taken.
4. Regions with fewer than ``min_cluster_size`` or more than ``max_cluster_size``
   points are dropped (their points get label 0, as PCL leaves them out of every
   cluster).

How it is computed
------------------
Rather than a queue per seed, the same result is obtained with graph operations:
the low-curvature points joined by passing edges form connected components
(``scipy.sparse.csgraph``) -- each is exactly the part of one PCL region that keeps
growing, seeded by its lowest-curvature point; a high-curvature point touched by
several such components goes to the one whose seed comes first, as the sequential
queue would do; the high-curvature points no component reaches are the seeds PCL
handles last, each claiming its untaken neighbours -- that greedy-in-curvature-order
step is resolved in vectorised rounds (a lexicographically-first independent set).

Deviation from PCL
------------------
PCL grows from a point to its own k neighbours only (a directed kNN graph). Here the
kNN graph is symmetrised (j in kNN(i) or i in kNN(j)), which makes each region
independent of the visiting order; on evenly sampled surfaces the two differ only
where the density changes. PCL's optional residual test (off by default) is not
implemented.

Optional voxel grid
-------------------
``voxel_size`` (default None: off) first replaces the points by their voxel centroids,
as PCL users do with ``VoxelGrid`` before ``RegionGrowing`` on dense, noisy depth
frames (at 640 x 480 the Kinect depth noise exceeds the pixel spacing, and kNN
normals of raw points are noise). Each point then takes its voxel's label;
``min_cluster_size``/``max_cluster_size`` still count input points.

Defaults
--------
The function defaults are PCL's (anchors.md): ``n_neighbours=30``,
``smoothness_deg=30``, ``curvature_threshold=0.05``, ``min_cluster_size=1``, no
maximum. PCL's tutorial uses 3 deg, curvature 1.0, min cluster 50 and 50 neighbours
for the normals. The sensor presets in ``configs/*_region_growing.yaml`` carry values
tuned on the synthetic suites, so the comparison is against a tuned baseline.

Complexity
----------
O(N k log N) for the kNN queries, O(N k) for normals, the angle tests and the graph
components; memory O(N k). No step is quadratic in N (``rangeseg compare`` plots the
time per point from 10k to 300k points).
"""

from __future__ import annotations

import logging
import time

import numpy as np
from pydantic import BaseModel, ConfigDict, model_validator

from ..cloud import OrganizedCloud
from ..registry import Plugin, defaults_of, params_model
from ..result import Segmentation

__all__ = [
    "RegionGrowingConfig",
    "estimate_normals",
    "voxel_centroids",
    "region_growing_labels",
    "segment_region_growing",
    "PLUGIN",
]

log = logging.getLogger(__name__)

# Rows per block when gathering (rows, k, 3) neighbourhoods: bounds memory at ~50 MB.
_BLOCK = 1 << 16


def _blocks(n: int):
    for start in range(0, n, _BLOCK):
        yield slice(start, min(start + _BLOCK, n))


def _check_points(points) -> np.ndarray:
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3); got {pts.shape}")
    if not np.isfinite(pts).all():
        raise ValueError("points must be finite; drop the invalid (NaN) pixels first")
    return pts


def _check_params(n_neighbours, normal_neighbours, smoothness_deg, curvature_threshold,
                  min_cluster_size, max_cluster_size, voxel_size=None) -> None:
    if voxel_size is not None and not float(voxel_size) > 0:
        raise ValueError(f"voxel_size must be None or > 0; got {voxel_size!r}")
    if not (isinstance(n_neighbours, (int, np.integer)) and n_neighbours >= 1):
        raise ValueError(f"n_neighbours must be an integer >= 1; got {n_neighbours!r}")
    if not (isinstance(normal_neighbours, (int, np.integer)) and normal_neighbours >= 3):
        raise ValueError(f"normal_neighbours must be an integer >= 3; got {normal_neighbours!r}")
    if not 0.0 < float(smoothness_deg) <= 90.0:
        raise ValueError(f"smoothness_deg must be in (0, 90]; got {smoothness_deg!r}")
    if not 0.0 <= float(curvature_threshold):
        raise ValueError(f"curvature_threshold must be >= 0; got {curvature_threshold!r}")
    if not (isinstance(min_cluster_size, (int, np.integer)) and min_cluster_size >= 1):
        raise ValueError(f"min_cluster_size must be an integer >= 1; got {min_cluster_size!r}")
    if max_cluster_size is not None and not (
        isinstance(max_cluster_size, (int, np.integer)) and max_cluster_size >= min_cluster_size
    ):
        raise ValueError(
            f"max_cluster_size must be None or an integer >= min_cluster_size "
            f"({min_cluster_size}); got {max_cluster_size!r}"
        )


def estimate_normals(points: np.ndarray, neighbours: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals and curvature by PCA over given neighbourhoods (PCL NormalEstimation).

    Parameters
    ----------
    points : (N, 3) float array
    neighbours : (N, k) int array
        Indices of the points forming each point's neighbourhood (the point itself
        normally included), k >= 3.

    Returns
    -------
    normals : (N, 3) float array
        Eigenvector of the smallest covariance eigenvalue (unoriented).
    curvature : (N,) float array
        ``l0 / (l0 + l1 + l2)`` in [0, 1/3]; 0 where all eigenvalues are 0
        (coincident points), as PCL does.

    Examples
    --------
    >>> import numpy as np
    >>> pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.]])
    >>> n, c = estimate_normals(pts, np.tile(np.arange(4), (4, 1)))
    >>> np.abs(n[0]).round(6).tolist(), float(c[0])
    ([0.0, 0.0, 1.0], 0.0)
    """
    pts = _check_points(points)
    nbr = np.asarray(neighbours)
    if nbr.ndim != 2 or nbr.shape[0] != len(pts) or nbr.shape[1] < 3:
        raise ValueError(f"neighbours must have shape ({len(pts)}, k>=3); got {nbr.shape}")
    normals = np.empty_like(pts)
    curvature = np.empty(len(pts))
    for rows in _blocks(len(pts)):
        hood = pts[nbr[rows]]
        # Centre each neighbourhood first: raw second moments lose precision far from the origin.
        hood = hood - hood.mean(axis=1, keepdims=True)
        cov = hood.transpose(0, 2, 1) @ hood / nbr.shape[1]  # batched matmul: ~10x einsum
        eigval, eigvec = np.linalg.eigh(cov)
        eigval = np.clip(eigval, 0.0, None)
        total = eigval.sum(axis=1)
        normals[rows] = eigvec[:, :, 0]
        curvature[rows] = np.divide(eigval[:, 0], total, out=np.zeros_like(total), where=total > 0)
    return normals, curvature


def _greedy_claims(n: int, lo: np.ndarray, hi: np.ndarray, undecided: np.ndarray) -> np.ndarray:
    """Resolve PCL's last seeds (high-curvature points no smooth region reached).

    Each of these points, in seed order, starts a region and takes its untaken
    neighbours, which do not grow further. ``lo -> hi`` are the passing edges among
    them with ``lo`` earlier in seed order. Returns, for each point, the seed-order
    index (its position in the curvature ranking, same as ``lo``/``hi``) of the seed
    whose region it joins. Computed in rounds: a point becomes a seed once all its
    earlier neighbours are decided and none is a seed; it is claimed by the first
    seed among its neighbours.
    """
    owner = np.full(n, -1, dtype=np.int64)
    state = np.where(undecided, 0, 3).astype(np.int8)  # 0 undecided, 1 seed, 2 claimed
    while True:
        open_nodes = state == 0
        if not open_nodes.any():
            break
        seed_edge = state[lo] == 1
        state[hi[seed_edge & (state[hi] == 0)]] = 2
        blocked = np.zeros(n, dtype=bool)
        blocked[hi[state[lo] == 0]] = True
        state[(state == 0) & ~blocked] = 1
        # An edge from a claimed point neither claims nor blocks: drop it to keep rounds cheap.
        # (Edges from undecided points stay: such a point may still become a seed that
        # comes before the one that claimed ``hi``.)
        keep = state[lo] != 2
        lo, hi = lo[keep], hi[keep]
    seeds = np.flatnonzero(state == 1)
    owner[seeds] = seeds
    # A claimed point belongs to the first seed (lowest seed-order index) next to it.
    claim = (state[lo] == 1) & (state[hi] == 2)
    best = np.full(n, n, dtype=np.int64)
    np.minimum.at(best, hi[claim], lo[claim])
    claimed = state == 2
    owner[claimed] = best[claimed]
    return owner


def region_growing_labels(
    points,
    *,
    n_neighbours: int = 30,
    normal_neighbours: int = 30,
    smoothness_deg: float = 30.0,
    curvature_threshold: float = 0.05,
    min_cluster_size: int = 1,
    max_cluster_size: int | None = None,
    voxel_size: float | None = None,
    timings: dict | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Region-grow an unorganized point set (see the module docstring for the rules).

    Parameters
    ----------
    points : (N, 3) float array, finite
    n_neighbours : int
        Neighbours a region grows across (PCL ``setNumberOfNeighbours``, default 30;
        the point itself not counted).
    normal_neighbours : int
        Neighbourhood size for the PCA normals, the point included (PCL tutorial 50).
    smoothness_deg : float
        Largest angle between neighbouring normals inside a region (PCL 30; tutorial 3).
    curvature_threshold : float
        Only points at or below it grow the region (PCL 0.05; tutorial 1.0).
    min_cluster_size, max_cluster_size : int, int or None
        Regions outside this size range are dropped (PCL 1 and unbounded; tutorial 50
        and 1e6). Counted in input points.
    voxel_size : float or None
        Metres; if given, grow regions on voxel centroids (see the module docstring).
    timings : dict, optional
        Filled with seconds per stage (``knn``, ``normals``, ``growth``).

    Returns
    -------
    labels : (N,) int32
        1..n in seed order, 0 for points in no kept region.
    curvature : (N,) float
        Of the point, or of its voxel's centroid when ``voxel_size`` is given.

    Raises
    ------
    ValueError
        On points that are not (N, 3) and finite, or parameters out of range.

    Notes
    -----
    Fewer than 3 points cannot give a normal: all labels are 0.

    Examples
    --------
    >>> import numpy as np
    >>> g = np.stack(np.meshgrid(np.arange(20.), np.arange(20.)), -1).reshape(-1, 2)
    >>> floor = np.c_[g, np.zeros(len(g))]
    >>> wall = np.c_[g[:, 0], np.full(len(g), -1.0), g[:, 1] + 1]
    >>> labels, _ = region_growing_labels(np.r_[floor, wall], n_neighbours=8,
    ...                                   normal_neighbours=9, min_cluster_size=50)
    >>> len(np.unique(labels[labels > 0]))
    2
    """
    pts = _check_points(points)
    _check_params(n_neighbours, normal_neighbours, smoothness_deg, curvature_threshold,
                  min_cluster_size, max_cluster_size, voxel_size)
    timings = {} if timings is None else timings
    if voxel_size is not None and len(pts):
        start = time.perf_counter()
        centroids, voxel_of = voxel_centroids(pts, voxel_size)
        timings["voxels"] = time.perf_counter() - start
        labels, curvature = region_growing_labels(
            centroids, n_neighbours=n_neighbours, normal_neighbours=normal_neighbours,
            smoothness_deg=smoothness_deg, curvature_threshold=curvature_threshold,
            timings=timings,
        )
        return _filter_sizes(labels[voxel_of], min_cluster_size, max_cluster_size), curvature[voxel_of]
    n = len(pts)
    if n < 3:
        return np.zeros(n, dtype=np.int32), np.zeros(n)

    from scipy.spatial import cKDTree

    start = time.perf_counter()
    k_normal = min(normal_neighbours, n)
    k_grow = min(n_neighbours + 1, n)  # +1: the query point is its own first neighbour
    _, nbr = cKDTree(pts).query(pts, k=max(k_normal, k_grow), workers=-1)
    nbr = nbr.reshape(n, -1)
    timings["knn"] = time.perf_counter() - start

    start = time.perf_counter()
    normals, curvature = estimate_normals(pts, nbr[:, :k_normal])
    timings["normals"] = time.perf_counter() - start

    start = time.perf_counter()
    src, dst = _smooth_pairs(normals, nbr[:, :k_grow], np.cos(np.deg2rad(smoothness_deg)))
    owner = _grow_regions(src, dst, curvature, curvature_threshold)
    timings["growth"] = time.perf_counter() - start

    # Seed ranks -> 1..n in seed order (PCL's cluster order), then the size filter.
    _, region = np.unique(owner, return_inverse=True)
    labels = _filter_sizes(region.ravel().astype(np.int32) + 1, min_cluster_size, max_cluster_size)
    log.debug("region growing: %d points, %d regions kept", n, int(labels.max(initial=0)))
    return labels, curvature


def _smooth_pairs(normals: np.ndarray, hood: np.ndarray, cos_limit: float) -> tuple[np.ndarray, np.ndarray]:
    """The directed pairs (point, neighbour in ``hood``) whose normals are within the
    smoothness angle (``|cos| >= cos_limit``), the point itself excluded; in blocks of rows."""
    n = len(normals)
    src_parts, dst_parts = [], []
    for rows in _blocks(n):
        block = hood[rows]
        dots = np.abs(normals[block] @ normals[rows][:, :, None])[:, :, 0]
        src = np.broadcast_to(np.arange(rows.start, rows.stop)[:, None], block.shape)
        ok = (dots >= cos_limit) & (block != src)
        src_parts.append(src[ok])
        dst_parts.append(block[ok])
    return np.concatenate(src_parts), np.concatenate(dst_parts)


def _grow_regions(src: np.ndarray, dst: np.ndarray, curvature: np.ndarray,
                  curvature_threshold: float) -> np.ndarray:
    """PCL's region growing over the smooth pairs, in closed form: per point the seed rank
    (position in increasing curvature) of the region it joins."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(curvature)
    # Seed order: increasing curvature, ties by index (stable), as PCL's sort.
    order = np.argsort(curvature, kind="stable")
    rank = np.empty(n, dtype=np.int64)
    rank[order] = np.arange(n)
    grows = curvature <= curvature_threshold

    both = grows[src] & grows[dst]
    graph = coo_matrix((np.ones(int(both.sum()), dtype=np.int8), (src[both], dst[both])), shape=(n, n))
    _, component = connected_components(graph, directed=True, connection="weak")
    # Each smooth component is seeded by its lowest-curvature point.
    seed_rank = np.full(component.max() + 1, n, dtype=np.int64)
    np.minimum.at(seed_rank, component[grows], rank[grows])
    owner = np.full(n, -1, dtype=np.int64)  # seed rank of the region each point joins
    owner[grows] = seed_rank[component[grows]]

    # A non-growing point touched by smooth regions joins the one seeded first.
    one_side = grows[src] != grows[dst]
    smooth_end = np.where(grows[src], src, dst)[one_side]
    rough_end = np.where(grows[src], dst, src)[one_side]
    first = np.full(n, n, dtype=np.int64)
    np.minimum.at(first, rough_end, owner[smooth_end])
    touched = ~grows & (first < n)
    owner[touched] = first[touched]

    # The remaining points are PCL's last seeds, each taking its untaken neighbours.
    left = owner < 0
    if left.any():
        pair = left[src] & left[dst]
        a, b = rank[src[pair]], rank[dst[pair]]
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        left_by_rank = np.zeros(n, dtype=bool)
        left_by_rank[rank[left]] = True
        claimed_by = _greedy_claims(n, lo, hi, left_by_rank)
        owner[left] = claimed_by[rank[left]]
    return owner


def _filter_sizes(labels: np.ndarray, min_size: int, max_size: int | None) -> np.ndarray:
    # Drop regions outside [min_size, max_size] and renumber the rest 1..n, order kept.
    sizes = np.bincount(labels)
    upper = np.iinfo(np.int64).max if max_size is None else max_size
    kept = (sizes >= min_size) & (sizes <= upper)
    kept[0] = False
    new_id = np.zeros(len(sizes), dtype=np.int32)
    new_id[kept] = np.arange(1, int(kept.sum()) + 1, dtype=np.int32)
    return new_id[labels]


def voxel_centroids(points, voxel_size: float) -> tuple[np.ndarray, np.ndarray]:
    """Centroids of the occupied cubic voxels (PCL ``VoxelGrid``) and each point's voxel.

    Parameters
    ----------
    points : (N, 3) float array, finite
    voxel_size : float
        Edge of the voxels, metres (> 0).

    Returns
    -------
    centroids : (M, 3) float array
    voxel_of : (N,) int array
        Row of ``centroids`` for each point.

    Examples
    --------
    >>> import numpy as np
    >>> c, v = voxel_centroids(np.array([[0.1, 0, 0], [0.3, 0, 0], [1.5, 0, 0]]), 1.0)
    >>> c.tolist(), v.tolist()
    ([[0.2, 0.0, 0.0], [1.5, 0.0, 0.0]], [0, 0, 1])
    """
    pts = _check_points(points)
    if not (voxel_size is not None and float(voxel_size) > 0):
        raise ValueError(f"voxel_size must be > 0; got {voxel_size!r}")
    if len(pts) == 0:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    cells = np.floor(pts / voxel_size).astype(np.int64)
    cells -= cells.min(axis=0)
    dims = cells.max(axis=0) + 1
    if np.prod(dims.astype(float)) >= 2.0**62:
        raise ValueError(f"voxel_size {voxel_size} is too small for a cloud this large ({dims} voxels)")
    # One int64 key per voxel: a 1-D unique is much faster than unique over rows.
    flat = (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2]
    _, voxel_of, counts = np.unique(flat, return_inverse=True, return_counts=True)
    voxel_of = voxel_of.ravel()
    centroids = np.stack([np.bincount(voxel_of, pts[:, d]) for d in range(3)], axis=1) / counts[:, None]
    return centroids, voxel_of


@defaults_of(region_growing_labels)  # PCL's defaults, written there
def segment_region_growing(
    cloud: OrganizedCloud,
    *,
    sensor=None,
    n_neighbours: int,
    normal_neighbours: int,
    smoothness_deg: float,
    curvature_threshold: float,
    min_cluster_size: int,
    max_cluster_size: int | None,
    voxel_size: float | None,
) -> Segmentation:
    """Segment an organized cloud by smoothness-constraint region growing.

    Runs :func:`region_growing_labels` on the valid points and puts the labels back
    on the grid. Parameters as there; defaults are PCL's.

    Parameters
    ----------
    cloud : OrganizedCloud
    sensor : the run's :class:`~rangeseg_o3d.sensor.Sensor`, received as every segmenter
        does; PCL's method as implemented here has no noise model (angles and curvature
        are scale-free, the voxel size is a parameter), so it is not used yet.
    n_neighbours, normal_neighbours, smoothness_deg, curvature_threshold, min_cluster_size, max_cluster_size, voxel_size
        See :func:`region_growing_labels`.

    Returns
    -------
    Segmentation
        ``labels`` (H, W) int32, 0 for invalid pixels and points in no kept region;
        ``stages['curvature']`` (H, W) float, NaN at invalid pixels; ``timings`` with
        ``knn``, ``normals``, ``growth``. An all-NaN cloud gives all-zero labels.

    Raises
    ------
    TypeError
        If ``cloud`` is not an OrganizedCloud.
    ValueError
        On parameters out of range.
    """
    if not isinstance(cloud, OrganizedCloud):
        raise TypeError(f"cloud must be an OrganizedCloud; got {type(cloud).__name__}")
    _check_params(n_neighbours, normal_neighbours, smoothness_deg, curvature_threshold,
                  min_cluster_size, max_cluster_size, voxel_size)
    valid = cloud.valid
    timings: dict[str, float] = {}
    point_labels, point_curvature = region_growing_labels(
        cloud.xyz[valid],
        n_neighbours=n_neighbours,
        normal_neighbours=normal_neighbours,
        smoothness_deg=smoothness_deg,
        curvature_threshold=curvature_threshold,
        min_cluster_size=min_cluster_size,
        max_cluster_size=max_cluster_size,
        voxel_size=voxel_size,
        timings=timings,
    )
    labels = np.zeros(cloud.shape, dtype=np.int32)
    labels[valid] = point_labels
    curvature = np.full(cloud.shape, np.nan)
    curvature[valid] = point_curvature
    return Segmentation(labels=labels, stages={"curvature": curvature}, timings=timings)


class _RegionGrowingChecks(BaseModel):
    # the checks across fields; the fields (and their defaults) come from the signature
    model_config = ConfigDict(extra="forbid", frozen=True)

    @model_validator(mode="after")
    def _sizes_ordered(self):
        if self.max_cluster_size is not None and self.max_cluster_size < self.min_cluster_size:
            raise ValueError(
                f"max_cluster_size ({self.max_cluster_size}) must be >= "
                f"min_cluster_size ({self.min_cluster_size})"
            )
        return self


RegionGrowingConfig = params_model(segment_region_growing, dict(
    n_neighbours=dict(ge=1, description="neighbours a region grows across"),
    normal_neighbours=dict(ge=3, description="neighbourhood size for PCA normals"),
    smoothness_deg=dict(gt=0.0, le=90.0, description="max normal angle, degrees"),
    curvature_threshold=dict(ge=0.0, description="max curvature of growing points"),
    min_cluster_size=dict(ge=1, description="smallest region kept"),
    max_cluster_size=dict(ge=1, description="largest region kept; None = no limit"),
    voxel_size=dict(gt=0, description="grow on voxel centroids (metres); None = off"),
), name="RegionGrowingConfig", base=_RegionGrowingChecks,
    doc="Parameters of :func:`segment_region_growing` (defaults: PCL's, written in its signature).")


PLUGIN = Plugin(
    name="region_growing",
    config=RegionGrowingConfig,
    run=segment_region_growing,
    description="Smoothness-constraint region growing over kNN (Rabbani et al. 2006; PCL RegionGrowing)",
)
