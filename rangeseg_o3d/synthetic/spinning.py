"""A simulated spinning multi-beam lidar (Velodyne / Ouster class), ray-cast exactly.

Frame: the sensor frame, x forward, y left, z up, origin at the optical centre (all
beams start there; real units offset each beam by a few cm, left out here).
Grid: row ``i`` is beam ``i`` of the ``rows`` beams, elevations evenly spread over
``vertical_fov_deg`` from the top (row 0) down; column ``j`` is azimuth
``2 pi j / cols`` (counter-clockwise seen from above, column 0 along +x), so the
grid covers 360 degrees and the last column is the first one's neighbour across the
seam. A point is ``r (cos e cos a, cos e sin a, sin e)``.

Noise: Gaussian on range, ``noise_sigma`` metres; returns beyond ``max_range`` or
closer than ``min_range`` are no return (NaN). No beam footprint (no mixed pixels).
"""

from __future__ import annotations

import numpy as np

from ..cloud import OrganizedCloud
from .raycast import cast
from .scene import Scene, SyntheticScan

__all__ = ["spinning_angles", "spinning_directions", "spinning_points", "simulate_spinning_lidar"]


def spinning_angles(rows: int, cols: int, *, vertical_fov_deg: float = 45.0) -> tuple[np.ndarray, np.ndarray]:
    """Beam elevations (rows,) from the top down and azimuths (cols,), radians.

    Elevations are evenly spaced over ``vertical_fov_deg`` centred on the horizon, both
    ends included; azimuths ``2 pi j / cols``, so column ``cols - 1`` is one step from 0.
    """
    for name, value in (("rows", rows), ("cols", cols)):
        if int(value) != value or value < 2:
            raise ValueError(f"{name} must be an integer >= 2; got {value}")
    if not (np.isfinite(vertical_fov_deg) and 0 < vertical_fov_deg < 180):
        raise ValueError(f"vertical_fov_deg must be in (0, 180); got {vertical_fov_deg}")
    half = np.deg2rad(vertical_fov_deg) / 2
    elevations = np.linspace(half, -half, int(rows))
    azimuths = 2 * np.pi * np.arange(int(cols)) / int(cols)
    return elevations, azimuths


def spinning_directions(elevations, azimuths) -> np.ndarray:
    """(H, W, 3) unit beam directions for beam elevations (H,) and azimuths (W,)."""
    e = np.asarray(elevations, dtype=float)[:, None]
    a = np.asarray(azimuths, dtype=float)[None, :]
    return np.stack(np.broadcast_arrays(np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)), axis=-1)


def spinning_points(ranges, elevations, azimuths) -> np.ndarray:
    """(H, W, 3) points from (H, W) ranges; NaN, inf or <= 0 ranges give NaN points."""
    ranges = np.asarray(ranges, dtype=float)
    directions = spinning_directions(elevations, azimuths)
    if ranges.shape != directions.shape[:2]:
        raise ValueError(f"ranges must have shape {directions.shape[:2]}; got {ranges.shape}")
    clean = np.where(np.isfinite(ranges) & (ranges > 0), ranges, np.nan)
    return clean[..., None] * directions


def simulate_spinning_lidar(
    scene: Scene,
    *,
    rows: int = 64,
    cols: int = 1024,
    vertical_fov_deg: float = 45.0,
    noise_sigma: float = 0.015,
    min_range: float = 0.3,
    max_range: float = 100.0,
    seed=0,
) -> SyntheticScan:
    """Scan ``scene`` with a spinning lidar of ``rows`` beams and ``cols`` azimuth steps.

    Returns
    -------
    SyntheticScan
        ``cloud`` from :meth:`OrganizedCloud.from_spherical` (ranges in metres, NaN = no
        return; its SphericalGeometry says the columns close a full turn),
        ``truth_ids`` (0 = no return) and ``truth`` of the surfaces seen.

    Examples
    --------
    >>> from rangeseg_o3d.synthetic.scene import Scene, room
    >>> scene = Scene(room(x=(-4, 4), y=(-3, 3), z=(-1, 2), first_id=1))
    >>> scan = simulate_spinning_lidar(scene, rows=8, cols=32, noise_sigma=0.0)
    >>> scan.cloud.shape, sorted(scan.truth)  # the ceiling (2) is above the +-22.5 deg beams
    ((8, 32), [1, 3, 4, 5, 6])
    """
    if not (np.isfinite(noise_sigma) and noise_sigma >= 0):
        raise ValueError(f"noise_sigma must be >= 0; got {noise_sigma}")
    if not (0 <= min_range < max_range):
        raise ValueError(f"need 0 <= min_range < max_range; got {min_range}, {max_range}")
    elevations, azimuths = spinning_angles(rows, cols, vertical_fov_deg=vertical_fov_deg)
    directions = spinning_directions(elevations, azimuths)
    shape = directions.shape[:2]
    hit, ids = cast(scene, np.zeros((directions[..., 0].size, 3)), directions.reshape(-1, 3))
    ranges = hit.reshape(shape)
    ids = ids.reshape(shape)
    if noise_sigma > 0:
        ranges = ranges + np.random.default_rng(seed).normal(0.0, noise_sigma, size=shape)
    no_return = ~np.isfinite(ranges) | (ranges < min_range) | (ranges > max_range) | (ids == 0)
    ranges[no_return] = np.nan
    ids[no_return] = 0
    cloud = OrganizedCloud.from_spherical(ranges, elevations, azimuths)
    return SyntheticScan(cloud=cloud, truth_ids=ids.astype(np.int32), truth=scene.truth(seen=ids), scene=scene)
