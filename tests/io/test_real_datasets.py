import functools

import numpy as np
import pytest

from rangeseg_o3d import NoddingGeometry, PinholeGeometry
from rangeseg_o3d.io.datasets import (
    estimate_pinhole,
    load_3dtk,
    load_andreashaus,
    load_cape_depth,
    load_peac_frame,
    load_pcd,
    real_clouds,
)
from rangeseg_o3d.geometry import nodding_points


def _plane(points):
    """Unit normal (z >= 0), centroid and rms residual of a least-squares plane."""
    points = points.reshape(-1, 3)
    points = points[np.isfinite(points).all(axis=1)]
    centroid = points.mean(axis=0)
    _, s, vt = np.linalg.svd(points - centroid, full_matrices=False)
    normal = vt[-1] * np.sign(vt[-1][2])
    return normal, centroid, s[-1] / np.sqrt(len(points))


def _angle_to_z_deg(normal):
    return np.degrees(np.arccos(min(1.0, abs(normal[2]))))


# -- 3DTK -------------------------------------------------------------------------------

@pytest.mark.parametrize(
    "scan, n_invalid",
    # SOURCES.md: at max range + r < 20 cm + 20 <= r < 48 cm
    [("scan000", 1481 + 1892 + 373), ("scan001", 1313 + 1727 + 489), ("scan002", 1618 + 1624 + 535)],
)
def test_3dtk_grid_and_filter(shared_file, scan, n_invalid):
    cloud = load_3dtk(shared_file(f"3dtk/{scan}.3d"))
    assert cloud.shape == (226, 360)
    assert 226 * 360 - cloud.n_valid == n_invalid
    r = cloud.ranges[cloud.valid]
    assert r.min() >= 0.48 and r.max() < 32.75
    np.testing.assert_array_equal(np.isnan(cloud.ranges), ~cloud.valid)


def test_3dtk_scan000_geometry_is_plausible(shared_file):
    """Our frame (x forward, y left, z up), checked on scan000:

    - the lowest 15 rows (looking down), central 60 beams, lie on a horizontal floor
      (normal within 2 deg of z, rms < 2 cm) 0.25..0.5 m below the sensor;
    - the top 15 rows (looking up), same beams, on a horizontal ceiling 1.8..2.3 m above;
    - beam 0 looks right (y < 0), beam 359 left (y > 0), the middle beam forward (x > 0):
      a mirrored (left-handed) conversion would swap the first two;
    - the attached nodding geometry reproduces every valid point to 1 mm, with beams
      0.5 deg apart and tilt +48.7 deg (down) at row 0 to -67.6 deg (up) at row 225.
    """
    cloud = load_3dtk(shared_file("3dtk/scan000.3d"))
    normal, centroid, rms = _plane(cloud.xyz[:15, 150:210])
    assert _angle_to_z_deg(normal) < 2.0 and rms < 0.02
    assert -0.5 < centroid[2] < -0.25
    normal, centroid, rms = _plane(cloud.xyz[-15:, 150:210])
    assert _angle_to_z_deg(normal) < 5.0 and rms < 0.03
    assert 1.8 < centroid[2] < 2.3

    assert np.nanmedian(cloud.xyz[:, 0, 1]) < 0
    assert np.nanmedian(cloud.xyz[:, -1, 1]) > 0
    assert np.nanmedian(cloud.xyz[:, 180, 0]) > 0

    geometry = cloud.geometry
    assert isinstance(geometry, NoddingGeometry)
    np.testing.assert_allclose(np.degrees(np.diff(geometry.beam_angles)), 0.5)
    assert np.degrees(geometry.tilt_angles[0]) == pytest.approx(48.7, abs=0.05)
    assert np.degrees(geometry.tilt_angles[-1]) == pytest.approx(-67.6, abs=0.05)
    error = np.abs(nodding_points(cloud.ranges, geometry) - cloud.xyz)[cloud.valid]
    assert error.max() <= 1e-3


def _write_uos(path, points_cm):
    path.write_text("\n".join(" ".join(f"{v:.4f}" for v in p) for p in points_cm) + "\n")
    return path


def test_3dtk_synthetic_scan_recovers_tilts(tmp_path):
    """A scan written in 3DTK's frame (x right, y up, z forward, cm) from known tilts
    comes back in our frame with those tilts and the 0.5 deg beams."""
    tilts = np.deg2rad(np.array([30.0, 10.0, -5.0, -20.0]))
    geometry = NoddingGeometry(beam_angles=np.deg2rad(np.arange(360) * 0.5), tilt_angles=tilts)
    ranges = np.full((4, 360), 3.0)
    ranges[1, 2] = 40.0  # beyond the max-range filter
    ranges[2, 100] = 0.3  # below the min-range filter
    ours = nodding_points(ranges, geometry)
    cm = np.stack([-ours[..., 1], ours[..., 2], ours[..., 0]], axis=-1).reshape(-1, 3) * 100
    cloud = load_3dtk(_write_uos(tmp_path / "s.3d", cm))
    assert cloud.shape == (4, 360) and cloud.n_valid == 4 * 360 - 2
    np.testing.assert_allclose(cloud.xyz[cloud.valid], ours[cloud.valid], atol=1e-5)
    np.testing.assert_allclose(cloud.geometry.tilt_angles, tilts, atol=1e-5)


def test_3dtk_without_consistent_geometry(tmp_path, random_xyz):
    """Points that no 0.5-deg nodding scan produces load without a geometry."""
    points = (random_xyz(3, 360, nan_pixels=()) * 200).reshape(-1, 3)
    cloud = load_3dtk(_write_uos(tmp_path / "r.3d", points))
    assert cloud.shape == (3, 360) and cloud.geometry is None


@pytest.mark.parametrize(
    "text, message",
    [
        ("1 2 3 4\n5 6 7 8\n9 10 11 12\n", "3 values"),
        ("1 2 3\n4 5 6\n7 8 9\n", "multiple of 2"),
        ("1 2 3\n4 5 a\n", "not a number"),
        ("", "multiple of 2"),
    ],
)
def test_3dtk_malformed(tmp_path, text, message):
    path = tmp_path / "bad.3d"
    path.write_text(text)
    with pytest.raises(ValueError, match=message):
        load_3dtk(path, columns=2)


# -- depth cameras ------------------------------------------------------------------------

def test_cape_depth(shared_file):
    cloud = load_cape_depth(shared_file("cape/depth_0.png"), shared_file("cape/calib_params.xml"))
    assert cloud.shape == (480, 640)
    assert 480 * 640 - cloud.n_valid == 45256
    g = cloud.geometry
    assert (g.fx, g.fy, g.cx, g.cy) == pytest.approx((575.93, 576.41, 315.15, 230.59), abs=0.01)
    z = cloud.xyz[cloud.valid][:, 2]
    assert z.min() == pytest.approx(0.832) and z.max() == pytest.approx(6.990)


def test_cape_bad_inputs(tmp_path, shared_file):
    cv2 = pytest.importorskip("cv2")
    calib = shared_file("cape/calib_params.xml")
    cv2.imwrite(str(tmp_path / "eight_bit.png"), np.zeros((4, 5), np.uint8))
    with pytest.raises(ValueError, match="16-bit"):
        load_cape_depth(tmp_path / "eight_bit.png", calib)
    cv2.imwrite(str(tmp_path / "d.png"), np.ones((4, 5), np.uint16))
    (tmp_path / "empty.xml").write_text('<?xml version="1.0"?>\n<opencv_storage>\n</opencv_storage>\n')
    with pytest.raises(ValueError, match="IR_intrinsic_params"):
        load_cape_depth(tmp_path / "d.png", tmp_path / "empty.xml")
    with pytest.raises(FileNotFoundError):
        load_cape_depth(tmp_path / "absent.png", calib)


def test_peac_frame(shared_file):
    cloud = load_peac_frame(shared_file("peac/frame.mat"))
    assert cloud.shape == (480, 640)
    assert 480 * 640 - cloud.n_valid == 69556  # only z is NaN in the file
    g = cloud.geometry
    assert (g.fx, g.fy, g.cx, g.cy) == pytest.approx((525.0, 525.0, 319.5, 239.5), abs=1e-6)
    z = cloud.xyz[cloud.valid][:, 2]
    assert z.min() == pytest.approx(0.596) and z.max() == pytest.approx(2.181)


def test_peac_bad_file(tmp_path):
    scipy_io = pytest.importorskip("scipy.io")
    scipy_io.savemat(tmp_path / "f.mat", {"other": np.zeros(3)})
    with pytest.raises(ValueError, match="struct 'frame'"):
        load_peac_frame(tmp_path / "f.mat")
    scipy_io.savemat(tmp_path / "g.mat", {"frame": {"xyz": np.zeros((4, 3))}})
    with pytest.raises(ValueError, match=r"shape \(H, W, 3\)"):
        load_peac_frame(tmp_path / "g.mat")


def test_estimate_pinhole_recovers_intrinsics_and_rejects_non_pinhole(random_xyz):
    depth = np.linspace(1.0, 3.0, 12 * 16).reshape(12, 16)
    depth[0, :4] = 0
    truth = PinholeGeometry(500.0, 510.0, 7.2, 5.9)
    from rangeseg_o3d.geometry import pinhole_points

    estimated = estimate_pinhole(pinhole_points(depth, truth))
    assert (estimated.fx, estimated.fy, estimated.cx, estimated.cy) == pytest.approx(
        (500.0, 510.0, 7.2, 5.9), abs=1e-6)
    assert estimate_pinhole(random_xyz(12, 16)) is None
    assert estimate_pinhole(np.full((3, 3, 3), np.nan)) is None


def test_pcl_loader_attaches_intrinsics(shared_file):
    cloud = load_pcd(shared_file("pcl/office1.pcd"))
    g = cloud.geometry
    assert (g.fx, g.fy, g.cx, g.cy) == pytest.approx((525.0, 525.0, 320.0, 240.0), abs=1e-3)
    assert load_pcd(shared_file("pcl/sac_plane_test.pcd")).geometry is None


def test_andreashaus_in_metres(shared_file):
    cloud = load_andreashaus(shared_file("peac/andreashaus_scan000.pcd"))
    assert cloud.shape == (633, 513) and 633 * 513 - cloud.n_valid == 13996
    extent = np.nanmax(cloud.xyz, axis=(0, 1)) - np.nanmin(cloud.xyz, axis=(0, 1))
    assert (extent > 1.0).all() and (extent < 10.0).all()  # a room, in metres


# -- catalogue ------------------------------------------------------------------------------

def test_real_clouds_empty_root(tmp_path):
    assert real_clouds(tmp_path) == []


def test_real_clouds_lists_present_files_with_presets(tmp_path, random_xyz):
    from rangeseg_o3d import OrganizedCloud

    (tmp_path / "3dtk").mkdir()
    (tmp_path / "pcl").mkdir()
    (tmp_path / "cape").mkdir()
    (tmp_path / "3dtk" / "scan001.3d").write_text("0 0 100\n" * 360)
    OrganizedCloud(random_xyz(2, 3, nan_pixels=((0, 0),))).save(tmp_path / "pcl" / "office1.pcd")
    (tmp_path / "cape" / "depth_0.png").write_bytes(b"")  # no calib_params.xml: skipped
    found = {c.name: c for c in real_clouds(tmp_path)}
    assert sorted(found) == ["3dtk_scan001", "pcl_office1"]
    assert found["3dtk_scan001"].preset == "sick_3dtk"
    assert found["pcl_office1"].preset == "rgbd_vga"
    assert found["3dtk_scan001"].load().shape == (1, 360)
    assert found["pcl_office1"].load().shape == (2, 3)


def test_real_clouds_on_shared_data(shared_file):
    shared_file("SOURCES.md")
    clouds = real_clouds()
    presets = {c.name: c.preset for c in clouds}
    assert presets.get("peac_andreashaus", "tls_andreashaus") == "tls_andreashaus"
    assert presets.get("cape_tunnel", "rgbd_vga") == "rgbd_vga"
    cape = [c for c in clouds if c.name == "cape_tunnel"]
    if cape:
        assert isinstance(cape[0].loader, functools.partial)
        assert cape[0].load().geometry is not None
