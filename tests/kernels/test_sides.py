"""kernels.crease_sides: a cylinder that misfits its region across its axis, cut into two sides."""

import numpy as np
import pytest

from rangeseg_o3d.fitting import fit_cylinder
from rangeseg_o3d.kernels import crease_sides
from rangeseg_o3d.kernels.linalg import CHI_SQUARE_SIGMAS

BINS, SAMPLE, CUTS = 8, 256, 33


def _wedge(rows=50, cols=60, sigma=0.01, seed=0):
    """Two planes meeting at a 12-degree crease (a floor 1 m below the sensor, 3-5 m ahead,
    2 cm by 4 cm pixels) with ``sigma`` of range noise along each ray: ``(points, side)``,
    ``side`` True on the flat half (x < 0)."""
    v, u = np.mgrid[0:rows, 0:cols].astype(float)
    x, z = -0.6 + u * 0.02, 3.0 + v * 2.0 / rows
    y = np.where(u < cols // 2, -1.0, -1.0 + np.tan(np.radians(12.0)) * x)
    xyz = np.dstack([x, y, z]).reshape(-1, 3)
    ranges = np.linalg.norm(xyz, axis=1, keepdims=True)
    rng = np.random.default_rng(seed)
    return xyz * (1.0 + rng.normal(0.0, sigma, ranges.shape) / ranges), (u < cols // 2).ravel()


def _arc(sigma=0.001, range_noise=True, seed=0):
    """A 70-degree arc of a cylinder of radius 0.5 m (axis along y) 3 m ahead, 50 x 60
    pixels, with ``sigma`` of noise along each ray (``range_noise``) or across the surface."""
    v, u = np.mgrid[0:50, 0:60].astype(float)
    angle = np.radians(-35.0 + 70.0 * u / 59.0)
    xyz = np.dstack([0.5 * np.sin(angle), v * 0.02, 3.0 - 0.5 * np.cos(angle)]).reshape(-1, 3)
    rng = np.random.default_rng(seed)
    noise = rng.normal(0.0, sigma, (len(xyz), 1))
    if range_noise:
        return xyz * (1.0 + noise / np.linalg.norm(xyz, axis=1, keepdims=True))
    radial = xyz - np.array([0.0, 0.0, 3.0]) * [1.0, 0.0, 1.0] - xyz * [0.0, 1.0, 0.0]
    return xyz + noise * radial / np.linalg.norm(radial, axis=1, keepdims=True)


def _sides(points, sigma, cylinder, min_size=10, cover=0.9):
    idx = np.arange(len(points), dtype=np.int64)
    return crease_sides(points, np.full(len(points), sigma), idx, cylinder.distances(points), cylinder.axis,
                        cylinder.point, float(cylinder.radius), min_size, BINS, SAMPLE, CUTS, CHI_SQUARE_SIGMAS, cover, 2)


@pytest.mark.slow
@pytest.mark.parametrize("rows", [50, 200])  # the gate on every pixel, and on a sample of 256
def test_a_cylinder_over_a_grazing_wedge_is_cut_at_the_crease(rows):
    sigma = 0.01
    points, flat = _wedge(rows=rows, sigma=sigma)
    cylinder = fit_cylinder(points)
    assert cylinder.kind == "cylinder" and cylinder.rms < sigma  # within the range noise
    first = _sides(points, sigma, cylinder)
    assert first.shape == flat.shape
    # one side is the flat half, the other the tilted one, up to a pixel column or two
    agree = max((first == flat).mean(), (first != flat).mean())
    assert agree >= 0.95, agree


def test_a_true_cylinder_is_not_cut():
    points = _arc(sigma=0.001)
    cylinder = fit_cylinder(points)
    assert abs(cylinder.radius - 0.5) < 0.005
    assert _sides(points, 0.001, cylinder).size == 0


def test_a_cylinder_off_at_random_is_not_cut():
    # noise across the surface 1.5 times what the sensor predicts for the distances: the
    # rms is beyond the noise of the distances (the gate's first test), but the misfit has
    # no pattern across the axis (each bin's mean distance is within that noise)
    points = _arc(sigma=0.001, range_noise=False)
    cylinder = fit_cylinder(points)
    distances = cylinder.distances(points)
    sigma = 0.0007  # range noise; along the rays 0.57-0.7 mm of distance noise
    assert np.sqrt(np.mean(distances ** 2)) > 1.3 * sigma
    assert _sides(points, sigma, cylinder).size == 0
    # four times: the bins' means are beyond that noise too and the gate passes, but the
    # planes of the best cut leave far more than the cylinder: refused by the bound (with
    # no share to cover, no bound, the cut is returned)
    assert _sides(points, sigma / 4, cylinder).size == 0
    first = _sides(points, sigma / 4, cylinder, cover=0.0)
    assert first.size == len(points) and 10 <= first.sum() <= len(points) - 10


def test_a_region_too_small_to_cut_gives_nothing():
    points, _ = _wedge(sigma=0.01)
    cylinder = fit_cylinder(points)
    assert _sides(points, 0.01, cylinder, min_size=len(points) // 2 + 1).size == 0
    few = points[:2 * BINS - 1]
    assert _sides(few, 0.01, cylinder).size == 0


def test_the_gate_noise_is_distance_noise_with_its_sagitta_term():
    # a pillar of radius 0.3 m 4 m ahead under 3 cm of range noise (a depth camera there):
    # the gate's per-pixel variance is fitting.robust.distance_noise squared, whose sagitta
    # term is most of the noise at the flanks, where the first-order term (sigma x cosine)
    # nears zero
    from rangeseg_o3d.fitting.primitives import Cylinder
    from rangeseg_o3d.fitting.robust import distance_noise
    from rangeseg_o3d.kernels.sides import _normals_and_noise

    angle = np.radians(np.linspace(-85.0, 85.0, 69))
    points = np.column_stack([0.3 * np.sin(angle), np.zeros(69), 4.0 - 0.3 * np.cos(angle)])
    cylinder = Cylinder(axis=[0.0, 1.0, 0.0], point=[0.0, 0.0, 4.0], radius=0.3, rms=0.0, inliers=0)
    sigma = np.full(69, 0.03)
    _, variance = _normals_and_noise(points, sigma, np.arange(69, dtype=np.int64), np.asarray(cylinder.axis),
                                     np.asarray(cylinder.point), 0.3)
    expected = distance_noise(cylinder, points, sigma)
    assert np.sqrt(variance) == pytest.approx(expected, rel=1e-9)
    rays = points / np.linalg.norm(points, axis=1, keepdims=True)
    first = sigma * np.abs(np.einsum("ij,ij->i", rays, cylinder.normals(points)))
    flank = np.abs(angle) > np.radians(80.0)
    assert (np.sqrt(variance[flank]) > 1.3 * first[flank]).all()
    # head-on the sagitta is nothing beside sigma x cosine
    assert np.sqrt(variance[34]) == pytest.approx(0.03, rel=1e-6)
