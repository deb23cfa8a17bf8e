"""Conversion between OrganizedCloud and Open3D point clouds, keeping the grid.

The tensor cloud holds the valid pixels only, in row-major grid order, with
per-point attributes ``row`` and ``col`` (int32, shape (N, 1)) giving each
point's pixel, ``intensity`` (float64, (N, 1)) when the cloud has one, ``colors``
(float32 in [0, 1]) when it has colours, one attribute per extra field, and
``grid_shape`` (int32, (N, 2), every row = (H, W)) so that the full grid comes
back even when its last rows or columns are empty. Positions are float64 by
default (exact round trip); pass ``dtype="float32"`` for Open3D operations that
want single precision.

Open3D is imported inside these functions only.
"""

from __future__ import annotations

import numpy as np

from ..cloud import OrganizedCloud

__all__ = ["to_open3d", "to_legacy", "from_open3d", "infer_grid_shape"]

_DTYPES = ("float64", "float32")
#: Point attributes with a meaning here; any other attribute is kept as an extra field.
_RESERVED = ("positions", "row", "col", "grid_shape", "intensity", "colors")
#: Fewest points whose grid :func:`infer_grid_shape` tries to recover.
_MIN_INFERRED = 64


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
    if cloud.colors is not None:
        pcd.point.colors = tensor(np.ascontiguousarray(cloud.colors[rows, cols], dtype=np.float32) / 255)
    for name, field in cloud.extras.items():
        if name not in _RESERVED:
            values = np.asarray(field)[rows, cols]
            pcd.point[name] = tensor(np.ascontiguousarray(values.reshape(n, -1)))
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


def _vertical_gap(points: np.ndarray, width: int, sample: np.ndarray) -> float:
    """Median distance between the sampled points and the ones ``width`` further on."""
    top = sample[sample + width < len(points)]
    gaps = np.linalg.norm(points[top + width] - points[top], axis=1)
    gaps = gaps[np.isfinite(gaps)]
    return float(np.median(gaps)) if gaps.size else np.inf


def infer_grid_shape(points) -> tuple[int, int]:
    """The (H, W) of an organized cloud flattened row-major, from its points alone.

    Open3D reads an organized PCD as a flat list of all WIDTH x HEIGHT points (NaN
    included) and drops HEIGHT. In the grid's width, the points ``W`` apart are the
    pixels straight below: closer (median angle between the viewing directions)
    than the diagonal neighbours
    ``W - 1`` and ``W + 1`` apart. Along a row (a width too small) the distance grows
    with the lag instead, and in a wrong width nothing lines up. Of the widths that
    divide the point count and show that dip, the one with the closest points wins.

    Raises
    ------
    ValueError
        If no width shows it (the points were filtered, e.g. by ``remove_nan_points``,
        or are not a grid).
    """
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    n = len(points)
    if n < _MIN_INFERRED:
        raise ValueError(f"cannot recover a grid from {n} points (fewer than {_MIN_INFERRED}: "
                         "any width could fit by chance); pass shape=(H, W)")
    # Compare viewing directions, not points: range noise moves a point along its ray
    # and would blur the distances, while neighbouring pixels' rays stay one step apart.
    with np.errstate(invalid="ignore", divide="ignore"):
        points = points / np.linalg.norm(points, axis=1)[:, None]
    widths = sorted({d for k in range(1, int(np.sqrt(n)) + 1) if n % k == 0 for d in (k, n // k)
                     if 3 <= d <= n // 2})
    # 40 runs of 250 consecutive points spread over the cloud: contiguous runs keep the
    # gathers in cache (random single points made this 20x slower on a VGA frame).
    starts = np.linspace(0, max(n - 250, 0), 40).astype(np.int64)
    sample = (starts[:, None] + np.arange(min(250, n))).ravel()
    gaps = [_vertical_gap(points, width, sample) for width in widths]
    best = None
    for k in np.argsort(gaps):  # closest first; the diagonal test settles it, usually at once
        if not np.isfinite(gaps[k]):
            break
        width = widths[k]
        diagonal = min(_vertical_gap(points, width - 1, sample), _vertical_gap(points, width + 1, sample))
        if gaps[k] < 0.8 * diagonal:
            best = width
            break
    if best is None:
        raise ValueError(
            f"cannot recover the grid of {n} points: no width that divides {n} puts rows of "
            "neighbouring points under each other (were NaN points removed? read the file with "
            "remove_nan_points=False, or pass shape=(H, W))")
    return n // best, best


def from_open3d(pcd, shape: tuple[int, int] | None = None) -> OrganizedCloud:
    """Rebuild an :class:`OrganizedCloud` from an Open3D point cloud.

    Parameters
    ----------
    pcd : open3d.t.geometry.PointCloud or open3d.geometry.PointCloud
        A tensor cloud needs int ``row`` and ``col`` attributes (as written by
        :func:`to_open3d`); pixels no point maps to become NaN. A legacy cloud
        (or a tensor cloud without ``row``/``col``, such as Open3D reads from an
        organized PCD file) must hold exactly H*W points in row-major order; without
        ``shape`` the grid is recovered by :func:`infer_grid_shape`.
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
        h, w = (_grid_shape(shape, None, np.zeros(0), np.zeros(0)) if shape is not None
                else infer_grid_shape(points))
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
    if flat.size and np.bincount(flat, minlength=h * w).max() > 1:  # O(N), no sort
        raise ValueError("two or more points map to the same (row, col) pixel")
    xyz = np.full((h * w, 3), np.nan)
    xyz[flat] = points
    colors = _attribute(pcd, "colors")
    if colors is not None:
        if colors.dtype != np.uint8:  # Open3D's float colours are in [0, 1]
            colors = np.round(np.clip(colors, 0, 1) * 255).astype(np.uint8)
        grid_colors = np.zeros((h * w, 3), np.uint8)
        grid_colors[flat] = colors
        colors = grid_colors.reshape(h, w, 3)
    extras = {}
    for name in pcd.point:
        if name not in _RESERVED:
            values = pcd.point[name].numpy()
            if values.ndim == 2 and values.shape[1] == 1:
                values = values[:, 0]  # Open3D's (N, 1) scalars become (H, W) images
            grid = np.zeros((h * w,) + values.shape[1:], values.dtype)
            grid[flat] = values
            extras[name] = grid.reshape((h, w) + values.shape[1:])
    grid_intensity = None
    if intensity is not None:
        grid_intensity = np.full(h * w, np.nan)
        grid_intensity[flat] = intensity.reshape(-1)
        grid_intensity = grid_intensity.reshape(h, w)
    return OrganizedCloud(xyz.reshape(h, w, 3), intensity=grid_intensity, colors=colors, extras=extras)
