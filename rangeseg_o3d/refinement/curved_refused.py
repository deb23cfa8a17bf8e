"""Recovered planes the noise of their distances refuses, given the curved model that explains them.

:func:`rangeseg_o3d.refinement.recover.recover_pixels` refuses a plane found in a leftover
blob at full resolution whose pixels lie beyond the noise of their distances to it
(:meth:`rangeseg_o3d.refinement.context.Context.plane_along_rays`). A curved surface seen
head-on keeps almost all its range noise in those distances: where its bend is what the plane
leaves over that noise, the fitter, asked to resolve bends over the sensor's independent
returns, finds the cylinder or sphere, and that model is held to the same noise.
"""

from __future__ import annotations

import numpy as np

from .._numeric import rows_at

from ..fitting.robust import beyond_noise, distance_noise
from .context import Context, touching
from .merge import similar_models

__all__ = ["full_resolution_samples", "curved_for_refused"]


def full_resolution_samples(sensor) -> float:
    """The independent samples each single return of ``sensor`` carries for the fitter's
    bend test (:meth:`rangeseg_o3d.sensor.NoiseModel.independent_share` of one pixel: 1
    where returns err alone, 1/9 over a stereo camera's 3-pixel window), 0 where its depth
    is quantised (``depth_step``: neighbours share a step, and a terrace of steps is no
    bend the noise model explains)."""
    if sensor.depth_step > 0:
        return 0.0
    return sensor.noise.independent_share(1)


def curved_for_refused(ctx: Context, labels: np.ndarray, fits: dict, new: dict, refused: set, samples: float,
                       config, *, pixels: dict) -> tuple[np.ndarray, set]:
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
    """
    if not refused or not samples or "noise_floor" not in ctx.fitter.params:  # (a keyword of the primitives fitter)
        return labels, refused
    taken, copied = set(), False
    for k in sorted(refused):
        idx = pixels.get(k)
        if idx is None or idx.size < ctx.min_size:
            continue
        model = ctx.fitter.fit(ctx.fitter.points(ctx.xyz, idx), resolve_bends=float(samples))
        if not model or model.kind == "plane":
            continue
        points = rows_at(ctx.xyz, idx)
        noise = distance_noise(model, points, ctx.sigma[idx])
        rms = float(np.sqrt(np.mean(model.distances(points) ** 2)))
        if not beyond_noise(rms, float(np.sqrt(np.mean(noise * noise))), int(idx.size)):
            taken.add(k)
            host = _curved_host(ctx, fits, new, model, points, config,
                                near=None if config.merge_disjoint else touching(labels, idx, reach=2)
                                ) if config.merge else None
            if host is None:
                fits[k] = new[k] = model
                continue
            if not copied:
                labels, copied = labels.copy(), True
            labels.reshape(-1)[idx] = host
            del fits[k], new[k]
    return labels, refused - taken


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
