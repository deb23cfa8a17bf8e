"""Pipes a stereo camera's full-resolution labels hold as plane regions, given their cylinders.

A stereo camera's range noise lies along the rays and grows with the square of the range
(8 cm a sigma at 5 m on the matrix's 1280 x 720 row). A pipe 0.1-0.25 m in radius at 4-6 m
is then a strip 20-40 pixels wide whose least-squares plane in ``xyz`` turns towards the
rays: its rms (20-65 mm) falls far within the noise, the quadric of its heights over that
plane gains nothing (1.000-1.009), and the fitter's decision, with or without its bend test
over the pixels' independent samples, calls it a plane (held-out seeds 709, 719, 727, 739:
four false fittings on eight seeds). Along the rays, the noise's own direction, the bend is
there: the pipe's inverse ranges leave their plane a profile across the pipe's axis that a
quadratic term explains, and a cylinder fitted to the residuals along the rays comes out
near the pipe's radius with its squares well under the plane's.

Here, on a stereo camera (``NoiseModel.matched_window``) only, each plane region whose
plane along the rays, bent across the region's main direction, explains it within the noise
is asked (:func:`cylinders_for_bent_planes`; a pipe seen whole near enough leaves its plane
beyond the noise, and no other step asks a plane region for a cylinder: stereo seed 23
scan 3, a pipe 3.7 m away whose region held 14674 px, kept its plane):

1. the bend, by a linear test: its inverse ranges against their plane along the rays, and
   with a quadratic term across the main direction of the region seen from the camera (an
   F-test over the region's independent returns, ``NoiseModel.independent_share``, whose drop
   must also exceed the sqrt(2n) spread of the squares' chi-square);
2. where it bends, a cylinder fitted along the rays (:func:`_refit_along_rays`, from the
   region's silhouette: the axis along its longest extent across the view, turned into the
   region's plane along the rays, the radius half its width across it), kept when its squares
   fall under the plane's by more than ``CHI_SQUARE_SIGMAS`` sqrt(2 n) in independent returns,
   its radius at most the fitter's ``max_radius``, and the region's width across its axis within
   ``SILHOUETTE_SHARE`` of its diameter (a pipe seen whole shows its diameter; a face a cylinder
   bends over is wider or narrower than the cylinder it makes).

Where the camera also reports depth in steps (``NoiseModel.step_quadratic``: a Kinect's
1/8-px disparity, 84 mm at 5.4 m), the squares are not a chi-square over independent returns:
a pillar 0.35 m across at 5.4 m bends by about two steps and drops them by 7 independent-return
units against the sqrt(2n) = 11 asked, and pipes at 3.7 m that pass that gate (drops of 22-25)
miss the cylinder's 4 sqrt(2n) = 44-46 (kinect_real_640x480 study scans 3/1, 0/4, 71/3: all
three fitted as planes). There the bend is measured against its own scatter
instead (:func:`_bend_over_blocks`): the region is cut along its main direction into blocks
one matching window long, each block's residuals across the region give its own quadratic
term, and the bend stands when their mean is ``CHI_SQUARE_SIGMAS`` standard errors above zero
and convex towards the camera (a pipe's sides recede in every block; a flat face's terraces
and noise turn the term's sign from block to block: t of -3.7..2.4 on the 34 plane regions
asked in eight study scans with false fittings, 4.1-9.9 on three pipes at 3.7-5.4 m, 3.1 on
a pillar at 6.2 m, left a plane). Such pipes often stand against a
wall or behind a box, showing part of their width (0.45-0.8 of the diameter): the cylinder
is started from the bend's curvature as well as from the silhouette, and the region may be
narrower than its diameter, never wider, though not so narrow that the cylinder spans less than
the fitter's ``min_arc_deg`` about its axis (the correlated noise and steps of faces 4 m away
bent cylinders of 3 m over 15 degrees of them). The cylinder must then explain the bend: its squares within
the chi-square spread of those of the plane with the bend.

Only the model's kind changes: the labels stay, the statistics are measured again.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from . import kernels  # the package: its names load on first use (no compiler at import)
from .fitting._compiled import arc_around_axis
from .fitting.classify import MIN_ARC_DEG
from .fitting.primitives import Cylinder, Plane
from .fitting.region_fitter import region_samples
from .fitting.robust import curvature_resolved
from .fullres import region_stats
from .kernels.linalg import CHI_SQUARE_SIGMAS
from .scales import GRAZING_COSINE

#: Most pixels of a region the tests read (an even subsample).
TEST_POINTS = 1200
#: Most pixels the cylinder is fitted to along the rays.
REFIT_POINTS = 400
#: Evaluations of the cylinder's residuals along the rays.
REFIT_EVALUATIONS = 20
#: The region's width across the cylinder's axis (its 3rd to 97th percentile) over the
#: cylinder's diameter may differ from 1 by at most this share.
SILHOUETTE_SHARE = 0.2
#: Most starts of a cylinder refitted where the depth comes in steps (_stepped_pipe_of).
REFIT_STARTS = 3
#: Fewest independent returns a region needs to be asked.
MIN_SAMPLES = 30
#: The compiled screen of the bend test (:func:`rangeseg_o3d.kernels.bend_screen`) refuses a
#: region only where it fails a gate by more than this share of the quantities compared
#: (their rounding differs from numpy's by about 1e-9 at most); numpy's form answers the rest.
SCREEN_MARGIN = 1e-6


def cylinders_for_bent_planes(cloud, labels: np.ndarray, fits: dict, stats, *, sigma: np.ndarray,
                              share: float, inlier_factor: float, max_radius: float,
                              window: int = 1, stepped: bool = False, min_arc_deg: float = MIN_ARC_DEG):
    """``(fits, stats)`` with the plane regions of ``labels`` that are pipes given cylinders
    (see the module's docstring); the inputs when none is.

    ``sigma``: each pixel's range noise (the grid's shape); ``share``: the independent
    returns each pixel carries (``NoiseModel.independent_share(1)``, 1/9 over a 3-pixel
    matching window); ``max_radius``: the fitter's largest radius; ``min_arc_deg``: the least
    arc the fitter's cylinders span (asked where the depth comes in steps, see the module's
    docstring); ``window``: the side (px) of
    the box over which the returns err together (``NoiseModel.correlation_px``); ``stepped``:
    the depth comes in steps (``NoiseModel.step_quadratic > 0``), so the bend is judged over
    blocks of ``window`` pixels along the region (see the module's docstring)."""
    if not 0.0 < share <= 1.0:
        raise ValueError(f"share: expected a number in (0, 1], got {share!r}")
    sigma = np.asarray(sigma, dtype=np.float64)
    if sigma.shape != labels.shape:
        raise ValueError(f"sigma: expected shape {labels.shape}, got {sigma.shape}")
    planes = [k for k, m in fits.items() if k > 0 and isinstance(m, Plane)]
    if not planes:
        return fits, stats
    xyz, noise = cloud.xyz.reshape(-1, 3), sigma.reshape(-1)
    found = {}
    # the test pixels alone (idx[:: max(1, idx.size // TEST_POINTS)] of each region's pixels),
    # not every plane pixel's index
    for k, (sample, count) in region_samples(labels, planes, TEST_POINTS).items():
        cylinder = bent_pipe(xyz, noise, sample, count, shape=labels.shape, share=share, max_radius=max_radius,
                             window=window, stepped=stepped, min_arc_deg=min_arc_deg)
        if cylinder is not None:
            found[k] = cylinder
    if not found:
        return fits, stats
    fits = {**fits, **found}
    stats = region_stats(cloud.xyz, labels, fits, sigma, inlier_factor, known=stats, stale=set(found))
    return fits, stats


def bent_pipe(xyz: np.ndarray, noise: np.ndarray, sample: np.ndarray, count: int, *, shape: tuple, share: float,
              max_radius: float, window: int = 1, stepped: bool = False, min_arc_deg: float = MIN_ARC_DEG):
    """The cylinder of a plane region whose pixels are a pipe, asked as
    :func:`cylinders_for_bent_planes` asks each plane region, or None.

    ``xyz`` (N, 3) and ``noise`` (N,): the grid's points and range noise, flat; ``sample``: the
    flat indices of the region's test pixels (``idx[:: max(1, idx.size // TEST_POINTS)]`` of its
    ``count`` pixels ``idx``, increasing); ``shape``: the grid's; the other arguments as there."""
    samples = share * count
    if samples < MIN_SAMPLES:
        return None
    points, noises = xyz[sample], noise[sample]
    compiled = np.ascontiguousarray(points, dtype=np.float64)
    # nine in ten regions fail a gate before the cylinder's fit: a compiled screen (one pass)
    # spares them numpy's form (~1 ms a region, 8-12 ms a stereo scan; where the depth comes
    # in steps ~1.7 ms a region with its blocks, ~5 regions a kinect_real scan, 98 % refused)
    if stepped:
        if kernels.stepped_bend_screen(compiled, noises, np.asarray(sample, dtype=np.int64), shape[1],
                                       float(samples), float(max_radius), int(window), CHI_SQUARE_SIGMAS,
                                       SCREEN_MARGIN):
            return None
        pixels = np.column_stack(np.unravel_index(sample, shape)).astype(np.float64)
        return _pipe_of(points, noises, samples, max_radius, pixels=pixels, window=window, min_arc_deg=min_arc_deg)
    if kernels.bend_screen(compiled, noises, float(samples), float(max_radius), CHI_SQUARE_SIGMAS,
                           SCREEN_MARGIN)[0]:
        return None
    return _pipe_of(points, noises, samples, max_radius)


def _pipe_of(points: np.ndarray, noise: np.ndarray, samples: float, max_radius: float,
             pixels: np.ndarray | None = None, window: int = 1, min_arc_deg: float = MIN_ARC_DEG):
    # the cylinder of a plane region's pixels ``points`` (their range noise ``noise``; the region
    # holds ``samples`` independent returns), or None (see cylinders_for_bent_planes); with
    # ``pixels`` (their (row, column)) the depth comes in steps and the bend is judged over
    # blocks ``window`` pixels long (_bend_over_blocks), the cylinder spanning ``min_arc_deg`` or more
    keep = np.isfinite(points).all(axis=1) & np.isfinite(noise) & (noise > 0)
    points, noise = points[keep], noise[keep]
    stepped = pixels is not None
    if stepped:
        pixels = pixels[keep]
    if len(points) < 10:
        return None
    n = min(float(samples), float(len(points)))
    unit = n / len(points)  # independent returns a test point stands for
    ranges = np.linalg.norm(points, axis=1)
    rays = points / ranges[:, None]
    scale = ranges * ranges / noise  # 1 / (the noise of an inverse range)
    centre = points.mean(axis=0)
    view = centre / np.linalg.norm(centre)
    offsets = points - centre
    across_view = offsets - np.outer(offsets @ view, view)
    axis = np.linalg.eigh(across_view.T @ across_view)[1][:, 2]  # the longest extent seen
    across = np.cross(axis, view)
    across /= np.linalg.norm(across)
    lateral = offsets @ across
    width = float(np.percentile(lateral, 97) - np.percentile(lateral, 3))
    if not 0.0 < 0.5 * width <= max_radius:
        return None
    # 1. the plane along the rays (inverse ranges = rays . a) and with a bend across the axis
    design = np.column_stack([rays, (lateral / width) ** 2]) * scale[:, None]
    target = scale / ranges
    if stepped:
        region = _Region(points=points, noise=noise, independent=n, centre=centre, view=view, axis=axis,
                         across=across, lateral=lateral, width=width)
        return _stepped_pipe_of(region, design, target, pixels, window, max_radius, np.radians(min_arc_deg))
    flat = _squares(design[:, :3], target)
    bent = _squares(design, target)
    if bent > len(points) * (1.0 + CHI_SQUARE_SIGMAS * np.sqrt(2.0 / n)):
        return None  # not even bent does its plane explain it along the rays: another step's question
    if not curvature_resolved(flat * unit, bent * unit, max(int(n), 2), 1):
        return None
    if (flat - bent) * unit / (bent / len(points)) < np.sqrt(2.0 * n):
        # the bend must also take more than one deviation of the squares' own chi-square spread
        # (sqrt(2n) over n independent returns): the F-test over the returns alone passes the
        # matching window's leftover correlations (drops of 0.04-0.13 of the decision's bound on
        # seed 0's walls and boxes, each costing a refit, against 0.32-0.65 for the pipes)
        return None
    # 2. the cylinder along the rays, from the silhouette. The longest extent seen lies across the
    # view: a pipe that recedes from the camera has its axis in its plane along the rays, which is
    # that direction turned towards the rays (seed 23 scan 3 of the stereo matrix: a pipe 32 degrees
    # from the image plane; started unturned, 18 degrees off, the refit stopped 5 degrees off in a
    # local minimum whose squares exceeded the plane's, and the pipe kept its plane)
    axis = _lifted_into_plane(axis, view, _solution(design[:, :3], target))
    away = view - (view @ axis) * axis
    away /= np.linalg.norm(away)
    start = Cylinder(axis=axis, point=centre + away * (width / np.pi), radius=0.5 * width, rms=0.0,
                     inliers=len(points))
    cylinder = _refit_along_rays(start, points, noise)
    if cylinder is None or not 0.0 < cylinder.radius <= max_radius:
        return None
    seen = np.cross(np.asarray(cylinder.axis), view)
    seen /= max(np.linalg.norm(seen), 1e-12)
    lateral = offsets @ seen
    silhouette = float(np.percentile(lateral, 97) - np.percentile(lateral, 3)) / (2.0 * cylinder.radius)
    if abs(silhouette - 1.0) > SILHOUETTE_SHARE:
        return None
    residuals = _residuals_along_rays(cylinder, points, noise)
    curved = float(np.sum(residuals ** 2))
    if curved <= 0.0:
        return None
    drop = (flat - curved) * unit / (curved / len(points))  # in independent returns' variance units
    if drop <= CHI_SQUARE_SIGMAS * np.sqrt(2.0 * n):
        return None
    return _measured(cylinder, residuals, noise)


def _solution(design: np.ndarray, target: np.ndarray) -> np.ndarray:
    # the least-squares x of design @ x - target
    return np.linalg.lstsq(design, target, rcond=None)[0]


def _lifted_into_plane(direction: np.ndarray, view: np.ndarray, plane: np.ndarray) -> np.ndarray:
    """``direction`` (a unit vector across ``view``) moved along ``view`` into the plane
    ``plane . x = 1`` (its directions ``d`` with ``plane . d = 0``): the 3D direction a line of
    that plane shows across the view. ``direction`` itself where the plane is seen within the
    grazing cosine of edge-on (the lift would be unbounded there)."""
    facing = float(plane @ view)
    if abs(facing) <= GRAZING_COSINE * float(np.linalg.norm(plane)):
        return direction
    lifted = direction - view * (float(plane @ direction) / facing)
    return lifted / np.linalg.norm(lifted)


class _Region(NamedTuple):
    """A plane region's test pixels as _pipe_of measures them where the depth comes in steps."""

    points: np.ndarray  #: (N, 3), finite, with a finite positive noise
    noise: np.ndarray  #: (N,) their range noise
    independent: float  #: the independent returns they stand for (at most N)
    centre: np.ndarray  #: their mean
    view: np.ndarray  #: the unit direction from the camera to the centre
    axis: np.ndarray  #: the unit direction of their longest extent seen across the view
    across: np.ndarray  #: the unit direction across that axis and the view
    lateral: np.ndarray  #: (N,) each point's offset from the centre along ``across``
    width: float  #: the 3rd-97th percentile extent of ``lateral``


def _stepped_pipe_of(region: _Region, design: np.ndarray, target: np.ndarray, pixels: np.ndarray, window: int,
                     max_radius: float, min_arc: float):
    # _pipe_of's steps 1-2 where the depth comes in steps (the module's docstring): the plane
    # along the rays, the bend over blocks of the matching window, the cylinder started from the
    # silhouette and from the bend, the region no wider than its diameter, the cylinder's squares
    # near those of the bend. ``design`` / ``target``: _pipe_of's least squares along the rays
    # (the plane's three columns and the bend's); ``pixels``: each point's (row, column)
    points, noise, n, width = region.points, region.noise, region.independent, region.width
    view, axis, across, centre = region.view, region.axis, region.across, region.centre
    plane = _solution(design[:, :3], target)
    residuals = target - design[:, :3] @ plane
    flat = float(residuals @ residuals)
    if flat > len(points) * (1.0 + CHI_SQUARE_SIGMAS * np.sqrt(2.0 / n)):
        return None  # its plane does not explain it along the rays: another step's question
    convex, t = _bend_over_blocks(residuals, region.lateral / width, pixels, window)
    if not (convex and t >= CHI_SQUARE_SIGMAS):
        return None
    ranges = np.linalg.norm(points, axis=1)
    # the bend's term in metres of range (its value a width off the middle, (lateral / width)^2
    # = 1): a circle of radius R recedes by about x^2 / (2 R) at x off its nearest point
    coefficients = _solution(design, target)
    bent = float(np.sum((design @ coefficients - target) ** 2))
    sagitta = -coefficients[3] * float(np.median(ranges)) ** 2
    radii = [0.5 * width]
    if sagitta > 0:
        radii.append(min(width * width / (2.0 * sagitta), max_radius))
    away = view - (view @ axis) * axis
    away /= np.linalg.norm(away)
    # the starts are refitted in the order of how near their cylinders lie to the pixels along
    # the rays, up to REFIT_STARTS of them (each fit costs ~40 ms); the first to pass is kept
    starts = [Cylinder(axis=axis, point=centre + away * radius + across * shift, radius=radius, rms=0.0,
                       inliers=len(points))
              for radius in radii for shift in (0.0, -0.5 * width, 0.5 * width)]  # the axis behind the middle or a side
    nearness = [float(np.sum(_residuals_along_rays(c, points, noise) ** 2)) for c in starts]
    for index in np.argsort(nearness)[:REFIT_STARTS]:
        cylinder = _explaining_bend(starts[index], region, max_radius, flat, bent, min_arc)
        if cylinder is not None:
            return cylinder
    return None


def _explaining_bend(start: Cylinder, region: _Region, max_radius: float, flat: float, bent: float,
                     min_arc: float):
    # ``start`` refitted along the rays (_stepped_pipe_of) where it is a pipe no wider than the
    # region, spanning ``min_arc`` (radians) or more about its axis, and explains the bend (its
    # squares within sqrt(2 n) independent returns' variance of the plane with the bend, ``bent``,
    # and under the plane's, ``flat``); None otherwise
    points, noise, n, view, centre = region.points, region.noise, region.independent, region.view, region.centre
    cylinder = _refit_along_rays(start, points, noise)
    if cylinder is None or not 0.0 < cylinder.radius <= max_radius:
        return None
    residuals = _residuals_along_rays(cylinder, points, noise)
    squares = float(np.sum(residuals ** 2))
    seen = np.cross(np.asarray(cylinder.axis), view)
    seen /= max(np.linalg.norm(seen), 1e-12)
    lateral = (points - centre) @ seen
    if float(np.percentile(lateral, 97) - np.percentile(lateral, 3)) / (2.0 * cylinder.radius) > 1.0 + SILHOUETTE_SHARE:
        return None  # wider than the pipe: a face it bends over
    if arc_around_axis(np.ascontiguousarray(points, dtype=np.float64), np.asarray(cylinder.axis, dtype=np.float64),
                       np.asarray(cylinder.point, dtype=np.float64)) < min_arc:
        # narrower allows a pipe partly hidden (a pillar behind a box: 0.6-0.7 of its width, an
        # arc of 70-90 degrees), but an arc under the fitter's own least is a face, as the fitter
        # calls one (kinect_real_640x480 study seed 1046, scans 1 and 3: faces at 3.9 and 4.5 m
        # facing the camera, whose correlated noise and depth steps bent 3.2 and 2.9 m cylinders
        # over 14.5 and 17.3 degrees; the pipes this step found on seeds 1044-1061 spanned 49
        # degrees and more, as arc_around_axis measures their noisy returns)
        return None
    unit = n / len(points)
    if not squares < flat or (squares - bent) * unit / (bent / len(points)) > np.sqrt(2.0 * n):
        return None  # the cylinder does not explain the bend
    return _measured(cylinder, residuals, noise)


def _bend_over_blocks(residuals: np.ndarray, across_share: np.ndarray, pixels: np.ndarray,
                      window: int) -> tuple[bool, float]:
    """``(convex, t)``: whether a region's ``residuals`` from its plane along the rays (its
    points' inverse ranges less the plane's, in their noise) bend away from the camera towards its sides, and
    the mean of that bend over blocks ``window`` pixels long along the region's main direction
    in the image (``pixels``: each point's (row, column)) in standard errors of the blocks'
    own scatter. ``across_share``: each point's position across the region over its width.
    Blocks of one matching window err about independently; their scatter holds the noise and
    the depth steps as they are, whatever their law. (False, 0) with fewer than three blocks."""
    offsets = pixels - pixels.mean(axis=0)
    main = np.linalg.eigh(offsets.T @ offsets)[1][:, 1]
    along = offsets @ main
    block = np.floor((along - along.min()) / max(int(window), 1)).astype(np.int64)
    # each block's least squares of residuals ~ c0 + c1 u + c2 u^2 from its sums (one pass of
    # bincounts, not a fit a block: a wall holds 50-130 blocks)
    u = across_share
    powers = [np.bincount(block, weights=u ** p) for p in range(5)]
    moments = [np.bincount(block, weights=residuals * u ** p) for p in range(3)]
    normal = np.stack([np.stack(powers[i:i + 3], axis=-1) for i in range(3)], axis=-2)  # (blocks, 3, 3)
    right = np.stack(moments, axis=-1)
    count = np.maximum(powers[0], 1.0)
    spread = np.sqrt(np.maximum(powers[2] / count - (powers[1] / count) ** 2, 0.0))
    # a block of few points, or not spanning about half the region's width (the spread of an
    # even cover of half of it, 0.5 / sqrt(12)), cannot show its bend
    usable = (powers[0] >= 6) & (spread >= 0.5 / np.sqrt(12.0))
    if np.count_nonzero(usable) < 3:
        return False, 0.0
    normal, right = normal[usable], right[usable]
    conditioned = np.abs(np.linalg.det(normal)) > 1e-12 * np.einsum("bii->b", normal) ** 3
    if np.count_nonzero(conditioned) < 3:
        return False, 0.0
    terms = -np.linalg.solve(normal[conditioned], right[conditioned][..., None])[:, 2, 0]
    # (the inverse range falls towards the sides: convex)
    spread = float(np.std(terms, ddof=1))
    if spread <= 0.0:
        return False, 0.0
    t = float(np.mean(terms)) / (spread / np.sqrt(terms.size))
    return t > 0.0, t


def _squares(design: np.ndarray, target: np.ndarray) -> float:
    # the least sum of squares of design @ x - target
    x = _solution(design, target)
    return float(np.sum((design @ x - target) ** 2))


def _along_the_ray(a, b, c, ranges: np.ndarray, noise: np.ndarray, bound: np.ndarray) -> np.ndarray:
    # the signed residual, in range noise as an inverse range, of each point at ``ranges`` along its
    # ray to where the ray meets the quadric ``a t^2 + 2 b t + c = 0`` nearest that range; ``bound``
    # (>= 0) where the ray misses it or meets it farther off than that (a ray that misses it counts as far off)
    disc = b * b - a * c
    root = np.sqrt(np.maximum(disc, 0.0))
    a = np.maximum(a, 1e-12)
    near, far = (-b - root) / a, (-b + root) / a
    meet = np.where(np.abs(near - ranges) < np.abs(far - ranges), near, far)
    along = (meet - ranges) / noise * ranges / np.maximum(meet, 1e-12)
    return np.where((disc >= 0) & (meet > 0) & (np.abs(along) < bound), along, bound)


def _cylinder_terms(axis, point, radius, points, rays):
    # the ray-quadric coefficients of a cylinder and each point's distance to it
    origin = -np.asarray(point, dtype=np.float64)
    across = rays - np.outer(rays @ axis, axis)
    offset = origin - (origin @ axis) * axis
    a, b, c = np.einsum("ij,ij->i", across, across), across @ offset, offset @ offset - radius ** 2
    radial = points + origin
    radial = radial - np.outer(radial @ axis, axis)
    return a, b, c, np.linalg.norm(radial, axis=1) - abs(radius)


def _residuals_along_rays(cylinder, points: np.ndarray, noise: np.ndarray) -> np.ndarray:
    # each point's residual along its ray to ``cylinder`` in range noise (as an inverse range); a
    # ray that misses it counts the point's distance over the grazing cosine
    ranges = np.linalg.norm(points, axis=1)
    a, b, c, distance = _cylinder_terms(np.asarray(cylinder.axis, dtype=np.float64), cylinder.point,
                                        cylinder.radius, points, points / ranges[:, None])
    return _along_the_ray(a, b, c, ranges, noise, np.abs(distance) / GRAZING_COSINE / noise)


def cylinder_along_rays(start: Cylinder, points: np.ndarray, noise: np.ndarray, max_radius: float = np.inf):
    """``start`` refitted to ``points`` (finite, with their range ``noise`` > 0) by their
    residuals along the rays: the likeliest cylinder where the returns err along their rays
    (a depth camera's), with its rms (of those residuals, in metres) and ``len(points)`` inliers;
    None when the fit fails or its radius is not in (0, ``max_radius``].

    The fitter places a cylinder by the points' distances to it, and a stereo camera's noise,
    several times a pipe's width along the rays, pulls that cylinder off the pipe (a pipe of r
    0.136 m at 4.4 m, stereo study seed 1343 scan 3: the fitter's r 0.10 m; along the rays
    0.14 m)."""
    points = np.asarray(points, dtype=np.float64)
    noise = np.asarray(noise, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or noise.shape != (len(points),):
        raise ValueError(f"cylinder_along_rays: expected (N, 3) points and (N,) noise, got {points.shape} "
                         f"and {noise.shape}")
    if len(points) < 6 or not (np.isfinite(points).all() and np.all(noise > 0)):
        return None
    cylinder = _refit_along_rays(start, points, noise)
    if cylinder is None or not 0.0 < cylinder.radius <= max_radius:
        return None
    residuals = _residuals_along_rays(cylinder, points, noise)
    return _measured(cylinder, residuals, noise)


def _measured(cylinder: Cylinder, residuals: np.ndarray, noise: np.ndarray) -> Cylinder:
    # ``cylinder`` with the rms of its ``residuals`` along the rays (in range noise ``noise``),
    # in metres, and as many inliers as residuals
    return Cylinder(axis=cylinder.axis, point=cylinder.point, radius=cylinder.radius,
                    rms=float(np.sqrt(np.mean((residuals * noise) ** 2))), inliers=len(residuals))


def _refit_along_rays(start: Cylinder, points: np.ndarray, noise: np.ndarray):
    """``start`` refitted to ``points`` by their residuals along the rays (on at most
    ``REFIT_POINTS`` of them, ``REFIT_EVALUATIONS`` evaluations): the likeliest cylinder under
    a stereo camera's range noise; None when the fit fails."""
    from scipy.optimize import least_squares

    step = max(1, len(points) // REFIT_POINTS)
    points, noise = points[::step], noise[::step]
    ranges = np.linalg.norm(points, axis=1)
    rays = points / ranges[:, None]
    axis = np.asarray(start.axis, dtype=np.float64)
    first = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    first /= np.linalg.norm(first)
    second = np.cross(axis, first)
    centre = np.asarray(start.point, dtype=np.float64)

    def model(x):
        turned = axis + x[0] * first + x[1] * second
        return turned / np.linalg.norm(turned), centre + x[2] * first + x[3] * second, x[4]

    def residuals(x):
        a, b, c, distance = _cylinder_terms(*model(x), points, rays)
        return _along_the_ray(a, b, c, ranges, noise, np.abs(distance) / GRAZING_COSINE / noise)

    x0 = np.array([0.0, 0.0, 0.0, 0.0, float(start.radius)])
    try:
        x = least_squares(residuals, x0, max_nfev=REFIT_EVALUATIONS, x_scale=np.full(5, 0.05)).x
    except (ValueError, np.linalg.LinAlgError):
        return None
    if not (np.all(np.isfinite(x)) and x[4] != 0):
        return None
    turned, point, radius = model(x)
    return Cylinder(axis=turned, point=point, radius=abs(float(radius)), rms=0.0, inliers=len(points))
