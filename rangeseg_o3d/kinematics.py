"""Sensor geometry: nodding-laser kinematics and pinhole back-projection.

The nodding-laser frame follows ``shared/docs/protocols.md``: base frame x forward,
y left, z up; the tilt ``theta`` turns about +y, positive looking down. A beam at
angle ``phi`` (0 = right, 90 deg = forward, 180 deg = left) travels along
``(sin phi, -cos phi, 0)`` in the scan plane, starting at the mirror centre, which
sits at ``mount_offset`` from the tilt axis in the tilting frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "NoddingGeometry",
    "PinholeGeometry",
    "nodding_rays",
    "nodding_points",
    "pinhole_points",
]


@dataclass(frozen=True, eq=False)
class NoddingGeometry:
    """Geometry of a 2-D scanner on a tilt unit.

    Attributes
    ----------
    beam_angles : (W,) float array, radians, one per column.
    tilt_angles : (H,) float array, radians, one per row (the *actual* angles).
    mount_offset : (3,) mirror centre relative to the tilt axis, tilting frame, metres.
    tilt_sign : +1 or -1; multiplies the unit's angle to give theta (mounting dependent).
    """

    beam_angles: np.ndarray
    tilt_angles: np.ndarray
    mount_offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    tilt_sign: float = 1.0

    def __post_init__(self):
        beams = np.asarray(self.beam_angles, dtype=float)
        tilts = np.asarray(self.tilt_angles, dtype=float)
        offset = np.asarray(self.mount_offset, dtype=float)
        if beams.ndim != 1 or tilts.ndim != 1:
            raise ValueError(
                "beam_angles and tilt_angles must be 1-D; "
                f"got shapes {beams.shape} and {tilts.shape}"
            )
        if offset.shape != (3,):
            raise ValueError(f"mount_offset must have shape (3,); got {offset.shape}")
        if self.tilt_sign not in (1, -1, 1.0, -1.0):
            raise ValueError(f"tilt_sign must be +1 or -1; got {self.tilt_sign!r}")
        object.__setattr__(self, "beam_angles", beams)
        object.__setattr__(self, "tilt_angles", tilts)
        object.__setattr__(self, "mount_offset", offset)

    @property
    def shape(self) -> tuple[int, int]:
        return (self.tilt_angles.size, self.beam_angles.size)


@dataclass(frozen=True)
class PinholeGeometry:
    """Pinhole intrinsics of a depth camera (pixels)."""

    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self):
        if not (self.fx > 0 and self.fy > 0):
            raise ValueError(f"fx and fy must be positive; got fx={self.fx}, fy={self.fy}")


def nodding_rays(geometry: NoddingGeometry) -> tuple[np.ndarray, np.ndarray]:
    """Ray origins and unit directions for every pixel of a nodding scan.

    Returns
    -------
    origins, directions : (H, W, 3) float arrays in the base frame.
    """
    theta = geometry.tilt_sign * geometry.tilt_angles
    phi = geometry.beam_angles
    c, s = np.cos(theta), np.sin(theta)
    # Rotation about +y for every row: R = [[c,0,s],[0,1,0],[-s,0,c]].
    rot = np.zeros((theta.size, 3, 3))
    rot[:, 0, 0], rot[:, 0, 2] = c, s
    rot[:, 1, 1] = 1.0
    rot[:, 2, 0], rot[:, 2, 2] = -s, c
    beam = np.stack([np.sin(phi), -np.cos(phi), np.zeros_like(phi)], axis=-1)  # (W, 3)
    directions = np.einsum("hij,wj->hwi", rot, beam)
    origins = np.broadcast_to((rot @ geometry.mount_offset)[:, None, :], directions.shape).copy()
    return origins, directions


def nodding_points(ranges: np.ndarray, geometry: NoddingGeometry) -> np.ndarray:
    """3-D points ``(H, W, 3)`` from ranges in metres; non-finite or <= 0 ranges give NaN."""
    ranges = np.asarray(ranges, dtype=float)
    if ranges.shape != geometry.shape:
        raise ValueError(
            f"ranges must have shape (H, W) = {geometry.shape} to match the geometry; "
            f"got {ranges.shape}"
        )
    origins, directions = nodding_rays(geometry)
    valid = np.isfinite(ranges) & (ranges > 0)
    r = np.where(valid, ranges, np.nan)
    return origins + directions * r[..., None]


def pinhole_points(depth: np.ndarray, geometry: PinholeGeometry) -> np.ndarray:
    """Back-project a depth image (metres, 0 / NaN = invalid) to ``(H, W, 3)`` points."""
    depth = np.asarray(depth, dtype=float)
    if depth.ndim != 2:
        raise ValueError(f"depth must have shape (H, W); got {depth.shape}")
    h, w = depth.shape
    z = np.where(np.isfinite(depth) & (depth > 0), depth, np.nan)
    u = np.arange(w, dtype=float)[None, :]
    v = np.arange(h, dtype=float)[:, None]
    x = (u - geometry.cx) / geometry.fx * z
    y = (v - geometry.cy) / geometry.fy * z
    return np.stack([x, y, z], axis=-1)
