"""Every input path, on files the tests make: depth PNG, RGB-D, KITTI .bin, E57, ROS bags."""

import json

import numpy as np
import pytest

from rangeseg_o3d import OrganizedCloud
from rangeseg_o3d.io.readers import (
    from_rgbd,
    load_depth_png,
    load_input,
    project_spinning,
    read_intrinsics,
)

INTRINSICS = (525.0, 525.0, 319.5, 239.5)


@pytest.fixture(scope="module")
def depth_frame():
    from rangeseg_o3d.synthetic.depth_camera import simulate_depth_camera
    from rangeseg_o3d.synthetic.suite import rgbd_scenes

    cloud = simulate_depth_camera(rgbd_scenes()[1][1], seed=0).cloud
    depth_mm = np.nan_to_num(np.round(cloud.xyz[..., 2] * 1000)).astype(np.uint16)
    colour = np.zeros(depth_mm.shape + (3,), np.uint8)
    colour[..., 0] = np.arange(depth_mm.shape[1]) % 256
    colour[..., 1] = (np.arange(depth_mm.shape[0]) % 256)[:, None]
    return depth_mm, colour, cloud.geometry


def _write_png(path, image):
    import cv2

    assert cv2.imwrite(str(path), image)
    return path


# -- depth PNG -----------------------------------------------------------------------

def test_depth_png_with_numbers_or_open3d_json(tmp_path, depth_frame):
    import open3d as o3d

    depth_mm, _, geometry = depth_frame
    path = _write_png(tmp_path / "depth.png", depth_mm)
    intrinsics = (geometry.fx, geometry.fy, geometry.cx, geometry.cy)
    cloud = load_depth_png(path, intrinsics, depth_scale=0.001)
    expected = OrganizedCloud.from_depth(depth_mm, *intrinsics, depth_scale=0.001)
    np.testing.assert_array_equal(cloud.xyz, expected.xyz)
    camera = o3d.camera.PinholeCameraIntrinsic(640, 480, *intrinsics)
    o3d.io.write_pinhole_camera_intrinsic(str(tmp_path / "camera.json"), camera)
    assert read_intrinsics(tmp_path / "camera.json") == pytest.approx(intrinsics)
    assert read_intrinsics(camera) == pytest.approx(intrinsics)
    from_json = load_input(path, intrinsics=tmp_path / "camera.json")
    np.testing.assert_array_equal(from_json.xyz, expected.xyz)


@pytest.mark.parametrize("kwargs, message", [
    ({}, "needs the camera's intrinsics"),
    ({"intrinsics": (0, 1, 2, 3)}, "fx, fy > 0"),
    ({"intrinsics": (1, 2, 3)}, "fx fy cx cy"),
    ({"intrinsics": INTRINSICS, "depth_scale": 1000}, "Open3D's depth_scale .its inverse.: use 0.001"),
    ({"intrinsics": INTRINSICS, "depth_scale": float("nan")}, "finite number > 0"),
])
def test_depth_png_bad_options(tmp_path, depth_frame, kwargs, message):
    path = _write_png(tmp_path / "depth.png", depth_frame[0])
    with pytest.raises(ValueError, match=message):
        load_input(path, **kwargs)


def test_eight_bit_png_is_no_depth_image(tmp_path):
    path = _write_png(tmp_path / "photo.png", np.zeros((4, 4), np.uint8))
    with pytest.raises(ValueError, match="8-bit image is no depth image"):
        load_input(path, intrinsics=INTRINSICS)


def test_bad_intrinsics_json(tmp_path):
    (tmp_path / "c.json").write_text(json.dumps({"width": 4}))
    with pytest.raises(ValueError, match="intrinsic_matrix"):
        read_intrinsics(tmp_path / "c.json")


def test_cli_segments_a_depth_png(tmp_path, depth_frame):
    from rangeseg_o3d.cli import main

    path = _write_png(tmp_path / "depth.png", depth_frame[0])
    g = depth_frame[2]
    out = tmp_path / "r.json"
    code = main(["segment", str(path), "--config", "rgbd_vga", "--intrinsics", str(g.fx), str(g.fy),
                 str(g.cx), str(g.cy), "--depth-scale", "0.001", "--out", str(out)])
    assert code == 0
    assert json.loads(out.read_text())["counts"]["plane"] >= 3


# -- Open3D RGB-D --------------------------------------------------------------------

def test_rgbd_legacy_and_tensor_keep_colour(depth_frame):
    import open3d as o3d

    depth_mm, colour, geometry = depth_frame
    intrinsics = (geometry.fx, geometry.fy, geometry.cx, geometry.cy)
    expected = OrganizedCloud.from_depth(depth_mm, *intrinsics, depth_scale=0.001)
    legacy = o3d.geometry.RGBDImage.create_from_color_and_depth(
        o3d.geometry.Image(colour), o3d.geometry.Image(depth_mm), depth_scale=1000.0,
        depth_trunc=1000.0, convert_rgb_to_intensity=False)
    tensor = o3d.t.geometry.RGBDImage(o3d.t.geometry.Image(colour), o3d.t.geometry.Image(depth_mm))
    for rgbd in (legacy, tensor):
        cloud = from_rgbd(rgbd, o3d.camera.PinholeCameraIntrinsic(640, 480, *intrinsics))
        np.testing.assert_allclose(cloud.xyz, expected.xyz, rtol=1e-6, equal_nan=True)  # legacy: float32 metres
        np.testing.assert_array_equal(cloud.colors, colour)
    with pytest.raises(TypeError, match="RGBDImage"):
        from_rgbd(depth_mm, intrinsics)


# -- KITTI-style .bin ------------------------------------------------------------------

def _lidar_sweep(rows=64, cols=2048):
    """A ground plane 1.73 m below and a wall 8 m ahead, seen by a 64-beam spinning lidar."""
    elevation = np.radians(np.linspace(2.0, -24.9, rows, endpoint=False) - 26.9 / rows / 2)
    azimuth = np.radians(180 - 360 * (np.arange(cols) + 0.5) / cols)
    el, az = np.meshgrid(elevation, azimuth, indexing="ij")
    rays = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        to_ground = np.where(rays[..., 2] < 0, -1.73 / rays[..., 2], np.inf)
        to_wall = np.where(rays[..., 0] > 0, 8.0 / rays[..., 0], np.inf)
    r = np.minimum(np.minimum(to_ground, to_wall), 80.0)
    hit = r < 80.0
    return (rays * r[..., None])[hit], hit


def test_kitti_bin_becomes_a_range_image(tmp_path):
    points, hit = _lidar_sweep()
    table = np.column_stack([points, np.full(len(points), 0.5)]).astype("<f4")
    rng = np.random.default_rng(0)
    table = table[rng.permutation(len(table))]  # a sweep's order is not the grid's
    table.tofile(tmp_path / "000000.bin")
    cloud = load_input(tmp_path / "000000.bin")
    assert cloud.shape == (64, 2048)
    # every beam lands in its own pixel: the grid is the sweep's
    np.testing.assert_array_equal(cloud.valid, hit)
    assert np.nanmax(np.abs(cloud.xyz[..., 2][cloud.xyz[..., 0] < 7.99] + 1.73)) < 1e-4  # the ground
    np.testing.assert_allclose(cloud.intensity[cloud.valid], 0.5)
    assert cloud.geometry.full_turn  # 360 degrees of columns: the first and last are neighbours
    # the pixel-centre directions of the geometry are those the sweep was cast along
    directions = cloud.geometry.directions()
    np.testing.assert_allclose(directions[cloud.valid], cloud.xyz[cloud.valid] / cloud.ranges[cloud.valid][:, None],
                               atol=1e-5)


def test_kitti_sweep_segments_with_the_spinning_preset(tmp_path):
    from rangeseg_o3d import Pipeline

    points, _ = _lidar_sweep()
    np.column_stack([points, np.zeros(len(points))]).astype("<f4").tofile(tmp_path / "s.bin")
    result = Pipeline("spinning_lidar").run(load_input(tmp_path / "s.bin"))
    planes = [f for f in result.features if f.kind == "plane"]
    normals = np.abs([p.normal for p in planes if p.n_pixels > 500])
    assert (normals[:, 2] > 0.99).any() and (normals[:, 0] > 0.99).any()  # ground and wall


def test_projection_keeps_the_nearest_point_of_a_pixel():
    cloud = project_spinning(np.array([[10.0, 0, 0], [5.0, 0, 0], [7.0, 0, 0]]), rows=4, cols=8,
                             elevation_range=(-10, 10))
    assert cloud.n_valid == 1 and cloud.xyz[cloud.valid][0, 0] == 5.0


def test_kitti_bin_of_wrong_size(tmp_path):
    (tmp_path / "x.bin").write_bytes(b"\0" * 20)
    with pytest.raises(ValueError, match="not a multiple of 16"):
        load_input(tmp_path / "x.bin")


# -- E57 ----------------------------------------------------------------------------------

def test_structured_e57_gives_grid_and_pose(tmp_path):
    pye57 = pytest.importorskip("pye57")
    h, w = 20, 30
    rows, cols = np.mgrid[0:h, 0:w]
    xyz = np.stack([cols * 0.1, rows * 0.1, np.full((h, w), 3.0)], axis=-1).reshape(-1, 3)
    invalid = np.zeros(h * w, np.int8)
    invalid[[5, 77]] = 1
    angle = np.radians(30)
    quaternion = np.array([np.cos(angle / 2), 0, 0, np.sin(angle / 2)])  # 30 deg about z
    e57 = pye57.E57(str(tmp_path / "scan.e57"), mode="w")
    e57.write_scan_raw({"cartesianX": xyz[:, 0], "cartesianY": xyz[:, 1], "cartesianZ": xyz[:, 2],
                        "rowIndex": rows.ravel().astype(np.int32), "columnIndex": cols.ravel().astype(np.int32),
                        "cartesianInvalidState": invalid, "intensity": np.linspace(0, 1, h * w)},
                       rotation=quaternion, translation=np.array([1.0, 2.0, 0.5]))
    e57.close()
    cloud = load_input(tmp_path / "scan.e57")
    assert cloud.shape == (h, w) and cloud.n_valid == h * w - 2
    assert not cloud.valid.ravel()[5] and not cloud.valid.ravel()[77]
    np.testing.assert_allclose(cloud.xyz.reshape(-1, 3)[invalid == 0], xyz[invalid == 0])
    np.testing.assert_allclose(cloud.pose[:3, 3], [1.0, 2.0, 0.5])
    np.testing.assert_allclose(cloud.pose[:2, :2], [[np.cos(angle), -np.sin(angle)],
                                                    [np.sin(angle), np.cos(angle)]], atol=1e-12)


def test_unstructured_e57_is_refused(tmp_path):
    pye57 = pytest.importorskip("pye57")
    e57 = pye57.E57(str(tmp_path / "flat.e57"), mode="w")
    e57.write_scan_raw({k: np.arange(5.0) for k in ("cartesianX", "cartesianY", "cartesianZ")})
    e57.close()
    with pytest.raises(ValueError, match="not structured"):
        load_input(tmp_path / "flat.e57")


def test_garbage_e57(tmp_path):
    pytest.importorskip("pye57")
    (tmp_path / "bad.e57").write_bytes(b"not an e57 file at all" * 10)
    with pytest.raises(ValueError, match="not a readable E57"):
        load_input(tmp_path / "bad.e57")


# -- ROS bags ---------------------------------------------------------------------------

@pytest.fixture(scope="module")
def typestore():
    pytest.importorskip("rosbags")
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


def _header(ts, seconds, frame="laser"):
    Time = ts.types["builtin_interfaces/msg/Time"]
    Header = ts.types["std_msgs/msg/Header"]
    return Header(stamp=Time(sec=int(seconds), nanosec=int(round((seconds % 1) * 1e9))), frame_id=frame)


def _pointcloud2(ts, xyz, rgb):
    PointField = ts.types["sensor_msgs/msg/PointField"]
    PointCloud2 = ts.types["sensor_msgs/msg/PointCloud2"]
    h, w = xyz.shape[:2]
    record = np.zeros((h, w), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("pad", "<f4"), ("rgb", "<u4")])
    record["x"], record["y"], record["z"] = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    record["rgb"] = (rgb[..., 0].astype(np.uint32) << 16) | (rgb[..., 1].astype(np.uint32) << 8) | rgb[..., 2]
    fields = [PointField(name=n, offset=o, datatype=d, count=1)
              for n, o, d in (("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("rgb", 16, 6))]
    return PointCloud2(header=_header(ts, 1.0), height=h, width=w, fields=fields, is_bigendian=False,
                       point_step=20, row_step=20 * w, data=np.frombuffer(record.tobytes(), np.uint8),
                       is_dense=False)


@pytest.mark.parametrize("ros", [1, 2])
def test_organized_pointcloud2_from_a_bag(tmp_path, typestore, ros):
    ts = typestore
    rng = np.random.default_rng(0)
    xyz = rng.normal(size=(6, 8, 3)).astype(np.float32)
    xyz[2, 3] = np.nan
    rgb = rng.integers(0, 256, (6, 8, 3)).astype(np.uint8)
    msg = _pointcloud2(ts, xyz, rgb)
    if ros == 1:
        from rosbags.rosbag1 import Writer

        path = tmp_path / "cloud.bag"
        with Writer(path) as writer:
            conn = writer.add_connection("/camera/points", "sensor_msgs/msg/PointCloud2", typestore=ts)
            writer.write(conn, 1_000_000_000, ts.serialize_ros1(msg, "sensor_msgs/msg/PointCloud2"))
    else:
        from rosbags.rosbag2 import Writer

        path = tmp_path / "cloud_bag"
        with Writer(path, version=8) as writer:
            conn = writer.add_connection("/camera/points", "sensor_msgs/msg/PointCloud2", typestore=ts)
            writer.write(conn, 1_000_000_000, ts.serialize_cdr(msg, "sensor_msgs/msg/PointCloud2"))
    cloud = load_input(path)
    assert cloud.shape == (6, 8) and cloud.n_valid == 47
    np.testing.assert_array_equal(cloud.xyz[cloud.valid], xyz[cloud.valid].astype(float))
    np.testing.assert_array_equal(cloud.colors, rgb)


def test_nodding_laserscan_and_jointstate_bag(tmp_path, typestore):
    """A tilting rig: LaserScan rows, tilt from JointState; the floor 1 m below comes out flat."""
    from rosbags.rosbag2 import Writer

    ts = typestore
    LaserScan = ts.types["sensor_msgs/msg/LaserScan"]
    JointState = ts.types["sensor_msgs/msg/JointState"]
    angles = np.radians(np.arange(-60, 61, 2.0))  # ROS: 0 straight ahead, counter-clockwise
    tilts = np.radians(np.linspace(20, 60, 15))  # looking down at the floor
    path = tmp_path / "nod_bag"
    with Writer(path, version=8) as writer:
        scans = writer.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=ts)
        joints = writer.add_connection("/joint_states", "sensor_msgs/msg/JointState", typestore=ts)
        for k, tilt in enumerate(tilts):
            t = 1.0 + 0.1 * k
            # a ray (cos a, sin a) in the scan plane, tilted down by `tilt` about +y: z = -sin(tilt) cos(a)
            ranges = 1.0 / (np.sin(tilt) * np.cos(angles))
            msg = LaserScan(header=_header(ts, t), angle_min=float(angles[0]), angle_max=float(angles[-1]),
                            angle_increment=float(angles[1] - angles[0]), time_increment=0.0, scan_time=0.1,
                            range_min=0.05, range_max=30.0, ranges=ranges.astype(np.float32),
                            intensities=np.zeros(0, np.float32))
            writer.write(scans, int(t * 1e9), ts.serialize_cdr(msg, "sensor_msgs/msg/LaserScan"))
            for dt in (-0.05, 0.0):
                joint = JointState(header=_header(ts, t + dt), name=["wrist", "tilt"],
                                   position=np.array([0.0, tilt]), velocity=np.zeros(0),
                                   effort=np.zeros(0))
                writer.write(joints, int((t + dt) * 1e9), ts.serialize_cdr(joint, "sensor_msgs/msg/JointState"))
    cloud = load_input(path, joint="tilt")
    assert cloud.shape == (15, 61)
    np.testing.assert_allclose(cloud.xyz[..., 2], -1.0, atol=1e-5)  # the floor
    # ROS angle 0 is straight ahead: the middle column looks along +x
    middle = cloud.xyz[:, 30]
    assert np.all(middle[:, 0] > 0) and np.abs(middle[:, 1]).max() < 1e-6
    # positive ROS angles are to the left (+y)
    assert np.all(cloud.xyz[:, -1, 1] > 0)
    with pytest.raises(ValueError, match="names the joint 'elbow'"):
        load_input(path, joint="elbow")


def test_unorganized_pointcloud2_is_refused(typestore):
    from rangeseg_o3d.io.rosbag import pointcloud2_to_cloud

    msg = _pointcloud2(typestore, np.zeros((1, 5, 3), np.float32), np.zeros((1, 5, 3), np.uint8))
    with pytest.raises(ValueError, match="not organized"):
        pointcloud2_to_cloud(msg)


def test_unknown_suffix_names_the_known_ones(tmp_path):
    (tmp_path / "scan.xyz").write_text("1 2 3\n")
    with pytest.raises(ValueError, match=r"must be one of .npz, .pcd"):
        load_input(tmp_path / "scan.xyz")
