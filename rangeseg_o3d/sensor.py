"""The sensor: its range-noise model, the unit of its files, its grid and its working ranges.

One immutable :class:`Sensor` per run, resolved once from the ``sensor:`` section of a
preset (:class:`rangeseg_o3d.config.SensorConfig`); the segmenter, the fitter's thresholds
and every refinement step receive it (or what follows from it) as arguments. This module
imports numpy only; the checks of a scan against its sensor (a unit mistake, the noise
model's excess) are in :mod:`rangeseg_o3d.sensor_checks`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

__all__ = [
    "NoiseModel",
    "Sensor",
    "UNIT_SCALES",
    "noise_sigma",
    "unit_scale",
]

#: Metres per unit of the coordinate units a scan file may use.
UNIT_SCALES = {"m": 1.0, "dm": 0.1, "cm": 0.01, "mm": 0.001, "um": 1e-6, "in": 0.0254, "ft": 0.3048}

def unit_scale(units: str) -> float:
    """Metres per ``units`` (``"m"``, ``"cm"``, ``"mm"``, ...); ValueError naming the known ones."""
    try:
        return UNIT_SCALES[units]
    except (KeyError, TypeError):
        raise ValueError(f"units must be one of {', '.join(UNIT_SCALES)}; got {units!r}") from None


def noise_sigma(ranges: np.ndarray, *, sigma0: float, sigma_quadratic: float = 0.0) -> np.ndarray:
    """Range noise model ``sigma(r) = sigma0 + sigma_quadratic * r**2`` in metres.

    A constant term suits time-of-flight lasers (LMS200: ~5 mm); the quadratic term suits
    triangulating depth cameras (Kinect: ~1.425e-3 z^2, the CAPE model).
    """
    return sigma0 + sigma_quadratic * np.square(ranges)


@dataclass(frozen=True)
class NoiseModel:
    """Range noise ``sigma(r) = sigma0 + sigma_quadratic r^2`` (metres, r in metres).

    ``sigma0`` stands for what averaging does not remove (quantisation, calibration
    ripple); the range-dependent term shrinks like ``1/sqrt(n)`` for means of ``n``
    returns (see :meth:`sigma`).

    ``step_quadratic`` (1/m, 0 for none) is the depth step ``step_quadratic r^2`` of a
    structured-light camera that measures disparity in fixed sub-pixel steps (Kinect v1 /
    PrimeSense: 1/8 px, ``1 / (8 f b)`` ~ 2.9e-3 /m, measured on the PCL and PEAC frames). Read
    only where the returns also err together over a window (:attr:`matched_window`): there
    ``bent_planes`` judges a pipe's bend over blocks of that window, the steps voiding its
    chi-square gates. Tile means of such a camera
    scatter more than ``1/sqrt(n)`` says because its errors are correlated over several
    pixels (the staircase among them); the fitter widens by the measured excess
    (:func:`rangeseg_o3d.sensor_checks.noise_excess`). A floor of the steps' rms under the
    segmenter's noise of tile means merged the real frames' surfaces across their creases.
    """

    sigma0: float = 0.005
    sigma_quadratic: float = 0.0
    correlation_px: int = 1
    step_quadratic: float = 0.0

    def __post_init__(self):
        for name in ("sigma0", "sigma_quadratic"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite number >= 0; got {value!r}")
        if self.sigma0 == 0 and self.sigma_quadratic == 0:
            raise ValueError("sigma0 and sigma_quadratic cannot both be 0 (the noise model would be zero)")
        if not (isinstance(self.correlation_px, (int, np.integer)) and self.correlation_px >= 1):
            raise ValueError(f"correlation_px must be an integer >= 1; got {self.correlation_px!r}")
        step = self.step_quadratic
        # Not checked against sigma_quadratic: an override of the noise alone (a quieter
        # model, ``--set sensor.sigma_quadratic=...``) must not need the steps restated.
        if not (isinstance(step, (int, float)) and math.isfinite(step) and step >= 0):
            raise ValueError(f"step_quadratic must be a finite number >= 0 (1/m); got {step!r}")

    def mean_scale(self, samples):
        """Factor on the range-dependent term for means of ``samples`` returns: one over the
        square root of the independent returns among them. Returns that err together over
        ``correlation_px`` x ``correlation_px`` pixels (a stereo camera's matching window)
        count once per such block: ``samples / correlation_px**2``, at least 1."""
        independent = np.maximum(np.asarray(samples, dtype=np.float64) / self.correlation_px ** 2, 1.0)
        return 1.0 / np.sqrt(independent)

    @property
    def matched_window(self) -> bool:
        """Whether this is a stereo camera's noise: growing with the range (``sigma_quadratic``)
        and erring together over a matching window (``correlation_px`` > 1). The steps for
        far faces seen near grazing (``plane_faces``, the strips fitted along their rays)
        run only there.

        The correlation is what they need, not a matcher's continuous depth: on the
        kinect_real_640x480 row (errors over 9 px and 1/8-px disparity steps, stated) they won
        26 surfaces over 21 seeds (1107 against 1081 of 1258 correct with them keyed to
        ``step_quadratic == 0`` as well; 12 study seeds and 1001-1009). rgbd_vga does not state the real Kinect's
        correlation (see its sensor section): with it the six real frames took 85-264 ms CPU
        each."""
        return self.sigma_quadratic > 0.0 and self.correlation_px > 1

    def independent_share(self, tile: int = 1) -> float:
        """The independent samples each point of a grid of ``tile`` x ``tile`` means carries
        (1 for single returns that err alone): the number of points over which a mean errs
        as much as one of independent points, per point.

        Returns that err together over ``correlation_px`` pixels square are modelled as box
        means of independent errors (a stereo camera's matching window); a tile's mean then
        weighs the independent errors under it by the convolution ``w`` of a ``tile`` box
        with a ``correlation_px`` box, and neighbouring tiles share the errors at their
        borders. Along one axis the tile means' correlations summed over every lag are
        ``tile correlation_px**2 / sum(w**2)``, the factor by which the variance of a mean of
        many of them exceeds that of independent ones; over the grid's two axes its square.
        Single returns over a 3-pixel window: 1/9; 6-pixel tiles over it: 0.73 (neighbours
        correlate by 0.09 a side).
        """
        if not (isinstance(tile, (int, np.integer)) and tile >= 1):
            raise ValueError(f"tile must be an integer >= 1; got {tile!r}")
        c = int(self.correlation_px)
        if c == 1:
            return 1.0
        weights = np.convolve(np.ones(int(tile)), np.ones(c))
        return float((weights @ weights) / (tile * c * c)) ** 2

    def independent_returns(self, mask: np.ndarray) -> float:
        """The independent returns among the pixels of ``mask`` (a boolean grid): the number
        of independent returns whose mean errs as much as the mean of those pixels.

        Returns that err together over ``correlation_px`` pixels square are modelled as box
        means of independent errors (:meth:`independent_share`): two pixels ``dr`` rows and
        ``dc`` columns apart correlate by ``(c - |dr|)(c - |dc|) / c**2`` (``c`` the window),
        and ``n`` pixels count ``n**2`` over the sum of their pairs' correlations. A compact
        piece has ``n / c**2`` of them, a strip one pixel high ``n / c`` (over a 3-pixel window:
        a 1 x 90 strip 30, a 3 x 90 strip 43, a 100 x 100 block 1131 of its 10000 pixels)."""
        mask = np.asarray(mask, dtype=bool)
        n = int(np.count_nonzero(mask))
        c = int(self.correlation_px)
        if c == 1 or n == 0:
            return float(n)
        h, w = mask.shape
        pairs = 0.0
        # (lags beyond the mask's own size pair nothing: skipped, as negative slice ends would wrap)
        for dr in range(max(1 - c, 1 - h), min(c, h)):
            for dc in range(max(1 - c, 1 - w), min(c, w)):
                here = mask[max(dr, 0):h + min(dr, 0), max(dc, 0):w + min(dc, 0)]
                there = mask[max(-dr, 0):h + min(-dr, 0), max(-dc, 0):w + min(-dc, 0)]
                pairs += (c - abs(dr)) * (c - abs(dc)) * np.count_nonzero(here & there)
        return float(n * n * c * c / pairs)

    def sigma(self, ranges: np.ndarray, samples: np.ndarray | None = None) -> np.ndarray:
        """Noise per pixel (m) at ``ranges``; for means of ``samples`` returns the
        range-dependent term is multiplied by :meth:`mean_scale`."""
        quadratic = self.sigma_quadratic
        if samples is not None:
            quadratic = quadratic * self.mean_scale(samples)
        return noise_sigma(ranges, sigma0=self.sigma0, sigma_quadratic=quadratic)

    def of_means(self, samples: int, excess: float = 1.0) -> "NoiseModel":
        """The noise of means of ``samples`` returns (a tile grid's points): the
        range-dependent term times :meth:`mean_scale` and ``excess`` (>= 1, the measured
        excess scatter of such means: :func:`noise_excess`); the means err independently."""
        if not (math.isfinite(excess) and excess >= 1.0):
            raise ValueError(f"excess must be a finite number >= 1; got {excess!r}")
        scale = float(self.mean_scale(samples)) * excess
        return NoiseModel(self.sigma0, self.sigma_quadratic * scale, 1)


@dataclass(frozen=True)
class Sensor:
    """What the method needs to know about the scanner.

    Attributes
    ----------
    noise : the range-noise model.
    units : unit of the coordinates in its scan files (``.pcd``, ``.npz`` without a
        recorded unit); inputs are converted to metres when read.
    wrap_columns : the columns close a full turn (360-degree scanners): the first and last
        column are neighbours.
    row_spacing_deg, column_spacing_deg : angular step between rows / columns, when known.
    min_range, max_range : the sensor's working ranges (m): a scan whose median range lies
        far outside them is taken for a unit mistake (:func:`check_plausible`).
    depth_step : the depth quantisation step (m; 0 for none): an 8-bit structured-light
        camera reports depth in steps, and a window too small to span one sees a flat
        terrace instead of its surface's slope (:mod:`rangeseg_o3d.scales`).
    lateral_noise_px : rms offset across its viewing ray, in grid steps, of the point of the
        surface a return measures (0 for none: the return lies on its pixel's ray). A camera
        whose spot or blur spans more than its pixel measures the surface somewhat beside the
        ray it reports; seen head-on this is invisible, seen at grazing incidence it moves the
        point off its surface by about this times the range times the grid step, where the
        range noise moves it by almost nothing (:func:`lateral_distance_noise`).
    beam_width_deg : a laser beam's full width (deg; 0 for none stated). A beam that wide
        straddles an occlusion (a column's limb before the wall behind it) and returns a
        range between the two surfaces, on neither: a mixed return
        (:mod:`rangeseg_o3d.refinement.mixed_returns`). With 0 no return is taken for one.
    """

    noise: NoiseModel = NoiseModel()
    units: str = "m"
    wrap_columns: bool = False
    row_spacing_deg: float | None = None
    column_spacing_deg: float | None = None
    min_range: float = 0.01
    max_range: float = 1000.0
    depth_step: float = 0.0
    lateral_noise_px: float = 0.0
    beam_width_deg: float = 0.0

    def __post_init__(self):
        if not isinstance(self.noise, NoiseModel):
            raise TypeError(f"noise must be a NoiseModel; got {type(self.noise).__name__}")
        unit_scale(self.units)
        for name in ("row_spacing_deg", "column_spacing_deg"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and 0 < value <= 360):
                raise ValueError(f"{name} must be None or in (0, 360]; got {value!r}")
        if not (math.isfinite(self.min_range) and math.isfinite(self.max_range)
                and 0 <= self.min_range < self.max_range):
            raise ValueError("min_range and max_range must be finite with 0 <= min_range < max_range; "
                             f"got {self.min_range!r}, {self.max_range!r}")
        if not (isinstance(self.depth_step, (int, float)) and math.isfinite(self.depth_step)
                and self.depth_step >= 0):
            raise ValueError(f"depth_step must be a finite number of metres >= 0; got {self.depth_step!r}")
        if not (isinstance(self.lateral_noise_px, (int, float)) and math.isfinite(self.lateral_noise_px)
                and self.lateral_noise_px >= 0):
            raise ValueError(f"lateral_noise_px must be a finite number >= 0; got {self.lateral_noise_px!r}")
        if not (isinstance(self.beam_width_deg, (int, float)) and math.isfinite(self.beam_width_deg)
                and 0 <= self.beam_width_deg <= 180):
            raise ValueError(f"beam_width_deg must be a number of degrees in [0, 180]; got {self.beam_width_deg!r}")

    @property
    def scale(self) -> float:
        """Metres per unit of the sensor's files."""
        return unit_scale(self.units)

    @property
    def laser_returns(self) -> bool:
        """Whether the model states a laser's single returns along its rays: a range noise
        constant over range (``sigma_quadratic`` 0; a triangulating camera's grows with the
        square of the range, :func:`noise_sigma`) that errs return by return
        (``correlation_px`` 1; a stereo camera's errs together over its matching window,
        :attr:`NoiseModel.matched_window`), no depth steps (``depth_step`` 0; an 8-bit
        structured-light camera's) and each return on its pixel's ray (``lateral_noise_px``
        0; a camera's spot or blur measures beside it). Where the rays start (a nodding
        laser's mirror off its tilt axis) is the cloud's geometry, not the sensor's."""
        noise = self.noise
        return (noise.sigma_quadratic == 0.0 and noise.correlation_px == 1 and self.depth_step == 0.0
                and self.lateral_noise_px == 0.0)

    def of_means(self, samples: int, excess: float = 1.0) -> "Sensor":
        """This sensor as seen through means of ``samples`` returns (its tile grid): the same
        sensor with the noise of the means (:meth:`NoiseModel.of_means`)."""
        return replace(self, noise=self.noise.of_means(samples, excess))
