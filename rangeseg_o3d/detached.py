"""A curved region's small pieces apart from its body, given to the region around them.

A model is unbounded where its region is not: a pipe's cylinder runs on past the pipe's end,
a box face fitted as a wide cylinder bends on past its edges, and where that continuation
crosses another surface within the range noise, the labelling by the tile models hands the
crossing's pixels that happen to lie nearer the model to that region, as specks inside the
other surface's region. On kinect_real_640x480 study seed 1317 scan 4 a pipe's region of
1532 px held 323 px of a wall 2 m behind it along the arc where its cylinder met the wall,
which left the pipe under the 80 % share a correct detection needs; on seed 1317 scan 0 a
box face at 5.2-5.6 m fitted as a cylinder of r 0.83 m held 659 px of the wall 1.5 m behind
it, and without them the face is a plane region.

Over the regions of 24 scans of two study seeds (1317, 1318: kinect_640x480 and
kinect_real_640x480), the pieces of a region apart from its largest piece under 50 px held
2629 px, 11 % of them the region's own surface; the cylinders' pieces of 50-368 px held 751
px, none of them the cylinder's surface. Only curved regions give: asked of plane regions
too, it handed a face's own specks to its neighbour and left the face under a correct
detection's share (kinect_real study seed 1325 scan 0: 878 of its 1101 px), and the planes'
specks gained no surface on the ten study seeds it was tried on.
"""

from __future__ import annotations

import numpy as np

from .fitting.region_fitter import model_table
from .kernels.kinds import CYLINDER, SPHERE

__all__ = ["give_detached_pieces", "specks_apart"]


def specks_apart(noise) -> bool:
    """Whether a curved region's pieces apart from its body are specks of other surfaces under
    the noise model ``noise`` (a :class:`rangeseg_o3d.sensor.NoiseModel`): not under a stereo
    matcher's, which errs together over its matching window (``matched_window``) with no
    stated depth steps (``step_quadratic == 0``). There the curved region's own surface breaks
    into pieces as well: on stereo_1280x720 study seeds 1317 and 1318, 580 of the 1175 px of
    its cylinders' pieces apart under 288 px were the cylinder's own surface, against 20 of 829
    px on kinect_real_640x480 (errors over 9 px too, and disparity steps); on stereo the step
    lost five surfaces over 21 seeds and gained two."""
    return not noise.matched_window or noise.step_quadratic > 0.0


def give_detached_pieces(cloud, labels: np.ndarray, fits: dict, stats, *, sigma: np.ndarray, ranges: np.ndarray,
                         k_sigma: float, jump_ratio: float, jump_min: float, max_size: int, inlier_factor: float,
                         wrap_columns: bool = False):
    """Each piece of a cylinder or sphere region apart from the region's largest (4-connected,
    under ``max_size`` pixels) goes to the region it touches most across no range jump
    (:func:`rangeseg_o3d.kernels.detached_pieces`) when that region's model explains every
    pixel of it within ``k_sigma``
    times the larger of its range noise (``sigma``) and the model's rms, as the labelling asks
    of a model (:func:`rangeseg_o3d.fullres.label_pixels`). ``ranges`` (H, W), NaN where
    invalid, for the jump test of ``jump_ratio`` (per grid step) and ``jump_min``. Returns
    ``(labels, stats)``; the inputs when no piece moves. Models are not refitted: a few pixels
    within the noise of both models move neither.
    """
    from .fullres import stats_after_moves
    from .kernels import detached_pieces

    if sigma.shape != labels.shape or ranges.shape != labels.shape:
        raise ValueError(f"give_detached_pieces: sigma and ranges need one value a pixel of the {labels.shape} "
                         f"labels, got {sigma.shape} and {ranges.shape}")
    grid = np.ascontiguousarray(labels, dtype=np.int32)
    kinds, params, rms = model_table(fits, int(grid.max(initial=0)) + 1)
    pixels, starts, hosts = detached_pieces(
        grid, (kinds == CYLINDER) | (kinds == SPHERE), np.ascontiguousarray(cloud.xyz.reshape(-1, 3)),
        np.ascontiguousarray(ranges, dtype=np.float64), np.ascontiguousarray(sigma, dtype=np.float64).ravel(),
        kinds, params, rms, float(k_sigma), float(jump_ratio), float(jump_min), int(max_size), bool(wrap_columns))
    if not hosts.size:
        return labels, stats
    out = grid.copy()
    out.ravel()[pixels] = np.repeat(hosts, np.diff(starts)).astype(np.int32)
    moved = np.sort(pixels)
    stats = stats_after_moves(cloud.xyz, sigma, grid, out, fits, stats, moved, set(), inlier_factor=inlier_factor)
    return out.astype(labels.dtype, copy=False), stats
