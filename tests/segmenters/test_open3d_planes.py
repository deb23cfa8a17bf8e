"""Open3D comparison segmenters (planes only) on scenes with known planes."""

import numpy as np
import pytest
from pydantic import ValidationError

from rangeseg_o3d import OrganizedCloud
from rangeseg_o3d.registry import get
from rangeseg_o3d.segmenters.open3d_planes import (
    PLANAR_PATCHES,
    RANSAC_PLANES,
    PlanarPatchesConfig,
    RansacPlanesConfig,
    assign_to_boxes,
    segment_planar_patches,
    segment_ransac_planes,
)

pytest.importorskip("open3d")


def test_ransac_planes_find_both_planes(two_planes, matched_regions):
    cloud, truth = two_planes
    seg = segment_ransac_planes(cloud)
    assert seg.labels.shape == cloud.shape and seg.labels.dtype == np.int32
    assert len(np.unique(seg.labels[seg.labels > 0])) == 2
    assert matched_regions(seg.labels, truth, min_pixels=50, tol=0.95).keys() == {1, 2}
    assert seg.timings["ransac"] >= 0


def test_ransac_planes_on_box_scene_find_every_visible_plane(box_on_floor, matched_regions):
    cloud, truth = box_on_floor
    seg = segment_ransac_planes(cloud, distance_threshold=0.01)
    assert matched_regions(seg.labels, truth, min_pixels=50).keys() == {1, 2, 3, 4, 7}


def test_ransac_planes_stop_at_max_planes_and_min_inliers(box_on_floor):
    cloud, _ = box_on_floor
    assert segment_ransac_planes(cloud, max_planes=2).labels.max() == 2
    # The two big planes have ~3000 points each; nothing else reaches 1000 inliers.
    assert segment_ransac_planes(cloud, min_inliers=1000).labels.max() == 2


def test_seeded_ransac_runs_find_the_same_planes(box_on_floor, matched_regions):
    # Open3D's RANSAC is multithreaded: under load two seeded runs may differ in a few border
    # points (Open3D issue 7270), never in which surfaces they find.
    cloud, truth = box_on_floor
    first, second = (segment_ransac_planes(cloud, seed=3, distance_threshold=0.01).labels
                     for _ in range(2))
    found_first = matched_regions(first, truth, min_pixels=50)
    assert found_first.keys() == matched_regions(second, truth, min_pixels=50).keys()
    assert found_first.keys() == {1, 2, 3, 4, 7}
    differing = np.count_nonzero((first > 0) != (second > 0))
    assert differing <= 0.02 * np.count_nonzero(truth)


def test_planar_patches_find_both_planes(two_planes, matched_regions):
    cloud, truth = two_planes
    seg = segment_planar_patches(cloud)
    assert matched_regions(seg.labels, truth, min_pixels=50).keys() == {1, 2}
    assert set(seg.timings) == {"normals", "detect", "assign"}
    ids = np.unique(seg.labels[seg.labels > 0])
    assert np.array_equal(ids, np.arange(1, len(ids) + 1))  # consecutive


def test_planar_patches_on_box_scene_find_floor_and_wall(box_on_floor, matched_regions):
    cloud, truth = box_on_floor
    found = matched_regions(segment_planar_patches(cloud).labels, truth, min_pixels=50)
    assert {1, 2} <= found.keys()


def test_assign_to_boxes_prefers_nearest_plane_and_respects_box_bounds():
    # Two thick boxes that overlap: the plane z = 0 and the plane z = 0.1.
    centers = np.array([[0, 0, 0.0], [0, 0, 0.1]])
    rotations = np.stack([np.eye(3), np.eye(3)])
    extents = np.array([[2, 2, 0.3], [1, 1, 0.3]])
    pts = np.array([[0, 0, 0.02], [0, 0, 0.08], [0.9, 0, 0.08], [0, 0, 0.5], [5, 0, 0]])
    assert assign_to_boxes(pts, centers, rotations, extents).tolist() == [1, 2, 1, 0, 0]
    # A thin box with a distance tolerance takes points off the plane.
    thin = np.array([[2, 2, 0.001]])
    pts = np.array([[0, 0, 0.005]])
    assert assign_to_boxes(pts, centers[:1], rotations[:1], thin).tolist() == [0]
    assert assign_to_boxes(pts, centers[:1], rotations[:1], thin, distance_threshold=0.01).tolist() == [1]
    assert assign_to_boxes(pts, np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3))).tolist() == [0]


def test_tilted_box_uses_its_own_axes():
    angle = np.deg2rad(40)
    rot = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
    on_plane = rot @ np.array([0.5, 0.2, 0.0])
    off_plane = rot @ np.array([0.5, 0.2, 0.2])
    labels = assign_to_boxes(np.stack([on_plane, off_plane]), np.zeros((1, 3)), rot[None],
                             np.array([[2, 2, 0.02]]))
    assert labels.tolist() == [1, 0]


@pytest.mark.parametrize("segment", [segment_planar_patches, segment_ransac_planes])
def test_all_nan_or_tiny_clouds_give_zero_labels(segment):
    assert not segment(OrganizedCloud(np.full((3, 4, 3), np.nan))).labels.any()
    xyz = np.full((3, 4, 3), np.nan)
    xyz[0, :2] = [[1, 0, 0], [1, 0.1, 0]]
    assert not segment(OrganizedCloud(xyz)).labels.any()


@pytest.mark.parametrize(
    "segment, config, bad, match",
    [
        (segment_ransac_planes, RansacPlanesConfig, dict(distance_threshold=0.0), "distance_threshold"),
        (segment_ransac_planes, RansacPlanesConfig, dict(ransac_n=2), "ransac_n"),
        (segment_ransac_planes, RansacPlanesConfig, dict(max_planes=0), "max_planes"),
        (segment_ransac_planes, RansacPlanesConfig, dict(min_inliers=1), "min_inliers"),
        (segment_planar_patches, PlanarPatchesConfig, dict(normal_neighbours=2), "normal_neighbours"),
        (segment_planar_patches, PlanarPatchesConfig, dict(coplanarity_deg=0.0), "coplanarity_deg"),
        (segment_planar_patches, PlanarPatchesConfig, dict(outlier_ratio=1.5), "outlier_ratio"),
        (segment_planar_patches, PlanarPatchesConfig, dict(distance_threshold=-1.0), "distance_threshold"),
    ],
)
def test_bad_parameters(two_planes, segment, config, bad, match):
    with pytest.raises(ValueError, match=match):
        segment(two_planes[0], **bad)
    with pytest.raises(ValidationError, match=match):
        config(**bad)


@pytest.mark.parametrize("segment", [segment_planar_patches, segment_ransac_planes])
def test_wrong_kind_of_cloud(segment):
    with pytest.raises(TypeError, match="OrganizedCloud"):
        segment(np.zeros((4, 4, 3)))


@pytest.mark.parametrize("plugin, segment", [(PLANAR_PATCHES, segment_planar_patches),
                                             (RANSAC_PLANES, segment_ransac_planes)])
def test_registered_and_config_matches_keywords(plugin, segment):
    import inspect

    assert get("segmenter", plugin.name) is plugin
    params = inspect.signature(segment).parameters
    keywords = {k: p.default for k, p in params.items() if p.kind is p.KEYWORD_ONLY}
    assert plugin.config().model_dump() == keywords
    assert "planes only" in plugin.description
