import numpy as np
import pytest

from rangeseg_o3d import OrganizedCloud
from rangeseg_o3d.io.open3d_conv import from_open3d, to_open3d

o3d = pytest.importorskip("open3d")


@pytest.fixture
def cloud(random_xyz):
    # Last row and last column entirely invalid: the grid must still come back whole.
    xyz = random_xyz(5, 6, nan_pixels=((1, 1), (2, 4)))
    xyz[4, :] = np.nan
    xyz[:, 5] = np.nan
    return OrganizedCloud(xyz, intensity=np.arange(30.0).reshape(5, 6))


def test_tensor_round_trip_keeps_grid(cloud):
    pcd = cloud.to_open3d()
    assert isinstance(pcd, o3d.t.geometry.PointCloud)
    assert pcd.point.positions.shape == (cloud.n_valid, 3)
    assert pcd.point.positions.dtype == o3d.core.float64
    assert pcd.point["row"].dtype == o3d.core.int32 and pcd.point["row"].shape == (cloud.n_valid, 1)
    back = OrganizedCloud.from_open3d(pcd)
    assert back.shape == (5, 6)
    np.testing.assert_array_equal(back.xyz, cloud.xyz)
    np.testing.assert_array_equal(back.intensity[cloud.valid], cloud.intensity[cloud.valid])
    assert np.isnan(back.intensity[~cloud.valid]).all()


def test_row_col_index_the_points(cloud):
    pcd = to_open3d(cloud, dtype="float32")
    rows = pcd.point["row"].numpy()[:, 0]
    cols = pcd.point["col"].numpy()[:, 0]
    np.testing.assert_allclose(pcd.point.positions.numpy(), cloud.xyz[rows, cols], rtol=1e-6)
    assert pcd.point.positions.dtype == o3d.core.float32


def test_shape_inferred_from_row_col_without_grid_shape(cloud):
    pcd = to_open3d(cloud)
    del pcd.point["grid_shape"]
    assert from_open3d(pcd).shape == (4, 5)  # max row/col + 1
    assert from_open3d(pcd, shape=(5, 6)).shape == (5, 6)


def test_subset_after_open3d_operation_keeps_pixels(cloud):
    pcd = to_open3d(cloud)
    keep = o3d.core.Tensor(np.arange(0, cloud.n_valid, 2))
    subset = pcd.select_by_index(keep)
    back = from_open3d(subset)
    assert back.shape == cloud.shape and back.n_valid == len(range(0, cloud.n_valid, 2))
    np.testing.assert_array_equal(back.xyz[back.valid], cloud.xyz[back.valid])


def test_legacy_and_back(cloud):
    legacy = cloud.to_legacy()
    assert isinstance(legacy, o3d.geometry.PointCloud)
    np.testing.assert_array_equal(np.asarray(legacy.points), cloud.xyz[cloud.valid])
    full = OrganizedCloud(np.nan_to_num(cloud.xyz))
    back = from_open3d(full.to_legacy(), shape=full.shape)
    np.testing.assert_array_equal(back.xyz, full.xyz)


def test_empty_cloud(random_xyz):
    empty = OrganizedCloud(np.full((2, 3, 3), np.nan))
    pcd = to_open3d(empty)
    assert pcd.point.positions.shape == (0, 3)
    assert from_open3d(pcd, shape=(2, 3)).n_valid == 0
    with pytest.raises(ValueError, match="pass shape"):
        from_open3d(o3d.t.geometry.PointCloud())


def test_bad_inputs(cloud):
    with pytest.raises(TypeError, match="open3d.t.geometry.PointCloud"):
        from_open3d(np.zeros((3, 3)))
    with pytest.raises(TypeError, match="OrganizedCloud"):
        to_open3d(np.zeros((2, 2, 3)))
    with pytest.raises(ValueError, match="dtype"):
        to_open3d(cloud, dtype="float16")
    pcd = to_open3d(cloud)
    with pytest.raises(ValueError, match="outside the 2x2 grid"):
        from_open3d(pcd, shape=(2, 2))
    with pytest.raises(ValueError, match="pass shape"):
        from_open3d(cloud.to_legacy())
    with pytest.raises(ValueError, match="needs 30"):
        from_open3d(cloud.to_legacy(), shape=(5, 6))
    pcd.point["row"] = o3d.core.Tensor(np.zeros((cloud.n_valid, 1), np.int32))
    pcd.point["col"] = o3d.core.Tensor(np.zeros((cloud.n_valid, 1), np.int32))
    with pytest.raises(ValueError, match="same"):
        from_open3d(pcd)


def test_written_pcd_is_read_by_open3d(tmp_path, cloud):
    """Interoperability: Open3D reads our organized PCD with every point in place."""
    cloud.save(tmp_path / "scan.pcd")
    pcd = o3d.t.io.read_point_cloud(str(tmp_path / "scan.pcd"), remove_nan_points=False)
    assert pcd.point.positions.shape == (30, 3)
    valid = cloud.valid.ravel()
    np.testing.assert_allclose(pcd.point.positions.numpy()[valid], cloud.xyz.reshape(-1, 3)[valid],
                               rtol=1e-6)


@pytest.mark.parametrize("sensor", ["lms200", "depth_camera"])
@pytest.mark.parametrize("reader", ["tensor", "legacy"])
def test_open3d_read_organized_pcd_gets_its_grid_back(tmp_path, sensor, reader):
    # Open3D drops HEIGHT when it reads an organized PCD; the grid is recovered from the points.
    from rangeseg_o3d.synthetic.suite import default_scene, rgbd_scenes

    if sensor == "lms200":
        from rangeseg_o3d.synthetic.lms200 import simulate_lms200

        cloud = simulate_lms200(default_scene(), seed=0).cloud
    else:
        from rangeseg_o3d.synthetic.depth_camera import simulate_depth_camera

        cloud = simulate_depth_camera(rgbd_scenes()[1][1], seed=0).cloud
    path = cloud.save(tmp_path / "scan.pcd")
    pcd = (o3d.t.io.read_point_cloud(str(path)) if reader == "tensor"
           else o3d.io.read_point_cloud(str(path)))
    back = OrganizedCloud.from_open3d(pcd)
    assert back.shape == cloud.shape
    np.testing.assert_array_equal(back.valid, cloud.valid)
    np.testing.assert_allclose(back.xyz[back.valid], cloud.xyz[cloud.valid], atol=1e-5)


def test_filtered_cloud_cannot_pass_for_a_grid(tmp_path):
    from rangeseg_o3d.synthetic.lms200 import simulate_lms200
    from rangeseg_o3d.synthetic.suite import default_scene

    xyz = simulate_lms200(default_scene(), seed=0).cloud.xyz.copy()
    xyz[::7, ::5] = np.nan  # a few missing returns, which remove_nan_points drops
    cloud = OrganizedCloud(xyz)
    pcd = o3d.io.read_point_cloud(str(cloud.save(tmp_path / "scan.pcd")), remove_nan_points=True)
    assert len(pcd.points) < cloud.shape[0] * cloud.shape[1]
    with pytest.raises(ValueError, match="remove_nan_points=False|pass shape"):
        OrganizedCloud.from_open3d(pcd)


def test_colours_and_extras_survive_open3d(cloud):
    colors = np.arange(90, dtype=np.uint8).reshape(5, 6, 3)
    rich = OrganizedCloud(cloud.xyz, colors=colors, extras={"curvature": np.linspace(0, 1, 30).reshape(5, 6)})
    pcd = to_open3d(rich)
    assert pcd.point.colors.numpy().dtype == np.float32
    back = from_open3d(pcd)
    np.testing.assert_array_equal(back.colors[back.valid], colors[rich.valid])
    np.testing.assert_allclose(back.extras["curvature"][back.valid], rich.extras["curvature"][rich.valid])


def test_open3d_read_pcd_keeps_colour(shared_file):
    path = shared_file("pcl/table_scene_mug_stereo_textured.pcd")
    ours = OrganizedCloud.load(path)
    theirs = OrganizedCloud.from_open3d(o3d.t.io.read_point_cloud(str(path)))
    np.testing.assert_array_equal(theirs.colors[theirs.valid], ours.colors[ours.valid])
