"""Lines of sight: whether a plane can reach a piece apart from its region.

A plane region's model extends without end; a piece of free pixels lying on that extension
may be the same surface seen past an occluder (a wall between two columns) or another
surface the extension happens to cross (a pipe three metres behind a box face). The
pixels the camera sees between the piece and the region tell them apart: an occluder
stands in front of the plane, while what lies behind the plane could not be seen had the
plane reached there.
"""

from __future__ import annotations

import numpy as np

__all__ = ["SEEN_PAST_SHARE", "seen_past_plane"]

#: A piece is refused when more than this share of the valid pixels on the image line
#: between it and its plane's region (and at least two) lie beyond that plane: a single
#: glimpse through a gap (a door, a window, a noisy return) does not refuse a wall's strip.
SEEN_PAST_SHARE = 0.1
# the nearest pixel of a region is looked for among at most this many of its pixels (an
# even subsample): the line needs to reach the region, not its very nearest pixel
_NEAREST_SAMPLE = 4096


def seen_past_plane(xyz: np.ndarray, sigma: np.ndarray, labels: np.ndarray, piece: np.ndarray, region: int,
                    plane, k_sigma: float, *, members: np.ndarray | None = None, wrap_columns: bool = False) -> bool:
    """Whether the camera sees past ``plane`` between the free pixels ``piece`` and the
    pixels of its region ``region`` (so the plane does not reach the piece).

    Along the image line from the piece's pixel nearest its centre to the nearest pixel of
    the region (the short way round when ``wrap_columns``), the valid pixels of neither
    are looked at: one whose range exceeds the range at which its ray meets the plane by
    more than ``k_sigma`` times its range noise (at least the plane's rms over the ray's
    incidence cosine) is seen past the plane. True when more than ``SEEN_PAST_SHARE`` of
    them, and at least two, are.

    Parameters
    ----------
    xyz : (H*W, 3) points, NaN where invalid; ``sigma`` their (H*W,) range noise.
    labels : (H, W) region labels; ``piece`` flat pixel indices (not of ``region``).
    plane : the region's :class:`rangeseg_o3d.fitting.primitives.Plane` (``normal . x = d``).
    members : the region's flat pixels, when the caller has them (a pass over the grid less).
    """
    width = labels.shape[1]
    flat = labels.ravel()
    if members is None:
        members = np.flatnonzero(flat == region)
    if members.size == 0 or piece.size == 0:
        return False
    rows, cols = np.divmod(piece, width)
    centre = np.argmin((rows - rows.mean()) ** 2 + (cols - cols.mean()) ** 2)
    start_row, start_col = rows[centre], cols[centre]
    sample = members[:: max(1, members.size // _NEAREST_SAMPLE)]
    d_row, d_col = np.divmod(sample, width)
    d_row, d_col = d_row - start_row, d_col - start_col
    if wrap_columns:
        d_col = (d_col + width // 2) % width - width // 2
    nearest = np.argmin(d_row * d_row + d_col * d_col)
    d_row, d_col = int(d_row[nearest]), int(d_col[nearest])
    steps = np.linspace(0.0, 1.0, max(abs(d_row), abs(d_col)) + 1)
    line_rows = np.rint(start_row + d_row * steps).astype(np.int64)
    line_cols = np.rint(start_col + d_col * steps).astype(np.int64) % width
    line = line_rows * width + line_cols
    line = line[(flat[line] != region) & ~np.isin(line, piece)]
    points = xyz[line]
    valid = np.isfinite(points).all(axis=1)
    line, points = line[valid], points[valid]
    if line.size < 2:
        return False
    ranges = np.linalg.norm(points, axis=1)
    cosines = (points @ plane.normal) / np.maximum(ranges, 1e-12)
    with np.errstate(divide="ignore", invalid="ignore"):
        meets = plane.d / cosines  # the range at which each ray meets the plane
        bound = k_sigma * np.maximum(sigma[line], plane.rms / np.abs(cosines))
        beyond = (meets > 0) & np.isfinite(meets) & (ranges - meets > bound)
    count = int(np.count_nonzero(beyond))
    return count >= 2 and count > SEEN_PAST_SHARE * line.size
