"""A full-resolution cylinder region's end cap split off (end_caps), and only where it closes the pipe."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.end_caps import closes_the_pipe, split_end_caps
from rangeseg_o3d.fitting import fit_cylinder, fit_plane
from rangeseg_o3d.fullres import region_stats
from rangeseg_o3d.result import INLIER_SIGMAS
from rangeseg_o3d.synthetic.depth_camera import simulate_depth_camera
from rangeseg_o3d.synthetic.scene import Scene, cylinder

NOISE = 0.015  # the spinning_lidar preset's range noise; its fitter's bounds suit it
PIPE, CAP = 1, 3  # cylinder() ids: the side, the far end's cap (facing the camera here)
RADIUS = 0.15


def _capped_pipe(seed: int, caps: bool = True):
    """A pipe (radius 15 cm, 1.2 m) pointing at a camera 2.6-3.2 m away, its far end's cap
    facing the camera, seen whole in one region under the cylinder fitted to all of it:
    ``(cloud, labels, model, truth, sigma)``."""
    axis = np.array([0.5, 0.0, -1.0]) / np.hypot(0.5, 1.0)
    scene = Scene([cylinder((-0.4, 0.0, 3.2), axis, RADIUS, 1.2, caps=caps, first_id=1)])
    scan = simulate_depth_camera(scene, width=160, height=120, fx=150.0, fy=150.0, cx=79.5, cy=59.5,
                                 noise_coeff=0.0, noise_sigma0=NOISE, seed=seed)
    labels = (scan.truth_ids > 0).astype(np.int32)
    model = fit_cylinder(scan.cloud.xyz[labels == 1])
    return scan.cloud, labels, model, scan.truth_ids, np.full(labels.shape, NOISE)


def _split(cloud, labels, model, sigma, min_size=10):
    fits = {1: model}
    stats = region_stats(cloud.xyz, labels, fits, sigma, INLIER_SIGMAS)
    return split_end_caps(cloud, labels, fits, stats, sigma=sigma, fitter=rs.Pipeline("spinning_lidar").fitter,
                          min_size=min_size, inlier_factor=INLIER_SIGMAS)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_pipe_region_gives_its_end_cap_a_plane_region_of_its_own(seed):
    cloud, labels, model, truth, sigma = _capped_pipe(seed)
    # the premise: the cylinder fitted over pipe and cap is pulled inwards (11.4 cm for 15)
    assert model.kind == "cylinder" and model.radius < RADIUS - 0.02
    out, fits, stats = _split(cloud, labels, model, sigma)
    assert sorted(m.kind for m in fits.values()) == ["cylinder", "plane"]
    cap = next(k for k, m in fits.items() if m.kind == "plane")
    on_cap = out == cap
    # most of the cap, and little else (a few of the pipe's pixels at the rim, which both explain)
    assert (truth[on_cap] == CAP).mean() > 0.95 and on_cap.sum() > 0.8 * (truth == CAP).sum()
    assert abs(float(fits[cap].normal @ model.axis)) > np.cos(np.radians(5.0))
    assert abs(fits[1].radius - RADIUS) < 0.5 * abs(model.radius - RADIUS)  # the pipe refitted to the rest
    assert np.array_equal(out > 0, labels > 0)  # no pixel lost
    # the statistics are those of the new labels under the new models
    fresh = region_stats(cloud.xyz, out, fits, sigma, INLIER_SIGMAS)
    assert np.array_equal(stats.counts[:fresh.counts.size], fresh.counts)
    assert np.allclose(stats.squares[:fresh.squares.size], fresh.squares, rtol=1e-9)


def test_a_pipe_without_a_cap_keeps_its_region():
    cloud, labels, model, truth, sigma = _capped_pipe(0, caps=False)
    out, fits, stats = _split(cloud, labels, model, sigma)
    assert out is labels and fits == {1: model}


def test_a_cap_under_the_size_floor_stays_with_the_pipe():
    cloud, labels, model, truth, sigma = _capped_pipe(0)
    out, fits, _ = _split(cloud, labels, model, sigma, min_size=int((truth == CAP).sum()) + 1)
    assert out is labels and list(fits) == [1]


def _pipe_points(seed: int = 0):
    # pixels of a capless pipe along z (radius RADIUS, z 3-4 m), seen from the origin: (points, model)
    rng = np.random.default_rng(seed)
    z = rng.uniform(3.0, 4.0, 2000)
    angle = rng.uniform(np.pi, 2 * np.pi, z.size)  # the half facing the sensor (below y = 0.5)
    side = np.stack([0.4 + RADIUS * np.cos(angle), 0.5 + RADIUS * np.sin(angle), z], axis=1)
    model = fit_cylinder(side)
    assert abs(model.radius - RADIUS) < 1e-6
    return side, model


def _disc(z: float, n: int = 300, seed: int = 1):
    rng = np.random.default_rng(seed)
    rho, angle = RADIUS * np.sqrt(rng.uniform(0.0, 1.0, n)), rng.uniform(0.0, 2 * np.pi, n)
    return np.stack([0.4 + rho * np.cos(angle), 0.5 + rho * np.sin(angle), np.full(n, z)], axis=1)


def _closes(side, model, cap_points):
    xyz = np.concatenate([side, cap_points])
    pipe, cap = np.arange(side.shape[0]), np.arange(side.shape[0], xyz.shape[0])
    sigma = np.full(xyz.shape[0], 0.005)
    return closes_the_pipe(xyz, sigma, pipe, cap, model, fit_plane(cap_points))


def test_a_disc_at_the_pipe_end_facing_the_sensor_closes_it():
    side, model = _pipe_points()
    assert _closes(side, model, _disc(3.0))
    # the far end's disc faces away: the sensor (at the origin) would see its inner face
    assert not _closes(side, model, _disc(4.0))


def test_a_disc_across_the_middle_of_the_pipe_does_not_close_it():
    # (a quantising camera's depth step across a pipe seen along its axis: one axial coordinate)
    side, model = _pipe_points()
    assert not _closes(side, model, _disc(3.5))


def test_a_plane_along_the_axis_is_no_cap():
    side, model = _pipe_points()
    rng = np.random.default_rng(2)
    strip = np.stack([rng.uniform(0.3, 0.5, 300), np.full(300, 0.5 - RADIUS), rng.uniform(2.9, 3.0, 300)], axis=1)
    assert not _closes(side, model, strip)


def test_a_disc_beside_the_pipe_is_no_cap():
    side, model = _pipe_points()
    assert not _closes(side, model, _disc(3.0) + [2.5 * RADIUS, 0.0, 0.0])


def test_a_tunnel_around_the_sensor_is_not_searched_for_a_cap():
    # a closed tunnel (radius 1 m) around the camera, its end wall 3 m ahead: the cap split
    # finds the wall, but a wall closing a tunnel is the tile grid's plane, not a pipe's cap
    from rangeseg_o3d.refinement.context import Context
    from rangeseg_o3d.refinement.facets import cap_split

    scene = Scene([cylinder((0.0, 0.0, -0.5), (0.0, 0.0, 1.0), 1.0, 3.5, caps=True, first_id=1)])
    scan = simulate_depth_camera(scene, width=80, height=60, fx=40.0, fy=40.0, cx=39.5, cy=29.5,
                                 noise_coeff=0.0, noise_sigma0=NOISE, seed=0)
    labels = (scan.truth_ids > 0).astype(np.int32)
    model = fit_cylinder(scan.cloud.xyz[labels == 1])
    sigma = np.full(labels.shape, NOISE)
    assert model.kind == "cylinder"
    ctx = Context(scan.cloud, rs.Pipeline("spinning_lidar").fitter, sigma, 10)
    idx = np.flatnonzero(labels.ravel())
    split = cap_split(ctx, model, idx, None, closes=lambda *_: True)  # (the end screen, no closure test)
    assert len(split) == 2 and (scan.truth_ids.ravel()[split[1][0]] == CAP).mean() > 0.9  # the premise
    out, fits, _ = _split(scan.cloud, labels, model, sigma)
    assert out is labels and list(fits) == [1]


def test_a_pipe_seen_broadside_is_not_searched_for_a_cap():
    # a pipe across the view, its span along the axis holding the sensor's coordinate: a cap at
    # either end is seen from inside the pipe's end, and the split is not run
    from rangeseg_o3d.end_caps import _beyond_the_sensor_both_ways
    from rangeseg_o3d.fitting.primitives import Cylinder

    y = np.linspace(-1.0, 1.0, 200)
    points = np.stack([np.zeros_like(y), y, np.full_like(y, 3.0)], axis=1)
    pipe = Cylinder(axis=np.array([0.0, 1.0, 0.0]), point=np.array([0.0, 0.0, 3.15]), radius=RADIUS, rms=0.0,
                    inliers=200)
    sigma = np.full(200, 0.01)
    assert _beyond_the_sensor_both_ways(points, sigma, np.arange(200), pipe)
    assert not _beyond_the_sensor_both_ways(points, sigma, np.arange(100, 200), pipe)  # one side only
