"""Checks of a scan against its sensor: a unit mistake (:func:`check_plausible`) and how
much more the points scatter than the noise model says (:func:`noise_excess`).

Both look at the 3x3 plane-fit residual (:func:`rangeseg_o3d.segmentation.residual.residual_image`)
of a sub-grid of about 1024 pixels: as much as the whole scan says, in about 0.1 ms.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from ._numeric import median
from .segmentation.residual import residual_image
from .sensor import UNIT_SCALES, Sensor

__all__ = ["UnitsWarning", "check_plausible", "noise_excess"]

# A scan whose median range is further than this factor outside the sensor's working
# ranges is taken for a unit mistake (those are factors of 10 and more).
_RANGE_SLACK = 3.0
# A median normalised window residual above this (local scatter ten times the noise
# model) means no window looks planar: coordinates in a smaller unit than declared,
# or a preset for another sensor.
_SCATTER_LIMIT = 100.0
# The checks look at a sub-grid of about this many pixels (every k-th row and column).
_CHECK_PIXELS = 1024


class UnitsWarning(UserWarning):
    """A scan whose coordinates look implausible for the sensor (probably a unit mistake)."""


def _unit_hint(median_m: float, sensor: Sensor) -> str:
    """Which unit mistake puts the median range nearest the middle of the working ranges.

    A file in unit ``x`` read as ``y`` is off by ``scale(y) / scale(x)``. Pairs reading in
    the sensor's own units come first (the usual mistake), then the nearest to the middle.
    """
    middle = math.log(max(sensor.min_range, 1e-3) * sensor.max_range) / 2
    best = None
    for x, sx in UNIT_SCALES.items():
        for y, sy in UNIT_SCALES.items():
            corrected = median_m * sx / sy
            if x == y or not sensor.min_range <= corrected <= sensor.max_range:
                continue
            rank = (y != sensor.units, round(abs(math.log(corrected) - middle), 6),
                    x not in ("m", "cm", "mm"), y not in ("m", "cm", "mm"))
            if best is None or rank < best[0]:
                best = (rank, x, y, corrected)
    if best is None:
        return "no unit puts it there: is this a scan of that sensor at all?"
    _, x, y, corrected = best
    return (f"coordinates in {x} read as {y}? Read in {x} the median range is {corrected:.3g} m "
            f"(--units {x}, or sensor.units: {x})")


def _median_scatter(cloud, sensor: Sensor, step: int) -> float:
    # Median noise-normalised plane residual of the windows of a sub-grid: about 1 when
    # the noise model matches (much less for models that over-state the noise).
    xyz = np.ascontiguousarray(cloud.xyz[::step, ::step])
    if min(xyz.shape[:2]) < 3:
        return float("nan")
    samples = None if cloud.samples is None else cloud.samples[::step, ::step]
    scale = 1.0 if samples is None else sensor.noise.mean_scale(samples)
    residual, _ = residual_image(xyz, sigma0=sensor.noise.sigma0,
                                 sigma_quadratic=sensor.noise.sigma_quadratic,
                                 with_normals=False, noise_scale=scale)
    finite = residual[np.isfinite(residual)]
    return median(finite) if finite.size else float("nan")


def _check_step(cloud) -> int:
    # every k-th row and column: a sub-grid of about _CHECK_PIXELS pixels
    return max(1, round(math.sqrt(cloud.shape[0] * cloud.shape[1] / _CHECK_PIXELS)))


def noise_excess(cloud, sensor: Sensor) -> float:
    """How much more the cloud's points scatter about their local planes than ``sensor``'s
    noise model says, as a factor on the noise (at least 1).

    The square root of the median noise-normalised residual of the 3x3 windows of a
    sub-grid of about 1024 points spread over the grid (about 1 when the model holds: most
    windows lie on one surface). On a tile grid it measures the means' noise against
    :meth:`NoiseModel.mean_scale`: real depth cameras' returns err together (block
    matching, disparity quantisation terraces, calibration ripple), so their means average
    less noise away than independent returns would; errors that run over several tiles
    show at the sub-grid's spacing, as they do in the fit of a region spanning many tiles.
    1 when the model holds or over-states the noise, or no window is valid.
    """
    scatter = _median_scatter(cloud, sensor, _check_step(cloud))
    return float(math.sqrt(scatter)) if math.isfinite(scatter) and scatter > 1.0 else 1.0


def check_plausible(cloud, sensor: Sensor, *, name: str = "the sensor") -> None:
    """Refuse or flag a scan whose coordinates do not fit ``sensor`` (a unit mistake).

    The cloud is in metres (already converted from ``sensor.units``).

    Raises
    ------
    ValueError
        The median range lies more than a factor 3 outside ``[min_range, max_range]``
        (a cm scan read as metres by a depth-camera preset, a scene scaled by 1e-30):
        the message names the units that would fit.

    Warns
    -----
    UnitsWarning
        No window of the grid looks planar within 10 noise sigmas (a cm scan read as
        metres under a sensor with a long reach, or a preset for another sensor).
    """
    # A sub-grid of about 32 x 32 pixels says as much as the whole scan, in about 0.1 ms.
    step = _check_step(cloud)
    if cloud.ranges is not None:
        ranges = np.asarray(cloud.ranges[::step, ::step], dtype=np.float64)
    else:
        ranges = np.linalg.norm(cloud.xyz[::step, ::step], axis=2)
    ranges = ranges[np.isfinite(ranges)]
    if ranges.size == 0:
        return
    median_m = median(ranges)
    low, high = sensor.min_range / _RANGE_SLACK, sensor.max_range * _RANGE_SLACK
    if not low <= median_m <= high:
        raise ValueError(
            f"the scan's median range is {median_m:.3g} m, but {name} works at "
            f"{sensor.min_range:g}-{sensor.max_range:g} m: probably a unit problem, "
            f"{_unit_hint(median_m, sensor)}")
    scatter = _median_scatter(cloud, sensor, step)
    if scatter > _SCATTER_LIMIT:
        warnings.warn(
            f"the scan's local scatter is about {math.sqrt(scatter):.0f} times {name}'s noise "
            f"model (sigma0 {sensor.noise.sigma0:g} m): no window looks planar, so few or no "
            "regions will be found. Probably a unit problem (coordinates in a smaller unit "
            "than they were read in, e.g. cm read as m: --units / sensor.units), or a preset "
            "for another sensor.", UnitsWarning, stacklevel=2)
