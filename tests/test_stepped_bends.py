"""bent_planes where the depth comes in steps (a Kinect's 1/8-px disparity, errors correlated
over 9 px): a pillar 0.35 m across at 5.4 m, a third of it hidden behind a box, bends by about
two depth steps; the chi-square gates over independent returns refuse it, the bend measured
over blocks of the matching window along the pillar finds it. A flat board of the same size at
the same range stays a plane."""

import numpy as np
import pytest

from rangeseg_o3d.bent_planes import TEST_POINTS, _pipe_of
from rangeseg_o3d.fitting.region_fitter import region_samples
from rangeseg_o3d.sensor import NoiseModel
from rangeseg_o3d.synthetic.depth_camera import KINECT_NOISE, camera_pose_scene, simulate_depth_camera
from rangeseg_o3d.synthetic.matrix import KINECT_CORRELATION_PX, KINECT_STEP
from rangeseg_o3d.synthetic.scene import Scene, box, cylinder, patch

PILLAR, BOARD = 2, 21  # truth ids: the pillar's side, the board's face towards the camera
RADIUS = 0.175
NOISE = NoiseModel(sigma0=0.001, sigma_quadratic=KINECT_NOISE, correlation_px=KINECT_CORRELATION_PX,
                   step_quadratic=KINECT_STEP)
F = 320 / np.tan(np.deg2rad(31.0))  # the matrix's Kinect: 62 degrees across 640 columns


def _scan(seed):
    # world: x ahead, y left, z up; a wall 6 m ahead, the pillar at 5.4 m with its left third
    # behind a box 4 m ahead, a board 0.30 m wide facing the camera at 5.4 m to the right
    ex, ey, ez = np.eye(3)
    parts = (patch((6.0, 0.0, 1.0), ey, ez, 3.0, 2.0, first_id=1)
             + cylinder((5.4 + RADIUS, 0.5, -0.5), (0, 0, 1), RADIUS, 3.0, caps=False, first_id=PILLAR)
             + box((4.1, 0.915, 1.0), (0.2, 1.0, 4.0), first_id=10)
             + box((5.4 + 0.15, -0.8, 1.0), (0.3, 0.30, 3.0), first_id=20))
    scene = camera_pose_scene(Scene(parts), position=(0.0, 0.0, 1.0))
    return simulate_depth_camera(scene, fx=F, fy=F, cx=319.5, cy=239.5, noise_coeff=KINECT_NOISE,
                                 noise_sigma0=0.001, noise_correlation=KINECT_CORRELATION_PX,
                                 step_quadratic=KINECT_STEP, seed=seed)


def _asked(scan, surface, stepped):
    # _pipe_of on the surface's test pixels as cylinders_for_bent_planes draws them
    (sample, count), = region_samples(scan.truth_ids, [surface], TEST_POINTS).values()
    xyz = scan.cloud.xyz.reshape(-1, 3)[sample]
    sigma = NOISE.sigma(np.linalg.norm(xyz, axis=1))
    pixels = np.column_stack(np.unravel_index(sample, scan.truth_ids.shape)).astype(np.float64)
    samples = NOISE.independent_share(1) * count
    if stepped:
        return _pipe_of(xyz, sigma, samples, 2.0, pixels=pixels, window=NOISE.correlation_px)
    return _pipe_of(xyz, sigma, samples, 2.0)


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(4))
def test_a_partly_hidden_pillar_two_steps_deep_is_a_cylinder(seed):
    scan = _scan(seed)
    seen = scan.truth_ids == PILLAR
    columns = np.nonzero(seen.any(axis=0))[0]
    # the pillar shows 0.6-0.7 of its 35-px width, its bend about two depth steps
    assert 20 <= columns.size <= 26
    assert 2 * RADIUS / (KINECT_STEP * 5.4 ** 2) > 4  # its full depth: four steps and more
    found = _asked(scan, PILLAR, stepped=True)
    assert found is not None
    assert abs(found.radius - RADIUS) < 0.3 * RADIUS  # measured 0.138-0.213 over seeds 0-5
    assert abs(abs(found.axis[1]) - 1.0) < 0.02  # the camera's y is down: the pillar's axis
    # the chi-square gates over independent returns do not find it (main's form)
    assert _asked(scan, PILLAR, stepped=False) is None


@pytest.mark.parametrize("seed", range(4))
def test_a_flat_board_of_the_same_size_stays_a_plane(seed):
    scan = _scan(seed)
    assert np.count_nonzero(scan.truth_ids == BOARD) > 2500
    assert _asked(scan, BOARD, stepped=True) is None
