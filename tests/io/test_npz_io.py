import numpy as np
import pytest

from rangeseg_o3d import NoddingGeometry, OrganizedCloud, PinholeGeometry
from rangeseg_o3d.io import load_cloud, load_npz, save_cloud, save_npz
from rangeseg_o3d.io.npz import NPZ_FORMAT_VERSION


def _assert_same_cloud(a: OrganizedCloud, b: OrganizedCloud):
    np.testing.assert_array_equal(a.xyz, b.xyz)  # NaN == NaN for assert_array_equal
    for name in ("ranges", "intensity", "timestamps"):
        va, vb = getattr(a, name), getattr(b, name)
        if va is None:
            assert vb is None, name
        else:
            assert vb.dtype == va.dtype, name
            np.testing.assert_array_equal(va, vb, err_msg=name)


def test_round_trip_every_field(tmp_path, full_cloud):
    path = save_cloud(full_cloud, tmp_path / "scan.npz")
    back = load_cloud(path)
    _assert_same_cloud(full_cloud, back)
    assert back.intensity.dtype == np.uint16
    g, h = full_cloud.geometry, back.geometry
    assert isinstance(h, NoddingGeometry)
    np.testing.assert_array_equal(g.beam_angles, h.beam_angles)
    np.testing.assert_array_equal(g.tilt_angles, h.tilt_angles)
    np.testing.assert_array_equal(g.mount_offset, h.mount_offset)
    assert h.tilt_sign == -1.0


def test_round_trip_pinhole_and_method_api(tmp_path, pinhole_cloud):
    pinhole_cloud.save(tmp_path / "frame.npz")
    back = OrganizedCloud.load(tmp_path / "frame.npz")
    _assert_same_cloud(pinhole_cloud, back)
    assert back.geometry == PinholeGeometry(525.0, 526.0, 3.5, 2.5)
    assert back.n_valid == 6 * 8 - 3


def test_round_trip_bare_cloud_compressed(tmp_path, random_xyz):
    cloud = OrganizedCloud(random_xyz(3, 2, nan_pixels=((2, 1),)))
    save_npz(cloud, tmp_path / "bare.npz", compress=True)
    back = load_npz(tmp_path / "bare.npz")
    _assert_same_cloud(cloud, back)
    assert back.geometry is None


def test_file_has_version_key(tmp_path, full_cloud):
    save_cloud(full_cloud, tmp_path / "s.npz")
    with np.load(tmp_path / "s.npz") as data:
        assert int(data["format_version"]) == NPZ_FORMAT_VERSION


def test_plain_savez_with_xyz_is_accepted(tmp_path, random_xyz):
    np.savez(tmp_path / "plain.npz", xyz=random_xyz(2, 2, nan_pixels=()))
    assert load_cloud(tmp_path / "plain.npz").shape == (2, 2)


@pytest.mark.parametrize(
    "arrays, message",
    [
        ({"points": np.zeros((3, 3))}, "has no 'xyz' array"),
        ({"xyz": np.zeros((1000, 3))}, r"xyz must have shape \(H, W, 3\); got \(1000, 3\)"),
        ({"xyz": np.zeros((2, 3, 3)), "ranges": np.zeros((3, 2))}, "ranges must have shape"),
        ({"xyz": np.zeros((2, 3, 3)), "timestamps": np.zeros(5)}, "timestamps must have shape"),
        ({"xyz": np.zeros((2, 3, 3)), "format_version": np.asarray(99)}, "format_version 99"),
        ({"xyz": np.zeros((2, 3, 3)), "geometry_kind": np.asarray("fisheye")}, "geometry_kind"),
        ({"xyz": np.zeros((2, 3, 3)), "geometry_kind": np.asarray("pinhole"), "fx": np.asarray(1.0)},
         "needs key 'fy'"),
        ({"xyz": np.zeros((2, 3, 3)), "geometry_kind": np.asarray("nodding"),
          "beam_angles": np.zeros(2), "tilt_angles": np.zeros(2), "mount_offset": np.zeros(3),
          "tilt_sign": np.asarray(1.0)}, "geometry describes"),
    ],
)
def test_malformed_files_raise(tmp_path, arrays, message):
    path = tmp_path / "bad.npz"
    np.savez(path, **arrays)
    with pytest.raises(ValueError, match=message):
        load_cloud(path)


def test_not_a_zip_and_missing_file(tmp_path):
    (tmp_path / "junk.npz").write_bytes(b"not a zip file at all")
    with pytest.raises(ValueError, match="not a readable .npz"):
        load_cloud(tmp_path / "junk.npz")
    with pytest.raises(FileNotFoundError):
        load_cloud(tmp_path / "absent.npz")


def test_unknown_suffix_and_wrong_object(tmp_path, full_cloud):
    with pytest.raises(ValueError, match="suffix must be one of"):
        save_cloud(full_cloud, tmp_path / "scan.ply")
    with pytest.raises(TypeError, match="OrganizedCloud"):
        save_npz(np.zeros((2, 2, 3)), tmp_path / "x.npz")
    assert list(tmp_path.iterdir()) == []
