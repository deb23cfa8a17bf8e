"""The sensor matrix: simulated sensors, each scanning independent random scenes.

Each :class:`SensorSpec` names a sensor model (grid, angular spacing, noise), the preset
that segments it, the sensor facts the preset is given (``sensor_facts(quick)``: the
noise model ``sigma0`` and ``sigma_quadratic`` in metres, ``sigma(r) = sigma0 +
sigma_quadratic r^2``, and the grid's ``row_spacing_deg`` / ``column_spacing_deg``), and draws
scan ``k`` of a benchmark run from ``numpy.random.default_rng([seed, sensor, k])``: a new
scene and new noise for every scan, the same ones for the same seed. Nothing here is
tuned to a scene; the scenes come from :mod:`rangeseg_o3d.synthetic.rooms`.

Rows (``SENSORS``):

* ``nodding_1deg`` / ``_0.5deg`` / ``_0.25deg``: a nodding 2-D laser (beams 25..155 deg)
  at 1, 0.5 and 0.25 deg, with 70, 140 and 280 tilt rows over -0.4..0.3 rad (the tilt
  step shrinks with the beam step), 5 mm range noise, beam footprint 0.75 deg x step;
* ``noise_2mm`` ... ``noise_20mm``: the 1-deg nodding laser at 2, 10 and 20 mm (5 mm is
  ``nodding_1deg``);
* ``spinning_32x1024`` (3 cm), ``spinning_64x1024`` (1.5 cm), ``spinning_128x2048``
  (1 cm): 360-degree lidars with a 45-degree vertical field inside rooms all around them;
* ``kinect_640x480``: Kinect noise ``1.425e-3 z^2``, independent per pixel;
  ``kinect_real_640x480``: the same scenes and camera, the noise correlated over 9 x 9 pixels
  and the depth in 1/8-px disparity steps (``2.9e-3 z^2``) as on the real frames; ``stereo_1280x720``: a stereo
  camera (90 deg horizontal field, 5 cm baseline, 0.1 px disparity noise -> ``sigma_z =
  0.1 z^2 / (f B)``, correlated over 3 x 3 pixels);
* ``tabletop_abw``: a structured-light tabletop of polyhedra (512 x 512, ABW's focal
  lengths, 0.25 mm noise, depth quantised to 1.26 mm steps).
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .depth_camera import KINECT_NOISE, camera_pose_scene, simulate_depth_camera
from .lms200 import simulate_lms200
from .rooms import random_room, random_tabletop
from .scene import SyntheticScan
from .spinning import simulate_spinning_lidar

__all__ = ["SensorSpec", "SENSORS", "sensor_names", "get_sensor", "matrix_rng"]


@dataclass(frozen=True)
class SensorSpec:
    """One row of the sensor matrix.

    ``simulate(rng, quick)`` draws one scene and scans it; ``quick`` asks for a smaller
    grid of the same sensor family (fast checks). ``noise`` is the sensor's noise model and
    ``spacing(quick)`` its grid's (row, column) angular steps in degrees, both handed to the
    preset's ``sensor:`` section (:meth:`sensor_facts`); ``family`` groups rows.
    """

    name: str
    family: str
    preset: str
    noise: dict
    scans: int
    simulate: Callable[[np.random.Generator, bool], SyntheticScan]
    spacing: Callable[[bool], tuple[float, float]]
    description: str = ""
    quick_scans: int = 2
    region_growing: dict = field(default_factory=dict)  # overrides of the baseline's parameters
    scenes_of: str = ""  # another row whose scenes (and noise seeds) this one draws; "" for its own

    @property
    def draws(self) -> str:
        """The name :func:`matrix_rng` draws this row's scans under: ``scenes_of`` or its own."""
        return self.scenes_of or self.name

    def sensor_facts(self, quick: bool = False) -> dict:
        """``{sigma0, sigma_quadratic[, noise_correlation_px], row_spacing_deg, column_spacing_deg}``
        of the (quick) grid."""
        rows, cols = self.spacing(quick)
        return {**self.noise, "row_spacing_deg": float(rows), "column_spacing_deg": float(cols)}


def matrix_rng(seed: int, sensor: str, scan: int) -> np.random.Generator:
    """The generator of scan ``scan`` of ``sensor`` in a run seeded ``seed``."""
    return np.random.default_rng([int(seed), zlib.crc32(sensor.encode()), int(scan)])


def _noise_seed(rng: np.random.Generator) -> int:
    return int(rng.integers(2**31))


# The nodding rows' tilt schedule: -0.4 .. 0.3 rad (the paper's), rows growing as the step shrinks.
_TILT_SPAN_DEG = float(np.rad2deg(0.7))


def _nodding_grid(step_deg: float, quick: bool) -> tuple[int, float]:
    """Rows and beam step of a nodding row (quick: a finer laser scanned at twice its step)."""
    rows = int(round(70 / step_deg))
    if quick and step_deg < 1:
        return rows // 2, step_deg * 2
    return rows, step_deg


def _nodding(step_deg: float, noise: float):
    def simulate(rng, quick):
        scene = random_room(rng, around=False)
        rows, beam_step = _nodding_grid(step_deg, quick)
        return simulate_lms200(scene, rows=rows, beam_step_deg=beam_step, noise_sigma=noise,
                               beam_width_deg=0.75 * min(1.0, beam_step), seed=_noise_seed(rng))

    def spacing(quick):
        rows, beam_step = _nodding_grid(step_deg, quick)
        return _TILT_SPAN_DEG / (rows - 1), beam_step
    return simulate, spacing


_SPINNING_FOV_DEG = 45.0


def _spinning(rows: int, cols: int, noise: float):
    def simulate(rng, quick):
        scene = random_room(rng, around=True)
        cols_ = cols if not quick else cols // 2
        return simulate_spinning_lidar(scene, rows=rows, cols=cols_, vertical_fov_deg=_SPINNING_FOV_DEG,
                                       noise_sigma=noise, seed=_noise_seed(rng))

    def spacing(quick):
        return _SPINNING_FOV_DEG / (rows - 1), 360.0 / (cols if not quick else cols // 2)
    return simulate, spacing


def _pixel_deg(focal_px: float) -> float:
    """A pinhole pixel's angular step at the image centre, degrees."""
    return float(np.rad2deg(np.arctan(1.0 / focal_px)))


def _camera(width: int, height: int, hfov_deg: float, **noise):
    def focal(quick):
        return (width / (2 if quick else 1) / 2) / np.tan(np.deg2rad(hfov_deg) / 2)

    def simulate(rng, quick):
        w, h = (width, height) if not quick else (width // 2, height // 2)
        f = focal(quick)
        world = random_room(rng, around=False, sensor_height=(1.0, 1.6))
        scene = camera_pose_scene(world, yaw=rng.uniform(-0.3, 0.3), pitch=rng.uniform(0.2, 0.45))
        return simulate_depth_camera(scene, width=w, height=h, fx=f, fy=f, cx=(w - 1) / 2,
                                     cy=(h - 1) / 2, seed=_noise_seed(rng), **noise)

    def spacing(quick):
        return _pixel_deg(focal(quick)), _pixel_deg(focal(quick))
    return simulate, spacing


# ABW's camera (SOURCES.md): fx = |F| ~ 1586, fy = |F| C ~ 2301 px, 512 x 512.
_ABW_FX, _ABW_FY = 1586.0, 2301.0
_ABW_NOISE = 0.00025
_ABW_STEP = 0.00126


def _tabletop_spacing(quick):
    scale = 0.5 if quick else 1.0
    return _pixel_deg(_ABW_FY * scale), _pixel_deg(_ABW_FX * scale)


def _tabletop(rng, quick):
    size = 512 if not quick else 256
    scale = size / 512
    world = random_tabletop(rng)
    distance = rng.uniform(0.85, 1.0)
    pitch = rng.uniform(0.5, 0.9)
    position = (-distance * np.cos(pitch), rng.uniform(-0.02, 0.02), distance * np.sin(pitch))
    scene = camera_pose_scene(world, position=position, yaw=rng.uniform(-0.1, 0.1), pitch=pitch)
    return simulate_depth_camera(
        scene, width=size, height=size, fx=_ABW_FX * scale, fy=_ABW_FY * scale,
        cx=(size - 1) / 2, cy=(size - 1) / 2, noise_coeff=0.0, noise_sigma0=_ABW_NOISE,
        depth_step=_ABW_STEP, min_depth=0.3, max_depth=2.0, seed=_noise_seed(rng))


#: The real Kinect's depth step (1/m, ``q z^2``: 1/8-px disparity steps, 1 / (8 f b)) and the
#: side (px) of the box over which its errors are correlated, as measured on the real frames
#: (kinect_real_640x480).
KINECT_STEP = 0.0029
KINECT_CORRELATION_PX = 9

_STEREO_HFOV = 90.0
_STEREO_F = 640 / np.tan(np.deg2rad(_STEREO_HFOV) / 2)
_STEREO_COEFF = 0.1 / (_STEREO_F * 0.05)  # sigma_z = sigma_d z^2 / (f B)

SENSORS: tuple[SensorSpec, ...] = (
    SensorSpec("nodding_1deg", "nodding", "lms200", {"sigma0": 0.005, "sigma_quadratic": 0.0}, 8,
               *_nodding(1.0, 0.005), "70 x 131, 1 deg beams, 0.58 deg tilt steps, 5 mm"),
    SensorSpec("nodding_0.5deg", "nodding", "lms200", {"sigma0": 0.005, "sigma_quadratic": 0.0}, 6,
               *_nodding(0.5, 0.005), "140 x 261, 0.5 deg beams, 0.29 deg tilt steps, 5 mm"),
    SensorSpec("nodding_0.25deg", "nodding", "lms200", {"sigma0": 0.005, "sigma_quadratic": 0.0}, 4,
               *_nodding(0.25, 0.005), "280 x 521, 0.25 deg beams, 0.145 deg tilt steps, 5 mm"),
    SensorSpec("noise_2mm", "noise", "lms200", {"sigma0": 0.002, "sigma_quadratic": 0.0}, 8,
               *_nodding(1.0, 0.002), "70 x 131 nodding laser, 2 mm"),
    SensorSpec("noise_10mm", "noise", "lms200", {"sigma0": 0.010, "sigma_quadratic": 0.0}, 8,
               *_nodding(1.0, 0.010), "70 x 131 nodding laser, 10 mm"),
    SensorSpec("noise_20mm", "noise", "lms200", {"sigma0": 0.020, "sigma_quadratic": 0.0}, 8,
               *_nodding(1.0, 0.020), "70 x 131 nodding laser, 20 mm"),
    SensorSpec("spinning_32x1024", "spinning", "spinning_lidar", {"sigma0": 0.03, "sigma_quadratic": 0.0}, 4,
               *_spinning(32, 1024, 0.03), "32 x 1024, 45 deg vertical, 360 deg, 3 cm"),
    SensorSpec("spinning_64x1024", "spinning", "spinning_lidar", {"sigma0": 0.015, "sigma_quadratic": 0.0}, 4,
               *_spinning(64, 1024, 0.015), "64 x 1024, 45 deg vertical, 360 deg, 1.5 cm"),
    SensorSpec("spinning_128x2048", "spinning", "spinning_lidar", {"sigma0": 0.01, "sigma_quadratic": 0.0}, 3,
               *_spinning(128, 2048, 0.01), "128 x 2048, 45 deg vertical, 360 deg, 1 cm"),
    SensorSpec("kinect_640x480", "depth", "rgbd_vga",
               {"sigma0": 0.001, "sigma_quadratic": KINECT_NOISE, "noise_correlation_px": 1, "step_quadratic": 0.0}, 6,
               *_camera(640, 480, 62.0), "Kinect, 62 deg horizontal, 1.425e-3 z^2"),
    # The real Kinect (kinectq, session 31): depth in 1/8-px disparity steps (2.9e-3 z^2) and
    # errors correlated over about 9 px. Measured on the PCL / PEAC / CAPE frames, residuals
    # about fitted planes: row correlation 0.74-0.91 / 0.52-0.79 / 0.28-0.66 at lags 1 / 3 /
    # 6 px and a 6x6 tile mean keeping 0.68-0.84 of a pixel's rms (office1 at 3.8-5.2 m:
    # 0.74-0.78 / 0.52-0.58 / 0.28-0.34, 0.68-0.70). Noise as box means over 9 px, then the
    # steps: 0.72 / 0.51 / 0.26 and 0.69 at every range (5 px: 0.62 / 0.29 / 0.00, 0.53).
    SensorSpec("kinect_real_640x480", "depth", "rgbd_vga",
               {"sigma0": 0.001, "sigma_quadratic": KINECT_NOISE, "noise_correlation_px": KINECT_CORRELATION_PX,
                "step_quadratic": KINECT_STEP}, 6,
               *_camera(640, 480, 62.0, noise_correlation=KINECT_CORRELATION_PX, step_quadratic=KINECT_STEP),
               f"Kinect as measured: 1.425e-3 z^2 correlated over {KINECT_CORRELATION_PX} px, "
               "1/8-px disparity steps 2.9e-3 z^2", scenes_of="kinect_640x480"),
    SensorSpec("stereo_1280x720", "depth", "rgbd_vga",
               {"sigma0": 0.001, "sigma_quadratic": float(_STEREO_COEFF), "noise_correlation_px": 3,
                "step_quadratic": 0.0}, 4,
               *_camera(1280, 720, _STEREO_HFOV, noise_coeff=float(_STEREO_COEFF), noise_correlation=3),
               f"stereo, 90 deg horizontal, {_STEREO_COEFF:.2e} z^2 correlated over 3 px"),
    SensorSpec("tabletop_abw", "tabletop", "abw", {"sigma0": 0.0005, "sigma_quadratic": 0.0}, 6,
               _tabletop, _tabletop_spacing, "structured light 512 x 512, polyhedra at 0.8-1 m, 0.25 mm + 1.26 mm steps",
               region_growing={"voxel_size": 0.004}),
)


def sensor_names() -> list[str]:
    """Names of the matrix's rows, in order."""
    return [s.name for s in SENSORS]


def get_sensor(name: str) -> SensorSpec:
    """The row called ``name``; ValueError listing the known ones otherwise."""
    for spec in SENSORS:
        if spec.name == name:
            return spec
    raise ValueError(f"unknown sensor {name!r}; known: {', '.join(sensor_names())}")
