"""A simulated nodding SICK LMS200 (the paper's sensor), ray-cast exactly.

Frame: the nodding geometry's base frame (x forward, y left, z up, origin on the tilt
axis; see :mod:`rangeseg_o3d.geometry`). Build scenes in that frame: a sensor
0.5 m above the floor means a floor at z = -0.5.

Defaults follow the paper: beams 25..155 deg at 1 deg (131 columns, the central part
of the 181-beam scan), 70 rows with tilts ``np.linspace(-0.4, 0.3, 70)`` rad (explicit
endpoints, step 0.01014 rad), 5 mm Gaussian range noise, 8.183 m maximum range. The
mirror centre sits 0.1 m above the tilt axis (``mount_offset=(0, 0, 0.1)``, tilting frame).

Mixed pixels. A real LMS200 beam has a footprint of about 0.75 deg; when it straddles a
jump edge, the returned range lies between foreground and background. The model casts
five sub-rays (centre and +-half the beam width in beam angle and in tilt), weights
0.4 / 0.15 x 4. If the sub-rays that hit see more than one surface, the returned range
is the weighted mean of their ranges (a point floating between the surfaces); the pixel's
truth id is 0 unless that mean stays within ``mixed_tolerance`` of the centre ray's range
(a crease, where the mix still lies on the surface). A centre ray that misses gives no
return. Noise is added after mixing; a noisy range beyond ``max_range`` is no return.
"""

from __future__ import annotations

import numpy as np

from ..cloud import OrganizedCloud
from ..geometry import NoddingGeometry, nodding_rays
from .raycast import cast
from .scene import Scene, SyntheticScan

__all__ = [
    "simulate_lms200",
    "lms200_row_ranges",
    "nodding_ranges",
    "lms200_beam_angles",
    "lms200_tilt_angles",
    "DEFAULT_MOUNT_OFFSET",
    "MAX_RANGE",
]

DEFAULT_MOUNT_OFFSET = (0.0, 0.0, 0.1)
MAX_RANGE = 8.183
# Footprint pattern: (beam offset, tilt offset) in units of half the beam width, and weights.
_SUB_RAYS = np.array([[0.0, 0.0], [-1.0, 0.0], [1.0, 0.0], [0.0, -1.0], [0.0, 1.0]])
_SUB_WEIGHTS = np.array([0.4, 0.15, 0.15, 0.15, 0.15])


def lms200_beam_angles(start_deg: float = 25.0, stop_deg: float = 155.0, step_deg: float = 1.0) -> np.ndarray:
    """Beam angles in radians from ``start_deg`` to ``stop_deg`` inclusive (131 by default)."""
    if not step_deg > 0:
        raise ValueError(f"beam_step_deg must be positive; got {step_deg}")
    if not stop_deg >= start_deg:
        raise ValueError(f"beam_stop_deg must be >= beam_start_deg; got {start_deg}..{stop_deg}")
    count = int(np.floor((stop_deg - start_deg) / step_deg + 1e-9)) + 1
    return np.deg2rad(start_deg + step_deg * np.arange(count))


def lms200_tilt_angles(rows: int = 70, start: float = -0.4, stop: float = 0.3) -> np.ndarray:
    """The tilt schedule: ``np.linspace(start, stop, rows)`` radians, both ends included."""
    if int(rows) != rows or rows < 1:
        raise ValueError(f"rows must be a positive integer; got {rows}")
    return np.linspace(float(start), float(stop), int(rows))


def nodding_ranges(
    scene: Scene,
    beam_angles,
    tilt_angles,
    *,
    mount_offset=DEFAULT_MOUNT_OFFSET,
    tilt_sign: float = 1.0,
    noise_sigma: float = 0.005,
    max_range: float = MAX_RANGE,
    mixed_pixels: bool = True,
    beam_width_deg: float = 0.75,
    mixed_tolerance: float = 0.01,
    seed=0,
) -> tuple[np.ndarray, np.ndarray]:
    """Ranges and truth ids of a nodding scan (the core of :func:`simulate_lms200`).

    Parameters
    ----------
    scene : Scene
    beam_angles : (W,) radians.  tilt_angles : (H,) radians (the unit's actual angles).
    mount_offset, tilt_sign : see :class:`~rangeseg_o3d.geometry.NoddingGeometry`.
    noise_sigma : Gaussian range noise, metres (0 = exact).
    max_range : returns beyond this are no return.
    mixed_pixels, beam_width_deg, mixed_tolerance : the footprint model (module docstring).
    seed : int or numpy Generator for the noise.

    Returns
    -------
    ranges : (H, W) float, metres, NaN = no return.
    truth_ids : (H, W) int32, 0 = no return or mixed pixel.
    """
    if not (np.isfinite(noise_sigma) and noise_sigma >= 0):
        raise ValueError(f"noise_sigma must be >= 0; got {noise_sigma}")
    if not (np.isfinite(max_range) and max_range > 0):
        raise ValueError(f"max_range must be positive; got {max_range}")
    if not (np.isfinite(beam_width_deg) and beam_width_deg >= 0):
        raise ValueError(f"beam_width_deg must be >= 0; got {beam_width_deg}")
    beams = np.asarray(beam_angles, dtype=float)
    tilts = np.asarray(tilt_angles, dtype=float)
    geometry = NoddingGeometry(beams, tilts, mount_offset, tilt_sign)
    shape = geometry.shape
    pattern = _SUB_RAYS if mixed_pixels and beam_width_deg > 0 else _SUB_RAYS[:1]
    half_width = np.deg2rad(beam_width_deg) / 2
    origins, directions = [], []
    for d_beam, d_tilt in pattern:
        sub = NoddingGeometry(beams + d_beam * half_width, tilts + d_tilt * half_width,
                              geometry.mount_offset, tilt_sign)
        o, d = nodding_rays(sub)
        origins.append(o.reshape(-1, 3))
        directions.append(d.reshape(-1, 3))
    hit_ranges, hit_ids = cast(scene, np.concatenate(origins), np.concatenate(directions))
    hit_ranges = hit_ranges.reshape(len(pattern), *shape)
    hit_ids = hit_ids.reshape(len(pattern), *shape)

    ranges = hit_ranges[0].copy()
    ids = hit_ids[0].copy()
    if len(pattern) > 1:
        hits = hit_ids > 0
        several = (hits & (hit_ids != hit_ids[0][None])).any(axis=0) & (hit_ids[0] > 0)
        weights = _SUB_WEIGHTS[:, None, None] * hits
        weighted = np.where(hits, hit_ranges, 0.0)
        mix = (weights * weighted).sum(axis=0) / np.maximum(weights.sum(axis=0), 1e-12)
        ranges = np.where(several, mix, ranges)
        off_surface = several & (np.abs(mix - hit_ranges[0]) > mixed_tolerance)
        ids[off_surface] = 0

    rng = np.random.default_rng(seed)
    if noise_sigma > 0:
        ranges = ranges + rng.normal(0.0, noise_sigma, size=shape)
    no_return = ~np.isfinite(ranges) | (ranges > max_range) | (ranges <= 0) | (hit_ids[0] == 0)
    ranges[no_return] = np.nan
    ids[no_return] = 0
    return ranges, ids.astype(np.int32)


def lms200_row_ranges(
    scene: Scene,
    tilt: float,
    beam_angles=None,
    *,
    mount_offset=DEFAULT_MOUNT_OFFSET,
    tilt_sign: float = 1.0,
    noise_sigma: float = 0.005,
    max_range: float = MAX_RANGE,
    mixed_pixels: bool = True,
    seed=None,
) -> np.ndarray:
    """One scan line at an arbitrary (actual) tilt angle, for device simulators.

    Parameters
    ----------
    scene : Scene
    tilt : float, radians, the tilt unit's angle (``theta = tilt_sign * tilt``).
    beam_angles : (W,) radians; default the full 181-beam scan 0..180 deg at 1 deg.
    seed : int, Generator or None (fresh entropy) for the noise.

    Returns
    -------
    (W,) float array of ranges in metres, NaN for no return.
    """
    if beam_angles is None:
        beam_angles = lms200_beam_angles(0.0, 180.0, 1.0)
    ranges, _ = nodding_ranges(
        scene, beam_angles, [float(tilt)], mount_offset=mount_offset, tilt_sign=tilt_sign,
        noise_sigma=noise_sigma, max_range=max_range, mixed_pixels=mixed_pixels, seed=seed,
    )
    return ranges[0]


def simulate_lms200(
    scene: Scene,
    *,
    rows: int = 70,
    tilt_start: float = -0.4,
    tilt_stop: float = 0.3,
    beam_start_deg: float = 25.0,
    beam_stop_deg: float = 155.0,
    beam_step_deg: float = 1.0,
    mount_offset=DEFAULT_MOUNT_OFFSET,
    tilt_sign: float = 1.0,
    noise_sigma: float = 0.005,
    max_range: float = MAX_RANGE,
    mixed_pixels: bool = True,
    beam_width_deg: float = 0.75,
    seed=0,
) -> SyntheticScan:
    """Scan ``scene`` with a simulated nodding LMS200.

    Returns
    -------
    SyntheticScan
        ``cloud`` built with :meth:`OrganizedCloud.from_ranges` (so it carries its
        NoddingGeometry), ``truth_ids`` (0 = no return / mixed pixel / beyond max range)
        and ``truth`` for every surface seen.

    Examples
    --------
    >>> from rangeseg_o3d.synthetic.scene import Scene, room
    >>> scan = simulate_lms200(Scene(room(first_id=1)), noise_sigma=0.0)
    >>> scan.cloud.shape, sorted(scan.truth)  # the wall behind (id 3) is not seen
    ((70, 131), [1, 2, 4, 5, 6])
    """
    beams = lms200_beam_angles(beam_start_deg, beam_stop_deg, beam_step_deg)
    tilts = lms200_tilt_angles(rows, tilt_start, tilt_stop)
    ranges, ids = nodding_ranges(
        scene, beams, tilts, mount_offset=mount_offset, tilt_sign=tilt_sign,
        noise_sigma=noise_sigma, max_range=max_range, mixed_pixels=mixed_pixels,
        beam_width_deg=beam_width_deg, seed=seed,
    )
    cloud = OrganizedCloud.from_ranges(ranges, beams, tilts, mount_offset=mount_offset, tilt_sign=tilt_sign)
    return SyntheticScan(cloud=cloud, truth_ids=ids, truth=scene.truth(seen=ids), scene=scene)

