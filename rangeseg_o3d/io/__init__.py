"""Reading and writing organized clouds: ``.npz``, organized PCD, Open3D, real data sets.

Importing this package is cheap: Open3D, OpenCV and SciPy load only inside the
functions that need them (:mod:`.open3d_conv`, :mod:`.datasets`).
"""

from __future__ import annotations

from pathlib import Path

from .atomic import atomic_write
from .files import require_regular_file
from .npz import load_npz, save_npz
from .pcd import read_pcd, write_pcd

__all__ = [
    "atomic_write",
    "save_cloud",
    "load_cloud",
    "save_npz",
    "load_npz",
    "read_pcd",
    "write_pcd",
]

_SUFFIXES = (".npz", ".pcd")


def _suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in _SUFFIXES:
        raise ValueError(
            f"cannot tell the format of {path}: the suffix must be one of {_SUFFIXES}; "
            f"got {path.suffix!r}"
        )
    return suffix


def save_cloud(cloud, path) -> Path:
    """Write ``cloud`` atomically to ``.npz`` (every field) or ``.pcd`` (points and intensity).

    Parameters
    ----------
    cloud : OrganizedCloud
    path : str or os.PathLike
        Its suffix picks the format.

    Returns
    -------
    pathlib.Path

    Raises
    ------
    ValueError
        If the suffix is neither ``.npz`` nor ``.pcd``.
    """
    path = Path(path)
    if _suffix(path) == ".npz":
        return save_npz(cloud, path)
    return write_pcd(cloud, path)


def load_cloud(path, *, units: str = "m"):
    """Read an :class:`~rangeseg_o3d.cloud.OrganizedCloud` from ``.npz`` or ``.pcd``, in metres.

    Parameters
    ----------
    path : str or os.PathLike
    units : unit of the file's coordinates (``"m"``, ``"cm"``, ``"mm"``, ...; see
        :data:`rangeseg_o3d.sensor.UNIT_SCALES`). ``.npz`` files written by
        :func:`save_npz` are in metres by contract and are not converted.

    Raises
    ------
    ValueError
        If the suffix or the units are unknown or the file's content is malformed.
    FileNotFoundError
        If ``path`` does not exist.
    """
    from ..sensor import unit_scale

    scale = unit_scale(units)
    path = Path(path)
    suffix = _suffix(path)
    require_regular_file(path)  # a FIFO or device named scan.pcd must not block the reader
    if suffix == ".npz":
        return load_npz(path, units=units)
    return read_pcd(path).scaled(scale)
