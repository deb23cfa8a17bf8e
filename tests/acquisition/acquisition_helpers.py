"""Shared test helpers: a flat wall standing in for a synthetic scene."""

import numpy as np

from rangeseg_o3d.geometry import NoddingGeometry, nodding_rays

WALL_X = 3.0
MOUNT = (0.0, 0.0, 0.1)



def wall_ranges(tilt, beams, *, mount=MOUNT, tilt_sign=1.0, wall_x=WALL_X):
    """Exact ranges to the plane x = wall_x (inf where a beam misses it)."""
    o, d = nodding_rays(NoddingGeometry(beams, np.array([tilt]), mount, tilt_sign))
    o, d = o[0], d[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (wall_x - o[:, 0]) / d[:, 0]
    return np.where(np.isfinite(t) & (t > 0), t, np.inf)
