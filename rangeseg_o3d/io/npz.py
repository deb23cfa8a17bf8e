"""``.npz`` storage of an OrganizedCloud: every field, bit for bit."""

from __future__ import annotations

import logging
import zipfile
import zlib
from pathlib import Path

import numpy as np

from ..cloud import OrganizedCloud, check_grid_size
from ..geometry import NoddingGeometry, PinholeGeometry, SphericalGeometry
from ..sensor import unit_scale
from .atomic import atomic_write

__all__ = ["save_npz", "load_npz", "NPZ_FORMAT_VERSION"]

log = logging.getLogger(__name__)

#: Written as ``format_version``; bump when the key layout changes incompatibly.
NPZ_FORMAT_VERSION = 1

_OPTIONAL_GRIDS = ("ranges", "intensity", "samples", "colors", "pose")
_EXTRA = "extra__"  # prefix of the keys of extra per-pixel fields


def save_npz(cloud: OrganizedCloud, path, *, compress: bool = False) -> Path:
    """Write ``cloud`` to a ``.npz`` file atomically.

    Keys: ``format_version``, ``xyz`` (H, W, 3) float64, and when present
    ``ranges``, ``intensity``, ``samples`` (dtypes kept), ``tile`` (when not 1),
    ``colors`` (H, W, 3) uint8, ``pose`` (4, 4),
    ``extra__<name>`` per extra field, ``timestamps``, ``geometry_kind``
    (``"nodding"``, ``"pinhole"`` or ``"spherical"``) with ``beam_angles``, ``tilt_angles``,
    ``mount_offset``, ``tilt_sign``, or ``fx``, ``fy``, ``cx``, ``cy``, or ``elevations``,
    ``azimuths``.

    Parameters
    ----------
    cloud : OrganizedCloud
    path : str or os.PathLike
        Written exactly as given (no ``.npz`` is appended).
    compress : bool
        Deflate the arrays: about 20 % smaller for a noisy VGA cloud but some
        25 times slower to write (``scripts/bench_io.py``), hence off by default.

    Returns
    -------
    pathlib.Path
        The written path.
    """
    if not isinstance(cloud, OrganizedCloud):
        raise TypeError(f"cloud must be an OrganizedCloud; got {type(cloud).__name__}")
    arrays: dict[str, np.ndarray] = {
        "format_version": np.asarray(NPZ_FORMAT_VERSION),
        "xyz": np.asarray(cloud.xyz),
    }
    for name in _OPTIONAL_GRIDS:
        value = getattr(cloud, name)
        if value is not None:
            arrays[name] = np.asarray(value)
    if cloud.timestamps is not None:
        arrays["timestamps"] = np.asarray(cloud.timestamps)
    if cloud.tile != 1:
        arrays["tile"] = np.asarray(cloud.tile)
    for name, field in cloud.extras.items():
        arrays[_EXTRA + name] = np.asarray(field)
    geometry = cloud.geometry
    if isinstance(geometry, NoddingGeometry):
        arrays.update(
            geometry_kind=np.asarray("nodding"),
            beam_angles=geometry.beam_angles,
            tilt_angles=geometry.tilt_angles,
            mount_offset=geometry.mount_offset,
            tilt_sign=np.asarray(float(geometry.tilt_sign)),
        )
    elif isinstance(geometry, SphericalGeometry):
        arrays.update(geometry_kind=np.asarray("spherical"), elevations=geometry.elevations,
                      azimuths=geometry.azimuths)
    elif isinstance(geometry, PinholeGeometry):
        arrays.update(
            geometry_kind=np.asarray("pinhole"),
            fx=np.asarray(geometry.fx),
            fy=np.asarray(geometry.fy),
            cx=np.asarray(geometry.cx),
            cy=np.asarray(geometry.cy),
        )
    path = Path(path)
    writer = np.savez_compressed if compress else np.savez
    with atomic_write(path, "wb") as handle:
        writer(handle, **arrays)
    return path


def _scalar(data, key: str, path) -> float:
    if key not in data:
        raise ValueError(f"{path}: geometry needs key {key!r}, which is missing")
    value = np.asarray(data[key])
    if value.shape != () or not np.isfinite(value):
        raise ValueError(f"{path}: {key} must be one finite number; got {value!r}")
    return float(value)


def _tile(data, path) -> int:
    if "tile" not in data:
        return 1
    value = np.asarray(data["tile"])
    if value.shape != () or value.dtype.kind not in "iu" or value < 1:
        raise ValueError(f"{path}: tile must be one positive integer; got {value!r}")
    return int(value)


def _geometry(data, path):
    if "geometry_kind" not in data:
        return None
    kind = str(data["geometry_kind"])
    if kind == "pinhole":
        return PinholeGeometry(*(_scalar(data, key, path) for key in ("fx", "fy", "cx", "cy")))
    if kind == "nodding":
        for key in ("beam_angles", "tilt_angles", "mount_offset"):
            if key not in data:
                raise ValueError(f"{path}: nodding geometry needs key {key!r}, which is missing")
        return NoddingGeometry(
            beam_angles=data["beam_angles"],
            tilt_angles=data["tilt_angles"],
            mount_offset=data["mount_offset"],
            tilt_sign=_scalar(data, "tilt_sign", path),
        )
    if kind == "spherical":
        for key in ("elevations", "azimuths"):
            if key not in data:
                raise ValueError(f"{path}: spherical geometry needs key {key!r}, which is missing")
        return SphericalGeometry(elevations=data["elevations"], azimuths=data["azimuths"])
    raise ValueError(f"{path}: geometry_kind must be 'nodding', 'pinhole' or 'spherical'; got {kind!r}")


#: What reading a damaged archive member raises (truncated, bad CRC, bad deflate stream,
#: a header numpy cannot parse).
_DAMAGED = (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError, KeyError)


def _declared_shape(archive: np.lib.npyio.NpzFile, key: str, path) -> tuple[int, ...]:
    """The shape a member's .npy header declares, read without loading its data."""
    try:
        with archive.zip.open(f"{key}.npy") as member:
            version = np.lib.format.read_magic(member)
            read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                           else np.lib.format.read_array_header_2_0)
            shape, _, _ = read_header(member)
    except _DAMAGED as err:
        raise ValueError(f"{path}: member {key!r} is damaged or not an .npy array ({err})") from None
    return shape


def _member(data: np.lib.npyio.NpzFile, key: str, path) -> np.ndarray:
    """One array of the archive; a damaged member is a ValueError naming it."""
    try:
        return data[key]
    except _DAMAGED as err:
        raise ValueError(f"{path}: member {key!r} is damaged ({type(err).__name__}: {err})") from None


def load_npz(path, *, units: str = "m") -> OrganizedCloud:
    """Read a cloud written by :func:`save_npz`.

    A file without ``format_version`` is accepted if it holds a valid ``xyz``
    (e.g. ``np.savez(path, xyz=points)``); its coordinates (and ranges) are taken to be
    in ``units`` and converted to metres. A file with ``format_version`` was written by
    :func:`save_npz` and is in metres: ``units`` does not apply to it.

    Raises
    ------
    ValueError
        If the file is not an npz archive, lacks ``xyz``, has arrays of the wrong
        shape, or comes from a newer format version.
    FileNotFoundError
        If ``path`` does not exist.
    """
    scale = unit_scale(units)
    path = Path(path)
    try:
        archive = np.load(path, allow_pickle=False)
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as err:
        if not path.exists():
            raise FileNotFoundError(f"no such file: {path}") from err
        raise ValueError(f"{path} is not a readable .npz archive: {err}") from err
    if not isinstance(archive, np.lib.npyio.NpzFile):
        raise ValueError(f"{path} holds a single array, not an .npz archive with key 'xyz'")
    with archive as data:
        if "format_version" in data:
            version = _member(data, "format_version", path)
            if version.shape != () or not np.issubdtype(version.dtype, np.integer):
                raise ValueError(f"{path}: format_version must be one integer; got {version!r}")
            version = int(version)
            if version > NPZ_FORMAT_VERSION:
                raise ValueError(
                    f"{path} has format_version {version}; this reader knows up to "
                    f"{NPZ_FORMAT_VERSION}"
                )
        if "xyz" not in data:
            raise ValueError(f"{path} has no 'xyz' array; keys are {sorted(data.files)}")
        shape = _declared_shape(data, "xyz", path)
        if len(shape) != 3 or shape[2] != 3:
            raise ValueError(f"{path}: xyz must have shape (H, W, 3); got {shape}")
        check_grid_size(shape[0], shape[1], source=str(path))  # before reading the points
        xyz = _member(data, "xyz", path)
        grids = {name: _member(data, name, path) for name in _OPTIONAL_GRIDS if name in data}
        extras = {k[len(_EXTRA):]: _member(data, k, path) for k in data.files if k.startswith(_EXTRA)}
        timestamps = _member(data, "timestamps", path) if "timestamps" in data else None
        try:
            tile = _tile(data, path)
            geometry = _geometry(data, path)
        except (zipfile.BadZipFile, zlib.error, EOFError, OSError, KeyError) as err:
            raise ValueError(f"{path}: geometry is damaged ({type(err).__name__}: {err})") from None
        ours = "format_version" in data
    try:
        cloud = OrganizedCloud(xyz, geometry=geometry, timestamps=timestamps, extras=extras, tile=tile, **grids)
    except (ValueError, TypeError) as err:
        raise ValueError(f"{path}: {err}") from err
    if ours:
        if units != "m":
            log.info("%s was written by save_npz, in metres; units=%r does not apply", path, units)
        return cloud
    return cloud.scaled(scale)
