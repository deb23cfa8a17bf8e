"""Scans from ROS 1 and ROS 2 bags (through ``rosbags``, the ``[ros]`` extra).

Two kinds of scan are read:

- an organized ``sensor_msgs/PointCloud2`` (``height > 1``): the grid is the message's;
- a nodding rig: ``sensor_msgs/LaserScan`` rows and the tilt joint's
  ``sensor_msgs/JointState``, the joint's position interpolated at each scan's stamp.
  ROS measures a scan's angles from straight ahead (+x), counter-clockwise; this
  package's beam angles from the right (0 = right, 90 deg = forward), so
  ``beam = ros_angle + pi/2``. The tilt is the joint's position times ``tilt_sign``
  (positive looking down, about +y).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..cloud import OrganizedCloud

__all__ = ["load_rosbag", "pointcloud2_to_cloud", "nodding_scans_to_cloud"]

_CLOUD = ("sensor_msgs/msg/PointCloud2", "sensor_msgs/PointCloud2")
_SCAN = ("sensor_msgs/msg/LaserScan", "sensor_msgs/LaserScan")
_JOINTS = ("sensor_msgs/msg/JointState", "sensor_msgs/JointState")
# PointField datatypes -> numpy
_FIELD_TYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


def _stamp(header) -> float:
    return float(header.stamp.sec) + 1e-9 * float(header.stamp.nanosec)


def pointcloud2_to_cloud(msg) -> OrganizedCloud:
    """An organized PointCloud2 message as a cloud (x, y, z; intensity and rgb when present)."""
    if msg.height < 2:
        raise ValueError(f"PointCloud2 is not organized (height {msg.height}, width {msg.width}); "
                         "an organized cloud (height > 1) is needed")
    fields = {f.name: f for f in msg.fields}
    if not {"x", "y", "z"} <= set(fields):
        raise ValueError(f"PointCloud2 lacks x, y or z; fields are {sorted(fields)}")
    order = ">" if msg.is_bigendian else "<"
    names, formats, offsets = [], [], []
    for name, field in fields.items():
        if field.datatype not in _FIELD_TYPES or field.count != 1:
            continue
        names.append(name)
        formats.append(order + _FIELD_TYPES[field.datatype])
        offsets.append(field.offset)
    for axis in "xyz":
        if fields[axis].datatype not in (7, 8):
            raise ValueError(f"PointCloud2 field {axis} must be a float (FLOAT32/64); "
                             f"got datatype {fields[axis].datatype}")
    record = np.dtype({"names": names, "formats": formats, "offsets": offsets,
                       "itemsize": msg.point_step})
    data = np.frombuffer(np.asarray(msg.data, np.uint8).tobytes(), np.uint8)
    h, w = int(msg.height), int(msg.width)
    if msg.row_step < w * msg.point_step or len(data) < h * msg.row_step:
        raise ValueError(f"PointCloud2 holds {len(data)} bytes; {h} rows of {msg.row_step} are declared")
    rows = np.lib.stride_tricks.as_strided(data, (h, msg.row_step), (msg.row_step, 1))
    table = np.ascontiguousarray(rows[:, : w * msg.point_step]).view(record).reshape(h, w)
    xyz = np.stack([table[a].astype(np.float64) for a in "xyz"], axis=-1)
    xyz[~np.isfinite(xyz).all(axis=-1)] = np.nan
    extra = {}
    if "intensity" in names:
        extra["intensity"] = table["intensity"].astype(np.float64)
    colour = next((c for c in ("rgb", "rgba") if c in names), None)
    if colour is not None:
        bits = np.ascontiguousarray(table[colour]).view(np.uint32)
        extra["colors"] = np.stack([(bits >> 16) & 0xFF, (bits >> 8) & 0xFF, bits & 0xFF],
                                   axis=-1).astype(np.uint8)
    return OrganizedCloud(xyz, **extra)


def nodding_scans_to_cloud(scans: list, joint_times, joint_positions, *, tilt_sign: float = 1.0,
                           mount_offset=(0.0, 0.0, 0.0)) -> OrganizedCloud:
    """LaserScan messages (one row each) and the tilt joint's (times, positions) as a cloud."""
    if len(scans) < 2:
        raise ValueError(f"a nodding scan needs at least 2 LaserScan messages; got {len(scans)}")
    first = scans[0]
    n = len(first.ranges)
    for scan in scans:
        if len(scan.ranges) != n or scan.angle_min != first.angle_min or \
                scan.angle_increment != first.angle_increment:
            raise ValueError("the LaserScan messages differ in beam count or angles: not one rig")
    times = np.array([_stamp(s.header) for s in scans])
    joint_times = np.asarray(joint_times, float)
    if len(joint_times) < 2:
        raise ValueError("the tilt joint needs at least 2 JointState messages to interpolate")
    if times.min() < joint_times.min() or times.max() > joint_times.max():
        raise ValueError("LaserScan stamps fall outside the JointState stamps: cannot interpolate "
                         f"the tilt ({times.min():.3f}..{times.max():.3f} s vs "
                         f"{joint_times.min():.3f}..{joint_times.max():.3f} s)")
    tilts = np.interp(times, joint_times, np.asarray(joint_positions, float))
    ranges = np.array([np.asarray(s.ranges, float) for s in scans])
    low = np.array([s.range_min for s in scans])[:, None]
    high = np.array([s.range_max for s in scans])[:, None]
    ranges[~((ranges >= low) & (ranges <= high))] = np.nan
    ros_angles = first.angle_min + first.angle_increment * np.arange(n)
    intensity = None
    if all(len(s.intensities) == n for s in scans):
        intensity = np.array([np.asarray(s.intensities, float) for s in scans])
    return OrganizedCloud.from_ranges(ranges, ros_angles + np.pi / 2, tilts, tilt_sign=tilt_sign,
                                      mount_offset=mount_offset, intensity=intensity,
                                      timestamps=times - times[0])


def load_rosbag(path, *, topic: str | None = None, index: int = 0, joint: str | None = None,
                joint_topic: str | None = None, tilt_sign: float = 1.0,
                mount_offset=(0.0, 0.0, 0.0)) -> OrganizedCloud:
    """A scan from a ROS 1 ``.bag`` or a ROS 2 bag (folder, ``.db3`` or ``.mcap``).

    With a PointCloud2 topic (``topic``, or the first one in the bag) the ``index``-th
    message is read. Without one, every LaserScan of ``topic`` (or the first scan topic)
    is a row of a nodding scan and ``joint`` (name in the JointState messages, default
    the first) gives the tilt.
    """
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise ValueError("reading ROS bags needs the rosbags package: pip install 'rangeseg_o3d[ros]'") from None
    path = Path(path)
    if path.suffix.lower() in (".db3", ".mcap") and (path.parent / "metadata.yaml").is_file():
        path = path.parent  # a ROS 2 bag is its folder
    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as err:  # rosbags raises its own reader errors
        raise ValueError(f"{path}: not a readable ROS bag ({err})") from None
    try:
        connections = reader.connections
        clouds = [c for c in connections if c.msgtype in _CLOUD and (topic is None or c.topic == topic)]
        if clouds:
            for k, (conn, _, raw) in enumerate(reader.messages(connections=clouds[:1])):
                if k == index:
                    return pointcloud2_to_cloud(reader.deserialize(raw, conn.msgtype))
            raise ValueError(f"{path}: topic {clouds[0].topic} has no message {index}")
        scans = [c for c in connections if c.msgtype in _SCAN and (topic is None or c.topic == topic)]
        joints = [c for c in connections if c.msgtype in _JOINTS
                  and (joint_topic is None or c.topic == joint_topic)]
        if not scans or not joints:
            raise ValueError(f"{path}: no organized PointCloud2, nor LaserScan + JointState topics "
                             f"(topics: {sorted((c.topic, c.msgtype) for c in connections)})")
        rows = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(connections=scans[:1])]
        times, positions = [], []
        for conn, _, raw in reader.messages(connections=joints[:1]):
            msg = reader.deserialize(raw, conn.msgtype)
            names = list(msg.name)
            name = joint if joint is not None else (names[0] if names else None)
            if name not in names:
                continue
            times.append(_stamp(msg.header))
            positions.append(float(msg.position[names.index(name)]))
        if not times:
            raise ValueError(f"{path}: no JointState message names the joint {joint!r}")
        return nodding_scans_to_cloud(rows, times, positions, tilt_sign=tilt_sign, mount_offset=mount_offset)
    finally:
        reader.close()
