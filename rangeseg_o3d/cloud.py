"""OrganizedCloud: an (H, W) grid of 3-D points that keeps the sensor's image structure."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .geometry import NoddingGeometry, PinholeGeometry, SphericalGeometry, spherical_points

__all__ = ["OrganizedCloud", "DEFAULT_MAX_GRID_POINTS", "max_grid_points", "set_max_grid_points",
           "check_grid_size"]

#: Largest grid (rows x columns) a cloud may have unless raised with
#: :func:`set_max_grid_points` or the configuration's ``max_grid_points``. A 70 x 131 nodding
#: scan has 9 170 points, a VGA frame 307 200, the shared terrestrial scans under 2 million;
#: the pipeline needs a few hundred bytes per point, so 20 million is several GB. A lying
#: header or a mistyped size must fail at once, not after the machine runs out of memory.
DEFAULT_MAX_GRID_POINTS = 20_000_000
_max_grid_points = DEFAULT_MAX_GRID_POINTS


def max_grid_points() -> int:
    """The current limit on rows x columns of a cloud (see :func:`set_max_grid_points`)."""
    return _max_grid_points


def set_max_grid_points(limit: int) -> int:
    """Set the largest grid (rows x columns) clouds and loaders accept; returns the old limit."""
    global _max_grid_points
    if isinstance(limit, bool) or int(limit) != limit or limit < 1:
        raise ValueError(f"max_grid_points must be a positive integer; got {limit!r}")
    previous, _max_grid_points = _max_grid_points, int(limit)
    return previous


def check_grid_size(rows: int, cols: int, *, source: str = "grid") -> None:
    """Raise ValueError if a ``rows x cols`` grid exceeds :func:`max_grid_points`.

    Loaders call this with the size a header declares, before allocating anything.

    >>> check_grid_size(480, 640)
    >>> check_grid_size(10_000, 10_000, source="scan.pcd")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    ValueError: scan.pcd: a 10000 x 10000 grid (100,000,000 points) exceeds the limit of 20,000,000 ...
    """
    points = int(rows) * int(cols)
    if points > _max_grid_points:
        raise ValueError(
            f"{source}: a {int(rows)} x {int(cols)} grid ({points:,} points) exceeds the limit of "
            f"{_max_grid_points:,} points; raise max_grid_points in the configuration (or call "
            "rangeseg_o3d.cloud.set_max_grid_points) if this machine has the memory "
            "(a few hundred bytes per point)"
        )


def _check_grid(name: str, value, shape: tuple[int, int]) -> np.ndarray | None:
    if value is None:
        return None
    arr = np.asarray(value)
    if arr.shape != shape:
        raise ValueError(f"{name} must have shape {shape} to match xyz; got {arr.shape}")
    if not np.issubdtype(arr.dtype, np.number):
        raise ValueError(f"{name} must be numeric; got dtype {arr.dtype}")
    return arr


def _clean_points(arr: np.ndarray) -> np.ndarray:
    """A read-only float64 C-order copy of ``arr`` with every pixel all-finite or all-NaN.

    A read-only float64 C-order array whose pixels are already clean (as the readers
    build them) is adopted as it is: nobody can change it behind the cloud's back, and
    a VGA frame costs no 7 MB copy.
    """
    adopt = (arr.dtype == np.float64 and arr.flags.c_contiguous and not arr.flags.writeable)
    # The sum of a pixel's coordinates is finite only when all three are: one pass over
    # the points instead of separate NaN and inf tests.
    total = arr[..., 0] + arr[..., 1] + arr[..., 2]
    bad = ~np.isfinite(total)
    if bad.any():
        suspects = arr[bad]
        if np.isinf(suspects).any():
            raise ValueError(
                f"xyz contains {int(np.isinf(suspects).any(axis=1).sum())} points with infinite "
                "coordinates; mark missing returns with NaN instead"
            )
        adopt = adopt and bool(np.isnan(suspects).all())
    if adopt:
        return arr
    arr = np.array(arr, dtype=np.float64, order="C")  # C order: flat views cost no copy
    arr[bad] = np.nan
    arr.setflags(write=False)
    return arr


def _check_colors(value, shape: tuple[int, int]) -> np.ndarray | None:
    """(H, W, 3) uint8 RGB from uint8 values or floats in [0, 1]."""
    if value is None:
        return None
    arr = np.asarray(value)
    if arr.shape != shape + (3,):
        raise ValueError(f"colors must have shape {shape + (3,)} (RGB per pixel); got {arr.shape}")
    if arr.dtype == np.uint8:
        return arr
    if not np.issubdtype(arr.dtype, np.floating):
        raise ValueError(f"colors must be uint8 or floats in [0, 1]; got dtype {arr.dtype}")
    return np.round(np.clip(np.nan_to_num(arr), 0.0, 1.0) * 255).astype(np.uint8)


def _check_extras(value, shape: tuple[int, int]) -> dict:
    """Per-pixel fields by name: arrays of shape (H, W) or (H, W, k)."""
    extras = {}
    for name, field in dict(value or {}).items():
        arr = np.asarray(field)
        if arr.shape[:2] != shape or arr.ndim not in (2, 3) or not np.issubdtype(arr.dtype, np.number):
            raise ValueError(f"extra field {name!r} must be numbers of shape {shape} or "
                             f"{shape + ('k',)}; got {arr.shape} {arr.dtype}")
        extras[str(name)] = arr
    return extras


def _check_pose(value) -> np.ndarray | None:
    """A 4x4 rigid transform (sensor frame -> world), or None for the identity."""
    if value is None:
        return None
    pose = np.asarray(value, dtype=float)
    if pose.shape != (4, 4) or not np.isfinite(pose).all():
        raise ValueError(f"pose must be a finite 4x4 matrix; got shape {pose.shape}")
    rotation = pose[:3, :3]
    if (not np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-6)
            or not np.allclose(pose[3], [0, 0, 0, 1]) or np.linalg.det(rotation) < 0):
        raise ValueError("pose must be a rigid transform: a rotation (orthonormal, det +1) and "
                         "a translation, last row 0 0 0 1")
    pose.setflags(write=False)
    return pose


def _measurements(name: str, value) -> np.ndarray:
    """A 2-D image of numbers for the compiled constructors (ints and floats kept as they are)."""
    arr = np.asarray(value)
    if arr.ndim != 2:
        raise ValueError(f"{name} must have shape (H, W); got {arr.shape}")
    if arr.dtype == np.bool_ or not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
        raise ValueError(f"{name} must be an image of numbers; got dtype {arr.dtype}")
    if arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ValueError(f"{name} must have at least one row and one column; got {arr.shape}")
    check_grid_size(*arr.shape, source=name)
    if arr.dtype == np.float16 or not arr.dtype.isnative:  # types the compiled pass does not take
        arr = arr.astype(np.float64)
    return arr


def _adopt(arr: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Points a compiled constructor made (float64, C order, clean), made read-only as they are."""
    arr.setflags(write=False)
    valid.setflags(write=False)
    return arr


class OrganizedCloud:
    """An organized point cloud: ``xyz[i, j]`` is the point seen by pixel (row i, column j).

    Parameters
    ----------
    xyz : (H, W, 3) array of float
        Points in metres; NaN (all three coordinates) where the sensor had no return.
        A pixel with any NaN coordinate counts as invalid and is stored all-NaN.
    ranges, intensity : (H, W) arrays, optional
        Per-pixel range (metres) and return intensity, when the sensor gives them.
    geometry : NoddingGeometry, PinholeGeometry or SphericalGeometry, optional
        How the grid was produced, when known.
    timestamps : (H,) array, optional
        Acquisition time of each row, seconds.
    samples : (H, W) array of int, optional
        How many raw returns each point averages (see :meth:`tile_means`); 1 if omitted.
        The noise of a mean of ``n`` returns is ``1/sqrt(n)`` of one return's.
    tile : int
        Sensor pixels per grid step along rows and columns (1 for a raw scan).
    colors : (H, W, 3) uint8 (or floats in [0, 1]), optional
        RGB of each pixel (an RGB-D frame, a coloured PCD).
    extras : dict of (H, W) or (H, W, k) arrays, optional
        Other per-pixel fields read with the points (a PCD's normals, curvature...).
    pose : (4, 4) array, optional
        Sensor frame -> world (a PCD's VIEWPOINT, an E57 scan's pose). ``xyz`` is in the
        sensor frame, where ranges and the noise model apply; :meth:`world_xyz` applies it.

    Raises
    ------
    ValueError
        On a wrong shape, a non-numeric dtype, infinite coordinates or an empty grid.

    Examples
    --------
    >>> import numpy as np
    >>> cloud = OrganizedCloud(np.zeros((2, 3, 3)))
    >>> cloud.shape, cloud.n_valid
    ((2, 3), 6)
    """

    def __init__(self, xyz, *, ranges=None, intensity=None, geometry=None, timestamps=None,
                 samples=None, tile: int = 1, colors=None, extras=None, pose=None, _valid=None):
        arr = np.asarray(xyz)
        if arr.ndim != 3 or arr.shape[2] != 3:
            raise ValueError(f"xyz must have shape (H, W, 3); got {arr.shape}")
        if arr.shape[0] == 0 or arr.shape[1] == 0:
            raise ValueError(f"xyz must have at least one row and one column; got {arr.shape}")
        check_grid_size(*arr.shape[:2], source="xyz")
        if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
            raise ValueError(f"xyz must be a float array; got dtype {arr.dtype}")
        # ``_valid`` is for the compiled constructors only: their points are clean float64 by
        # construction and their validity comes out of the same pass, so no check is repeated.
        self._xyz = _clean_points(arr) if _valid is None else _adopt(arr, _valid)
        self._norms = None
        self._valid = None if _valid is None else _valid
        shape = arr.shape[:2]
        self.ranges = _check_grid("ranges", ranges, shape)
        self.intensity = _check_grid("intensity", intensity, shape)
        if geometry is not None and not isinstance(geometry, (NoddingGeometry, PinholeGeometry,
                                                              SphericalGeometry)):
            raise TypeError(
                "geometry must be NoddingGeometry, PinholeGeometry or SphericalGeometry; "
                f"got {type(geometry).__name__}"
            )
        if isinstance(geometry, (NoddingGeometry, SphericalGeometry)) and geometry.shape != shape:
            raise ValueError(
                f"geometry describes a {geometry.shape} grid but xyz is {shape}"
            )
        self.geometry = geometry
        if timestamps is not None:
            timestamps = np.asarray(timestamps, dtype=float)
            if timestamps.shape != (shape[0],):
                raise ValueError(
                    f"timestamps must have shape ({shape[0]},), one per row; got {timestamps.shape}"
                )
        self.timestamps = timestamps
        self.samples = _check_grid("samples", samples, shape)
        if self.samples is not None and (self.samples < 0).any():
            raise ValueError("samples must be >= 0 (returns averaged per point)")
        if int(tile) != tile or tile < 1:
            raise ValueError(f"tile must be a positive integer; got {tile!r}")
        self.tile = int(tile)
        self.colors = _check_colors(colors, shape)
        self.extras = _check_extras(extras, shape)
        self.pose = _check_pose(pose)

    def _scaled_pose(self, factor: float) -> np.ndarray | None:
        if self.pose is None:
            return None
        pose = self.pose.copy()
        pose[:3, 3] *= factor  # the translation is a length, the rotation is not
        return pose

    def _carried(self, sub=lambda a: a) -> dict:
        """Colour, extra fields and pose for a derived cloud (``sub`` cuts the grids)."""
        return {"colors": None if self.colors is None else sub(self.colors),
                "extras": {k: sub(v) for k, v in self.extras.items()}, "pose": self.pose}

    # -- constructors -------------------------------------------------------------
    @classmethod
    def from_ranges(
        cls,
        ranges,
        beam_angles,
        tilt_angles,
        *,
        mount_offset=(0.0, 0.0, 0.0),
        tilt_sign: float = 1.0,
        intensity=None,
        timestamps=None,
    ) -> "OrganizedCloud":
        """Build a cloud from a nodding laser's ranges (metres; NaN, inf or <= 0 = no return).

        ``ranges[i, j]`` is beam ``beam_angles[j]`` at tilt ``tilt_angles[i]`` (radians);
        the kinematics are those of :mod:`rangeseg_o3d.geometry`.
        """
        geometry = NoddingGeometry(
            beam_angles=beam_angles,
            tilt_angles=tilt_angles,
            mount_offset=mount_offset,
            tilt_sign=tilt_sign,
        )
        from .kernels.project import nodding_range_points

        ranges = _measurements("ranges", ranges)
        if ranges.shape != geometry.shape:
            raise ValueError(
                f"ranges must have shape (H, W) = {geometry.shape} to match the geometry; got {ranges.shape}"
            )
        theta = geometry.tilt_sign * geometry.tilt_angles
        phi = geometry.beam_angles
        xyz, clean, valid = nodding_range_points(ranges, np.cos(theta), np.sin(theta), np.sin(phi),
                                                 np.cos(phi), geometry.mount_offset)
        return cls(xyz, ranges=clean, intensity=intensity, geometry=geometry, timestamps=timestamps,
                   _valid=valid)

    @classmethod
    def from_spherical(cls, ranges, elevations, azimuths, *, intensity=None,
                       timestamps=None) -> "OrganizedCloud":
        """Build a cloud from a spinning lidar's range image (metres; NaN, inf or <= 0 = no return).

        ``ranges[i, j]`` is beam ``i`` at column ``j``: elevation ``elevations[i]`` above the
        horizontal plane, azimuth ``azimuths[j]`` counter-clockwise from +x (radians; either
        may be given per pixel, (H, W), for beams with azimuth offsets). A 64 x 1024 Ouster
        or Velodyne frame: 64 elevations over the vertical field, 1024 azimuths over 360 deg
        (``cloud.geometry.full_turn`` is then True: the columns wrap).
        """
        geometry = SphericalGeometry(elevations=elevations, azimuths=azimuths)
        ranges = _measurements("ranges", ranges).astype(np.float64, copy=False)
        xyz = spherical_points(ranges, geometry)
        clean = np.where(np.isfinite(ranges) & (ranges > 0), ranges, np.nan)
        return cls(xyz, ranges=clean, intensity=intensity, geometry=geometry, timestamps=timestamps)

    @classmethod
    def from_depth(cls, depth, fx, fy, cx, cy, *, depth_scale: float = 1.0) -> "OrganizedCloud":
        """Build a cloud from a depth image and pinhole intrinsics.

        ``depth * depth_scale`` must be metres (e.g. ``depth_scale=0.001`` for mm);
        0, negative, infinite and NaN depths mark invalid pixels. Points, ranges and
        validity come from one compiled pass over the image (any integer or float dtype,
        e.g. a 16-bit PNG as read, without a float copy first).
        """
        if not depth_scale > 0:
            raise ValueError(f"depth_scale must be positive; got {depth_scale}")
        from .kernels.project import depth_points

        geometry = PinholeGeometry(float(fx), float(fy), float(cx), float(cy))
        depth = _measurements("depth", depth)
        xyz, ranges, valid = depth_points(depth, float(depth_scale), geometry.fx, geometry.fy,
                                          geometry.cx, geometry.cy)
        return cls(xyz, ranges=ranges, geometry=geometry, _valid=valid)

    # -- views ----------------------------------------------------------------------
    @property
    def xyz(self) -> np.ndarray:
        """(H, W, 3) read-only float64 points, NaN where invalid."""
        return self._xyz

    @property
    def shape(self) -> tuple[int, int]:
        return self._xyz.shape[:2]

    @property
    def valid(self) -> np.ndarray:
        """(H, W) bool mask of pixels with a return (read-only; computed once per cloud)."""
        if self._valid is None:
            valid = ~np.isnan(self._xyz[..., 2])
            valid.setflags(write=False)
            self._valid = valid
        return self._valid

    @property
    def n_valid(self) -> int:
        return int(np.count_nonzero(self.valid))

    def crop(self, rows: slice = slice(None), cols: slice = slice(None)) -> "OrganizedCloud":
        """The sub-grid ``[rows, cols]`` with its ranges, intensity, timestamps and geometry.

        The paper processes only beams 25..155 deg of its 181, because points crowd at the
        lateral ends of a nodding scan: ``cloud.crop(cols=slice(25, 156))``. A pinhole
        geometry's principal point is shifted to the crop.
        """
        if not (isinstance(rows, slice) and isinstance(cols, slice)):
            raise TypeError("rows and cols must be slices")
        xyz = self._xyz[rows, cols]
        if xyz.shape[0] == 0 or xyz.shape[1] == 0:
            raise ValueError(f"crop [{rows}, {cols}] of a {self.shape} grid is empty")
        geometry = self.geometry
        if isinstance(geometry, NoddingGeometry):
            geometry = NoddingGeometry(geometry.beam_angles[cols], geometry.tilt_angles[rows],
                                       geometry.mount_offset, geometry.tilt_sign)
        elif isinstance(geometry, SphericalGeometry):
            elevations, azimuths = geometry.elevations, geometry.azimuths
            geometry = SphericalGeometry(
                elevations[rows] if elevations.ndim == 1 else elevations[rows, cols],
                azimuths[cols] if azimuths.ndim == 1 else azimuths[rows, cols])
        elif isinstance(geometry, PinholeGeometry):
            r0 = range(*rows.indices(self.shape[0]))
            c0 = range(*cols.indices(self.shape[1]))
            if r0.step != 1 or c0.step != 1:
                geometry = None  # a strided crop is no longer a pinhole image
            else:
                geometry = PinholeGeometry(geometry.fx, geometry.fy,
                                           geometry.cx - c0.start, geometry.cy - r0.start)

        def sub(a):
            return None if a is None else np.asarray(a)[rows, cols]

        return OrganizedCloud(
            xyz, ranges=sub(self.ranges), intensity=sub(self.intensity), geometry=geometry,
            timestamps=None if self.timestamps is None else self.timestamps[rows],
            samples=sub(self.samples), tile=self.tile, **self._carried(sub),
        )

    def tile_means(self, size: int, *, min_fraction: float = 0.5) -> "OrganizedCloud":
        """The grid of ``size x size`` tile means (NaN-aware), with ``samples`` and ``tile`` set.

        Averaging ``n`` returns divides the range noise by ``sqrt(n)``: a 3x3 window on
        6x6 tile means of a VGA depth frame sees creases that the depth noise hides at
        full resolution, at 1/36 of the cost. Tiles with fewer than ``min_fraction`` of
        their pixels valid are invalid; a tile straddling a depth jump gives a point
        between the surfaces, which the jump test flags like a mixed pixel. Ranges are
        recomputed from the means; intensity and geometry are dropped.
        """
        from .segmentation.residual import block_means

        if int(size) != size or size < 1:
            raise ValueError(f"size must be a positive integer; got {size!r}")
        size = int(size)
        if size == 1:
            return self
        if self.tile != 1 or self.samples is not None:
            raise ValueError(f"this cloud already holds means (tile {self.tile}); take tile means "
                             "of the raw cloud once, with the product of the sizes")
        means, counts = block_means(self._xyz, size, min_fraction=min_fraction)
        timestamps = None if self.timestamps is None else self.timestamps[::size]
        return OrganizedCloud(means, timestamps=timestamps, samples=counts, tile=self.tile * size)

    def scaled(self, factor: float) -> "OrganizedCloud":
        """The cloud with coordinates and ranges multiplied by ``factor`` (0.01 turns cm into m).

        Intensity, timestamps, samples and tile are kept; a nodding geometry's mount offset
        is scaled, its angles and a pinhole's intrinsics are unit-free.
        """
        factor = float(factor)
        if not (np.isfinite(factor) and factor > 0):
            raise ValueError(f"factor must be a finite number > 0; got {factor!r}")
        if factor == 1.0:
            return self
        geometry = self.geometry
        if isinstance(geometry, NoddingGeometry):
            geometry = NoddingGeometry(geometry.beam_angles, geometry.tilt_angles,
                                       geometry.mount_offset * factor, geometry.tilt_sign)
        return OrganizedCloud(
            self._xyz * factor, ranges=None if self.ranges is None else self.ranges * factor,
            intensity=self.intensity, geometry=geometry, timestamps=self.timestamps,
            samples=self.samples, tile=self.tile, **{**self._carried(), "pose": self._scaled_pose(factor)},
        )

    def world_xyz(self) -> np.ndarray:
        """(H, W, 3) points in the world frame: ``pose`` applied (``xyz`` itself without one)."""
        if self.pose is None:
            return self._xyz
        return self._xyz @ self.pose[:3, :3].T + self.pose[:3, 3]

    def range_image(self) -> np.ndarray:
        """Ranges if the sensor gave them, else the distance of each point from the origin.

        Read-only; computed once per cloud (the points cannot change).
        """
        if self.ranges is not None:
            return np.asarray(self.ranges, dtype=float)
        if self._norms is None:
            norms = np.sqrt(np.einsum("ijk,ijk->ij", self._xyz, self._xyz))
            norms.setflags(write=False)
            self._norms = norms
        return self._norms

    def __repr__(self) -> str:
        h, w = self.shape
        geo = type(self.geometry).__name__ if self.geometry is not None else "None"
        return f"OrganizedCloud({h}x{w}, valid={self.n_valid}, geometry={geo})"

    # -- I/O and Open3D (the heavy imports live in rangeseg_o3d.io) --------------
    def save(self, path) -> Path:
        """Write to ``.npz`` (everything) or organized ``.pcd`` (points, WIDTH/HEIGHT kept); atomic."""
        from .io import save_cloud

        return save_cloud(self, path)

    @classmethod
    def load(cls, path, *, units: str = "m") -> "OrganizedCloud":
        """Read a cloud written by :meth:`save`, or any organized PCD file (ascii, binary, binary_compressed).

        ``units`` is the unit of the file's coordinates (``"m"``, ``"cm"``, ``"mm"``, ...),
        converted to metres; files written by :meth:`save` are metres whatever it says.
        """
        from .io import load_cloud

        return load_cloud(path, units=units)

    def to_open3d(self):
        """``open3d.t.geometry.PointCloud`` of the valid points with int32 ``row``/``col`` attributes."""
        from .io.open3d_conv import to_open3d

        return to_open3d(self)

    def to_legacy(self):
        """Legacy ``open3d.geometry.PointCloud`` of the valid points (grid order, row-major)."""
        from .io.open3d_conv import to_legacy

        return to_legacy(self)

    @classmethod
    def from_open3d(cls, pcd, shape: tuple[int, int] | None = None) -> "OrganizedCloud":
        """Rebuild the grid from a tensor point cloud carrying ``row``/``col`` attributes."""
        from .io.open3d_conv import from_open3d

        return from_open3d(pcd, shape=shape)
