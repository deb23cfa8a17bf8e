"""Loaders for the real scans in ``<repo>/../shared/data`` (see its SOURCES.md).

Every loader returns an :class:`~rangeseg_o3d.cloud.OrganizedCloud` in metres, in
the sensor's frame, with the sensor geometry attached when the data determine it.
:func:`real_clouds` lists the files that are present, each with the
configuration preset meant for it.

OpenCV and SciPy are imported inside the loaders that need them.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from ..cloud import OrganizedCloud, check_grid_size
from ..geometry import NoddingGeometry, PinholeGeometry, nodding_points
from .files import require_regular_file
from .pcd import read_pcd_grid

__all__ = [
    "RealCloud",
    "real_clouds",
    "default_data_root",
    "load_3dtk",
    "load_cape_depth",
    "load_peac_frame",
    "load_pcd",
    "load_andreashaus",
    "estimate_pinhole",
    "SICK_3DTK_COLUMNS",
]

log = logging.getLogger(__name__)

#: 3DTK's example scans: 360 beams per row, 0.5 deg apart, 0 .. 179.5 deg.
SICK_3DTK_COLUMNS = 360
_SICK_3DTK_BEAM_STEP = np.deg2rad(0.5)
#: 3DTK's own range filter (dat/config.ini): min 48 cm, max 3276 cm. The scanner's
#: no-return value is 32.767 m, but the coordinates are printed rounded, so some
#: such points come out at 32.758 m; real returns in the shared scans stop at 32.4 m.
_SICK_3DTK_MIN_RANGE = 0.48
_SICK_3DTK_MAX_RANGE = 32.75
#: A derived geometry must reproduce the points to this many metres, else it is dropped.
_GEOMETRY_TOLERANCE = 1e-3
#: A fitted pinhole must reproduce the pixel coordinates to this many pixels.
_PINHOLE_TOLERANCE_PX = 0.05


# -- 3DTK tilting SICK ---------------------------------------------------------------

def _parse_xyz_text(path: Path, columns: int) -> np.ndarray:
    raw = path.read_bytes()
    tokens = raw.split()
    # Counting lines catches an x y z r (or x y z nx ny nz) file whose value count happens to divide by 3.
    n_lines = sum(1 for line in raw.splitlines() if line.strip())
    check_grid_size(max(n_lines // columns, 1), columns, source=str(path))
    if n_lines * 3 != len(tokens):
        raise ValueError(
            f"{path}: expected 3 values (x y z) per line; got {len(tokens)} values on {n_lines} lines"
        )
    try:
        values = np.array(tokens, dtype=np.float64)
    except ValueError as err:
        raise ValueError(f"{path}: a value is not a number ({err})") from None
    n_points = values.size // 3
    if n_points == 0 or n_points % columns:
        raise ValueError(
            f"{path}: {n_points} points do not fill rows of {columns} beams "
            f"(expected a multiple of {columns})"
        )
    return values.reshape(n_points // columns, columns, 3)


def _row_tilts(directions: np.ndarray, valid: np.ndarray, beam_angles: np.ndarray) -> np.ndarray | None:
    """Tilt of each row (radians, positive looking down) from its unit beam directions.

    A beam at angle phi tilted by theta points along (cos t sin phi, -cos phi,
    -sin t sin phi), so theta = atan2(-d_z, d_x) for any beam with sin phi > 0.
    Rows without a usable beam are interpolated from their neighbours.
    """
    usable = valid & (np.sin(beam_angles)[None, :] > 0.2)
    per_beam = np.where(usable, np.arctan2(-directions[..., 2], directions[..., 0]), np.nan)
    have = usable.any(axis=1)
    if have.sum() < 2:
        return None
    tilts = np.full(valid.shape[0], np.nan)
    tilts[have] = np.nanmedian(per_beam[have], axis=1)
    rows = np.arange(valid.shape[0])
    return np.interp(rows, rows[have], tilts[have])


def load_3dtk(path, *, columns: int = SICK_3DTK_COLUMNS) -> OrganizedCloud:
    """Load a 3DTK "uos" scan (``x y z`` lines in cm) of a tilting SICK scanner.

    The file has no header: one line per point, row-major, ``columns`` beams per
    row (one 2-D scan line per tilt step; 226 x 360 for the shared scans).

    Frames: 3DTK is left-handed with x right, y up, z forward. The result is in
    our right-handed sensor frame (x forward, y left, z up), i.e.
    ``x = z_3dtk, y = -x_3dtk, z = y_3dtk``, in metres. The minus sign is what
    turns left-handed into right-handed: with it, beam 0 (along +x_3dtk) points
    right (-y) and beam 179.5 deg left, as in :mod:`rangeseg_o3d.geometry`.

    Returns with 3DTK's own filter applied: ranges ``< 0.48 m`` or
    ``>= 32.75 m`` (the scanner's no-return value 32.767 m, printed rounded)
    become NaN. ``ranges``
    holds ``|p|`` in metres (NaN where invalid). A :class:`NoddingGeometry` is
    attached when it reproduces the points to 1 mm: beams 0, 0.5, ... deg and each
    row's tilt measured from the data (positive = looking down, ``tilt_sign=1``,
    no mount offset; for the shared scans +48.7 deg at row 0 to -67.6 deg at row
    225).

    Parameters
    ----------
    path : str or os.PathLike
    columns : int
        Beams per row.

    Raises
    ------
    ValueError
        If a line does not hold 3 numbers or the points do not fill whole rows.
    """
    path = require_regular_file(path)  # a FIFO named scan000.3d must not block the reader
    raw_cm = _parse_xyz_text(path, columns)
    xyz = np.stack([raw_cm[..., 2], -raw_cm[..., 0], raw_cm[..., 1]], axis=-1) / 100.0
    ranges = np.linalg.norm(xyz, axis=-1)
    valid = (ranges >= _SICK_3DTK_MIN_RANGE) & (ranges < _SICK_3DTK_MAX_RANGE)
    xyz[~valid] = np.nan
    ranges = np.where(valid, ranges, np.nan)

    beam_angles = np.arange(columns) * _SICK_3DTK_BEAM_STEP
    with np.errstate(invalid="ignore", divide="ignore"):
        directions = xyz / ranges[..., None]
    tilts = _row_tilts(directions, valid, beam_angles)
    geometry = None
    if tilts is not None:
        candidate = NoddingGeometry(beam_angles=beam_angles, tilt_angles=tilts)
        error = np.abs(nodding_points(ranges, candidate) - xyz)[valid]
        if error.size and error.max() <= _GEOMETRY_TOLERANCE:
            geometry = candidate
        else:
            log.info("%s: derived nodding geometry off by %.3g m; not attached", path,
                     error.max() if error.size else np.nan)
    return OrganizedCloud(xyz, ranges=ranges, geometry=geometry)


# -- depth cameras ------------------------------------------------------------------

def estimate_pinhole(xyz: np.ndarray) -> PinholeGeometry | None:
    """Intrinsics that project every valid point onto its own pixel, if there are such.

    Fits ``u = fx x/z + cx`` and ``v = fy y/z + cy`` by least squares over the
    valid pixels; returns None when fewer than 10 points are valid, z <= 0, or the
    fit misses a pixel by more than 0.05 px (the cloud was not made by a pinhole
    back-projection).
    """
    xyz = np.asarray(xyz, dtype=float)
    valid = np.isfinite(xyz).all(axis=-1)
    rows, cols = np.nonzero(valid)
    if rows.size < 10:
        return None
    x, y, z = xyz[rows, cols].T
    if (z <= 0).any():
        return None
    params = []
    for ratio, pixel in ((x / z, cols), (y / z, rows)):
        # Closed-form simple linear regression pixel = f * ratio + c.
        ratio_centred = ratio - ratio.mean()
        spread = np.dot(ratio_centred, ratio_centred)
        if not spread > 0:
            return None
        f = np.dot(ratio_centred, pixel - pixel.mean()) / spread
        c = pixel.mean() - f * ratio.mean()
        if not f > 0 or np.abs(f * ratio + c - pixel).max() > _PINHOLE_TOLERANCE_PX:
            return None
        params.append((f, c))
    (fx, cx), (fy, cy) = params
    return PinholeGeometry(float(fx), float(fy), float(cx), float(cy))


def load_pcd(path) -> OrganizedCloud:
    """Load an organized PCD (metres) and attach its pinhole intrinsics when they fit exactly.

    Same as :func:`rangeseg_o3d.io.load_cloud` plus :func:`estimate_pinhole`.
    """
    xyz, intensity = read_pcd_grid(path)
    geometry = estimate_pinhole(xyz) if xyz.shape[0] > 1 else None
    return OrganizedCloud(xyz, intensity=intensity, geometry=geometry)


def load_cape_depth(depth_png, calib_xml) -> OrganizedCloud:
    """Load a CAPE depth frame: 16-bit PNG in mm (0 = invalid) and its IR intrinsics.

    The intrinsics are the ``IR_intrinsic_params`` matrix of the OpenCV
    FileStorage file, as CAPE itself back-projects with the IR camera.

    Raises
    ------
    ValueError
        If the PNG is not a single-channel 16-bit image or the XML lacks the matrix.
    FileNotFoundError
        If a file is missing.
    """
    import cv2

    depth_png, calib_xml = Path(depth_png), Path(calib_xml)
    for path in (depth_png, calib_xml):
        if not path.is_file():
            raise FileNotFoundError(f"no such file: {path}")
    depth = cv2.imread(str(depth_png), cv2.IMREAD_UNCHANGED)
    if depth is None or depth.ndim != 2 or depth.dtype != np.uint16:
        got = "unreadable" if depth is None else f"{depth.dtype} image of shape {depth.shape}"
        raise ValueError(f"{depth_png}: expected a single-channel 16-bit depth PNG; got {got}")
    storage = cv2.FileStorage(str(calib_xml), cv2.FILE_STORAGE_READ)
    try:
        node = storage.getNode("IR_intrinsic_params")
        matrix = None if node.empty() else node.mat()
    finally:
        storage.release()
    if matrix is None or matrix.shape != (3, 3):
        raise ValueError(f"{calib_xml}: expected a 3x3 IR_intrinsic_params matrix")
    fx, fy, cx, cy = matrix[0, 0], matrix[1, 1], matrix[0, 2], matrix[1, 2]
    return OrganizedCloud.from_depth(depth, fx, fy, cx, cy, depth_scale=0.001)


def load_peac_frame(path) -> OrganizedCloud:
    """Load PEAC's ``frame.mat`` (struct ``frame`` with ``xyz`` in mm, organized).

    Invalid pixels have x = y = 0 and z = NaN, so validity is read from z. The
    pinhole intrinsics are attached when they fit the points exactly (for the
    shared frame: f = 525, c = (319.5, 239.5)).

    Raises
    ------
    ValueError
        If the file has no ``frame.xyz`` of shape (H, W, 3).
    """
    from scipy.io import loadmat

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    content = loadmat(path, simplify_cells=True)
    frame = content.get("frame")
    if not isinstance(frame, dict) or "xyz" not in frame:
        raise ValueError(f"{path}: expected a struct 'frame' with field 'xyz'")
    xyz = np.asarray(frame["xyz"], dtype=np.float64)
    if xyz.ndim != 3 or xyz.shape[2] != 3:
        raise ValueError(f"{path}: frame.xyz must have shape (H, W, 3); got {xyz.shape}")
    xyz = xyz / 1000.0
    xyz[~np.isfinite(xyz[..., 2])] = np.nan
    return OrganizedCloud(xyz, geometry=estimate_pinhole(xyz))


def load_andreashaus(path, *, unit: float = 0.01) -> OrganizedCloud:
    """Load PEAC's organized TLS scan ``andreashaus_scan000.pcd``, converted to metres.

    The file's coordinates are in cm (the room spans a few hundred units) and
    not centred on the scanner; no sensor geometry is attached.
    """
    xyz, intensity = read_pcd_grid(path)
    return OrganizedCloud(xyz * unit, intensity=intensity)


# -- the catalogue --------------------------------------------------------------------

@dataclass(frozen=True)
class RealCloud:
    """A real scan in the shared data: ``load()`` gives its OrganizedCloud.

    ``preset`` names the configuration meant for it (``configs/<preset>.yaml``).
    """

    name: str
    path: Path
    loader: Callable[[Path], OrganizedCloud]
    preset: str

    def load(self) -> OrganizedCloud:
        return self.loader(self.path)


def default_data_root() -> Path:
    """``<repo>/../shared/data``, where the shared real data live."""
    return Path(__file__).resolve().parents[2] / ".." / "shared" / "data"


# (name, relative path, loader, preset); CAPE's loader also needs its calibration file.
_CATALOGUE = (
    ("3dtk_scan000", "3dtk/scan000.3d", load_3dtk, "sick_3dtk"),
    ("3dtk_scan001", "3dtk/scan001.3d", load_3dtk, "sick_3dtk"),
    ("3dtk_scan002", "3dtk/scan002.3d", load_3dtk, "sick_3dtk"),
    ("pcl_table_scene_mug", "pcl/table_scene_mug_stereo_textured.pcd", load_pcd, "rgbd_vga"),
    ("pcl_milk_cartoon", "pcl/milk_cartoon_all_small_clorox.pcd", load_pcd, "rgbd_vga"),
    ("pcl_office1", "pcl/office1.pcd", load_pcd, "rgbd_vga"),
    ("pcl_frame_laptop", "pcl/frame_20121214T142255.814212.pcd", load_pcd, "rgbd_vga"),
    ("cape_tunnel", "cape/depth_0.png", "cape", "rgbd_vga"),
    ("peac_stairs", "peac/frame.mat", load_peac_frame, "rgbd_vga"),
    ("peac_andreashaus", "peac/andreashaus_scan000.pcd", load_andreashaus, "tls_andreashaus"),
)


def real_clouds(data_root=None) -> list[RealCloud]:
    """The real organized scans present under ``data_root`` (default :func:`default_data_root`).

    Absent files are skipped, so the list is empty on a machine without the
    shared data. Unorganized files (``pcl/sac_plane_test.pcd``,
    ``3dtk/test_sphere.xyz``) are not scans and are not listed.

    Returns
    -------
    list of RealCloud
    """
    root = Path(data_root) if data_root is not None else default_data_root()
    found = []
    for name, relative, loader, preset in _CATALOGUE:
        path = root / relative
        if not path.is_file():
            continue
        if loader == "cape":
            calib = path.parent / "calib_params.xml"
            if not calib.is_file():
                continue
            loader = functools.partial(load_cape_depth, calib_xml=calib)
        found.append(RealCloud(name=name, path=path, loader=loader, preset=preset))
    return found
