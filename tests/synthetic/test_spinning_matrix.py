"""Spinning lidar simulator, random matrix scenes and the sensor matrix's draws."""

import numpy as np
import pytest

from rangeseg_o3d.synthetic.matrix import SENSORS, get_sensor, matrix_rng, sensor_names
from rangeseg_o3d.synthetic.rooms import random_room, random_tabletop
from rangeseg_o3d.synthetic.scene import Scene, cylinder, room, sphere
from rangeseg_o3d.synthetic.spinning import simulate_spinning_lidar, spinning_angles


def _box_room():
    return Scene([room(x=(-4.0, 6.0), y=(-3.0, 5.0), z=(-1.2, 1.8), first_id=1),
                  sphere((2.0, 1.0, -0.5), 0.4, first_id=7),
                  cylinder((-2.0, -1.5, -1.2), (0, 0, 1), 0.3, 3.0, caps=False, first_id=8)])


def test_spinning_ranges_match_the_analytic_room():
    scan = simulate_spinning_lidar(Scene(room(x=(-4.0, 6.0), y=(-3.0, 5.0), z=(-1.2, 1.8), first_id=1)),
                                   rows=16, cols=256, noise_sigma=0.0)
    elev, azim = spinning_angles(16, 256)
    d = np.stack(np.broadcast_arrays(np.cos(elev)[:, None] * np.cos(azim), np.cos(elev)[:, None] * np.sin(azim),
                                     np.sin(elev)[:, None]), axis=-1)
    # Distance along each ray to the six planes of the box room; the nearest positive one is the truth.
    bounds = {0: (-4.0, 6.0), 1: (-3.0, 5.0), 2: (-1.2, 1.8)}
    with np.errstate(divide="ignore"):
        t = np.stack([np.where(d[..., a] > 0, hi / d[..., a], lo / d[..., a]) for a, (lo, hi) in bounds.items()])
    truth = np.min(np.where(t > 0, t, np.inf), axis=0)
    assert scan.cloud.shape == (16, 256) and scan.cloud.valid.all()
    np.testing.assert_allclose(scan.cloud.ranges, truth, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(scan.cloud.xyz, axis=2), truth, rtol=1e-9)
    # Row 0 looks up (ceiling or walls), the last row down; column 0 along +x.
    assert (scan.cloud.xyz[0, :, 2] > 0).all() and (scan.cloud.xyz[-1, :, 2] < 0).all()
    assert scan.cloud.xyz[8, 0, 0] > 0 and abs(scan.cloud.xyz[8, 0, 1]) < 1e-9


def test_spinning_points_lie_on_their_truth_surfaces_and_noise_matches_sigma():
    scene = _box_room()
    exact = simulate_spinning_lidar(scene, rows=32, cols=512, noise_sigma=0.0)
    valid = exact.cloud.valid
    for k, model in exact.truth.items():
        sel = exact.truth_ids == k
        assert np.abs(model.distances(exact.cloud.xyz[sel])).max() < 1e-9
    assert {m.kind for m in exact.truth.values()} == {"plane", "sphere", "cylinder"}
    noisy = simulate_spinning_lidar(scene, rows=32, cols=512, noise_sigma=0.02, seed=3)
    err = (noisy.cloud.ranges - exact.cloud.ranges)[valid]
    assert abs(err.std() - 0.02) < 0.02 * 0.05 and abs(err.mean()) < 0.02 * 0.05
    np.testing.assert_array_equal(noisy.truth_ids, exact.truth_ids)


def test_spinning_seam_columns_are_neighbours():
    scan = simulate_spinning_lidar(_box_room(), rows=16, cols=360, noise_sigma=0.0)
    xyz = scan.cloud.xyz
    step = np.linalg.norm(xyz[:, 1] - xyz[:, 0], axis=1)  # one azimuth step inside the grid
    seam = np.linalg.norm(xyz[:, -1] - xyz[:, 0], axis=1)  # across the seam
    # Column 0 looks along +x, onto the +x wall at 6 m: the seam step equals an ordinary one.
    np.testing.assert_allclose(seam, step, rtol=1e-3)
    _, azim = spinning_angles(16, 360)
    assert np.isclose((azim[0] - azim[-1]) % (2 * np.pi), azim[1] - azim[0])
    assert np.array_equal(scan.truth_ids[:, 0], scan.truth_ids[:, -1])


def test_spinning_bad_arguments():
    scene = _box_room()
    with pytest.raises(ValueError, match="rows"):
        simulate_spinning_lidar(scene, rows=1)
    with pytest.raises(ValueError, match="vertical_fov_deg"):
        simulate_spinning_lidar(scene, vertical_fov_deg=200)
    with pytest.raises(ValueError, match="noise_sigma"):
        simulate_spinning_lidar(scene, noise_sigma=-1)
    with pytest.raises(ValueError, match="min_range"):
        simulate_spinning_lidar(scene, min_range=5, max_range=1)


def _where(surface) -> np.ndarray:
    return np.asarray(getattr(surface, "center", getattr(surface, "base", None)))


def _signature(scene) -> list:
    return [(type(s).__name__, *np.round(_where(s), 9)) for s in scene]


def test_random_scenes_are_independent_draws_and_reproducible():
    a = random_room(np.random.default_rng(1), around=True)
    assert _signature(a) == _signature(random_room(np.random.default_rng(1), around=True))
    c = random_room(np.random.default_rng(2), around=True)
    assert _signature(a) != _signature(c)
    for scene in (a, c):
        assert len(scene) > 6  # objects were placed
        # Objects around the sensor keep clear of it (a 1.2 m keep-out disc for their footprints).
        for s in scene.surfaces[6:]:
            assert np.hypot(*_where(s)[:2]) > 0.6
    front = random_room(np.random.default_rng(3), around=False)
    assert all(_where(s)[0] > 0.5 for s in front.surfaces[6:])  # objects in front of the sensor
    with pytest.raises(TypeError, match="Generator"):
        random_room(1)
    top = random_tabletop(np.random.default_rng(0))
    assert len(top) >= 2 + 6 * 3


def test_matrix_rows_draw_different_scenes_per_scan_and_sensor():
    assert len(set(sensor_names())) == len(SENSORS)
    with pytest.raises(ValueError, match="known"):
        get_sensor("no_such_sensor")
    first = matrix_rng(0, "nodding_1deg", 0).random(4)
    assert not np.allclose(first, matrix_rng(0, "nodding_1deg", 1).random(4))
    assert not np.allclose(first, matrix_rng(0, "noise_2mm", 0).random(4))
    assert np.allclose(first, matrix_rng(0, "nodding_1deg", 0).random(4))
    # The grid facts handed to the preset follow the grid simulated (quick: a coarser one).
    facts = get_sensor("nodding_0.5deg").sensor_facts()
    assert facts["column_spacing_deg"] == 0.5 and np.isclose(facts["row_spacing_deg"], np.rad2deg(0.7) / 139)
    assert get_sensor("nodding_0.5deg").sensor_facts(quick=True)["column_spacing_deg"] == 1.0
    spinning = get_sensor("spinning_64x1024").sensor_facts()
    assert np.isclose(spinning["column_spacing_deg"], 360 / 1024) and spinning["sigma0"] == 0.015
    spec = get_sensor("nodding_1deg")
    one = spec.simulate(matrix_rng(0, spec.name, 0), True)
    two = spec.simulate(matrix_rng(0, spec.name, 1), True)
    assert one.cloud.shape == two.cloud.shape == (70, 131)
    assert not np.array_equal(one.truth_ids, two.truth_ids)


def _wall_scene():
    from rangeseg_o3d.synthetic.scene import patch

    # A wall 2 m in front of the camera, filling the view (camera frame: z forward).
    return Scene(patch((0.0, 0.0, 2.0), (1, 0, 0), (0, 1, 0), 5.0, 5.0, first_id=1))


def test_depth_camera_stereo_noise_is_correlated_with_the_stated_sigma():
    from rangeseg_o3d.synthetic.depth_camera import simulate_depth_camera

    kwargs = dict(width=200, height=160, fx=150.0, fy=150.0, cx=99.5, cy=79.5)
    exact = simulate_depth_camera(_wall_scene(), noise_coeff=0.0, **kwargs).cloud.xyz[..., 2]
    np.testing.assert_allclose(exact, 2.0, atol=1e-12)
    sigma = 0.001 + 0.002 * 2.0**2
    for correlation in (1, 3):
        z = simulate_depth_camera(_wall_scene(), noise_coeff=0.002, noise_sigma0=0.001,
                                  noise_correlation=correlation, seed=7, **kwargs).cloud.xyz[..., 2]
        err = z - 2.0
        assert abs(err.std() - sigma) < 0.05 * sigma
        neighbour = np.corrcoef(err[:, :-1].ravel(), err[:, 1:].ravel())[0, 1]
        if correlation == 1:
            assert abs(neighbour) < 0.05
        else:
            assert 0.5 < neighbour < 0.8  # a 3x3 box shares 6 of its 9 cells with the next one: 2/3
    with pytest.raises(ValueError, match="noise_correlation"):
        simulate_depth_camera(_wall_scene(), noise_correlation=0, **kwargs)


def test_depth_camera_quantised_depths():
    from rangeseg_o3d.synthetic.depth_camera import simulate_depth_camera

    scan = simulate_depth_camera(_wall_scene(), width=64, height=48, fx=50.0, fy=50.0, cx=31.5, cy=23.5,
                                 noise_coeff=0.0, noise_sigma0=0.002, depth_step=0.00126, seed=1)
    z = scan.cloud.xyz[..., 2]
    steps = z / 0.00126
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-6)
    assert len(np.unique(np.round(steps))) > 3  # noise spreads the wall over several steps
    with pytest.raises(ValueError, match="depth_step"):
        simulate_depth_camera(_wall_scene(), depth_step=-1.0)


def test_depth_camera_disparity_steps_grow_with_the_square_of_the_depth():
    from rangeseg_o3d.synthetic.depth_camera import simulate_depth_camera

    kwargs = dict(width=64, height=48, fx=50.0, fy=50.0, cx=31.5, cy=23.5, noise_sigma0=0.0)
    q = 0.0029
    plain = simulate_depth_camera(_wall_scene(), noise_coeff=0.001425, seed=3, **kwargs).cloud.xyz[..., 2]
    z = simulate_depth_camera(_wall_scene(), noise_coeff=0.001425, step_quadratic=q, seed=3,
                              **kwargs).cloud.xyz[..., 2]
    # every depth is 1 / (q k) for a whole disparity k: 172 steps at 2 m (1 / (0.0029 * 2) = 172.4)
    k = 1.0 / (q * z)
    np.testing.assert_allclose(k, np.round(k), atol=1e-9)
    assert 169 <= np.round(k).min() and np.round(k).max() <= 176  # the noise (5.7 mm) spans a few steps
    values = np.unique(np.round(z, 9))
    gaps = np.diff(values)
    np.testing.assert_allclose(gaps / (q * (values[1:] * values[:-1])), 1.0, rtol=1e-6)  # 1/(qk) - 1/(q(k+1))
    assert 0.0110 < gaps.min() and gaps.max() < 0.0126  # ~ q z^2 = 11.6 mm at 2 m
    np.testing.assert_array_less(np.abs(z - plain), 0.5 * q * plain**2 * 1.02)  # rounding within half a step
    assert np.array_equal(simulate_depth_camera(_wall_scene(), noise_coeff=0.001425, step_quadratic=0.0,
                                                seed=3, **kwargs).cloud.xyz[..., 2], plain)
    with pytest.raises(ValueError, match="step_quadratic must be a finite number >= 0"):
        simulate_depth_camera(_wall_scene(), step_quadratic=-1.0)


def _x_extent(surface) -> tuple[float, float]:
    if hasattr(surface, "axis") and hasattr(surface, "length"):  # a pipe or column side
        ends = np.array([surface.base, surface.base + surface.axis * surface.length])[:, 0]
        return float(ends.min() - surface.radius), float(ends.max() + surface.radius)
    centre = float(np.asarray(surface.center)[0])
    reach = float(getattr(surface, "radius", 0.0))
    return centre - reach, centre + reach


def test_a_room_too_shallow_for_an_object_skips_it_and_keeps_the_others_inside():
    # max_range 3 m leaves a 3 m deep room: a 1-2.5 m pipe's footprint (the widest
    # object) cannot be placed between the 1.3 m keep-clear and the far wall, which
    # used to raise from drawing in an empty interval.
    placed = []
    for seed in range(40):
        scene = random_room(np.random.default_rng(seed), around=False, max_range=3.0, n_objects=7)
        far_wall = float(scene.surfaces[3].center[0])
        assert far_wall == pytest.approx(3.0)
        objects = scene.surfaces[6:]
        for s in objects:
            low, high = _x_extent(s)
            assert low > 1.3 - 1e-9 and high < far_wall - 0.3 + 1e-9
        placed.append(len({s.id for s in objects}))
    assert max(placed) > 0  # boxes, columns and balls still find room


def test_kinect_real_row_draws_the_kinect_rows_scenes_with_the_real_cameras_noise():
    # same scenes and camera as kinect_640x480; the sensor facts state the correlation
    from rangeseg_o3d.synthetic.matrix import KINECT_CORRELATION_PX, KINECT_STEP
    plain, real = get_sensor("kinect_640x480"), get_sensor("kinect_real_640x480")
    assert (real.draws, plain.draws) == ("kinect_640x480", "kinect_640x480")
    facts = real.sensor_facts()
    assert (facts["noise_correlation_px"], facts["step_quadratic"]) == (9, 0.0029) == (KINECT_CORRELATION_PX, KINECT_STEP)
    assert (plain.sensor_facts()["noise_correlation_px"], plain.sensor_facts()["step_quadratic"]) == (1, 0.0)
    a = plain.simulate(matrix_rng(0, plain.draws, 0), True)
    b = real.simulate(matrix_rng(0, real.draws, 0), True)
    np.testing.assert_array_equal(a.truth_ids, b.truth_ids)
    depth = b.cloud.xyz[..., 2]
    ok = depth > 0
    # every depth is a whole disparity step: 1 / (q z) is an integer
    steps = 1.0 / (KINECT_STEP * depth[ok])
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-6)


def test_kinect_real_noise_matches_the_real_frames_statistics():
    # residuals of a plane at 1.6 and 4 m seen by the row's camera: neighbouring pixels err
    # together as measured on the PCL / PEAC / CAPE frames (row correlation 0.74-0.91 at 1 px,
    # 0.52-0.79 at 3 px, 0.28-0.66 at 6 px; office1 0.74 / 0.52 / 0.28), and a 6x6 tile mean
    # keeps 0.68-0.84 of a pixel's rms (independent errors: 1/6); the pixel rms is the model's
    # 1.425e-3 z^2 with the steps' (2.9e-3 z^2 / sqrt(12)) in quadrature
    from rangeseg_o3d.synthetic.depth_camera import KINECT_NOISE, simulate_depth_camera
    from rangeseg_o3d.synthetic.matrix import KINECT_CORRELATION_PX, KINECT_STEP
    from rangeseg_o3d.synthetic.scene import patch
    h, w = 240, 324
    for z in (1.6, 4.0):
        # a wall facing the camera at depth z, a little turned so that the steps dither
        wall = Scene(patch((0.0, 0.0, z), (1.0, 0.0, 0.01), (0.0, 1.0, 0.0), 10.0, 10.0, first_id=1))
        scan = simulate_depth_camera(wall, width=w, height=h, fx=266.0, fy=266.0, cx=(w - 1) / 2, cy=(h - 1) / 2,
                                     noise_correlation=KINECT_CORRELATION_PX, step_quadratic=KINECT_STEP, seed=5)
        depth = scan.cloud.xyz[..., 2]
        assert (depth > 0).all()
        cols = np.arange(w, dtype=float)
        slope = np.polyfit(np.tile(cols, h), depth.ravel(), 1)
        e = depth - np.polyval(slope, cols)[None, :]
        e = e - e.mean()
        acf = [float(np.mean(e[:, :-lag] * e[:, lag:]) / np.var(e)) for lag in (1, 3, 6)]
        assert 0.68 < acf[0] < 0.78 and 0.45 < acf[1] < 0.58 and 0.2 < acf[2] < 0.32, acf
        tiles = e.reshape(h // 6, 6, w // 6, 6).mean(axis=(1, 3))
        assert 0.62 < tiles.std() / e.std() < 0.76, tiles.std() / e.std()
        expected = np.hypot(KINECT_NOISE, KINECT_STEP / np.sqrt(12)) * z * z
        assert abs(e.std() / expected - 1) < 0.12, e.std() / expected
