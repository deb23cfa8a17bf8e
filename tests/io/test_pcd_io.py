import struct

import numpy as np
import pytest

from rangeseg_o3d import OrganizedCloud
from rangeseg_o3d.io import load_cloud, read_pcd, write_pcd
from rangeseg_o3d.io.lzf import lzf_compress
from rangeseg_o3d.io.pcd import parse_pcd_header, read_pcd_fields


def _header(fields="x y z", size="4 4 4", type_="F F F", count="1 1 1", width=3, height=2,
            points=None, data="binary", version="0.7", extra=""):
    points = width * height if points is None else points
    return (
        f"# .PCD v{version} - Point Cloud Data file format\nVERSION {version}\nFIELDS {fields}\n"
        f"SIZE {size}\nTYPE {type_}\nCOUNT {count}\nWIDTH {width}\nHEIGHT {height}\n{extra}"
        f"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {points}\nDATA {data}\n"
    ).encode()


def _grid(h=2, w=3):
    xyz = np.arange(h * w * 3, dtype=np.float32).reshape(h, w, 3) / 4
    xyz[0, 1] = np.nan
    return xyz


def _compressed_payload(columns: list[np.ndarray]) -> bytes:
    raw = b"".join(np.ascontiguousarray(c).tobytes() for c in columns)
    packed = lzf_compress(raw)
    return struct.pack("<II", len(packed), len(raw)) + packed


# -- round trips ---------------------------------------------------------------------

@pytest.mark.parametrize("data", ["binary", "binary_compressed", "ascii"])
def test_round_trip_organized_with_nan(tmp_path, random_xyz, data):
    xyz = random_xyz(5, 7, nan_pixels=((0, 0), (4, 6), (2, 2))).astype(np.float32)
    cloud = OrganizedCloud(xyz, intensity=np.arange(35, dtype=np.float32).reshape(5, 7))
    path = write_pcd(cloud, tmp_path / "scan.pcd", data=data)
    back = read_pcd(path)
    assert back.shape == (5, 7)
    assert back.n_valid == 35 - 3
    np.testing.assert_array_equal(back.xyz, cloud.xyz)  # float32 values survive exactly
    np.testing.assert_array_equal(back.intensity, cloud.intensity)
    header, _ = read_pcd_fields(path)
    assert (header.width, header.height, header.points) == (7, 5, 35)


def test_round_trip_float64_through_save_load(tmp_path, random_xyz):
    cloud = OrganizedCloud(random_xyz(3, 4))
    cloud.save(tmp_path / "a.pcd")  # default: float32
    np.testing.assert_allclose(OrganizedCloud.load(tmp_path / "a.pcd").xyz, cloud.xyz, rtol=1e-6)
    write_pcd(cloud, tmp_path / "b.pcd", precision="float64")
    np.testing.assert_array_equal(load_cloud(tmp_path / "b.pcd").xyz, cloud.xyz)


def test_writer_rejects_bad_options(tmp_path, random_xyz):
    cloud = OrganizedCloud(random_xyz(2, 2, nan_pixels=()))
    with pytest.raises(ValueError, match="data must be"):
        write_pcd(cloud, tmp_path / "x.pcd", data="binary_lzma")
    with pytest.raises(ValueError, match="precision"):
        write_pcd(cloud, tmp_path / "x.pcd", precision="float16")
    assert not (tmp_path / "x.pcd").exists()


# -- reading the three layouts ------------------------------------------------------

def test_binary_compressed_field_major_with_extras(tmp_path):
    """x y z rgba normal_x(COUNT 3, float64) intensity(uint16): only xyz + intensity kept."""
    xyz = _grid()
    n = xyz.shape[0] * xyz.shape[1]
    flat = xyz.reshape(n, 3)
    rgba = np.arange(n, dtype=np.uint32)
    normals = np.ones((n, 3), dtype=np.float64)
    intensity = np.arange(n, dtype=np.uint16) * 10
    header = _header("x y z rgba normal intensity", "4 4 4 4 8 2", "F F F U F U", "1 1 1 1 3 1",
                     data="binary_compressed")
    payload = _compressed_payload([flat[:, 0], flat[:, 1], flat[:, 2], rgba, normals, intensity])
    (tmp_path / "c.pcd").write_bytes(header + payload)
    cloud = read_pcd(tmp_path / "c.pcd")
    np.testing.assert_array_equal(cloud.xyz, xyz.astype(np.float64))
    np.testing.assert_array_equal(cloud.intensity, intensity.reshape(2, 3))
    _, fields = read_pcd_fields(tmp_path / "c.pcd")
    np.testing.assert_array_equal(fields["normal"], normals)
    np.testing.assert_array_equal(fields["rgba"], rgba)


def test_binary_interleaved_with_padding_and_mixed_types(tmp_path):
    n = 6
    record = np.dtype([("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("_", "u1", (3,)), ("_1", "<i2")])
    table = np.zeros(n, dtype=record)
    table["x"], table["y"], table["z"] = np.arange(n), -np.arange(n), 2.0
    table["z"][5] = np.inf  # non-finite coordinate = invalid pixel
    header = _header("x y z _ _", "8 8 8 1 2", "F F F U I", "1 1 1 3 1", width=6, height=1,
                     version=".7")
    (tmp_path / "b.pcd").write_bytes(header + table.tobytes())
    cloud = read_pcd(tmp_path / "b.pcd")
    assert cloud.shape == (1, 6)  # unorganized -> one row
    assert cloud.n_valid == 5
    np.testing.assert_array_equal(cloud.xyz[0, :5, 0], np.arange(5))
    assert np.isnan(cloud.xyz[0, 5]).all()


def test_ascii_v06_without_count_and_with_nan(tmp_path):
    header = (b"VERSION .6\nFIELDS x y z intensity\nSIZE 4 4 4 4\nTYPE F F F F\nWIDTH 2\n"
              b"HEIGHT 2\nPOINTS 4\nDATA ascii\n")
    body = b"0 0 1 5\nnan nan nan 0\n1 2 3 7\n  4 5 6 8  \n"
    (tmp_path / "a.pcd").write_bytes(header + body)
    cloud = read_pcd(tmp_path / "a.pcd")
    assert cloud.shape == (2, 2) and cloud.n_valid == 3
    np.testing.assert_array_equal(cloud.intensity, [[5, 0], [7, 8]])
    np.testing.assert_array_equal(cloud.xyz[1, 1], [4, 5, 6])


# -- headers that lie and truncated data ---------------------------------------------

_GOOD_BINARY = _grid().tobytes()


@pytest.mark.parametrize(
    "content, message",
    [
        (_header(points=7) + _GOOD_BINARY, r"POINTS is 7 but WIDTH x HEIGHT is 3 x 2 = 6"),
        (_header() + _GOOD_BINARY[:-5], "data shorter than declared"),
        (_header(data="binary_lzma") + _GOOD_BINARY, "DATA must be one of"),
        (_header(fields="x y intensity") + _GOOD_BINARY, "must include x, y and z"),
        (_header(size="4 4") + _GOOD_BINARY, "SIZE has 2 entries but FIELDS has 3"),
        (_header(type_="F F Q") + _GOOD_BINARY, "TYPE Q with SIZE 4"),
        (_header(size="4 4 3") + _GOOD_BINARY, "TYPE F with SIZE 3"),
        (_header(count="1 1 2") + _GOOD_BINARY, "field z must have COUNT 1"),
        # float data labelled as integers, and genuinely integer coordinates: both refused
        (_header(type_="F I F") + _GOOD_BINARY, "field y must be a float .TYPE F.; got TYPE I4"),
        (_header(type_="U U U") + _GOOD_BINARY, "field x must be a float .TYPE F.; got TYPE U4"),
        (_header(type_="F F I", size="4 4 2") + _GOOD_BINARY[:-6], "field z must be a float"),
        (_header(width=0, height=1, points=0), "WIDTH and HEIGHT must be >= 1"),
        (_header(width="three"), "WIDTH must be integers"),
        (_header().replace(b"DATA binary\n", b""), "no DATA line|before a DATA line"),
        (_header(data="ascii") + b"1 2 3\n" * 5, "holds 15 values but 6 points x 3 values = 18"),
        (_header(data="ascii") + b"1 2 3\n" * 7, "more than the declared"),
        (_header(data="ascii") + b"1 2 x\n" * 6, "not a number"),
        (_header(data="binary_compressed") + b"\x01\x00", "no size words"),
        (_header(data="binary_compressed") + struct.pack("<II", 10, 72) + b"\x00" * 4,
         "declares 10 compressed bytes but only 4 follow"),
        (_header(data="binary_compressed") + struct.pack("<II", 4, 80) + b"\x00" * 4,
         "declares 80 decompressed bytes but 6 points x 12 bytes = 72"),
        (_header(data="binary_compressed") + _compressed_payload([_GOOD_BINARY[:-12]]),
         "declares 60 decompressed bytes"),
    ],
)
def test_lying_headers_raise(tmp_path, content, message):
    path = tmp_path / "bad.pcd"
    path.write_bytes(content)
    with pytest.raises(ValueError, match=message):
        read_pcd(path)


def test_corrupt_compressed_stream_raises(tmp_path):
    packed = lzf_compress(_GOOD_BINARY)[:-3]  # stream cut short, sizes say otherwise
    payload = struct.pack("<II", len(packed), len(_GOOD_BINARY)) + packed
    (tmp_path / "bad.pcd").write_bytes(_header(data="binary_compressed") + payload)
    with pytest.raises(ValueError, match="corrupt binary_compressed data"):
        read_pcd(tmp_path / "bad.pcd")


def test_header_parser_reports_offset():
    header = parse_pcd_header(_header() + b"rest")
    assert header.data_offset == len(_header())
    assert header.record_size == 12 and header.data == "binary"


# -- the shared PCL / PEAC files -----------------------------------------------------

@pytest.mark.parametrize(
    "name, shape, n_nan",
    [
        ("pcl/table_scene_mug_stereo_textured.pcd", (480, 640), 97920),
        ("pcl/milk_cartoon_all_small_clorox.pcd", (480, 640), 65793),
        ("pcl/office1.pcd", (480, 640), 52744),
        ("pcl/frame_20121214T142255.814212.pcd", (480, 640), 35625),
        ("pcl/sac_plane_test.pcd", (1, 3283), 0),
        ("peac/andreashaus_scan000.pcd", (633, 513), 13996),
    ],
)
def test_shared_pcd_files(shared_file, name, shape, n_nan):
    cloud = load_cloud(shared_file(name))
    assert cloud.shape == shape
    assert cloud.shape[0] * cloud.shape[1] - cloud.n_valid == n_nan
    # An invalid pixel is all-NaN; valid ones are finite.
    assert np.isfinite(cloud.xyz[cloud.valid]).all()


@pytest.mark.parametrize(
    "name, f, c",
    [("pcl/milk_cartoon_all_small_clorox.pcd", 525.0, (319.5, 239.5)),
     ("pcl/office1.pcd", 525.0, (320.0, 240.0))],
)
def test_shared_kinect_files_back_project_exactly(shared_file, name, f, c):
    """SOURCES.md: u = fx x / z + cx, v = fy y / z + cy; checks the row/column order."""
    cloud = load_cloud(shared_file(name))
    rows, cols = np.nonzero(cloud.valid)
    x, y, z = cloud.xyz[rows, cols].T
    assert np.abs(f * x / z + c[0] - cols).max() < 0.05
    assert np.abs(f * y / z + c[1] - rows).max() < 0.05


def test_shared_compressed_file_reads_as_open3d_reads_it(shared_file):
    # An independent decoder of the same binary_compressed file: Open3D's (liblzf in C++).
    import open3d as o3d

    path = shared_file("pcl/table_scene_mug_stereo_textured.pcd")
    ours = load_cloud(path)
    theirs = o3d.io.read_point_cloud(str(path), remove_nan_points=False, remove_infinite_points=False)
    points = np.asarray(theirs.points).reshape(ours.shape + (3,))
    assert np.array_equal(np.isnan(points[..., 2]), ~ours.valid)
    assert np.array_equal(points[ours.valid], ours.xyz[ours.valid])


def test_crlf_header_and_nan_spellings(tmp_path):
    header = (b"# comment\r\nVERSION 0.7\r\nFIELDS x y z\r\nSIZE 4 4 4\r\nTYPE F F F\r\nCOUNT 1 1 1\r\n"
              b"WIDTH 3\r\nHEIGHT 1\r\nPOINTS 3\r\nDATA ascii\r\n")
    (tmp_path / "w.pcd").write_bytes(header + b"-nan -nan -nan\r\n1 2 3\r\nNaN inf 1\r\n")
    cloud = read_pcd(tmp_path / "w.pcd")
    assert cloud.shape == (1, 3) and cloud.n_valid == 1
    np.testing.assert_array_equal(cloud.xyz[0, 1], [1, 2, 3])


# -- colour, other fields, VIEWPOINT (issue 15 item 5) ---------------------------------

def test_colour_and_extra_fields_are_kept(tmp_path):
    rgb = np.array([[255, 0, 0], [0, 128, 0], [1, 2, 3], [10, 20, 30], [200, 100, 50], [0, 0, 255]], np.uint32)
    packed = ((rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]).astype("<u4")
    records = np.zeros(6, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "<f4"),
                                 ("curvature", "<f4"), ("_", "<f4")])
    records["x"], records["z"] = np.arange(6), 2.0
    records["rgb"] = packed.view("<f4")  # PCL's packed float colour
    records["curvature"] = np.linspace(0, 1, 6)
    path = tmp_path / "c.pcd"
    path.write_bytes(_header(fields="x y z rgb curvature _", size="4 4 4 4 4 4", type_="F F F F F F",
                             count="1 1 1 1 1 1") + records.tobytes())
    cloud = read_pcd(path)
    np.testing.assert_array_equal(cloud.colors.reshape(-1, 3), rgb)
    assert set(cloud.extras) == {"curvature"}  # padding dropped
    np.testing.assert_allclose(cloud.extras["curvature"].ravel(), np.linspace(0, 1, 6), rtol=1e-6)
    # written back (as a uint rgb) and read again: the same colours; npz keeps everything
    back = read_pcd(write_pcd(cloud, tmp_path / "back.pcd"))
    np.testing.assert_array_equal(back.colors, cloud.colors)
    again = load_cloud(cloud.save(tmp_path / "c.npz"))
    np.testing.assert_array_equal(again.colors, cloud.colors)
    np.testing.assert_array_equal(again.extras["curvature"], cloud.extras["curvature"])


def test_viewpoint_becomes_the_pose(tmp_path):
    # OpenNI frames: a half turn about x (qw qx qy qz = 0 1 0 0), sensor 1 m up.
    path = tmp_path / "v.pcd"
    path.write_bytes(_header().replace(b"VIEWPOINT 0 0 0 1 0 0 0", b"VIEWPOINT 0 0 1 0 1 0 0")
                     + _GOOD_BINARY)
    cloud = read_pcd(path)
    expected = np.diag([1.0, -1.0, -1.0, 1.0])
    expected[2, 3] = 1.0
    np.testing.assert_allclose(cloud.pose, expected, atol=1e-12)
    np.testing.assert_array_equal(cloud.xyz, read_pcd_plain(_GOOD_BINARY))  # points stay in the sensor frame
    world = cloud.world_xyz()
    np.testing.assert_allclose(world[1, 2], [cloud.xyz[1, 2, 0], -cloud.xyz[1, 2, 1], 1 - cloud.xyz[1, 2, 2]])
    back = read_pcd(write_pcd(cloud, tmp_path / "back.pcd"))
    np.testing.assert_allclose(back.pose, cloud.pose, atol=1e-12)


def read_pcd_plain(payload):
    return np.frombuffer(payload, "<f4").reshape(2, 3, 3).astype(float)


def test_shared_office1_keeps_its_colours_and_viewpoint(shared_file):
    cloud = load_cloud(shared_file("pcl/office1.pcd"))
    assert cloud.colors is not None and cloud.colors[cloud.valid].std() > 10
    np.testing.assert_allclose(cloud.pose[:3, :3], np.diag([1.0, -1.0, -1.0]), atol=1e-12)
