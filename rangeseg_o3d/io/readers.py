"""Scans from the formats people have: depth images, Open3D RGB-D, KITTI-style lidar, E57, ROS bags.

:func:`load_input` picks the reader by suffix (the ``rangeseg segment`` inputs):

========================  ===================================================================
``.npz``, ``.pcd``        :meth:`OrganizedCloud.load` (``units`` applies)
``.3d``                   3DTK's scans (:func:`rangeseg_o3d.io.datasets.load_3dtk`)
``.png``                  a depth image, with ``intrinsics`` and ``depth_scale``
``.bin``                  KITTI-style float32 x y z reflectance, projected to a range image
``.e57``                  a structured E57 scan (``pip install rangeseg_o3d[e57]``)
``.bag``, ``.mcap``,      a ROS 1 bag or a ROS 2 bag folder / file: an organized PointCloud2,
ROS 2 bag folder          or LaserScan + JointState of a nodding rig (``[ros]`` extra)
========================  ===================================================================

Optional packages (pye57, rosbags) are imported inside their readers only.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..cloud import OrganizedCloud
from ..geometry import SphericalGeometry

__all__ = [
    "load_input",
    "read_intrinsics",
    "load_depth_png",
    "from_rgbd",
    "load_kitti_bin",
    "project_spinning",
    "load_e57",
    "INPUT_SUFFIXES",
]

INPUT_SUFFIXES = (".npz", ".pcd", ".3d", ".png", ".bin", ".e57", ".bag", ".mcap", ".db3")


def read_intrinsics(value) -> tuple[float, float, float, float]:
    """``(fx, fy, cx, cy)`` from four numbers, a 3x3 matrix, an Open3D PinholeCameraIntrinsic
    or the JSON file Open3D writes for one (``o3d.io.write_pinhole_camera_intrinsic``)."""
    if isinstance(value, (str, Path)):
        path = Path(value)
        if not path.is_file():
            raise FileNotFoundError(f"no such intrinsics file: {path}")
        try:
            data = json.loads(path.read_text())
            matrix = np.asarray(data["intrinsic_matrix"], dtype=float).reshape(3, 3).T  # column-major
        except (ValueError, KeyError, TypeError) as err:
            raise ValueError(f"{path}: expected Open3D's PinholeCameraIntrinsic JSON with an "
                             f"'intrinsic_matrix' of 9 numbers ({err})") from None
        return read_intrinsics(matrix)
    if hasattr(value, "intrinsic_matrix"):  # open3d.camera.PinholeCameraIntrinsic
        return read_intrinsics(np.asarray(value.intrinsic_matrix))
    if hasattr(value, "numpy"):  # an open3d.core.Tensor
        value = value.numpy()
    arr = np.asarray(value, dtype=float)
    if arr.shape == (3, 3):
        arr = np.array([arr[0, 0], arr[1, 1], arr[0, 2], arr[1, 2]])
    if arr.shape != (4,) or not np.isfinite(arr).all() or arr[0] <= 0 or arr[1] <= 0:
        raise ValueError(f"intrinsics must be fx fy cx cy (fx, fy > 0), a 3x3 camera matrix or "
                         f"Open3D's PinholeCameraIntrinsic; got {np.asarray(value).tolist()}")
    return tuple(float(v) for v in arr)


def _check_depth_scale(depth_scale: float) -> float:
    scale = float(depth_scale)
    if not np.isfinite(scale) or scale <= 0:
        raise ValueError(f"depth_scale must be a finite number > 0; got {depth_scale!r}")
    if scale > 1:
        raise ValueError(
            f"depth_scale multiplies the stored values into metres (0.001 for millimetres); got "
            f"{depth_scale}, which looks like Open3D's depth_scale (its inverse): use {1 / scale:g}")
    return scale


def load_depth_png(path, intrinsics, *, depth_scale: float = 0.001) -> OrganizedCloud:
    """A depth image (16-bit PNG, 0 = no return) with pinhole ``intrinsics`` as a cloud.

    ``depth * depth_scale`` must be metres (0.001 for millimetres, the Kinect/RealSense
    convention; Open3D states the inverse, 1000).
    """
    import cv2

    path = Path(path)
    fx, fy, cx, cy = read_intrinsics(intrinsics)
    depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if depth is None:
        raise ValueError(f"{path}: not an image OpenCV can read")
    if depth.ndim != 2:
        raise ValueError(f"{path}: a depth image has one channel; got shape {depth.shape}")
    if depth.dtype == np.uint8:
        raise ValueError(f"{path}: an 8-bit image is no depth image (expected 16-bit or float)")
    return OrganizedCloud.from_depth(depth, fx, fy, cx, cy, depth_scale=_check_depth_scale(depth_scale))


def from_rgbd(rgbd, intrinsics, *, depth_scale: float | None = None) -> OrganizedCloud:
    """A cloud with colours from an Open3D RGB-D image (legacy or tensor) and its intrinsics.

    A legacy ``open3d.geometry.RGBDImage`` holds depth in metres already (Open3D divided
    by its depth_scale when building it); a tensor ``open3d.t.geometry.RGBDImage`` holds
    the raw values, turned into metres by ``depth_scale`` (default 0.001). Colour images
    of floats in [0, 1] or uint8 are kept as ``cloud.colors`` (grey ones as grey RGB).
    """
    import open3d as o3d

    if isinstance(rgbd, o3d.geometry.RGBDImage):
        depth = np.asarray(rgbd.depth, dtype=np.float64)
        scale = 1.0 if depth_scale is None else _check_depth_scale(depth_scale)
        color = np.asarray(rgbd.color)
    elif isinstance(rgbd, o3d.t.geometry.RGBDImage):
        depth = rgbd.depth.as_tensor().numpy()[..., 0].astype(np.float64)
        scale = _check_depth_scale(0.001 if depth_scale is None else depth_scale)
        color = rgbd.color.as_tensor().numpy()
    else:
        raise TypeError(f"rgbd must be an open3d.geometry.RGBDImage or open3d.t.geometry.RGBDImage; "
                        f"got {type(rgbd).__name__}")
    fx, fy, cx, cy = read_intrinsics(intrinsics)
    cloud = OrganizedCloud.from_depth(depth, fx, fy, cx, cy, depth_scale=scale)
    if color.ndim == 3 and color.shape[2] == 1:
        color = color[..., 0]
    if color.ndim == 2:
        color = np.repeat(color[..., None], 3, axis=2)
    if color.shape[:2] != cloud.shape:
        raise ValueError(f"colour image is {color.shape[:2]} but depth is {cloud.shape}")
    if color.dtype != np.uint8:
        color = np.clip(np.asarray(color, dtype=float), 0.0, 1.0)
    return OrganizedCloud(cloud.xyz, ranges=cloud.ranges, geometry=cloud.geometry, colors=color[..., :3])


# -- spinning lidars ------------------------------------------------------------------

def project_spinning(points, *, rows: int = 64, cols: int = 2048,
                     elevation_range: tuple[float, float] = (-24.9, 2.0), intensity=None) -> OrganizedCloud:
    """An unordered spinning-lidar sweep (N, 3) projected to a (rows, cols) range image.

    Row ``i`` covers elevations from ``elevation_range[1]`` (top, degrees) down to
    ``elevation_range[0]``; column ``j`` the azimuth ``180 - 360 (j + 0.5) / cols`` degrees
    (column 0 behind on the left, the middle straight ahead along +x, clockwise seen from
    above as the sensor turns). A pixel hit by several points keeps the nearest; pixels no
    point falls in are NaN. The cloud carries the grid's :class:`SphericalGeometry` (the
    pixel-centre beam directions; points keep their measured angles) for the
    ``spinning_lidar`` preset and the viewer. The defaults are a Velodyne HDL-64E's (KITTI).
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] < 3:
        raise ValueError(f"points must have shape (N, 3) or (N, 4); got {pts.shape}")
    low, high = (float(v) for v in elevation_range)
    if not (rows >= 2 and cols >= 2 and high > low):
        raise ValueError(f"need rows, cols >= 2 and elevation_range low < high; got {rows}, {cols}, "
                         f"{elevation_range}")
    xyz = pts[:, :3]
    ranges = np.linalg.norm(xyz, axis=1)
    keep = np.isfinite(ranges) & (ranges > 0)
    xyz, ranges = xyz[keep], ranges[keep]
    elevation = np.degrees(np.arcsin(xyz[:, 2] / ranges))
    azimuth = np.degrees(np.arctan2(xyz[:, 1], xyz[:, 0]))
    row = np.floor((high - elevation) / (high - low) * rows).astype(np.int64)
    col = np.floor((180.0 - azimuth) / 360.0 * cols).astype(np.int64) % cols
    inside = (row >= 0) & (row < rows)
    flat = row[inside] * cols + col[inside]
    order = np.lexsort((ranges[inside], flat))  # by pixel, nearest first
    first = np.ones(len(order), bool)
    first[1:] = flat[order][1:] != flat[order][:-1]
    chosen = np.flatnonzero(inside)[order[first]]
    grid = np.full((rows * cols, 3), np.nan)
    grid[flat[order[first]]] = xyz[chosen]
    ranges_grid = np.full(rows * cols, np.nan)
    ranges_grid[flat[order[first]]] = ranges[chosen]
    # The grid's beam directions (pixel centres): the measured points keep their own angles.
    geometry = SphericalGeometry(
        elevations=np.radians(high - (np.arange(rows) + 0.5) * (high - low) / rows),
        azimuths=np.radians(180.0 - 360.0 * (np.arange(cols) + 0.5) / cols))
    grid_intensity = None
    if intensity is not None:
        values = np.asarray(intensity, dtype=float)[keep]
        grid_intensity = np.full(rows * cols, np.nan)
        grid_intensity[flat[order[first]]] = values[chosen]
        grid_intensity = grid_intensity.reshape(rows, cols)
    return OrganizedCloud(grid.reshape(rows, cols, 3), ranges=ranges_grid.reshape(rows, cols),
                          intensity=grid_intensity, geometry=geometry)


def load_kitti_bin(path, **projection) -> OrganizedCloud:
    """A KITTI-style ``.bin`` sweep (float32 x y z reflectance per point) as a range image.

    ``projection`` goes to :func:`project_spinning` (rows, cols, elevation_range).
    """
    path = Path(path)
    raw = np.fromfile(path, dtype="<f4")
    if raw.size == 0 or raw.size % 4:
        raise ValueError(f"{path}: a KITTI .bin holds float32 (x, y, z, reflectance) per point; "
                         f"got {raw.size * 4} bytes, not a multiple of 16" if raw.size else
                         f"{path}: empty KITTI .bin")
    points = raw.reshape(-1, 4)
    return project_spinning(points[:, :3], intensity=points[:, 3], **projection)


# -- E57 ------------------------------------------------------------------------------

def load_e57(path, scan: int = 0) -> OrganizedCloud:
    """Scan ``scan`` of a structured E57 file: its grid from rowIndex/columnIndex, its pose.

    Points are read in the scan's own frame (the sensor's); the scan's pose (rotation and
    translation to the file's world frame) becomes ``cloud.pose``. Cartesian or spherical
    coordinates, intensity and colour are read when present.
    """
    try:
        import pye57
    except ImportError:
        raise ValueError("reading E57 needs the pye57 package: pip install 'rangeseg_o3d[e57]'") from None
    path = Path(path)
    try:
        e57 = pye57.E57(str(path))
    except Exception as err:  # libE57Format raises its own exception types
        raise ValueError(f"{path}: not a readable E57 file ({err})") from None
    if not 0 <= scan < e57.scan_count:
        raise ValueError(f"{path}: scan {scan} requested; the file holds {e57.scan_count}")
    header = e57.get_header(scan)
    fields = set(header.point_fields)
    if not {"rowIndex", "columnIndex"} <= fields:
        raise ValueError(f"{path}: scan {scan} is not structured (no rowIndex/columnIndex); "
                         "an organized scan is needed")
    data = e57.read_scan_raw(scan)
    rows, cols = np.asarray(data["rowIndex"], np.int64), np.asarray(data["columnIndex"], np.int64)
    rows, cols = rows - rows.min(), cols - cols.min()  # index bounds need not start at 0
    if {"cartesianX", "cartesianY", "cartesianZ"} <= fields:
        xyz = np.stack([data["cartesianX"], data["cartesianY"], data["cartesianZ"]], axis=1)
    elif {"sphericalRange", "sphericalAzimuth", "sphericalElevation"} <= fields:
        r, az, el = (np.asarray(data[k], float) for k in ("sphericalRange", "sphericalAzimuth",
                                                           "sphericalElevation"))
        xyz = np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)], axis=1)
    else:
        raise ValueError(f"{path}: scan {scan} has neither cartesian nor spherical coordinates")
    valid = np.ones(len(rows), bool)
    for flag in ("cartesianInvalidState", "sphericalInvalidState"):
        if flag in data:
            valid &= np.asarray(data[flag]) == 0
    h, w = int(rows.max()) + 1, int(cols.max()) + 1
    grid = np.full((h * w, 3), np.nan)
    flat = rows * w + cols
    grid[flat[valid]] = xyz[valid]
    extra = {}
    if "intensity" in data:
        values = np.full(h * w, np.nan)
        values[flat[valid]] = data["intensity"][valid]
        extra["intensity"] = values.reshape(h, w)
    if {"colorRed", "colorGreen", "colorBlue"} <= fields:
        colors = np.zeros((h * w, 3), np.uint8)
        colors[flat] = np.stack([data["colorRed"], data["colorGreen"], data["colorBlue"]], axis=1)
        extra["colors"] = colors.reshape(h, w, 3)
    pose = np.eye(4)
    pose[:3, :3] = header.rotation_matrix
    pose[:3, 3] = header.translation
    return OrganizedCloud(grid.reshape(h, w, 3), pose=pose, **extra)


# -- dispatch -------------------------------------------------------------------------

def load_input(path, *, units: str = "m", intrinsics=None, depth_scale: float = 0.001,
               scan: int = 0, **ros_options) -> OrganizedCloud:
    """Read any input ``rangeseg segment`` takes; the reader is picked by suffix.

    Parameters
    ----------
    path : str or Path
        A file (or a ROS 2 bag folder).
    units : coordinate unit of ``.npz``/``.pcd`` files.
    intrinsics : fx fy cx cy, a 3x3 matrix, or an Open3D PinholeCameraIntrinsic (object or
        JSON file); needed for a depth ``.png``.
    depth_scale : metres per depth unit of a ``.png`` (0.001 for millimetres).
    scan : which scan of an ``.e57`` file.
    ros_options : passed to :func:`rangeseg_o3d.io.rosbag.load_rosbag` (topics, message index...).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if path.is_dir() and (path / "metadata.yaml").is_file():
        suffix = ".db3"  # a ROS 2 bag folder
    if suffix in (".npz", ".pcd"):
        return OrganizedCloud.load(path, units=units)
    if suffix == ".3d":
        from .datasets import load_3dtk

        return load_3dtk(path)
    if suffix == ".png":
        if intrinsics is None:
            raise ValueError(f"{path}: a depth image needs the camera's intrinsics "
                             "(--intrinsics fx fy cx cy, or an Open3D PinholeCameraIntrinsic JSON)")
        return load_depth_png(path, intrinsics, depth_scale=depth_scale)
    if suffix == ".bin":
        return load_kitti_bin(path)
    if suffix == ".e57":
        return load_e57(path, scan=scan)
    if suffix in (".bag", ".mcap", ".db3"):
        from .rosbag import load_rosbag

        return load_rosbag(path, **ros_options)
    raise ValueError(f"input {path} must be one of {', '.join(INPUT_SUFFIXES)} (or a ROS 2 bag "
                     f"folder); got {path.suffix!r}")
