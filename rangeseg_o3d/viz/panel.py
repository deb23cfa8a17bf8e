"""A PNG for people without the rerun viewer: range, residual, edges and labels side by side.

Each tile is the scan grid upscaled by one integer factor (pixels stay square and
sharp), under a small title bar. A stage the segmenter did not produce is drawn as a
labelled grey tile.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np

from ..cloud import OrganizedCloud
from ..result import Result
from .colors import region_colors

__all__ = ["render_panel", "write_panel_png", "panel_scale", "TITLE_HEIGHT", "GAP", "TILES"]

log = logging.getLogger(__name__)

#: Tiles, left to right.
TILES = ("range", "residual", "edges", "labels")
#: Height in pixels of the title bar above each tile.
TITLE_HEIGHT = 24
#: Width in pixels of the gap between tiles.
GAP = 4
#: Minimum tile width, so that the title fits.
MIN_TILE_WIDTH = 160
#: Automatic scaling aims for tiles at least this tall (pixels) ...
TARGET_HEIGHT = 200
#: ... but never enlarges more than this.
MAX_SCALE = 8

_BACKGROUND = 64
_TITLE_BG = 24
_MISSING_GREY = 128
_INVALID_BGR = (0, 0, 0)


def panel_scale(shape: tuple[int, int]) -> int:
    """Integer upscaling factor for a grid of ``shape`` (70 x 131 gives 3; VGA gives 1)."""
    return int(min(MAX_SCALE, max(1, math.ceil(TARGET_HEIGHT / max(1, shape[0])))))


def _normalise(values: np.ndarray, valid: np.ndarray, lo: float, hi: float) -> np.ndarray:
    span = hi - lo if hi > lo else 1.0
    scaled = np.clip((np.where(valid, values, lo) - lo) / span, 0.0, 1.0)
    return np.round(scaled * 255).astype(np.uint8)


def _colormap(values: np.ndarray, valid: np.ndarray, lo: float, hi: float, cmap: int) -> np.ndarray:
    import cv2

    bgr = cv2.applyColorMap(_normalise(values, valid, lo, hi), cmap)
    bgr[~valid] = _INVALID_BGR
    return bgr


def _range_tile(cloud: OrganizedCloud) -> tuple[np.ndarray, str]:
    import cv2

    ranges = np.asarray(cloud.range_image(), dtype=float)
    valid = np.isfinite(ranges) & (ranges > 0)
    if not valid.any():
        return np.zeros(ranges.shape + (3,), np.uint8), "range (no returns)"
    lo, hi = float(ranges[valid].min()), float(ranges[valid].max())
    return _colormap(ranges, valid, lo, hi, cv2.COLORMAP_TURBO), f"range {lo:.2f}-{hi:.2f} m"


def _residual_tile(residual: np.ndarray) -> tuple[np.ndarray, str]:
    import cv2

    residual = np.asarray(residual, dtype=float)
    valid = np.isfinite(residual)
    if not valid.any():
        return np.zeros(residual.shape + (3,), np.uint8), "residual (all NaN)"
    # The 99th percentile keeps a few spikes at depth jumps from washing out the rest.
    lo = float(residual[valid].min())
    hi = float(np.percentile(residual[valid], 99))
    return _colormap(residual, valid, lo, hi, cv2.COLORMAP_INFERNO), f"residual {lo:.3g}-{hi:.3g}"


def _edges_tile(edges: np.ndarray) -> tuple[np.ndarray, str]:
    edges = np.asarray(edges)
    mask = edges.astype(bool) if edges.dtype == bool else (np.nan_to_num(edges) != 0)
    tile = np.zeros(edges.shape + (3,), np.uint8)
    tile[mask] = 255
    return tile, f"edges ({int(mask.sum())} px)"


def _labels_tile(cloud: OrganizedCloud, result: Result) -> tuple[np.ndarray, str]:
    labels = np.asarray(result.labels)
    lut_rgb = region_colors(result)
    tile = lut_rgb[labels][..., ::-1].copy()  # RGB table, BGR tile
    tile[~cloud.valid & (labels == 0)] = _INVALID_BGR
    n_regions = len(np.unique(labels[labels > 0]))
    return tile, f"labels ({n_regions} regions)"


def _put_title(canvas: np.ndarray, text: str) -> None:
    import cv2

    width = canvas.shape[1]
    font = cv2.FONT_HERSHEY_SIMPLEX
    scale = 0.45
    while scale > 0.3 and cv2.getTextSize(text, font, scale, 1)[0][0] > width - 8:
        scale -= 0.05
    while len(text) > 1 and cv2.getTextSize(text, font, scale, 1)[0][0] > width - 8:
        text = text[:-2] + "~"
    baseline = TITLE_HEIGHT - 8
    cv2.putText(canvas, text, (4, baseline), font, scale, (255, 255, 255), 1, cv2.LINE_AA)


def _tile(image: np.ndarray | None, title: str, shape: tuple[int, int], scale: int) -> np.ndarray:
    import cv2

    height, width = shape[0] * scale, shape[1] * scale
    canvas = np.full((TITLE_HEIGHT + height, max(width, MIN_TILE_WIDTH), 3), _BACKGROUND, np.uint8)
    canvas[:TITLE_HEIGHT] = _TITLE_BG
    _put_title(canvas[:TITLE_HEIGHT], title)
    body = canvas[TITLE_HEIGHT:, :width]
    if image is None:
        body[:] = _MISSING_GREY
        text = "not provided"
        size = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.45, 1)[0]
        origin = (max(2, (width - size[0]) // 2), max(size[1] + 2, (height + size[1]) // 2))
        cv2.putText(body, text, origin, cv2.FONT_HERSHEY_SIMPLEX, 0.45, (32, 32, 32), 1, cv2.LINE_AA)
    else:
        body[:] = cv2.resize(image, (width, height), interpolation=cv2.INTER_NEAREST)
    return canvas


def _check(cloud, result) -> None:
    if not isinstance(cloud, OrganizedCloud):
        raise TypeError(f"cloud must be an OrganizedCloud; got {type(cloud).__name__}")
    if not isinstance(result, Result):
        raise TypeError(f"result must be a rangeseg_o3d.Result; got {type(result).__name__}")
    labels = np.asarray(result.labels)
    if labels.shape != cloud.shape:
        raise ValueError(f"result.labels must have shape {cloud.shape} (the grid); got {labels.shape}")
    if not np.issubdtype(labels.dtype, np.integer) or (labels.size and labels.min() < 0):
        raise ValueError(f"result.labels must be non-negative integers; got dtype {labels.dtype}")
    for name in ("residual", "edges"):
        image = result.stages.get(name)
        if image is not None and np.shape(image) != cloud.shape:
            raise ValueError(
                f"stage image {name!r} must have shape {cloud.shape} (the grid); got {np.shape(image)}"
            )


def render_panel(cloud: OrganizedCloud, result: Result, *, scale: int | None = None) -> np.ndarray:
    """Range, residual, edges and labels side by side, each under a title.

    Parameters
    ----------
    cloud : OrganizedCloud
    result : Result
        ``result.stages["residual"]`` and ``["edges"]`` are used when present; otherwise
        their tiles are grey and say "not provided".
    scale : int, optional
        Integer upscaling of the grid; :func:`panel_scale` by default.

    Returns
    -------
    (TITLE_HEIGHT + H * scale, 4 * max(W * scale, MIN_TILE_WIDTH) + 3 * GAP, 3) uint8
        RGB image.

    Raises
    ------
    TypeError, ValueError
        For inputs of the wrong type or shape, or a scale that is not a positive integer.
    """
    import cv2

    _check(cloud, result)
    if scale is None:
        scale = panel_scale(cloud.shape)
    if isinstance(scale, bool) or not isinstance(scale, (int, np.integer)) or scale < 1:
        raise ValueError(f"scale must be a positive integer; got {scale!r}")
    residual = result.stages.get("residual")
    edges = result.stages.get("edges")
    images = [
        _range_tile(cloud),
        _residual_tile(residual) if residual is not None else (None, "residual"),
        _edges_tile(edges) if edges is not None else (None, "edges"),
        _labels_tile(cloud, result),
    ]
    tiles = [_tile(image, title, cloud.shape, int(scale)) for image, title in images]
    gap = np.full((tiles[0].shape[0], GAP, 3), _BACKGROUND, np.uint8)
    pieces = [tiles[0]]
    for tile in tiles[1:]:
        pieces += [gap, tile]
    return cv2.cvtColor(np.concatenate(pieces, axis=1), cv2.COLOR_BGR2RGB)


def write_panel_png(path, cloud: OrganizedCloud, result: Result, *, scale: int | None = None) -> Path:
    """Render :func:`render_panel` and write it to ``path`` atomically.

    Parameters
    ----------
    path : str or os.PathLike
        Destination, ending in ``.png``; its directory must exist.
    cloud, result, scale
        As for :func:`render_panel`.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    import cv2

    from ..io.atomic import atomic_write

    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"path must end in .png; got {str(path)!r}")
    panel = render_panel(cloud, result, scale=scale)
    ok, encoded = cv2.imencode(".png", cv2.cvtColor(panel, cv2.COLOR_RGB2BGR))
    if not ok:
        raise RuntimeError(f"OpenCV could not encode the {panel.shape} panel as PNG")
    with atomic_write(path, "wb") as handle:
        handle.write(encoded.tobytes())
    log.info("wrote panel %s (%d x %d)", path, panel.shape[1], panel.shape[0])
    return path
