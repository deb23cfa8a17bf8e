"""Simulated LMS200 and depth camera: points on their surfaces, noise, truth ids, mixed pixels."""

import numpy as np
import pytest

from rangeseg_o3d.geometry import NoddingGeometry, PinholeGeometry
from rangeseg_o3d.synthetic.depth_camera import camera_pose_scene, simulate_depth_camera
from rangeseg_o3d.synthetic.lms200 import (
    lms200_beam_angles,
    lms200_row_ranges,
    lms200_tilt_angles,
    simulate_lms200,
)
from rangeseg_o3d.synthetic.scene import Scene, box, cylinder, room, rotation_from_to, sphere


def _scene():
    return Scene([
        room(first_id=1),
        box((2.5, -0.9, -0.2), (0.8, 0.6, 0.6), yaw=0.4, first_id=7),
        cylinder((2.0, 0.8, -0.5), (0, 0, 1), 0.25, 1.5, first_id=12),
        cylinder((3.2, -0.2, 0.6), rotation_from_to((0, 0, 1), (0.3, 1, 0.2)) @ [0, 0, 1], 0.2, 1.2, first_id=15),
        sphere((3.5, 0.3, -0.1), 0.35, first_id=18),
    ])


def _distance_to_truth(points, ids, truth):
    out = np.full(len(points), np.inf)
    for k, model in truth.items():
        sel = ids == k
        out[sel] = np.abs(model.distances(points[sel]))
    return out


def test_lms200_shape_geometry_and_schedule():
    scan = simulate_lms200(_scene(), noise_sigma=0.0, mixed_pixels=False)
    assert scan.cloud.shape == (70, 131)
    geo = scan.cloud.geometry
    assert isinstance(geo, NoddingGeometry)
    assert np.allclose(geo.tilt_angles, np.linspace(-0.4, 0.3, 70))
    assert np.allclose(np.rad2deg(geo.beam_angles[[0, -1]]), [25, 155])
    assert scan.truth_ids.dtype == np.int32 and scan.truth_ids.shape == (70, 131)


def test_lms200_noiseless_points_lie_on_true_surfaces():
    scan = simulate_lms200(_scene(), noise_sigma=0.0, mixed_pixels=False)
    valid = scan.cloud.valid
    ids = scan.truth_ids[valid]
    assert np.all(ids > 0)
    assert np.array_equal(valid, scan.truth_ids > 0)
    dist = _distance_to_truth(scan.cloud.xyz[valid], ids, scan.truth)
    assert dist.max() < 1e-9
    # Every kind of surface is seen.
    kinds = {m.kind for m in scan.truth.values()}
    assert kinds == {"plane", "cylinder", "sphere"}
    assert set(scan.truth) == set(np.unique(ids).tolist())


def test_lms200_noise_statistics_match_sigma():
    sigma = 0.005
    scene = Scene(room(first_id=1))
    exact = simulate_lms200(scene, noise_sigma=0.0, mixed_pixels=False)
    noisy = simulate_lms200(scene, noise_sigma=sigma, mixed_pixels=False, seed=3)
    both = exact.cloud.valid & noisy.cloud.valid
    err = noisy.cloud.ranges[both] - exact.cloud.ranges[both]
    assert err.size > 8000
    assert abs(err.mean()) < 4 * sigma / np.sqrt(err.size)
    assert err.std() == pytest.approx(sigma, rel=0.05)


def test_lms200_deterministic_given_seed():
    a = simulate_lms200(_scene(), seed=5)
    b = simulate_lms200(_scene(), seed=5)
    c = simulate_lms200(_scene(), seed=6)
    assert np.array_equal(a.cloud.xyz, b.cloud.xyz, equal_nan=True)
    assert not np.array_equal(a.cloud.xyz, c.cloud.xyz, equal_nan=True)


def test_lms200_mixed_pixels_at_jump_edges_only():
    # A sphere in front of a far wall: jump edges around its silhouette.
    scene = Scene([room(first_id=1), sphere((2.0, 0.0, 0.0), 0.4, first_id=9)])
    clean = simulate_lms200(scene, noise_sigma=0.0, mixed_pixels=False)
    mixed = simulate_lms200(scene, noise_sigma=0.0, mixed_pixels=True)
    became_zero = (clean.truth_ids > 0) & (mixed.truth_ids == 0) & mixed.cloud.valid
    # Pixels next to the sphere's silhouette: one neighbour sees the sphere, another the background.
    sph = clean.truth_ids == 9
    near_sphere = np.zeros_like(sph)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            near_sphere |= np.roll(np.roll(sph, dy, 0), dx, 1)
    silhouette = became_zero & near_sphere & (clean.truth_ids != 9) | became_zero & sph & ~np.roll(sph, 1, 1)
    assert silhouette.sum() > 10
    # Mixed ranges lie between the nearest and farthest exact ranges of the 3x3 neighbourhood.
    r = clean.cloud.ranges
    shifted = [np.roll(np.roll(r, dy, 0), dx, 1) for dy in (-1, 0, 1) for dx in (-1, 0, 1)]
    low, high = np.nanmin(shifted, axis=0), np.nanmax(shifted, axis=0)
    sel = became_zero & near_sphere
    r_mixed = mixed.cloud.ranges[sel]
    assert np.all(r_mixed > low[sel] - 0.02) and np.all(r_mixed < high[sel] + 0.02)
    assert np.all(np.abs(r_mixed - r[sel]) > 0.01)
    # Other mixed pixels are at the room's creases (corners), where surfaces meet at an angle.
    assert (became_zero & ~near_sphere).sum() < became_zero.sum()
    # Away from edges the ranges are untouched.
    keep = (mixed.truth_ids > 0) & (mixed.truth_ids == clean.truth_ids)
    assert np.allclose(mixed.cloud.ranges[keep], clean.cloud.ranges[keep], atol=0.01)


def test_lms200_max_range_gives_no_return():
    scene = Scene(room(x=(-1, 20), first_id=1))
    scan = simulate_lms200(scene, noise_sigma=0.0, mixed_pixels=False, max_range=4.0)
    r = scan.cloud.ranges
    assert np.nanmax(r) <= 4.0
    assert np.array_equal(np.isnan(r), scan.truth_ids == 0)
    assert np.isnan(r).sum() > 100


def test_row_ranges_matches_full_scan_row():
    scene = _scene()
    beams = lms200_beam_angles()
    tilts = lms200_tilt_angles()
    scan = simulate_lms200(scene, noise_sigma=0.0, mixed_pixels=False)
    row = lms200_row_ranges(scene, tilts[40], beams, noise_sigma=0.0, mixed_pixels=False)
    assert np.allclose(row, scan.cloud.ranges[40], equal_nan=True)
    full = lms200_row_ranges(scene, 0.1, noise_sigma=0.0)
    assert full.shape == (181,)


def test_lms200_bad_parameters():
    with pytest.raises(ValueError, match="noise_sigma"):
        simulate_lms200(_scene(), noise_sigma=-1)
    with pytest.raises(ValueError, match="rows"):
        simulate_lms200(_scene(), rows=0)
    with pytest.raises(ValueError, match="beam_step_deg"):
        simulate_lms200(_scene(), beam_step_deg=0)


def _camera_scene():
    world = Scene([
        room(x=(-1, 5), y=(-2, 2), z=(0, 2.6), first_id=1),
        box((2.5, -0.6, 0.3), (0.6, 0.6, 0.6), yaw=0.3, first_id=7),
        sphere((2.2, 0.6, 0.5), 0.3, first_id=12),
        cylinder((3.0, 0.0, 0.0), (0, 0, 1), 0.2, 1.2, first_id=13),
    ])
    return camera_pose_scene(world, position=(0, 0, 1.2), pitch=0.3)


def test_depth_camera_noiseless_points_on_surfaces_and_intrinsics():
    scan = simulate_depth_camera(_camera_scene(), noise_coeff=0.0, width=160, height=120,
                                 fx=131.25, fy=131.25, cx=79.5, cy=59.5)
    assert isinstance(scan.cloud.geometry, PinholeGeometry)
    valid = scan.cloud.valid
    assert np.array_equal(valid, scan.truth_ids > 0)
    dist = _distance_to_truth(scan.cloud.xyz[valid], scan.truth_ids[valid], scan.truth)
    assert dist.max() < 1e-9
    assert {m.kind for m in scan.truth.values()} == {"plane", "sphere", "cylinder"}
    # The floor fills the bottom row (y down), 1.2 m from the camera, its normal pitched by 0.3 rad.
    floor = scan.truth_ids == 1
    assert floor[-1].all()
    plane = scan.truth[1]
    assert abs(plane.d) == pytest.approx(1.2)
    assert abs(plane.normal @ [0, np.cos(0.3), np.sin(0.3)]) == pytest.approx(1.0)


def test_depth_camera_noise_follows_kinect_model():
    scene = camera_pose_scene(Scene(room(x=(-1, 3), y=(-5, 5), z=(-5, 5), first_id=1)), position=(0, 0, 0))
    exact = simulate_depth_camera(scene, noise_coeff=0.0, width=80, height=60, fx=65.6, fy=65.6, cx=39.5, cy=29.5)
    noisy = simulate_depth_camera(scene, width=80, height=60, fx=65.6, fy=65.6, cx=39.5, cy=29.5, seed=2)
    z = exact.cloud.xyz[..., 2]
    dz = noisy.cloud.xyz[..., 2] - z
    sel = exact.truth_ids == 4  # the wall 3 m ahead
    ratio = dz[sel] / (1.425e-3 * z[sel] ** 2)
    assert ratio.size > 1000
    assert ratio.std() == pytest.approx(1.0, rel=0.08)


def test_depth_camera_full_vga_default():
    scan = simulate_depth_camera(_camera_scene())
    assert scan.cloud.shape == (480, 640)
    assert scan.cloud.n_valid > 0.95 * 640 * 480
