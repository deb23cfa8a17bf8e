"""Edge mask from the residual image: jump edges, grey-level closing, threshold."""

from __future__ import annotations

import numpy as np

from .._numeric import median

__all__ = ["jump_edges", "close_residual", "edge_mask", "angular_steps", "crease_edges"]

# A range step that the steps before and after it on the same line continue within this
# share of itself lies on a surface seen at a grazing angle (its steps change slowly): no
# jump. An occlusion's step has the occluder's small steps on one side at least.
JUMP_CONTINUATION = 0.5
# Finite stand-in for "no plane could be fitted here" so morphology and display work.
EDGE_CEILING = 1e6


def jump_edges(ranges: np.ndarray, *, jump_ratio: float = 0.08, jump_min: float = 0.05,
               continuation: float = JUMP_CONTINUATION, single_return_noise: float = 0.0) -> np.ndarray:
    """Occluded side of every depth discontinuity.

    Between 4-neighbours whose ranges differ by more than ``max(jump_min, jump_ratio * r)``
    (``r`` the nearer range) the *farther* pixel is marked: the nearer one is a genuine
    point of the occluding surface, and a thin object only a few pixels wide would lose
    most of itself if both sides were marked (PCL calls these occluded vs occluding edges).
    A mixed pixel between foreground and background is farther than the foreground, so it
    is marked too. The relative term follows the scan spacing, which grows linearly with
    range for a sensor with fixed angular steps, so the test behaves the same near and far;
    the absolute floor keeps range noise from triggering it at short range. It catches the
    jumps the plane residual misses, e.g. between parallel surfaces seen almost edge-on.

    Parameters
    ----------
    ranges : (H, W) ranges in metres, NaN where invalid.
    jump_ratio : relative jump threshold.
    jump_min : absolute jump threshold in metres.
    continuation : a step that the steps before and after it along the same row or column
        continue within this share of itself is no jump: a surface seen at a grazing angle
        steps steadily, pixel after pixel (on a fine grid such a face is many pixels wide
        and would otherwise be all edge), while an occlusion's step has the occluder's
        small steps on one side at least. 0 turns this off.
    single_return_noise : the range noise (m) of a laser's single returns, 0 for any other
        sensor. Above 0, a step continued on ONE side is no jump either when the continuing
        step is within ``continuation`` of it by three noises of the difference of two steps
        (``sqrt(6)`` noises) besides. A face two to four grid lines wide seen near grazing
        (a box side a few degrees from the beam) has no step with its own steps on both
        sides: its first step has the corner with the next face on one side, its last the
        jump onto what lies behind it, and the face would be cut into grid lines. Each of a
        laser's returns errs by the range noise alone (millimetres against steps of
        decimetres), so one step continuing the next beyond the noise is that face's steady
        stepping. A pair of steps continuing each other with no jump on either side of
        the pair is a mixed return (a beam's footprint straddling an occlusion, its two steps
        splitting the gap) and stays a jump; a narrow face's pair has the jump onto what lies
        behind it on one side. Not for a camera (the segmenter passes 0): a tile mean straddling an
        occlusion is a depth between the two surfaces, and its two steps, each about half
        the gap, would continue each other.

    Returns
    -------
    (H, W) bool mask.
    """
    from ..kernels import jump_mask

    r = np.asarray(ranges, dtype=np.float64)
    if r.ndim != 2:
        raise ValueError(f"ranges must have shape (H, W); got {r.shape}")
    for name, value in (("jump_ratio", jump_ratio), ("jump_min", jump_min), ("continuation", continuation),
                        ("single_return_noise", single_return_noise)):
        if not (np.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be a finite number >= 0; got {value!r}")
    # one compiled pass: the same test as a dozen whole-image numpy operations, at a tenth
    return jump_mask(np.ascontiguousarray(r), float(jump_ratio), float(jump_min), float(continuation),
                     float(single_return_noise))


def close_residual(residual: np.ndarray, *, iterations: int = 2, kernel: int = 3) -> np.ndarray:
    """Grey-level closing (dilate, then erode) of the residual image, ``iterations`` times.

    Closing fills the gaps along an edge line so that region borders do not leak
    (paper, Sec. 3.2: closing twice). Infinite residuals are clipped to a large finite value.
    """
    res = np.asarray(residual, dtype=np.float64)
    if res.ndim != 2:
        raise ValueError(f"residual must have shape (H, W); got {res.shape}")
    if iterations < 0:
        raise ValueError(f"iterations must be >= 0; got {iterations}")
    if not (isinstance(kernel, (int, np.integer)) and kernel >= 1):  # (OpenCV asserts on 0)
        raise ValueError(f"kernel must be an integer >= 1; got {kernel!r}")
    # fmin drops NaN for the ceiling; in float32 (rounding first, then the minimum, gives
    # the same image: the ceiling is exact in float32) without whole-image temporaries
    img = np.fmin(res, EDGE_CEILING, dtype=np.float32)
    if iterations == 0:
        return img
    import cv2  # here, not at module level: importing the stage stays light

    element = cv2.getStructuringElement(cv2.MORPH_RECT, (kernel, kernel))
    return cv2.morphologyEx(
        img, cv2.MORPH_CLOSE, element, iterations=iterations, borderType=cv2.BORDER_REPLICATE
    )


def edge_mask(closed: np.ndarray, *, threshold: float, valid: np.ndarray | None = None,
              jumps: np.ndarray | None = None) -> np.ndarray:
    """Binary edge image: closed residual above ``threshold``, jump edges, and invalid pixels."""
    if not threshold > 0:
        raise ValueError(f"threshold must be positive; got {threshold}")
    edges = np.asarray(closed) > threshold
    if edges.ndim != 2:
        raise ValueError(f"closed must have shape (H, W); got {edges.shape}")
    for name, mask in (("jumps", jumps), ("valid", valid)):
        if mask is not None and np.shape(mask) != edges.shape:
            raise ValueError(f"{name} must have the shape of closed {edges.shape}; got {np.shape(mask)}")
    if jumps is not None:
        edges |= jumps
    if valid is not None:
        edges |= ~valid
    return edges


def angular_steps(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The grid's angular spacing (radians) at every pixel, to the next row and column.

    Measured between the viewing directions of neighbouring pixels: it needs no sensor
    geometry, follows the grid where its spacing varies (a nodding scanner's rows crowd
    at the lateral beams), and range noise does not move a point's direction from the
    sensor. NaN where a neighbour is invalid.
    """
    from ..kernels import ray_steps

    xyz = np.ascontiguousarray(xyz, dtype=np.float64)
    if xyz.ndim != 3 or xyz.shape[2] != 3:
        raise ValueError(f"xyz must have shape (H, W, 3); got {xyz.shape}")
    steps = ray_steps(xyz)
    return steps[0], steps[1]


def _slope_noise(sigma, spacing, window: int):
    # Standard deviation (radians) of a least-squares plane's tilt over a window x window
    # grid of points ``spacing`` apart with orthogonal noise ``sigma``.
    return sigma / (spacing * np.sqrt(window * window * (window * window - 1) / 12.0))


def crease_edges(xyz: np.ndarray, ranges: np.ndarray, sigma: np.ndarray, *,
                 min_angle_deg: float = 20.0, k_sigma: float = 4.0, visible_ratio: float = 1.0,
                 max_window: int = 9):
    """Creases the 3x3 residual cannot see: normal discontinuities between flanking windows.

    Where the range noise ``sigma`` is comparable to the point spacing (range times the
    grid's angular step, measured from the cloud by :func:`angular_steps`) a 3x3 window
    straddling a crease differs from a plane by about one noise sigma, so the paper's
    residual misses it. The normals of wider windows are well determined even there: the
    window is the smallest (odd, up to ``max_window``) whose normals, compared in pairs,
    have ``k_sigma`` times their predicted tilt noise under ``min_angle_deg`` at the
    median of the grid. A pixel is a crease when the windows centred half a window to
    either side of it (along rows or columns) tilt apart by more than ``min_angle_deg``
    and more than ``k_sigma`` times their predicted noise. The test runs only where the
    residual is blind: where the spacing is under ``visible_ratio`` noise sigmas (and not
    at all when fewer pixels than one window holds are blind).

    Returns
    -------
    (mask, window) : (H, W) bool crease pixels, and the window used (0 when the test did
    not run because the residual sees creases everywhere).
    """
    from ..kernels import blind_spacing, crease_mask, window_normals
    from .residual import _check_grid

    xyz = np.ascontiguousarray(xyz, dtype=np.float64)
    if xyz.ndim != 3 or xyz.shape[2] != 3:
        raise ValueError(f"xyz must have shape (H, W, 3); got {xyz.shape}")
    ranges = np.ascontiguousarray(ranges, dtype=np.float64)
    if ranges.shape != xyz.shape[:2]:  # the kernels read ranges and sigma at xyz's pixels, unchecked
        raise ValueError(f"ranges must have the shape of the grid {xyz.shape[:2]}; got {ranges.shape}")
    sigma = np.asarray(sigma, dtype=np.float64)
    try:
        sigma = np.ascontiguousarray(np.broadcast_to(sigma, ranges.shape))
    except ValueError:
        raise ValueError(f"sigma must broadcast to the {ranges.shape} grid; got {sigma.shape}") from None
    # The spacing is the range times the smaller angular step (angular_steps: the
    # worse-sampled direction sets how well a window's tilt is determined), kept where it is
    # blind; one compiled pass, which skips the steps' arc sines where the spacing is
    # clearly over the noise (every pixel of a laser scanner's grid).
    spacing, n_blind = blind_spacing(xyz, ranges, sigma, float(visible_ratio))
    if n_blind == 0:
        return np.zeros(ranges.shape, bool), 0
    blind = ~np.isnan(spacing)
    limit = np.sin(np.radians(min_angle_deg))
    middle = median(sigma[blind] / spacing[blind])
    window = next((w for w in range(3, max_window + 1, 2)
                   if k_sigma * np.sqrt(2.0) * _slope_noise(middle, 1.0, w) <= limit), max_window)
    if np.count_nonzero(blind) < window * window:  # too few to hide a surface's crease
        return np.zeros(ranges.shape, bool), 0
    with np.errstate(invalid="ignore", divide="ignore"):
        tolerance = np.maximum(limit, k_sigma * np.sqrt(2.0) * _slope_noise(sigma, spacing, window))
    tolerance = np.where(blind, np.minimum(tolerance, 1.0), np.nan)
    # the test's grid: the blind pixels' box, a window around
    rows, cols = np.nonzero(blind)
    reach = window
    top, left = max(rows.min() - reach, 0), max(cols.min() - reach, 0)
    bottom, right = rows.max() + reach + 1, cols.max() + reach + 1
    box = (slice(top, bottom), slice(left, right))
    # window normals only at the blind pixels: crease_mask compares normals only where the
    # tolerance is set (a third of a 2 cm laser's grid, none of most of a 5 mm one's)
    normals = window_normals(_check_grid(xyz[box], window), int(window), np.ascontiguousarray(blind[box]))
    mask = np.zeros(ranges.shape, bool)
    mask[box] = crease_mask(normals, np.ascontiguousarray(tolerance[box]), window // 2)
    return mask, window
