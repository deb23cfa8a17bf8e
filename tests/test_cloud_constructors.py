"""OrganizedCloud.from_depth / from_ranges (one compiled pass) against the numpy reference."""

import numpy as np
import pytest

from rangeseg_o3d.cloud import OrganizedCloud
from rangeseg_o3d.io.datasets import default_data_root
from rangeseg_o3d.geometry import NoddingGeometry, PinholeGeometry, nodding_points, pinhole_points


def _reference_depth(depth, fx, fy, cx, cy, scale):
    # The numpy implementation from_depth had before the compiled pass.
    xyz = pinhole_points(np.asarray(depth, dtype=float) * scale, PinholeGeometry(fx, fy, cx, cy))
    return xyz, np.linalg.norm(xyz, axis=2)


def _depth_image(dtype):
    rng = np.random.default_rng(4)
    depth = rng.uniform(400, 7000, size=(48, 64))
    depth[rng.random(depth.shape) < 0.2] = 0
    if np.issubdtype(dtype, np.floating):
        depth[3, 5], depth[7, 9], depth[8, 1] = np.nan, np.inf, -12.0
    return depth.astype(dtype)


@pytest.mark.parametrize("dtype", [np.uint16, np.int32, np.float32, np.float64])
def test_from_depth_equals_the_numpy_reference(dtype):
    depth = _depth_image(dtype)
    cloud = OrganizedCloud.from_depth(depth, 575.8, 576.4, 31.2, 22.6, depth_scale=0.001)
    xyz, ranges = _reference_depth(depth, 575.8, 576.4, 31.2, 22.6, 0.001)
    np.testing.assert_allclose(cloud.xyz, xyz, rtol=1e-15, atol=0)
    np.testing.assert_allclose(cloud.ranges, ranges, rtol=1e-15, atol=0)
    expected_valid = np.isfinite(xyz[..., 2])
    np.testing.assert_array_equal(cloud.valid, expected_valid)
    assert 0 < expected_valid.sum() < depth.size  # both kinds of pixel present
    assert cloud.xyz.dtype == np.float64 and not cloud.xyz.flags.writeable and not cloud.valid.flags.writeable
    assert cloud.geometry == PinholeGeometry(575.8, 576.4, 31.2, 22.6)


def test_from_depth_on_the_cape_frame_equals_the_reference():
    root = default_data_root() / "cape"
    if not (root / "depth_0.png").is_file():
        pytest.skip("shared CAPE frame absent")
    import cv2

    depth = cv2.imread(str(root / "depth_0.png"), cv2.IMREAD_UNCHANGED)
    cloud = OrganizedCloud.from_depth(depth, 575.93, 576.41, 315.15, 230.59, depth_scale=0.001)
    xyz, ranges = _reference_depth(depth, 575.93, 576.41, 315.15, 230.59, 0.001)
    np.testing.assert_allclose(cloud.xyz, xyz, rtol=1e-15, atol=0)
    np.testing.assert_allclose(cloud.ranges, ranges, rtol=1e-15, atol=0)
    assert cloud.n_valid == int((depth > 0).sum()) == 480 * 640 - 45256


def test_from_depth_bad_input():
    with pytest.raises(ValueError, match="depth_scale"):
        OrganizedCloud.from_depth(np.ones((4, 4)), 1, 1, 1, 1, depth_scale=0)
    with pytest.raises(ValueError, match=r"depth must have shape \(H, W\)"):
        OrganizedCloud.from_depth(np.ones((4, 4, 1)), 1, 1, 1, 1)
    with pytest.raises(ValueError, match="numbers"):
        OrganizedCloud.from_depth(np.array([["a", "b"]]), 1, 1, 1, 1)
    with pytest.raises(ValueError, match="fx and fy"):
        OrganizedCloud.from_depth(np.ones((4, 4)), 0, 1, 1, 1)
    with pytest.raises(ValueError, match="at least one row"):
        OrganizedCloud.from_depth(np.ones((0, 4)), 1, 1, 1, 1)
    big_endian = OrganizedCloud.from_depth(np.full((2, 3), 1000, dtype=">u2"), 10, 10, 1, 1, depth_scale=1e-3)
    np.testing.assert_allclose(big_endian.xyz[..., 2], 1.0)


def test_from_ranges_equals_the_numpy_reference():
    rng = np.random.default_rng(5)
    beams = np.deg2rad(np.arange(25.0, 156.0))
    tilts = np.linspace(-0.4, 0.3, 70)
    ranges = rng.uniform(0.5, 8.0, size=(70, beams.size))
    ranges[rng.random(ranges.shape) < 0.1] = np.nan
    ranges[0, :3] = [0.0, -1.0, np.inf]
    for offset, sign in (((0.0, 0.0, 0.1), 1.0), ((0.02, -0.01, 0.12), -1.0)):
        cloud = OrganizedCloud.from_ranges(ranges, beams, tilts, mount_offset=offset, tilt_sign=sign)
        reference = nodding_points(ranges, NoddingGeometry(beams, tilts, offset, sign))
        np.testing.assert_allclose(cloud.xyz, reference, rtol=1e-13, atol=1e-15)
        clean = np.where(np.isfinite(ranges) & (ranges > 0), ranges, np.nan)
        np.testing.assert_array_equal(cloud.ranges, clean)
        np.testing.assert_array_equal(cloud.valid, np.isfinite(clean))
    with pytest.raises(ValueError, match="to match the geometry"):
        OrganizedCloud.from_ranges(ranges[:, :10], beams, tilts)
    ints = OrganizedCloud.from_ranges(np.full((2, 3), 2, dtype=np.int16), beams[:3], tilts[:2])
    np.testing.assert_allclose(np.linalg.norm(ints.xyz, axis=2), 2.0)


def test_crop_keeps_geometry_consistent():
    from rangeseg_o3d.synthetic.lms200 import simulate_lms200
    from rangeseg_o3d.synthetic.suite import default_scene

    scan = simulate_lms200(default_scene(), beam_start_deg=0, beam_stop_deg=180)
    full = scan.cloud
    crop = full.crop(cols=slice(25, 156))
    assert crop.shape == (70, 131)
    np.testing.assert_allclose(np.degrees(crop.geometry.beam_angles[[0, -1]]), [25, 155])
    np.testing.assert_array_equal(crop.xyz, full.xyz[:, 25:156])
    rebuilt = OrganizedCloud.from_ranges(crop.ranges, crop.geometry.beam_angles,
                                            crop.geometry.tilt_angles,
                                            mount_offset=crop.geometry.mount_offset)
    np.testing.assert_allclose(rebuilt.xyz, crop.xyz, equal_nan=True)
    with pytest.raises(ValueError, match="empty"):
        full.crop(cols=slice(5, 5))
    depth = OrganizedCloud.from_depth(np.full((4, 6), 1000.0), 100, 100, 3, 2, depth_scale=1e-3)
    sub = depth.crop(rows=slice(1, 3), cols=slice(2, 5))
    assert (sub.geometry.cx, sub.geometry.cy) == (1, 1)
