"""End caps a full-resolution cylinder region holds, split off as planes of their own.

A depth camera sees a pipe's end cap at 4-5 m as a disc a few tiles across whose pixels lie
within the range noise of the pipe's cylinder (kinect_real_640x480 study seed 1305 scan 3 and
seed 1311 scan 0: caps of 300 and 656 px on pipes of 0.152 and 0.146 m radius, their pixels
0.84 and 0.86 noise sigmas off the cylinder at the median). The tile grid's cap split
(:func:`rangeseg_o3d.refinement.facets.cap_split`) sees such a cap on too few tile means, the
pipe's tile model labels it, and the cylinder fitted over both is pulled inside the pipe
(radius 0.094 m for the pipe of 0.146 m).

At full resolution the same split finds the cap, but a quantising camera's depth steps cross
a pipe seen along its axis in terraces at one axial coordinate each, and strips along the
pipe fit a plane better than the cylinder over a few dozen pixels: the split offers those
too. A cap is told from them by what makes it one: it closes the pipe, so no pixel the pipe
keeps lies beyond the cap's plane by more than
:data:`~rangeseg_o3d.fitting.robust.CHI_SQUARE_SIGMAS` of the noise of its coordinate along
the axis; it faces along the axis (within :data:`~rangeseg_o3d.fullres.CAP_COS`); and its
pixels' centroid lies inside the cylinder (as :func:`rangeseg_o3d.fullres.settle_caps` asks
of a cap). On the kinect_real study seeds 1305-1311 (36 scans) the split's first cut reached
that test seven times: four caps, each passing it, and three pieces of a pipe's own side
(26-53 px), each refused; two of the caps (first cuts of 221 and 108 px) ended under the
camera's 288-px floor of a recovered region and stayed with their pipes.
"""

from __future__ import annotations

import numpy as np

from ._numeric import rows_at
from .fitting.primitives import Cylinder
from .fitting.region_fitter import fresh_label, region_indices
from .fitting.robust import CHI_SQUARE_SIGMAS
from .scales import MIN_PIXELS

__all__ = ["split_end_caps", "closes_the_pipe"]


def split_end_caps(cloud, labels: np.ndarray, fits: dict, stats, *, sigma: np.ndarray, fitter, min_size: int,
                   inlier_factor: float, wrap_columns: bool = False):
    """Each cylinder region's end cap (:func:`rangeseg_o3d.refinement.facets.cap_split` at full
    resolution, held to :func:`closes_the_pipe`) becomes a plane region of its own under a new
    label, the cylinder refitted to the rest. ``sigma`` is the pixels' range noise, ``min_size``
    the fewest pixels of a region (the cap and what the pipe keeps alike). Returns ``(labels,
    fits, stats)``; the inputs when no cap is split off."""
    from .fullres import stats_after_moves
    from .refinement.context import Context
    from .refinement.facets import cap_split

    cylinders = {k for k, m in fits.items() if isinstance(m, Cylinder) and k > 0}
    if not cylinders:
        return labels, fits, stats
    if sigma.shape != labels.shape:
        raise ValueError(f"split_end_caps: sigma needs one value a pixel of the {labels.shape} labels, "
                         f"got {sigma.shape}")
    noise = np.ascontiguousarray(sigma, dtype=np.float64)
    # the split searches down to the fewest returns that tell a plane: its first piece, cut with
    # the pulled-in cylinder, is smaller than the cap it ends with (kinect_real study seed 1308
    # scan 0: a cap of 325 px, under the sensor's 288-px floor at the first cut)
    ctx = Context(cloud, fitter, noise, min(MIN_PIXELS, int(min_size)), wrap_columns=wrap_columns)
    flat_noise = noise.ravel()

    def closes(rest, piece, cylinder, plane):  # the first cut asked too: most offers end there
        return closes_the_pipe(ctx.xyz, flat_noise, rest, piece, cylinder, plane)

    caps = []
    for k, idx in region_indices(labels, only=cylinders).items():
        model = fits[k]
        if (idx.size < 2 * min_size or _sees_the_inside(model)
                or _beyond_the_sensor_both_ways(ctx.xyz, flat_noise, idx, model)):
            continue
        split = cap_split(ctx, model, idx, None, closes=closes)
        if len(split) != 2:
            continue
        (kept, cylinder), (cap, plane) = split
        if min(kept.size, cap.size) >= min_size and closes(kept, cap, cylinder, plane):
            caps.append((k, cylinder, cap, plane))
    if not caps:
        return labels, fits, stats
    out, fits = np.array(labels, dtype=np.int32, order="C", copy=True), dict(fits)
    first = fresh_label(labels, fits)
    flat = out.ravel()
    for label, (k, cylinder, cap, plane) in enumerate(caps, start=first):
        flat[cap] = label
        fits[k], fits[label] = cylinder, plane
    moved = np.sort(np.concatenate([cap for _, _, cap, _ in caps]))
    refitted = {k for k, *_ in caps} | set(range(first, first + len(caps)))
    stats = stats_after_moves(cloud.xyz, noise, labels, out, fits, stats, moved, refitted,
                              inlier_factor=inlier_factor, first_new=first)
    return out.astype(labels.dtype, copy=False), fits, stats


def closes_the_pipe(xyz: np.ndarray, sigma: np.ndarray, pipe: np.ndarray, cap: np.ndarray, cylinder,
                    plane) -> bool:
    """Whether the plane of the flat pixels ``cap`` is the end cap of ``cylinder`` over the flat
    pixels ``pipe`` (``xyz`` (N, 3) points, ``sigma`` their range noise): it faces along the
    axis within :data:`~rangeseg_o3d.fullres.CAP_COS`, the cap's centroid lies inside the
    cylinder, the sensor (at the origin) lies beyond the cap's plane (a disc closing a pipe is
    seen from outside the pipe's end), and no pixel of the pipe lies beyond that plane (on the
    side away from the pipe's middle) by more than ``CHI_SQUARE_SIGMAS`` times the noise of
    its axial coordinate (its range noise times the cosine between its ray and the axis)."""
    from .fullres import CAP_COS
    from .refinement.facets import axial_noise

    axis = np.asarray(cylinder.axis, dtype=np.float64)
    if abs(float(np.dot(plane.normal, axis))) < CAP_COS:
        return False
    cap_points, pipe_points = rows_at(xyz, cap), rows_at(xyz, pipe)
    if cylinder.distances(cap_points.mean(axis=0)[None])[0] >= 0.0:  # the centroid outside the cylinder
        return False
    along = (pipe_points - cylinder.point) @ axis
    end = float(np.median((cap_points - cylinder.point) @ axis))
    outward = 1.0 if end > float(np.median(along)) else -1.0
    if outward * (-float(np.dot(cylinder.point, axis)) - end) <= 0.0:
        return False  # the sensor behind the cap's plane: it would see the cap's inner face
    beyond = outward * (along - end) > CHI_SQUARE_SIGMAS * axial_noise(pipe_points, sigma[pipe], axis)
    return not bool(np.any(beyond))


def _beyond_the_sensor_both_ways(xyz: np.ndarray, sigma: np.ndarray, idx: np.ndarray, cylinder) -> bool:
    """Whether pixels of the cylinder region ``idx`` (flat; ``sigma`` their range noise) lie
    on both sides of the sensor along the axis, by more than ``CHI_SQUARE_SIGMAS`` of their
    range noise: then the sensor is within the pipe's span and sees neither end's cap from
    outside (:func:`closes_the_pipe`), and the cap split need not run (a pipe seen broadside;
    in one run each, the search cost stereo study seed 1305 scan 0 6.0 ms, 2.4 ms once such
    pipes were skipped)."""
    along = rows_at(xyz, idx) @ np.asarray(cylinder.axis, dtype=np.float64)  # the sensor's is 0
    margin = CHI_SQUARE_SIGMAS * sigma[idx]
    return bool(np.any(along > margin) and np.any(along < -margin))


def _sees_the_inside(cylinder) -> bool:
    """Whether the sensor (at the origin) is inside the cylinder: a tunnel's, not a pipe's.
    From there the side is seen from within, and a cap along with it only from within the
    pipe's end, its inner face (:func:`closes_the_pipe` refuses it); the search is skipped (a
    185000-px tunnel wall, cape_tunnel, cost it 34 ms a frame, for no cap)."""
    return bool(cylinder.distances(np.zeros((1, 3)))[0] < 0.0)
