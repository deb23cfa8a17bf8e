"""Conversion between OrganizedCloud and Open3D point clouds, keeping the grid.

The tensor cloud holds the valid pixels only, in row-major grid order, with
per-point attributes ``row`` and ``col`` (int32, shape (N, 1)) giving each
point's pixel, ``intensity`` (float64, (N, 1)) when the cloud has one, and
``grid_shape`` (int32, (N, 2), every row = (H, W)) so that the full grid comes
back even when its last rows or columns are empty. Positions are float64 by
default (exact round trip); pass ``dtype="float32"`` for Open3D operations that
want single precision.

Open3D is imported inside these functions only.
"""

from __future__ import annotations

import numpy as np

from ..cloud import OrganizedCloud

__all__ = ["to_open3d", "to_legacy", "from_open3d"]

_DTYPES = ("float64", "float32")


def to_open3d(cloud: OrganizedCloud, *, dtype: str = "float64"):
    """Tensor point cloud of the valid pixels with ``row``/``col`` attributes.

    Parameters
    ----------
    cloud : OrganizedCloud
    dtype : {"float64", "float32"}
        Type of ``positions`` (and ``intensity``).

    Returns
    -------
    open3d.t.geometry.PointCloud
        ``positions`` (N, 3), ``row``/``col`` int32 (N, 1), ``grid_shape`` int32
        (N, 2), ``intensity`` (N, 1) if present; N = ``cloud.n_valid``.
    """
    import open3d as o3d

    if not isinstance(cloud, OrganizedCloud):
        raise TypeError(f"cloud must be an OrganizedCloud; got {type(cloud).__name__}")
    if dtype not in _DTYPES:
        raise ValueError(f"dtype must be one of {_DTYPES}; got {dtype!r}")
    rows, cols = np.nonzero(cloud.valid)
    n = rows.size
    tensor = o3d.core.Tensor
    pcd = o3d.t.geometry.PointCloud()
    pcd.point.positions = tensor(np.ascontiguousarray(cloud.xyz[rows, cols], dtype=dtype))
    pcd.point["row"] = tensor(rows.astype(np.int32)[:, None])
    pcd.point["col"] = tensor(cols.astype(np.int32)[:, None])
    pcd.point["grid_shape"] = tensor(np.tile(np.asarray(cloud.shape, np.int32), (n, 1)))
    if cloud.intensity is not None:
        values = np.asarray(cloud.intensity, dtype=dtype)[rows, cols]
        pcd.point["intensity"] = tensor(np.ascontiguousarray(values[:, None]))
    return pcd


def to_legacy(cloud: OrganizedCloud):
    """Legacy ``open3d.geometry.PointCloud`` of the valid points, row-major grid order.

    The legacy type has no per-point attributes: point ``k`` is pixel
    ``np.argwhere(cloud.valid)[k]``.
    """
    import open3d as o3d

    if not isinstance(cloud, OrganizedCloud):
        raise TypeError(f"cloud must be an OrganizedCloud; got {type(cloud).__name__}")
    points = np.ascontiguousarray(cloud.xyz[cloud.valid], dtype=np.float64)
    return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))


def _attribute(pcd, name: str) -> np.ndarray | None:
    if name not in pcd.point:
        return None
    return pcd.point[name].numpy()


def _grid_shape(shape, stored: np.ndarray | None, rows: np.ndarray, cols: np.ndarray):
    if shape is not None:
        shape = tuple(int(s) for s in shape)
        if len(shape) != 2 or min(shape) < 1:
            raise ValueError(f"shape must be (H, W) with H, W >= 1; got {shape}")
        return shape
    if stored is not None and stored.size:
        return int(stored[0, 0]), int(stored[0, 1])
    if rows.size == 0:
        raise ValueError("cannot infer the grid shape of an empty point cloud; pass shape=(H, W)")
    return int(rows.max()) + 1, int(cols.max()) + 1


def from_open3d(pcd, shape: tuple[int, int] | None = None) -> OrganizedCloud:
    """Rebuild an :class:`OrganizedCloud` from an Open3D point cloud.

    Parameters
    ----------
    pcd : open3d.t.geometry.PointCloud or open3d.geometry.PointCloud
        A tensor cloud needs int ``row`` and ``col`` attributes (as written by
        :func:`to_open3d`); pixels no point maps to become NaN. A legacy cloud
        (or a tensor cloud without ``row``/``col``) must hold exactly H*W points
        in row-major order and needs ``shape``.
    shape : (H, W), optional
        Grid shape; by default the ``grid_shape`` attribute, else
        ``max(row) + 1, max(col) + 1``.

    Raises
    ------
    TypeError
        If ``pcd`` is not an Open3D point cloud.
    ValueError
        On missing or inconsistent ``row``/``col``, pixels outside the grid,
        two points on one pixel, or a point count that does not fit ``shape``.
    """
    import open3d as o3d

    if isinstance(pcd, o3d.geometry.PointCloud):
        pcd = o3d.t.geometry.PointCloud.from_legacy(pcd, o3d.core.float64)
    if not isinstance(pcd, o3d.t.geometry.PointCloud):
        raise TypeError(
            f"pcd must be an open3d.t.geometry.PointCloud or open3d.geometry.PointCloud; "
            f"got {type(pcd).__name__}"
        )
    points = pcd.point.positions.numpy() if "positions" in pcd.point else np.zeros((0, 3))
    rows, cols = _attribute(pcd, "row"), _attribute(pcd, "col")
    intensity = _attribute(pcd, "intensity")
    if rows is None or cols is None:
        if shape is None:
            raise ValueError(
                "point cloud has no 'row'/'col' attributes; pass shape=(H, W) for a cloud "
                "of H*W points in row-major order"
            )
        h, w = _grid_shape(shape, None, np.zeros(0), np.zeros(0))
        if points.shape[0] != h * w:
            raise ValueError(
                f"point cloud without 'row'/'col' has {points.shape[0]} points; "
                f"shape {(h, w)} needs {h * w}"
            )
        rows, cols = np.divmod(np.arange(h * w), w)
    else:
        rows, cols = rows.reshape(-1).astype(np.int64), cols.reshape(-1).astype(np.int64)
        if rows.size != points.shape[0] or cols.size != points.shape[0]:
            raise ValueError(
                f"'row'/'col' have {rows.size}/{cols.size} entries for {points.shape[0]} points"
            )
        h, w = _grid_shape(shape, _attribute(pcd, "grid_shape"), rows, cols)
    if rows.size and (rows.min() < 0 or cols.min() < 0 or rows.max() >= h or cols.max() >= w):
        raise ValueError(
            f"row/col fall outside the {h}x{w} grid: rows {rows.min()}..{rows.max()}, "
            f"cols {cols.min()}..{cols.max()}"
        )
    flat = rows * w + cols
    if np.unique(flat).size != flat.size:
        raise ValueError("two or more points map to the same (row, col) pixel")
    xyz = np.full((h * w, 3), np.nan)
    xyz[flat] = points
    grid_intensity = None
    if intensity is not None:
        grid_intensity = np.full(h * w, np.nan)
        grid_intensity[flat] = intensity.reshape(-1)
        grid_intensity = grid_intensity.reshape(h, w)
    return OrganizedCloud(xyz.reshape(h, w, 3), intensity=grid_intensity)
