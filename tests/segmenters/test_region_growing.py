"""Region growing (Rabbani et al. 2006 / PCL RegionGrowing) on scenes with known surfaces."""

from collections import deque

import numpy as np
import pytest
from pydantic import ValidationError
from scipy.spatial import cKDTree

from rangeseg_o3d import OrganizedCloud
from rangeseg_o3d.registry import Segmentation, get
from rangeseg_o3d.segmenters.region_growing import (
    PLUGIN,
    RegionGrowingConfig,
    estimate_normals,
    region_growing_labels,
    segment_region_growing,
)

PCL_WITH_MIN_SIZE = dict(min_cluster_size=50)  # PCL's defaults, small regions dropped


def test_two_planes_at_an_angle_give_two_regions(two_planes, matched_regions):
    cloud, truth = two_planes
    seg = segment_region_growing(cloud, **PCL_WITH_MIN_SIZE)
    assert isinstance(seg, Segmentation)
    assert seg.labels.shape == cloud.shape and seg.labels.dtype == np.int32
    assert set(np.unique(seg.labels[seg.labels > 0])) == {1, 2}
    assert matched_regions(seg.labels, truth, min_pixels=50).keys() == {1, 2}
    # Only the crease loses points: at least 95 % of each plane is labelled.
    for tid in (1, 2):
        assert (seg.labels[truth == tid] > 0).mean() >= 0.95


def test_box_on_floor_gives_floor_wall_and_visible_faces(box_on_floor, matched_regions):
    cloud, truth = box_on_floor
    seg = segment_region_growing(cloud, **PCL_WITH_MIN_SIZE)
    visible = {int(t) for t in np.unique(truth) if t > 0 and (truth == t).sum() >= 50}
    assert visible == {1, 2, 3, 4, 7}  # floor, wall, top, two side faces
    assert len(np.unique(seg.labels[seg.labels > 0])) == len(visible)
    assert matched_regions(seg.labels, truth, min_pixels=50).keys() == visible
    assert (seg.labels[truth == 0] == 0).all()  # no return, no label


def test_stage_images_and_timings(two_planes):
    cloud, _ = two_planes
    seg = segment_region_growing(cloud)
    curv = seg.stages["curvature"]
    assert curv.shape == cloud.shape
    assert np.isnan(curv[~cloud.valid]).all() and np.isfinite(curv[cloud.valid]).all()
    assert ((curv[cloud.valid] >= 0) & (curv[cloud.valid] <= 1 / 3 + 1e-12)).all()
    assert set(seg.timings) == {"knn", "normals", "growth"}


def test_max_cluster_size_drops_large_regions(two_planes):
    cloud, truth = two_planes
    seg = segment_region_growing(cloud, min_cluster_size=50, max_cluster_size=2000)
    # The floor (1600 px) stays, the wall (3200 px) is dropped.
    assert len(np.unique(seg.labels[seg.labels > 0])) == 1
    assert (seg.labels[truth == 2] == 0).all()
    assert (seg.labels[truth == 1] > 0).mean() >= 0.95


def test_normals_and_curvature_of_a_plane_and_a_sphere():
    rng = np.random.default_rng(1)
    plane = np.c_[rng.uniform(-1, 1, (500, 2)), np.zeros(500)] @ np.linalg.qr(rng.normal(size=(3, 3)))[0]
    nbr = cKDTree(plane).query(plane, k=20)[1]
    normals, curvature = estimate_normals(plane, nbr)
    expected = np.cross(*(plane[1:3] - plane[0]))
    expected /= np.linalg.norm(expected)
    assert np.allclose(np.abs(normals @ expected), 1.0, atol=1e-9)
    assert np.allclose(curvature, 0.0, atol=1e-12)
    sphere = rng.normal(size=(2000, 3))
    sphere /= np.linalg.norm(sphere, axis=1, keepdims=True)
    normals, curvature = estimate_normals(sphere, cKDTree(sphere).query(sphere, k=20)[1])
    assert np.median(np.abs(np.sum(normals * sphere, axis=1))) > 0.99  # radial
    assert 0 < np.median(curvature) < 0.05


def test_coincident_points_have_zero_curvature_not_nan():
    pts = np.ones((10, 3))
    normals, curvature = estimate_normals(pts, np.tile(np.arange(10), (10, 1)))
    assert np.isfinite(normals).all() and (curvature == 0).all()


# --- the vectorised growth equals PCL's queue on the same (symmetrised) neighbour graph ---


def _pcl_queue(points, *, n_neighbours, normal_neighbours, smoothness_deg, curvature_threshold,
               min_cluster_size, max_cluster_size):
    """Literal transcription of pcl::RegionGrowing::applySmoothRegionGrowingAlgorithm."""
    n = len(points)
    k = max(n_neighbours + 1, normal_neighbours)
    nbr = cKDTree(points).query(points, k=k)[1]
    normals, curvature = estimate_normals(points, nbr[:, :normal_neighbours])
    adjacency = [set() for _ in range(n)]
    for i in range(n):
        for j in nbr[i, : n_neighbours + 1]:
            if j != i:
                adjacency[i].add(int(j))
                adjacency[int(j)].add(i)
    cos_limit = np.cos(np.deg2rad(smoothness_deg))
    owner = np.full(n, -1)
    regions = []
    for seed in np.argsort(curvature, kind="stable"):
        if owner[seed] >= 0:
            continue
        owner[seed] = len(regions)
        members, queue = [seed], deque([seed])
        while queue:
            current = queue.popleft()
            for j in sorted(adjacency[current]):
                if owner[j] >= 0 or abs(normals[current] @ normals[j]) < cos_limit:
                    continue
                owner[j] = len(regions)
                members.append(j)
                if curvature[j] <= curvature_threshold:
                    queue.append(j)
        regions.append(members)
    labels = np.zeros(n, dtype=np.int32)
    upper = max_cluster_size or n
    next_label = 1
    for members in regions:
        if min_cluster_size <= len(members) <= upper:
            labels[members] = next_label
            next_label += 1
    return labels


@pytest.mark.parametrize(
    "params",
    [
        dict(n_neighbours=8, normal_neighbours=10, smoothness_deg=30, curvature_threshold=0.05,
             min_cluster_size=1, max_cluster_size=None),
        dict(n_neighbours=6, normal_neighbours=8, smoothness_deg=8, curvature_threshold=0.02,
             min_cluster_size=1, max_cluster_size=None),
        dict(n_neighbours=10, normal_neighbours=12, smoothness_deg=15, curvature_threshold=0.01,
             min_cluster_size=3, max_cluster_size=150),
    ],
)
@pytest.mark.parametrize("seed", [0, 1])
def test_matches_pcl_queue_semantics(params, seed):
    rng = np.random.default_rng(seed)
    # A wavy sheet, a box corner and scattered clutter: smooth parts, creases and rough points.
    u = rng.uniform(-1, 1, (250, 2))
    sheet = np.c_[u, 0.15 * np.sin(3 * u[:, 0])]
    corner = np.r_[np.c_[rng.uniform(0, 0.5, (80, 2)), np.full(80, 0.5)],
                   np.c_[np.full(80, 0.5), rng.uniform(0, 0.5, (80, 2))]]
    clutter = rng.uniform(-1, 1, (60, 3))
    points = np.r_[sheet, corner, clutter] + rng.normal(0, 0.003, (470, 3))
    expected = _pcl_queue(points, **params)
    labels, _ = region_growing_labels(points, **params)
    assert np.array_equal(labels, expected)
    assert labels.max() >= 2  # the case is not trivial


# --- edge cases and failure paths ---


def test_all_nan_cloud_gives_all_zero_labels():
    cloud = OrganizedCloud(np.full((4, 5, 3), np.nan))
    seg = segment_region_growing(cloud)
    assert seg.labels.shape == (4, 5) and not seg.labels.any()
    assert np.isnan(seg.stages["curvature"]).all()


def test_fewer_than_three_points_give_zero_labels():
    xyz = np.full((3, 3, 3), np.nan)
    xyz[0, 0] = (1, 0, 0)
    xyz[1, 1] = (1, 0.1, 0)
    assert not segment_region_growing(OrganizedCloud(xyz)).labels.any()


def test_fewer_points_than_neighbours_still_segments():
    g = np.stack(np.meshgrid(np.arange(4.0), np.arange(4.0)), -1).reshape(-1, 2)
    labels, _ = region_growing_labels(np.c_[g, np.zeros(16)], n_neighbours=30)
    assert (labels == 1).all()


@pytest.mark.parametrize(
    "bad, match",
    [
        (dict(n_neighbours=0), "n_neighbours"),
        (dict(normal_neighbours=2), "normal_neighbours"),
        (dict(smoothness_deg=0.0), "smoothness_deg"),
        (dict(smoothness_deg=91.0), "smoothness_deg"),
        (dict(curvature_threshold=-0.1), "curvature_threshold"),
        (dict(min_cluster_size=0), "min_cluster_size"),
        (dict(min_cluster_size=10, max_cluster_size=5), "max_cluster_size"),
        (dict(voxel_size=0.0), "voxel_size"),
    ],
)
def test_bad_parameters_raise_value_error(two_planes, bad, match):
    with pytest.raises(ValueError, match=match):
        segment_region_growing(two_planes[0], **bad)
    with pytest.raises(ValidationError, match=match):
        RegionGrowingConfig(**bad)


def test_bad_inputs():
    with pytest.raises(TypeError, match="OrganizedCloud"):
        segment_region_growing(np.zeros((4, 4, 3)))
    with pytest.raises(ValueError, match=r"shape \(N, 3\); got \(4, 4, 3\)"):
        region_growing_labels(np.zeros((4, 4, 3)))
    with pytest.raises(ValueError, match="finite"):
        region_growing_labels(np.array([[0, 0, np.nan], [1, 0, 0], [0, 1, 0]]))


def test_config_fields_are_the_function_keywords_and_defaults_are_pcl():
    import inspect

    params = inspect.signature(segment_region_growing).parameters
    # the sensor is every segmenter's argument, not a parameter of the method
    keywords = {k: p.default for k, p in params.items() if p.kind is p.KEYWORD_ONLY and k != "sensor"}
    defaults = RegionGrowingConfig().model_dump()
    assert defaults == keywords
    assert defaults == dict(n_neighbours=30, normal_neighbours=30, smoothness_deg=30.0,
                            curvature_threshold=0.05, min_cluster_size=1, max_cluster_size=None,
                            voxel_size=None)
    with pytest.raises(ValidationError, match="extra"):
        RegionGrowingConfig(k=30)


def test_registered_under_its_name(two_planes):
    plugin = get("segmenter", "region_growing")
    assert plugin is PLUGIN
    params = plugin.config(smoothness_deg=10, min_cluster_size=50).model_dump()
    seg = plugin.run(two_planes[0], **params)
    assert len(np.unique(seg.labels[seg.labels > 0])) == 2


@pytest.mark.parametrize("seed", range(0, 60, 3))
def test_last_seeds_claim_like_the_sequential_queue(seed):
    """The rounds that resolve PCL's last (non-growing) seeds equal the sequential rule."""
    from rangeseg_o3d.segmenters.region_growing import _greedy_claims

    rng = np.random.default_rng(seed)
    n = 300
    a, b = rng.integers(0, n, (2, 900))
    a, b = a[a != b], b[a != b]
    lo, hi = np.minimum(a, b), np.maximum(a, b)  # node index = seed order
    undecided = rng.random(n) < 0.8
    pair = undecided[lo] & undecided[hi]
    owner = _greedy_claims(n, lo[pair], hi[pair], undecided)
    expected = np.full(n, -1)
    for node in np.flatnonzero(undecided):
        if expected[node] >= 0:
            continue
        expected[node] = node  # an untaken point starts a region and takes its untaken neighbours
        nbrs = np.r_[hi[pair][lo[pair] == node], lo[pair][hi[pair] == node]]
        nbrs = nbrs[expected[nbrs] < 0]
        expected[nbrs] = node
    assert np.array_equal(owner, expected)


def test_voxel_grid_keeps_the_regions_and_counts_sizes_in_points(two_planes, matched_regions):
    cloud, truth = two_planes
    seg = segment_region_growing(cloud, voxel_size=0.05, min_cluster_size=50)
    assert "voxels" in seg.timings
    assert matched_regions(seg.labels, truth, min_pixels=50).keys() == {1, 2}
    # The floor has 1600 points but far fewer voxels: a 1000-point minimum keeps it.
    seg = segment_region_growing(cloud, voxel_size=0.05, min_cluster_size=1000)
    assert len(np.unique(seg.labels[seg.labels > 0])) == 2


def test_voxel_centroids_average_the_points_of_each_voxel():
    from rangeseg_o3d.segmenters.region_growing import voxel_centroids

    rng = np.random.default_rng(2)
    pts = rng.uniform(-1, 1, (1000, 3))
    centroids, voxel_of = voxel_centroids(pts, 0.5)
    assert len(centroids) == 64  # the 2 m cube in 0.5 m voxels
    for v in (0, 17, 63):
        assert np.allclose(centroids[v], pts[voxel_of == v].mean(axis=0))
    assert voxel_centroids(np.zeros((0, 3)), 0.1)[0].shape == (0, 3)
    with pytest.raises(ValueError, match="voxel_size"):
        voxel_centroids(pts, -1.0)
