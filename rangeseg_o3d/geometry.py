"""Sensor geometry: how each kind of sensor's grid of ranges becomes points.

One frozen dataclass per kind of sensor, with the function from its ranges to points:
:class:`NoddingGeometry` (a 2-D scanner on a tilt unit: :func:`nodding_rays`,
:func:`nodding_points`), :class:`PinholeGeometry` (depth cameras: :func:`pinhole_points`)
and :class:`SphericalGeometry` (spinning lidars, terrestrial scanners: :func:`spherical_points`).

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
    "SphericalGeometry",
    "nodding_rays",
    "nodding_ray_origins",
    "nodding_points",
    "pinhole_points",
    "spherical_points",
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


@dataclass(frozen=True, eq=False)
class SphericalGeometry:
    """Beam angles of a spinning multi-beam lidar (Ouster / Velodyne class).

    Pixel (i, j) looks along elevation ``elevations[i]`` (or ``[i, j]``) above the
    sensor's horizontal plane and azimuth ``azimuths[j]`` (or ``[i, j]``), counter-clockwise
    from +x: direction ``(cos e cos a, cos e sin a, sin e)`` from the origin.

    Attributes
    ----------
    elevations : (H,) or (H, W) float array, radians.
    azimuths : (W,) or (H, W) float array, radians (per-beam azimuth offsets need (H, W)).
    """

    elevations: np.ndarray
    azimuths: np.ndarray

    def __post_init__(self):
        elevations = np.asarray(self.elevations, dtype=float)
        azimuths = np.asarray(self.azimuths, dtype=float)
        if elevations.ndim not in (1, 2) or azimuths.ndim not in (1, 2):
            raise ValueError("elevations must have shape (H,) or (H, W) and azimuths (W,) or (H, W); "
                             f"got {elevations.shape} and {azimuths.shape}")
        if elevations.size == 0 or azimuths.size == 0:
            raise ValueError("elevations and azimuths must not be empty")
        if not (np.isfinite(elevations).all() and np.isfinite(azimuths).all()):
            raise ValueError("elevations and azimuths must be finite (radians)")
        if np.abs(elevations).max() > np.pi / 2:
            raise ValueError(f"elevations must lie within +-pi/2 rad; got up to {np.abs(elevations).max():.3g}")
        rows = elevations.shape[0]
        cols = azimuths.shape[-1]
        for name, value in (("elevations", elevations), ("azimuths", azimuths)):
            if value.ndim == 2 and value.shape != (rows, cols):
                raise ValueError(f"{name} of shape {value.shape} does not match the ({rows}, {cols}) grid")
        object.__setattr__(self, "elevations", elevations)
        object.__setattr__(self, "azimuths", azimuths)

    @property
    def shape(self) -> tuple[int, int]:
        return (self.elevations.shape[0], self.azimuths.shape[-1])

    def directions(self) -> np.ndarray:
        """(H, W, 3) unit ray directions."""
        h, w = self.shape
        elevation = np.broadcast_to(self.elevations.reshape(h, -1), (h, w))
        azimuth = np.broadcast_to(self.azimuths.reshape(-1, w), (h, w))
        cos_e = np.cos(elevation)
        return np.stack([cos_e * np.cos(azimuth), cos_e * np.sin(azimuth), np.sin(elevation)], axis=-1)

    def column_step(self) -> float:
        """Median azimuth step between neighbouring columns, radians (0 for one column)."""
        azimuth = self.azimuths if self.azimuths.ndim == 1 else np.median(self.azimuths, axis=0)
        steps = np.abs(np.diff(np.unwrap(azimuth)))
        return float(np.median(steps)) if steps.size else 0.0

    @property
    def full_turn(self) -> bool:
        """The columns close a whole turn: the last column's neighbour is the first."""
        azimuth = self.azimuths if self.azimuths.ndim == 1 else np.median(self.azimuths, axis=0)
        step = self.column_step()
        if step == 0.0:
            return False
        span = abs(float(np.unwrap(azimuth)[-1] - azimuth[0])) + step
        return abs(span - 2 * np.pi) < 0.5 * step


def spherical_points(ranges: np.ndarray, geometry: SphericalGeometry) -> np.ndarray:
    """3-D points ``(H, W, 3)`` from a spinning lidar's ranges (m); non-finite or <= 0 give NaN."""
    ranges = np.asarray(ranges, dtype=float)
    if ranges.shape != geometry.shape:
        raise ValueError(f"ranges must have shape (H, W) = {geometry.shape} to match the beam angles; "
                         f"got {ranges.shape}")
    r = np.where(np.isfinite(ranges) & (ranges > 0), ranges, np.nan)
    return geometry.directions() * r[..., None]


def nodding_rays(geometry: NoddingGeometry) -> tuple[np.ndarray, np.ndarray]:
    """Ray origins and unit directions for every pixel of a nodding scan.

    Returns
    -------
    origins, directions : (H, W, 3) float arrays in the base frame.
    """
    phi = geometry.beam_angles
    rot = _tilt_rotations(geometry)
    beam = np.stack([np.sin(phi), -np.cos(phi), np.zeros_like(phi)], axis=-1)  # (W, 3)
    directions = np.einsum("hij,wj->hwi", rot, beam)
    origins = np.broadcast_to((rot @ geometry.mount_offset)[:, None, :], directions.shape).copy()
    return origins, directions


def nodding_ray_origins(geometry: NoddingGeometry) -> np.ndarray:
    """``(H, 3)``: where each row's rays start in the base frame, the mirror centre at the
    row's tilt (every ray of a row starts there; :func:`nodding_rays` gives them per pixel)."""
    return _tilt_rotations(geometry) @ geometry.mount_offset


def _tilt_rotations(geometry: NoddingGeometry) -> np.ndarray:
    # (H, 3, 3): the rotation about +y of every row, R = [[c,0,s],[0,1,0],[-s,0,c]]
    theta = geometry.tilt_sign * geometry.tilt_angles
    c, s = np.cos(theta), np.sin(theta)
    rot = np.zeros((theta.size, 3, 3))
    rot[:, 0, 0], rot[:, 0, 2] = c, s
    rot[:, 1, 1] = 1.0
    rot[:, 2, 0], rot[:, 2, 2] = -s, c
    return rot


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
