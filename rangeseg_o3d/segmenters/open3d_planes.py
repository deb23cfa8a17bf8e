"""What a user would pick instead: Open3D's plane detectors as segmenters. Planes only.

Open3D has no cylinder or sphere detection, so these two segmenters can only ever
find planar regions; curved surfaces come out unlabelled or cut into flat pieces.
They run on the valid points of an :class:`~rangeseg_o3d.cloud.OrganizedCloud`
(Open3D ignores the grid) and map the labels back to (H, W).

``o3d_planar_patches``
    ``PointCloud.estimate_normals`` (kNN) then ``PointCloud.detect_planar_patches``
    (Araujo & Oliveira 2020). Open3D returns oriented boxes, not inlier points: a
    point is given to a patch when it lies inside the patch's box in the plane
    directions and within ``max(half the box thickness, distance_threshold)`` of the
    patch plane (the box's third axis is the plane normal); a point inside several
    boxes goes to the patch whose plane is nearest.
``o3d_ransac_planes``
    ``PointCloud.segment_plane`` (RANSAC) called repeatedly, removing each plane's
    inliers, until ``max_planes`` planes are found or fewer than ``min_inliers``
    points remain or the best plane has fewer than ``min_inliers`` inliers. As users
    of that loop know, each label is one infinite plane: disjoint coplanar patches
    share a label, and points of other surfaces that happen to lie on it join it.

Open3D is imported inside the functions, so importing this module stays cheap.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from ..cloud import OrganizedCloud
from ..registry import Plugin, params_model
from ..result import Segmentation

__all__ = [
    "PlanarPatchesConfig",
    "RansacPlanesConfig",
    "assign_to_boxes",
    "segment_planar_patches",
    "segment_ransac_planes",
    "PLANAR_PATCHES",
    "RANSAC_PLANES",
]

log = logging.getLogger(__name__)


def _check_cloud(cloud) -> None:
    if not isinstance(cloud, OrganizedCloud):
        raise TypeError(f"cloud must be an OrganizedCloud; got {type(cloud).__name__}")


def _positive(name: str, value, *, allow_zero: bool = False) -> None:
    if not (value >= 0 if allow_zero else value > 0):
        bound = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name} must be {bound}; got {value!r}")


def _to_grid(cloud: OrganizedCloud, point_labels: np.ndarray) -> np.ndarray:
    labels = np.zeros(cloud.shape, dtype=np.int32)
    labels[cloud.valid] = point_labels
    return labels


def assign_to_boxes(points, centers, rotations, extents, *, distance_threshold: float = 0.0) -> np.ndarray:
    """Give each point to the oriented planar box that contains it (nearest plane wins).

    Parameters
    ----------
    points : (N, 3) float array
    centers : (P, 3) box centres
    rotations : (P, 3, 3) box axes as columns; the third column is the plane normal
    extents : (P, 3) full box sizes along those axes
    distance_threshold : float
        A point within this distance of a patch plane counts as on it even if the box
        is thinner.

    Returns
    -------
    (N,) int32
        1 + the index of the chosen box, 0 for points in no box.

    Examples
    --------
    >>> import numpy as np
    >>> pts = np.array([[0.0, 0.0, 0.001], [0.0, 0.0, 0.5], [3.0, 0.0, 0.0]])
    >>> assign_to_boxes(pts, np.zeros((1, 3)), np.eye(3)[None], np.array([[2.0, 2.0, 0.01]])).tolist()
    [1, 0, 0]
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3); got {pts.shape}")
    centers = np.asarray(centers, dtype=float).reshape(-1, 3)
    n_boxes = len(centers)
    rotations = np.asarray(rotations, dtype=float).reshape(n_boxes, 3, 3)
    extents = np.asarray(extents, dtype=float).reshape(n_boxes, 3)
    _positive("distance_threshold", distance_threshold, allow_zero=True)
    labels = np.zeros(len(pts), dtype=np.int32)
    best = np.full(len(pts), np.inf)
    half = extents / 2
    half[:, 2] = np.maximum(half[:, 2], distance_threshold)
    # One box at a time: P is tens of patches, N up to 300k, so memory stays O(N).
    for index in range(n_boxes):
        local = (pts - centers[index]) @ rotations[index]
        off_plane = np.abs(local[:, 2])
        inside = (np.abs(local) <= half[index]).all(axis=1) & (off_plane < best)
        labels[inside] = index + 1
        best[inside] = off_plane[inside]
    return labels


def segment_planar_patches(
    cloud: OrganizedCloud,
    *,
    normal_neighbours: int = 30,
    normal_variance_threshold_deg: float = 60.0,
    coplanarity_deg: float = 75.0,
    outlier_ratio: float = 0.75,
    min_plane_edge_length: float = 0.0,
    min_num_points: int = 0,
    distance_threshold: float = 0.0,
) -> Segmentation:
    """Planes from Open3D's ``detect_planar_patches``; defaults are Open3D's.

    Parameters
    ----------
    cloud : OrganizedCloud
    normal_neighbours : int
        k of the kNN used for ``estimate_normals`` and the detector's search.
    normal_variance_threshold_deg, coplanarity_deg, outlier_ratio, min_plane_edge_length, min_num_points
        Passed to ``detect_planar_patches`` unchanged (0 for the last two means
        Open3D's own automatic choice).
    distance_threshold : float
        Metres; see :func:`assign_to_boxes`.

    Returns
    -------
    Segmentation
        ``labels`` (H, W) int32 (1..n, patches without points dropped; 0 = in no patch);
        ``timings`` ``normals``, ``detect``, ``assign``. Fewer than 3 valid points give
        all-zero labels.
    """
    _check_cloud(cloud)
    if not (isinstance(normal_neighbours, (int, np.integer)) and normal_neighbours >= 3):
        raise ValueError(f"normal_neighbours must be an integer >= 3; got {normal_neighbours!r}")
    if not 0 < normal_variance_threshold_deg <= 90 or not 0 < coplanarity_deg <= 90:
        raise ValueError(
            "normal_variance_threshold_deg and coplanarity_deg must be in (0, 90]; got "
            f"{normal_variance_threshold_deg!r} and {coplanarity_deg!r}"
        )
    if not 0 < outlier_ratio <= 1:
        raise ValueError(f"outlier_ratio must be in (0, 1]; got {outlier_ratio!r}")
    _positive("min_plane_edge_length", min_plane_edge_length, allow_zero=True)
    _positive("min_num_points", min_num_points, allow_zero=True)
    _positive("distance_threshold", distance_threshold, allow_zero=True)
    timings: dict[str, float] = {}
    if cloud.n_valid < 3:
        return Segmentation(labels=np.zeros(cloud.shape, dtype=np.int32), timings=timings)

    import open3d as o3d

    pcd = cloud.to_legacy()
    search = o3d.geometry.KDTreeSearchParamKNN(knn=int(normal_neighbours))
    start = time.perf_counter()
    pcd.estimate_normals(search)
    timings["normals"] = time.perf_counter() - start
    start = time.perf_counter()
    boxes = pcd.detect_planar_patches(
        normal_variance_threshold_deg=float(normal_variance_threshold_deg),
        coplanarity_deg=float(coplanarity_deg),
        outlier_ratio=float(outlier_ratio),
        min_plane_edge_length=float(min_plane_edge_length),
        min_num_points=int(min_num_points),
        search_param=search,
    )
    timings["detect"] = time.perf_counter() - start
    start = time.perf_counter()
    points = np.asarray(pcd.points)
    if boxes:
        point_labels = assign_to_boxes(
            points,
            np.array([b.center for b in boxes]),
            np.array([b.R for b in boxes]),
            np.array([b.extent for b in boxes]),
            distance_threshold=distance_threshold,
        )
        # Consecutive ids: patches that won no point leave no gap.
        used = np.unique(point_labels[point_labels > 0])
        lookup = np.zeros(len(boxes) + 1, dtype=np.int32)
        lookup[used] = np.arange(1, len(used) + 1, dtype=np.int32)
        point_labels = lookup[point_labels]
    else:
        point_labels = np.zeros(len(points), dtype=np.int32)
    timings["assign"] = time.perf_counter() - start
    log.debug("planar patches: %d boxes, %d labelled points", len(boxes), int((point_labels > 0).sum()))
    return Segmentation(labels=_to_grid(cloud, point_labels), timings=timings)


def segment_ransac_planes(
    cloud: OrganizedCloud,
    *,
    distance_threshold: float = 0.02,
    ransac_n: int = 3,
    num_iterations: int = 1000,
    max_planes: int = 10,
    min_inliers: int = 100,
    seed: int | None = 0,
) -> Segmentation:
    """Planes by iterated Open3D ``segment_plane`` (RANSAC), removing inliers each round.

    Parameters
    ----------
    cloud : OrganizedCloud
    distance_threshold : float
        Metres from the plane for an inlier (PCL's organized default 0.02 m).
    ransac_n, num_iterations : int
        Passed to ``segment_plane`` (3 points per hypothesis; 1000 hypotheses).
    max_planes : int
        Stop after this many planes.
    min_inliers : int
        Stop when fewer points remain, or the best plane has fewer inliers.
    seed : int or None
        Seeds Open3D's global random generator; None leaves it. Open3D draws its
        hypotheses on several threads, so a seed narrows but does not remove run-to-run
        variation: on a busy machine two seeded runs can keep different border points.

    Returns
    -------
    Segmentation
        ``labels`` (H, W) int32, plane k's inliers labelled k, 0 = in no plane;
        ``timings`` ``ransac``.
    """
    _check_cloud(cloud)
    _positive("distance_threshold", distance_threshold)
    for name, value, low in (("ransac_n", ransac_n, 3), ("num_iterations", num_iterations, 1),
                             ("max_planes", max_planes, 1), ("min_inliers", min_inliers, 3)):
        if not (isinstance(value, (int, np.integer)) and value >= low):
            raise ValueError(f"{name} must be an integer >= {low}; got {value!r}")
    timings: dict[str, float] = {}
    n_points = cloud.n_valid
    point_labels = np.zeros(n_points, dtype=np.int32)
    if n_points < max(min_inliers, ransac_n):
        return Segmentation(labels=_to_grid(cloud, point_labels), timings=timings)

    import open3d as o3d

    if seed is not None:
        o3d.utility.random.seed(int(seed))
    start = time.perf_counter()
    pcd = cloud.to_legacy()
    remaining = np.arange(n_points)  # original index of each point still in pcd
    for plane in range(1, max_planes + 1):
        if len(remaining) < max(min_inliers, ransac_n):
            break
        _, inliers = pcd.segment_plane(
            distance_threshold=float(distance_threshold),
            ransac_n=int(ransac_n),
            num_iterations=int(num_iterations),
        )
        if len(inliers) < min_inliers:
            break
        point_labels[remaining[inliers]] = plane
        pcd = pcd.select_by_index(inliers, invert=True)
        keep = np.ones(len(remaining), dtype=bool)
        keep[inliers] = False
        remaining = remaining[keep]
    timings["ransac"] = time.perf_counter() - start
    return Segmentation(labels=_to_grid(cloud, point_labels), timings=timings)


PlanarPatchesConfig = params_model(segment_planar_patches, dict(
    normal_neighbours=dict(ge=3),
    normal_variance_threshold_deg=dict(gt=0, le=90),
    coplanarity_deg=dict(gt=0, le=90),
    outlier_ratio=dict(gt=0, le=1),
    min_plane_edge_length=dict(ge=0),
    min_num_points=dict(ge=0),
    distance_threshold=dict(ge=0),
), name="PlanarPatchesConfig",
    doc="Parameters of :func:`segment_planar_patches` (defaults: Open3D's, written in its signature).")

RansacPlanesConfig = params_model(segment_ransac_planes, dict(
    distance_threshold=dict(gt=0),
    ransac_n=dict(ge=3),
    num_iterations=dict(ge=1),
    max_planes=dict(ge=1),
    min_inliers=dict(ge=3),
    seed={},
), name="RansacPlanesConfig")


PLANAR_PATCHES = Plugin(
    name="o3d_planar_patches",
    config=PlanarPatchesConfig,
    run=segment_planar_patches,
    description="Open3D detect_planar_patches; planes only (boxes turned into point labels)",
)
RANSAC_PLANES = Plugin(
    name="o3d_ransac_planes",
    config=RansacPlanesConfig,
    run=segment_ransac_planes,
    description="Open3D segment_plane in a loop, removing inliers; planes only",
)
