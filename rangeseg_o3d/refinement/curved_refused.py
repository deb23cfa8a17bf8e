"""Recovered planes the noise of their distances refuses, given the curved model that explains them.

:func:`rangeseg_o3d.refinement.recover.recover_pixels` refuses a plane found in a leftover
blob at full resolution whose pixels lie beyond the noise of their distances to it
(:meth:`rangeseg_o3d.refinement.context.Context.plane_along_rays`). A curved surface seen
head-on keeps almost all its range noise in those distances: where its bend is what the plane
leaves over that noise, the fitter, asked to resolve bends over the sensor's independent
returns, finds the cylinder or sphere, and that model is held to the same noise.

Where the range noise exceeds the grid's footprint (a Kinect: :func:`rangeseg_o3d.scales.noise_spans_the_grid`)
a pipe or ball a few dozen pixels across spreads farther along its rays than across them: the
least-squares plane of its pixels turns towards the rays and fits them closer than the true
cylinder does, and the geometric curved fits start from that spread and fail. There the fitter
is asked once more on the blob's means over small blocks of its own pixels
(:func:`block_means`), whose noise is under the block's footprint, and the model it finds is
held, as ever, to the noise of the raw pixels' distances.
"""

from __future__ import annotations

import numpy as np

from .._numeric import rows_at

from ..fitting.primitives import with_statistics
from ..fitting.robust import beyond_noise, distance_noise
from .context import Context, touching
from .merge import similar_models

__all__ = ["full_resolution_samples", "curved_for_refused", "mean_window", "block_means"]


def full_resolution_samples(sensor) -> float:
    """The independent samples each single return of ``sensor`` carries for the fitter's
    bend test (:meth:`rangeseg_o3d.sensor.NoiseModel.independent_share` of one pixel: 1
    where returns err alone, 1/9 over a stereo camera's 3-pixel window), 0 where its depth
    is quantised (``depth_step``: neighbours share a step, and a terrace of steps is no
    bend the noise model explains)."""
    if sensor.depth_step > 0:
        return 0.0
    return sensor.noise.independent_share(1)


def mean_window(sigma: float, distance: float, step: float) -> int:
    """The odd window (pixels a side, at least 3) whose mean of independent returns has its
    noise under the window's footprint: ``w`` with ``sigma / w <= w distance step``, ``sigma`` the range noise
    at ``distance`` (m) and ``step`` the grid's angular step (radians). A Kinect at 2-5 m: 3."""
    if not (sigma > 0 and distance > 0 and step > 0):
        raise ValueError(f"mean_window: expected positive sigma, distance and step; got {sigma}, {distance}, {step}")
    w = int(np.ceil(np.sqrt(sigma / (distance * step))))
    return max(3, w + 1 - w % 2)


def block_means(xyz: np.ndarray, width: int, idx: np.ndarray, window: int) -> np.ndarray:
    """The mean points of pixels ``idx`` (flat indices into an organized ``(H * W, 3)`` grid
    ``xyz`` of ``width`` columns) over disjoint ``window`` x ``window`` blocks of the grid
    (from the pixels' first row and column), one per block holding at least half a block of
    them: a tile mean of their own pixels only (no return of a neighbouring surface), each an
    independent sample with its range noise divided by up to ``window``. Four bincounts."""
    idx = np.asarray(idx, dtype=np.int64)
    if window < 1:
        raise ValueError(f"block_means: expected a window >= 1; got {window}")
    if idx.size == 0:
        return np.zeros((0, 3))
    rows, cols = np.divmod(idx, int(width))
    across = (int(cols.max()) - int(cols.min())) // window + 1
    block = (rows - rows.min()) // window * across + (cols - cols.min()) // window
    counts = np.bincount(block)
    points = rows_at(xyz, idx)
    sums = np.stack([np.bincount(block, weights=points[:, i], minlength=counts.size) for i in range(3)], axis=1)
    kept = counts >= 0.5 * window * window
    return sums[kept] / counts[kept, None]


def curved_for_refused(ctx: Context, labels: np.ndarray, fits: dict, new: dict, refused: set, samples: float,
                       config, *, pixels: dict, step: float = 0.0) -> tuple[np.ndarray, set]:
    """``(labels, refused)`` with the planes of ``refused`` (found in the blobs, ``new``;
    ``pixels``: their flat pixels, increasing) whose pixels the fitter, asked to
    resolve bends over ``samples`` independent samples a pixel (0: not asked), calls a
    cylinder or a sphere that explains them within the noise of their distances to it
    taken out of the set: ``fits`` and ``new`` (changed in place) take that model, and the
    surface is recovered as any other (its rim, its claims); a piece of a curved region
    the scan has (:func:`_curved_host`) joins it instead (``labels`` then a changed copy).

    A pillar near the camera whose tile means all straddle its bend is left to the
    full-resolution pass whole; there a plane fits it within the range noise (its rms under
    the fitter's threshold), but not within the noise of its distances, which a curved
    surface seen head-on keeps almost whole: the plane is refused and, without this, the
    pillar freed (kinect seed 89 scan 3: 5247 px at 3.1 m, plane rms 11.1 mm against
    10.6 mm distance noise; its cylinder, r 0.15 m, 9.6 mm). The fitter's own tests
    (arc, radius, the F-test of the curvature over the independent samples) decide the
    kind; the distance noise then holds the curved model as it held the plane.

    ``step`` (radians, 0: not asked): the grid's angular step where the range noise exceeds its
    footprint (a Kinect's). When the pixels give no curved model within that noise, the fitter
    is asked on their means over disjoint blocks of :func:`mean_window` pixels a side
    (:func:`block_means`, each mean an independent sample): a pipe 0.13-0.17 m
    across at 4 m (kinect fresh seeds 1011 and 1018, 2300-2800 px) fits its pixels' plane at
    10-11 mm against its true cylinder's 12.5-13 mm under 23 mm of range noise, and was freed.
    """
    if not refused or not samples or "noise_floor" not in ctx.fitter.params:  # (a keyword of the primitives fitter)
        return labels, refused
    taken, copied = set(), False
    for k in sorted(refused):
        idx = pixels.get(k)
        if idx is None or idx.size < ctx.min_size:
            continue
        model = ctx.fitter.fit(ctx.fitter.points(ctx.xyz, idx), resolve_bends=float(samples))
        points = rows_at(ctx.xyz, idx)
        within = bool(model) and model.kind != "plane" and _within_noise(ctx, model, points, idx)
        by_means = False
        if not within and step > 0:  # the pixels' spread along the rays misled the fit: their means
            window = mean_window(float(np.median(ctx.sigma[idx])), float(np.median(np.linalg.norm(points, axis=1))),
                                 step)
            # means over disjoint blocks: each an independent sample, and a ninth of the points to fit
            model = ctx.fitter.fit(block_means(ctx.xyz, ctx.width, idx, window), resolve_bends=float(samples))
            within = bool(model) and model.kind != "plane" and _within_noise(ctx, model, points, idx)
            if within:  # (its rms, as every recovered model's, is its pixels')
                model = with_statistics(model, rms=float(np.sqrt(np.mean(model.distances(points) ** 2))))
                by_means = True
        if within:
            taken.add(k)
            near = None if config.merge_disjoint else touching(labels, idx, reach=2)
            host = _curved_host(ctx, fits, new, model, points, config, near=near) if config.merge else None
            if host is None and by_means and config.merge:
                # a model of the means is known to a few centimetres of radius: the piece is a
                # piece of a curved region the scan has when that region's model explains its
                # pixels within the noise of their distances (a pipe's flank beside its tile
                # cylinder, kinect seeds 37 and 1001: kept apart, the pipe was over-segmented)
                host = _curved_host_within_noise(ctx, fits, new, points, idx, near)
            if host is None:
                fits[k] = new[k] = model
                continue
            if not copied:
                labels, copied = labels.copy(), True
            labels.reshape(-1)[idx] = host
            del fits[k], new[k]
    return labels, refused - taken


def _within_noise(ctx: Context, model, points: np.ndarray, idx: np.ndarray) -> bool:
    # the model's rms over the pixels within the noise of their distances to it
    noise = distance_noise(model, points, ctx.sigma[idx])
    rms = float(np.sqrt(np.mean(model.distances(points) ** 2)))
    return not beyond_noise(rms, float(np.sqrt(np.mean(noise * noise))), int(idx.size))


def _curved_host_within_noise(ctx: Context, fits: dict, new: dict, points: np.ndarray, idx: np.ndarray,
                              near: set | None = None):
    """The curved region of ``fits`` (not among ``new``; among ``near`` when given) whose model
    explains ``points`` (pixels ``idx``) within the noise of their distances to it, the
    closest in rms; or None."""
    best, best_rms = None, np.inf
    for c, other in fits.items():
        if c in new or (near is not None and c not in near) or not other or other.kind == "plane":
            continue
        if _within_noise(ctx, other, points, idx):
            rms = float(np.sqrt(np.mean(other.distances(points) ** 2)))
            if rms < best_rms:
                best, best_rms = c, rms
    return best


def _curved_host(ctx: Context, fits: dict, new: dict, model, points: np.ndarray, config, near: set | None = None):
    """The curved region of ``fits`` (not among ``new``; among ``near`` when given: the
    regions a piece may join without ``merge_disjoint``) of ``model``'s kind that could be
    the same surface (:func:`rangeseg_o3d.refinement.merge.similar_models`) and whose
    model, as it stands, fits ``points`` (a piece ``model`` fits) within
    ``config.merge_rms_factor`` of ``model``'s rms; the closest such, or None. The piece of
    a pillar that the tile grid left beside the pillar's cylinder (kinect seed 71 scan 3:
    941 px, 3.7 m): their union's refit would hold the curvature to the fitter's gain over
    the plane (1.29 there, 1.5 asked), which a pillar far away under a camera's noise does
    not reach, while each part resolved its bend."""
    best, best_rms = None, config.merge_rms_factor * model.rms
    for c, other in fits.items():
        if c in new or (near is not None and c not in near) or not other or other.kind != model.kind:
            continue
        if not similar_models(model, other, max_angle_deg=config.merge_angle_deg, tolerance=config.merge_tolerance):
            continue
        rms = float(np.sqrt(np.mean(other.distances(points) ** 2)))
        if rms <= best_rms:
            best, best_rms = c, rms
    return best
