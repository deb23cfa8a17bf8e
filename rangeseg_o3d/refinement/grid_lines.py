"""Regions on one line of the grid tell no surface of their own.

The returns of one row or one column of the grid sample whatever they hit along one
curve, and a curve lies on many surfaces: nothing in it tells how the surface tilts
across it. A camera's image row or column and a nodding laser's scan row are rays in one
plane through the sensor, so their returns fit that plane (rms 0 but for rounding)
whatever they hit; a nodding laser's column sweeps a cone about the tilt axis, and a
spinning lidar's row one about its axis. Such regions are the returns mixed between two
surfaces along a crease seen near grazing (one row of 20-65 px on the noise_2mm row), or
one column of a thin column's strips; kept, each is a feature no surface stands for, and
where it holds a few pixels of a surface the scoring counts that surface as split
(noise_2mm seed 37 scan 0: a 2901-px wall found whole but for one pixel in a 23-px row of
mixed returns). On the laser rows of the 14 study seeds, no such region was a correctly
detected surface.
"""

from __future__ import annotations

import numpy as np

from .. import kernels  # the package: its names load on first use

__all__ = ["lines_across", "on_one_grid_line", "release_grid_lines"]


def lines_across(idx: np.ndarray, width: int) -> int:
    """How many grid lines the flat pixel indices ``idx`` of a grid ``width`` columns wide
    span in their narrower direction: the fewer of the rows and of the columns from their
    first to their last (0 for no pixel)."""
    if width < 1:
        raise ValueError(f"width must be a positive number of columns; got {width}")
    idx = np.asarray(idx)
    if idx.size == 0:
        return 0
    rows, columns = idx // width, idx % width
    return int(min(rows.max() - rows.min(), columns.max() - columns.min())) + 1


def on_one_grid_line(idx: np.ndarray, width: int) -> bool:
    """Whether the flat pixel indices ``idx`` of a grid ``width`` columns wide all lie on
    one row or all on one column (an empty set does)."""
    return lines_across(idx, width) <= 1


def release_grid_lines(labels: np.ndarray, fits: dict) -> tuple[np.ndarray, dict]:
    """``(labels, fits)`` with every region that lies on one row or one column of the grid
    unlabelled and its model dropped (``labels`` itself when there is none).

    A region crossing a 360-degree scan's seam spans its first and last columns, so it is
    not on one line. ``labels`` is an (H, W) integer image, ``fits`` maps labels to models.
    """
    if labels.ndim != 2:
        raise ValueError(f"labels must be an (H, W) image; got shape {labels.shape}")
    # every region's bounding box in one compiled pass (kernels.label_boxes, half-open):
    # a region's lines_across is the fewer of its box's rows and columns, and a label
    # without pixels has a negative extent, so exactly the regions on one line have 1
    # (a region and a numpy test of its pixel indices each cost ~30 us on a 9000-pixel scan)
    flat = np.ascontiguousarray(labels, dtype=np.int32)
    boxes = kernels.label_boxes(flat, int(flat.max(initial=0)) + 1)
    across = np.minimum(boxes[:, 1] - boxes[:, 0], boxes[:, 3] - boxes[:, 2])
    lines = (np.flatnonzero(across == 1)).tolist()
    if not lines:
        return labels, fits
    dropped = set(lines)
    out = np.where(np.isin(labels, lines), 0, labels).astype(labels.dtype, copy=False)
    return out, {k: m for k, m in fits.items() if k not in dropped}
