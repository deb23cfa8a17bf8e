import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.fitting import fit_plane
from rangeseg_o3d.fitting.primitives import Plane, Sphere
from rangeseg_o3d.refine import (
    grow_into_edges,
    leftover_candidates,
    merge_candidates,
    region_adjacency,
    similar_models,
)
from rangeseg_o3d.robust import trimmed_fit


def _flat_grid(h=12, w=16, z=2.0):
    v, u = np.mgrid[0:h, 0:w].astype(float)
    return np.dstack([u * 0.05, v * 0.05, np.full((h, w), z)])


def test_grow_hands_band_pixels_to_the_surface_that_explains_them():
    xyz = _flat_grid()
    xyz[:, 8:, 2] = 2.0 + (xyz[:, 8:, 0] - 0.4)  # a 45 degree crease at column 8
    labels = np.zeros((12, 16), np.int32)
    labels[:, :6] = 1
    labels[:, 10:] = 2
    models = {1: fit_plane(xyz[:, :6].reshape(-1, 3)), 2: fit_plane(xyz[:, 10:].reshape(-1, 3))}
    sigma = np.full((12, 16), 0.002)
    grown = grow_into_edges(xyz, labels, models, sigma, xyz[..., 2], iterations=5, k_sigma=3.0)
    assert (grown[:, :8] == 1).all()
    # Column 8 lies on both planes (the crease line); the rest must go to its own side.
    assert (grown[:, 9:] == 2).all()
    assert (grown[:, 8] > 0).all()


def test_grow_does_not_cross_jumps_or_take_far_points():
    xyz = _flat_grid()
    xyz[:, 8:, 2] = 3.0  # a parallel plane 1 m behind: a jump, not the same surface
    labels = np.zeros((12, 16), np.int32)
    labels[:, :6] = 1
    models = {1: fit_plane(xyz[:, :6].reshape(-1, 3))}
    grown = grow_into_edges(xyz, labels, models, np.full((12, 16), 0.002), xyz[..., 2],
                            iterations=10)
    assert (grown[:, :8] == 1).all() and (grown[:, 8:] == 0).all()


def test_leftover_candidates_cut_thin_bands_and_keep_blobs():
    labels = np.ones((20, 30), np.int32)
    labels[:, 14:16] = 0          # a 2-pixel band between two regions
    labels[5:12, 3:10] = 0        # a 7x7 blob
    valid = np.ones_like(labels, bool)
    cand = leftover_candidates(labels, valid, np.zeros_like(valid), min_size=20, first_label=5)
    assert set(np.unique(cand)) == {0, 5}
    assert (cand[5:12, 3:10] == 5).all()
    assert (cand[:, 14:16] == 0).all()


def test_leftover_candidates_keep_strips_along_the_grid_border():
    # A ceiling seen only by the first two scan rows: the border is no edge, so the
    # erosion that cuts crease bands must not eat the strip; the same strip inside the
    # grid is a crease band and is cut.
    labels = np.ones((20, 60), np.int32)
    labels[0:2, 10:50] = 0
    labels[9:11, 10:50] = 0
    valid = np.ones_like(labels, bool)
    cand = leftover_candidates(labels, valid, np.zeros_like(valid), min_size=20, first_label=3)
    assert (cand[0:2, 11:49] == 3).all()
    assert not cand[9:11].any()


def test_region_adjacency_reach():
    labels = np.zeros((5, 9), np.int32)
    labels[:, :3] = 1
    labels[:, 4:] = 2  # one empty column between: pixels two apart
    assert region_adjacency(labels, reach=2) == {(1, 2)}
    assert region_adjacency(labels, reach=1) == set()


def test_merge_candidates_need_adjacency_or_similar_parameters():
    a = Plane(normal=[0, 0, 1], d=1.0, rms=0.004, inliers=100)
    b = Plane(normal=[0, 0.01, 1], d=1.01, rms=0.004, inliers=100)
    c = Plane(normal=[1, 0, 0], d=1.0, rms=0.004, inliers=100)
    s = Sphere(center=[0, 0, 0], radius=1.0, rms=0.004, inliers=100)
    assert similar_models(a, b, max_angle_deg=3, tolerance=0.05)
    assert not similar_models(a, c, max_angle_deg=3, tolerance=0.05)
    assert not similar_models(a, s, max_angle_deg=3, tolerance=0.05)
    models = {1: a, 2: b, 3: c, 4: s}
    assert merge_candidates(models, max_angle_deg=3, tolerance=0.05, adjacency=set()) == [(1, 2)]
    assert merge_candidates(models, max_angle_deg=3, tolerance=0.05, adjacency=set(),
                            disjoint=False) == []
    assert (1, 3) in merge_candidates(models, max_angle_deg=3, tolerance=0.05, adjacency={(1, 3)})


def test_trimmed_fit_finds_the_dominant_plane_of_a_corner():
    rng = np.random.default_rng(0)
    floor = np.c_[rng.uniform(0, 2, 700), rng.uniform(0, 2, 700), rng.normal(0, 0.003, 700)]
    wall = np.c_[rng.normal(0, 0.003, 300), rng.uniform(0, 2, 300), rng.uniform(0, 1, 300)]
    points = np.vstack([floor, wall])
    judge = rs.registry.get("fitter", "primitives").run
    model, inliers = trimmed_fit(points, judge, sigma=0.003, min_points=30)
    assert model.kind == "plane"
    assert abs(model.normal[2]) > 0.999 and abs(model.d) < 0.005
    assert inliers[:700].mean() > 0.95 and inliers[700:].mean() < 0.1


def test_trimmed_fit_gives_up_on_noise():
    rng = np.random.default_rng(1)
    judge = rs.registry.get("fitter", "primitives").run
    assert trimmed_fit(rng.uniform(0, 1, (300, 3)), judge, sigma=0.003, min_points=30) == (None, None)
    assert trimmed_fit(np.zeros((3, 3)), judge, sigma=0.003, min_points=30) == (None, None)


def test_crop_keeps_geometry_consistent():
    from rangeseg_o3d.synthetic.lms200 import simulate_lms200
    from rangeseg_o3d.synthetic.suite import default_scene

    scan = simulate_lms200(default_scene(), beam_start_deg=0, beam_stop_deg=180)
    full = scan.cloud
    crop = full.crop(cols=slice(25, 156))
    assert crop.shape == (70, 131)
    np.testing.assert_allclose(np.degrees(crop.geometry.beam_angles[[0, -1]]), [25, 155])
    np.testing.assert_array_equal(crop.xyz, full.xyz[:, 25:156])
    rebuilt = rs.OrganizedCloud.from_ranges(crop.ranges, crop.geometry.beam_angles,
                                            crop.geometry.tilt_angles,
                                            mount_offset=crop.geometry.mount_offset)
    np.testing.assert_allclose(rebuilt.xyz, crop.xyz, equal_nan=True)
    with pytest.raises(ValueError, match="empty"):
        full.crop(cols=slice(5, 5))
    depth = rs.OrganizedCloud.from_depth(np.full((4, 6), 1000.0), 100, 100, 3, 2, depth_scale=1e-3)
    sub = depth.crop(rows=slice(1, 3), cols=slice(2, 5))
    assert (sub.geometry.cx, sub.geometry.cy) == (1, 1)


def _floor_and_resting_cylinder(seed):
    # a floor and the upper part of a cylinder lying on it (r = 0.15 m, axis along x):
    # no crease between them in range, so one region holds both
    rng = np.random.default_rng(seed)
    floor = np.c_[rng.uniform(0, 1.2, 260), rng.uniform(0.6, 1.4, 260), rng.normal(0, 0.004, 260)]
    t = rng.uniform(0.15 * np.pi, 0.85 * np.pi, 160)
    cylinder = np.c_[rng.uniform(0, 1.2, 160), 1.0 + 0.15 * np.cos(t), 0.15 + 0.15 * np.sin(t)]
    return floor, cylinder + rng.normal(0, 0.004, (160, 3))


@pytest.mark.parametrize("seed", [0, 1, 4])
def test_trimmed_fit_takes_the_floor_under_a_resting_cylinder(seed):
    # The quadric proposal bends from the floor onto the cylinder: that mixture fails,
    # and the floor, the surface most points lie on, is the answer.
    floor, cylinder = _floor_and_resting_cylinder(seed)
    model, inliers = trimmed_fit(np.vstack([floor, cylinder]), rs.registry.get("fitter", "primitives").run,
                                 sigma=0.004, min_points=30)
    assert model.kind == "plane" and abs(model.normal[2]) > 0.9999 and abs(model.d) < 0.002
    assert inliers[:260].mean() > 0.98 and inliers[260:].mean() < 0.05


def test_trimmed_fit_finds_a_clean_cylinder():
    _, cylinder = _floor_and_resting_cylinder(0)
    model, inliers = trimmed_fit(cylinder, rs.registry.get("fitter", "primitives").run, sigma=0.004,
                                 min_points=30)
    assert model.kind == "cylinder" and model.radius == pytest.approx(0.15, abs=0.005)
    assert abs(model.axis[0]) > 0.999 and inliers.mean() > 0.95


def test_trimmed_proposals_stop_at_their_fixed_point():
    # Steps that keep the support unchanged are skipped: any number of rounds past the
    # fixed point gives the same proposals.
    from rangeseg_o3d.kernels import trimmed_proposals

    floor, cylinder = _floor_and_resting_cylinder(2)
    pts = np.ascontiguousarray(np.vstack([floor, cylinder]))
    keep = int(0.6 * len(pts))
    answers = [trimmed_proposals(pts, 0.004, rounds, keep, 64, 0) for rounds in (15, 40, 100)]
    for plane_near, quad_near in answers[1:]:
        np.testing.assert_array_equal(plane_near, answers[0][0])
        np.testing.assert_array_equal(quad_near, answers[0][1])
    assert answers[0][0][:260].mean() > 0.95 and answers[0][0][260:].mean() < 0.1
