"""Small synthetic depth frames with ground truth, shared by the segmenter tests."""

import numpy as np
import pytest

from rangeseg_o3d import OrganizedCloud
from rangeseg_o3d.synthetic import Rectangle, Scene, box, cast


def render(scene: Scene, *, shape=(60, 80), fov_deg=(60.0, 65.0), noise=0.001, seed=0):
    """Pinhole view from the origin along +x (z up): (OrganizedCloud, truth ids (H, W))."""
    h, w = shape
    tan_v = np.tan(np.deg2rad(fov_deg[0] / 2)) * np.linspace(1, -1, h)
    tan_u = np.tan(np.deg2rad(fov_deg[1] / 2)) * np.linspace(1, -1, w)
    dirs = np.stack(np.broadcast_arrays(1.0, tan_u[None, :], tan_v[:, None]), -1).reshape(-1, 3)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    ranges, ids = cast(scene, np.zeros_like(dirs), dirs)
    ranges = ranges + np.random.default_rng(seed).normal(0.0, noise, ranges.shape)
    xyz = np.where(np.isfinite(ranges)[:, None], dirs * ranges[:, None], np.nan)
    return OrganizedCloud(xyz.reshape(h, w, 3)), ids.reshape(h, w)


ex, ey, ez = np.eye(3)


@pytest.fixture(scope="session")
def two_planes():
    """A floor (id 1) meeting a wall (id 2) at a right angle, seen from 0.6 m above the floor."""
    floor = Rectangle(1, (2.0, 0.0, -0.6), ex, ey, 2.0, 3.0)
    wall = Rectangle(2, (3.0, 0.0, 1.0), ey, ez, 3.0, 1.6)
    return render(Scene([floor, wall]))


@pytest.fixture(scope="session")
def box_on_floor():
    """A 0.6 m box turned 30 deg on a floor (id 1), against a wall (id 2); box faces from id 3.

    Seen from 1 m above the floor: the top (3), the -x face (4) and the +y face (7) show.
    """
    floor = Rectangle(1, (3.5, 0.0, -1.0), ex, ey, 3.5, 4.0)
    wall = Rectangle(2, (7.0, 0.0, 0.6), ey, ez, 4.0, 1.6)
    faces = box((2.0, 0.0, -0.7), (0.6, 0.6, 0.6), yaw=np.deg2rad(30), first_id=3)
    return render(Scene([floor, wall, *faces]), shape=(90, 120))


@pytest.fixture(scope="session")
def matched_regions():
    """The helper :func:`_matched_regions`, as a fixture (test modules here are not a package)."""
    return _matched_regions


def _matched_regions(labels, truth, *, min_pixels, tol=0.8):
    """Truth ids with >= min_pixels that one label covers both ways at >= tol (Hoover correct)."""
    found = {}
    for tid in np.unique(truth[truth > 0]):
        mask = truth == tid
        if mask.sum() < min_pixels:
            continue
        lab, count = np.unique(labels[mask], return_counts=True)
        best = lab[np.argmax(count)]
        overlap = count.max()
        if best > 0 and overlap >= tol * mask.sum() and overlap >= tol * (labels == best).sum():
            found[int(tid)] = int(best)
    return found
