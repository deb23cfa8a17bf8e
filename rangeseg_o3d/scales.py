"""Scale-dependent settings derived from the sensor, not written by the preset's author.

Every threshold of the method that has a length or a pixel count in it follows from two
facts about the scanner: its range-noise model ``sigma(r) = sigma0 + sigma_quadratic r^2``
(:class:`rangeseg_o3d.sensor.NoiseModel`) and the angular spacing of its grid (the
``sensor:`` section's ``row_spacing_deg`` / ``column_spacing_deg``, or measured from the
cloud's viewing directions when the preset gives none). :func:`derive_scales` turns them,
with the scan's median range, into the numbers the stages use (:class:`Scales`); the
constants below are the method's own, the same for every sensor and scene. A preset may
still set any of these values explicitly; left out (``null``), they are derived.

The rules (``delta`` the geometric mean of the row and column steps in radians, ``r`` the
scan's median range, ``sigma = sigma(r)``):

* ``jump_ratio = delta / GRAZING_TAN``: a range step between neighbouring pixels is a depth
  jump when it exceeds what a surface seen under ``atan(GRAZING_TAN)`` (about 9.5 degrees)
  from grazing produces over one pixel step (``r delta / tan(angle)``). Per sensor pixel;
  a tile grid multiplies it by the tile.
* ``jump_min = JUMP_SIGMAS * sigma0``: below ``jump_min / jump_ratio`` metres the test is
  an absolute one; ten times the constant noise keeps two noisy neighbours (their
  difference has ``sqrt(2) sigma0``) from ever passing for a jump. Doubling ``sigma0``
  doubles it.
* ``merge_tolerance = MERGE_SIGMAS * sigma_t``: two patches of one surface have fitted
  offsets within a few noise sigmas; ten leaves room for the bias of small patches.
  ``sigma_t`` is the noise of the points the models are fitted to (tile means: the
  range-dependent term divided by the tile, :meth:`NoiseModel.sigma`). Doubling the noise
  doubles it.
* ``min_region_size = max(MIN_PIXELS, MIN_CELLS * tile**2)`` sensor pixels: the fewest
  returns whose fit tells a plane from a curved surface, and on a tile grid the fewest
  tile means (each already averages ``tile**2`` returns) that still outline a surface.
* ``tile``: 1 where the point spacing ``r delta`` is at least the noise ``sigma``: the
  paper's 3x3 residual then sees creases at full resolution (nodding and spinning lasers).
  Where the noise exceeds the spacing (depth cameras, structured light), the grid is
  averaged into tiles until a tile mean's noise (``sigma / t``, the tile averaging ``t**2``
  independent returns) is under ``TILE_NOISE_RATIO`` of the tile spacing ``t r delta``:
  ``t = ceil(sqrt(sigma / (TILE_NOISE_RATIO r delta)))``; at most ``MAX_TILE``, and never
  so large that fewer than ``MIN_GRID_CELLS`` cells remain across the grid's shorter side.
  ``TILE_NOISE_RATIO`` was read off the sensor matrix's depth-camera rows (random scenes:
  on the Kinect row a 3-pixel tile lost a whole scan, 5-6 pixels did not).
  A sensor that reports depth in steps of ``q`` (``sensor.depth_step``, 8-bit structured
  light) needs, besides, a window that spans one step: the 3x3 window of the working grid
  spans ``WINDOW_STEPS`` tile steps, over which a face at 45 degrees to the viewing ray
  changes its depth by ``WINDOW_STEPS t r delta``; a smaller window sits on one terrace of
  the quantised depth and sees it flat, whatever the face's slope, so its residual and
  normals say nothing about creases. Hence ``t >= q / (WINDOW_STEPS r delta)``, whether
  or not the noise asks for a tile (the quantisation's rms ``q / sqrt(12)`` may well be
  under the spacing while its steps are over it: ABW's 1.26-1.29 mm against 0.4-0.6 mm).
* ``RELIEF_STEPS``: on such a sensor a cylinder or sphere of radius ``R`` changes its depth by
  at most ``R`` over its visible half, i.e. over ``R / q`` terraces; at ``RELIEF_STEPS`` or
  fewer its depth image is a few terraces that a bump of the camera's error makes as well
  (ABW's 2-3 mm "cylinders" inside flat faces, 4 mm off them), so no curved model that
  small is kept (:func:`rangeseg_o3d.fullres.drop_unresolvable_curves`).

This module imports numpy only (the spacing measurement imports :mod:`rangeseg_o3d.segmentation.edges`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ._numeric import median

__all__ = ["Scales", "derive_scales", "scales_for_cloud", "measured_spacing", "median_range",
           "with_derived_refinement", "grid_step", "noise_spans_the_grid", "pixelwise_noise_spans_the_grid",
           "GRAZING_TAN", "GRAZING_COSINE", "JUMP_SIGMAS", "MERGE_SIGMAS", "MIN_PIXELS", "MIN_CELLS", "TILE_NOISE_RATIO",
           "MIN_GRID_CELLS", "MAX_TILE", "WINDOW_STEPS", "RELIEF_STEPS"]

#: A range step over one pixel larger than a surface at ~9.5 deg from grazing makes is a jump.
GRAZING_TAN = 1.0 / 6.0
#: The incidence cosine of a ray atan(GRAZING_TAN) from grazing: the smallest a plane's
#: distance noise (range noise x incidence cosine) is scaled by where a tile's mean or a
#: pixel spans the plane's depth (refinement.split's hold, refinement.dissolve's ripples).
GRAZING_COSINE = float(np.sin(np.arctan(GRAZING_TAN)))
#: The absolute jump floor, in constant-noise sigmas.
JUMP_SIGMAS = 10.0
#: Merge tolerance (offsets, radii, centres of merge candidates), in noise sigmas at the median range.
MERGE_SIGMAS = 10.0
#: Smallest region, in sensor pixels ...
MIN_PIXELS = 20
#: ... and in cells of the working (tile) grid.
MIN_CELLS = 8
#: Tiles average until a tile mean's noise is under this share of the tile spacing.
TILE_NOISE_RATIO = 0.1
#: A derived tile leaves at least this many cells across the grid's shorter side.
MIN_GRID_CELLS = 48
#: Largest derived tile.
MAX_TILE = 8
#: Tile steps a 3x3 window of the working grid spans (its depth must change by a quantisation step).
WINDOW_STEPS = 2
#: Depth steps a curved surface's radius must exceed to be told from the quantisation's terraces.
RELIEF_STEPS = 3
# The measurements look at a sub-grid of about this many pixels.
_SAMPLE_PIXELS = 4096


@dataclass(frozen=True)
class Scales:
    """The scale-dependent numbers of one run (lengths in metres, sizes in sensor pixels).

    ``spacing_rad`` is the (row, column) angular step used; ``typical_range`` the median
    range and ``sigma`` the noise there, from which the rest follows (see the module).
    """

    tile: int
    jump_ratio: float
    jump_min: float
    min_region_size: int
    merge_tolerance: float
    spacing_rad: tuple[float, float]
    typical_range: float
    sigma: float


def _subgrid(image: np.ndarray) -> np.ndarray:
    step = max(1, round(math.sqrt(image.shape[0] * image.shape[1] / _SAMPLE_PIXELS)))
    return image[::step, ::step]


def median_range(cloud) -> float:
    """Median range (m) of the cloud's valid pixels (a sub-grid of ~4096 of them)."""
    if cloud.ranges is not None:
        ranges = np.asarray(_subgrid(cloud.ranges), dtype=np.float64)
    else:  # the norms of the sub-grid only: a whole VGA frame's would cost ~6 ms a scan
        ranges = np.asarray(np.linalg.norm(_subgrid(cloud.xyz), axis=2), dtype=np.float64)
    ranges = ranges[np.isfinite(ranges) & (ranges > 0)]
    if ranges.size == 0:
        raise ValueError("the cloud has no valid range to derive its scales from")
    return median(ranges)


def measured_spacing(cloud) -> tuple[float, float]:
    """Median angular step (radians) between neighbouring rows and columns, per sensor pixel.

    Measured between viewing directions (:func:`rangeseg_o3d.segmentation.edges.angular_steps`), so
    range noise does not enter, at the pixels of a sub-grid of about ``_SAMPLE_PIXELS``
    (each to its next row and column: a whole frame's steps would cost ~10 ms per scan for
    a median that a few thousand of them give as well); a cloud of tile means is divided
    by its tile. A direction without two valid neighbours takes the other's step (square pixels).
    """
    out = []
    for steps in _sampled_steps(np.asarray(cloud.xyz, dtype=np.float64)):
        steps = steps[np.isfinite(steps) & (steps > 0)]
        out.append(median(steps) / cloud.tile if steps.size else None)
    if out == [None, None]:
        raise ValueError("the cloud has no two valid neighbouring pixels to measure its "
                         "angular spacing from; give sensor.row_spacing_deg and column_spacing_deg")
    return (out[0] if out[0] is not None else out[1]), (out[1] if out[1] is not None else out[0])


def _sampled_steps(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    # The angular steps from about _SAMPLE_PIXELS pixels to their next row and next column.
    # The pixels are every stride-th in raster order, the stride prime to the width so that
    # they spread over every column and row (a scanner's column steps can vary column by
    # column). Each pixel and its neighbour are stacked into a two-row (two-column) grid
    # whose angular_steps between the two are the steps wanted.
    from .segmentation.edges import angular_steps

    h, w = xyz.shape[:2]
    stride = max(1, (h * w) // _SAMPLE_PIXELS)
    while math.gcd(stride, w) != 1:
        stride += 1
    flat = xyz.reshape(-1, 3)
    pixels = np.arange(0, h * w, stride)
    down = pixels[pixels < (h - 1) * w]
    right = pixels[pixels % w < w - 1]
    rows = angular_steps(np.stack([flat[down], flat[down + w]]))[0][0]
    cols = angular_steps(np.stack([flat[right], flat[right + 1]], axis=1))[1][:, 0]
    return rows, cols


def derive_scales(sensor, *, typical_range: float, spacing_rad: tuple[float, float] | None = None,
                  shape: tuple[int, int] | None = None, tile: int | None = None) -> Scales:
    """The scale-dependent settings for ``sensor`` at ``typical_range`` metres.

    Parameters
    ----------
    sensor : :class:`rangeseg_o3d.sensor.Sensor`.
    typical_range : the scan's median range (m), where range-dependent noise is evaluated.
    spacing_rad : (row, column) angular steps in radians; None: the sensor's.
    shape : the sensor grid's (rows, columns), which bounds the derived tile; None: unbounded.
    tile : a tile fixed by the preset (the other values follow it); None: derived.

    Raises
    ------
    ValueError
        No spacing (neither given nor in the sensor), or a non-positive range or spacing.
    """
    if spacing_rad is None:
        if sensor.row_spacing_deg is None or sensor.column_spacing_deg is None:
            raise ValueError("deriving scales needs the grid's angular spacing: give "
                             "sensor.row_spacing_deg and column_spacing_deg, or a cloud to measure it")
        spacing_rad = (math.radians(sensor.row_spacing_deg), math.radians(sensor.column_spacing_deg))
    row_step, col_step = (float(s) for s in spacing_rad)
    if not (math.isfinite(typical_range) and typical_range > 0):
        raise ValueError(f"typical_range must be a positive number of metres; got {typical_range!r}")
    if not all(math.isfinite(s) and s > 0 for s in (row_step, col_step)):
        raise ValueError(f"spacing_rad must be two positive angles; got {spacing_rad!r}")
    delta = math.sqrt(row_step * col_step)
    sigma = float(sensor.noise.sigma(np.float64(typical_range)))
    if tile is None:
        tile = _crease_tile(typical_range * delta, sigma, shape, sensor.depth_step)
    return Scales(
        tile=int(tile),
        jump_ratio=delta / GRAZING_TAN,
        jump_min=JUMP_SIGMAS * sensor.noise.sigma0,
        min_region_size=int(max(MIN_PIXELS, MIN_CELLS * tile * tile)),
        # the merged models are fitted to tile means: their noise (NoiseModel.sigma's rule)
        merge_tolerance=MERGE_SIGMAS * float(sensor.noise.sigma(np.float64(typical_range),
                                                                   np.float64(tile * tile))),
        spacing_rad=(row_step, col_step),
        typical_range=float(typical_range),
        sigma=sigma,
    )


def _crease_tile(spacing_m: float, sigma: float, shape, depth_step: float = 0.0) -> int:
    # 1 where the spacing is at least the noise, else the smallest t with
    # sigma / t <= TILE_NOISE_RATIO * t * spacing; at least the tile whose window spans a
    # depth step (module docstring); within MAX_TILE and the grid
    needed = 1
    if sigma > spacing_m:
        needed = math.ceil(math.sqrt(sigma / (TILE_NOISE_RATIO * spacing_m)) - 1e-9)
    if depth_step > 0:
        needed = max(needed, math.ceil(depth_step / (WINDOW_STEPS * spacing_m) - 1e-9))
    if needed <= 1:
        return 1
    largest = MAX_TILE if shape is None else max(1, min(MAX_TILE, min(shape) // MIN_GRID_CELLS))
    return int(min(needed, largest))


#: The refinement settings (RefineConfig fields) that None leaves to the sensor.
DERIVED_REFINEMENT = ("min_region_size", "jump_ratio", "jump_min", "merge_tolerance")


def with_derived_refinement(config, sensor, cloud):
    """``config`` (a RefineConfig) with the values it leaves to the sensor (None) derived for
    ``cloud``; ``config`` itself when it sets them all."""
    missing = [key for key in DERIVED_REFINEMENT if getattr(config, key) is None]
    if not missing:
        return config
    scales = scales_for_cloud(sensor, cloud, tile=cloud.tile)
    return config.model_copy(update={key: getattr(scales, key) for key in missing})


def scales_for_cloud(sensor, cloud, *, tile: int | None = None) -> Scales:
    """:func:`derive_scales` for ``cloud`` (sensor grid): its median range, the sensor's
    spacing or the one measured from the cloud when the sensor gives none."""
    spacing = None
    if sensor.row_spacing_deg is None or sensor.column_spacing_deg is None:
        spacing = measured_spacing(cloud)
    shape = tuple(s * cloud.tile for s in cloud.shape)
    return derive_scales(sensor, typical_range=median_range(cloud), spacing_rad=spacing,
                         shape=shape, tile=tile)


def grid_step(sensor, cloud=None) -> float | None:
    """The grid's coarser angular step (radians): the sensor's row and column spacings, else
    measured on ``cloud`` (:func:`measured_spacing`); None with neither."""
    if sensor.row_spacing_deg is not None and sensor.column_spacing_deg is not None:
        return float(np.radians(max(sensor.row_spacing_deg, sensor.column_spacing_deg)))
    if cloud is None:
        return None
    return float(max(measured_spacing(cloud)))


def noise_spans_the_grid(sensor, cloud=None) -> bool:
    """Whether ``sensor``'s range noise, growing with the range (``sigma_quadratic`` > 0),
    exceeds the footprint of its grid's coarser angular step ``d`` (radians) at every range:
    ``sigma0 + sigma_quadratic r**2 > r d`` for all ``r``, i.e. ``d**2 < 4 sigma0
    sigma_quadratic``. On such a camera (a Kinect: 0.11 deg, 1 mm + 1.425e-3 r^2, the noise
    1.2-4 footprints from 0.5 to 5 m) a face a few pixels wide spreads farther along its rays
    than across them, so its least-squares plane turns towards the rays. A laser whose noise
    is stated growing with the range (a SICK at 0.5 deg, 3 mm + 1e-3 r^2) stays under its
    footprint from 0.35 to 8.7 m. The step is :func:`grid_step`'s; False without one."""
    noise = sensor.noise
    if noise.sigma_quadratic <= 0.0:
        return False
    step = grid_step(sensor, cloud)
    return step is not None and step * step < 4.0 * noise.sigma0 * noise.sigma_quadratic


def pixelwise_noise_spans_the_grid(sensor, cloud=None) -> bool:
    """:func:`noise_spans_the_grid` on a camera whose returns err one by one: not a stereo
    camera, whose noise errs together over its matching window (``noise.matched_window``),
    nor a wrapped grid. The regime (a Kinect's) where a curved blob is fitted again on block
    means (:mod:`rangeseg_o3d.refinement.curved_refused`) and a curved model is judged by the
    noise of its distances (:func:`rangeseg_o3d.fullres.planes_for_unresolved`)."""
    return (not sensor.noise.matched_window and not sensor.wrap_columns
            and noise_spans_the_grid(sensor, cloud))
