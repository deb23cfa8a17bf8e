"""polish.bent_at_border_lines on a curved region whose plane is within the fitter's plane
threshold (the regions :func:`_unbent` answers, and keeps curved where the bend is resolved):
one border line of returns off the rest's plane bends a face into a shallow cylinder, or onto the
far half of one its own front hides (:func:`behind_own_front`), and the region is the rest's
plane; a pipe facing the sensor, whose arc is about half a turn and whose returns lie on its near
half, is left curved."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.config import load_config
from rangeseg_o3d.fitting import fit_cylinder, fit_plane
from rangeseg_o3d.fitting.classify import plane_threshold
from rangeseg_o3d.fitting.primitives import Cylinder, Plane, Sphere
from rangeseg_o3d.refinement import polish
from rangeseg_o3d.refinement.context import Context
from rangeseg_o3d.refinement.polish import behind_own_front, bent_at_border_lines, polish_models


def _rays(step: float = 1.0) -> np.ndarray:
    """(40, 40, 3) unit rays from the origin ``step`` degrees apart, the grid's middle on the z axis."""
    focal = 1.0 / np.tan(np.radians(step))
    v, u = np.mgrid[0:40, 0:40].astype(float)
    rays = np.dstack([(u - 19.5) / focal, (v - 19.5) / focal, np.ones((40, 40))])
    return rays / np.linalg.norm(rays, axis=2, keepdims=True)


def _context(xyz: np.ndarray, sigma: float) -> Context:
    fitter = rs.Pipeline(load_config("lms200", overrides={"sensor.sigma0": sigma})).fitter
    return Context(rs.OrganizedCloud(xyz), fitter, np.full(xyz.shape[:2], sigma), 10)


def _within_threshold(ctx: Context, idx: np.ndarray) -> bool:
    p = ctx.fitter.params
    points = ctx.xyz[idx]
    return fit_plane(points).rms <= plane_threshold(idx.size, points.mean(axis=0), plane_rms=p["plane_rms"],
                                                    noise_floor=p["noise_floor"], rms_per_range2=p["rms_per_range2"])


def _face_with_a_row_behind(seed: int, sigma: float = 0.005):
    """A face facing the sensor 4.4 m away (rows 12-19, columns 16-23) before a wall at 7 m, and
    the row above it (row 11, the same columns) of mixed returns 5-8 range sigmas behind the
    face along their rays (a jump edge across the beam), which the region took (label 1):
    ``(context, labels)`` (nodding_0.5deg seed 37 scan 5: such a row bent a 0.29 m cylinder)."""
    rng = np.random.default_rng(seed)
    rays = _rays()
    ranges, labels = 7.0 / rays[..., 2], np.zeros((40, 40), np.int32)
    face = 4.4 / rays[..., 2]
    ranges[12:20, 16:24] = face[12:20, 16:24]
    ranges[11, 16:24] = face[11, 16:24] + rng.uniform(5.0, 8.0, 8) * sigma
    labels[11:20, 16:24] = 1
    xyz = rays * (ranges + rng.normal(0.0, sigma, ranges.shape))[..., None]
    return _context(xyz, sigma), labels


def _pipe_facing_the_sensor(seed: int, sigma: float = 0.02):
    """An upright pipe of radius 0.05 m whose axis is 3 m away (label 1, rows 10-30, eight
    columns of a grid 0.25 degrees apart) before a wall at 5 m, under 20 mm of range noise, its
    whole visible arc in the region (noise_20mm seed 0 scan 7: a 0.09 m pipe at 2.8 m whose plane
    is within the threshold): ``(context, labels)``."""
    rng = np.random.default_rng(seed)
    rays = _rays(0.25)
    ranges, labels = 5.0 / rays[..., 2], np.zeros((40, 40), np.int32)
    across, depth = rays[..., 0], rays[..., 2]
    a, b = across ** 2 + depth ** 2, -3.0 * depth
    disc = b * b - a * (3.0 ** 2 - 0.05 ** 2)
    on = np.zeros((40, 40), bool)
    on[10:31] = disc[10:31] > 0
    ranges[on] = ((-b - np.sqrt(np.maximum(disc, 0.0))) / a)[on]
    labels[on] = 1
    xyz = rays * (ranges + rng.normal(0.0, sigma, ranges.shape))[..., None]
    return _context(xyz, sigma), labels


def _cylinder(ctx, labels):
    return fit_cylinder(ctx.xyz[labels.ravel() == 1])


@pytest.mark.parametrize("seed", [0, 2, 3])
def test_a_face_bent_by_one_row_within_the_threshold_is_the_plane_of_the_rest(seed):
    ctx, labels = _face_with_a_row_behind(seed)
    idx = np.flatnonzero(labels.ravel())
    cylinder = _cylinder(ctx, labels)
    # the premises: the region's plane is within the threshold (so _unbent asks it), its bend is
    # resolved (so _unbent keeps it curved), the cylinder a shallow arc
    assert _within_threshold(ctx, idx)
    assert polish._unbent(ctx, labels, [1], 1.0) == {}
    assert isinstance(cylinder, Cylinder)
    assert polish.arc_around_axis(ctx.xyz[idx], cylinder.axis, cylinder.point) < polish.TWO_SIDES_ARC
    plane = bent_at_border_lines(ctx, labels, {1: cylinder}, 1.0)[1]
    assert isinstance(plane, Plane)
    assert abs(plane.normal[2]) > np.cos(np.radians(1.0))  # the face's, from its own rows
    assert abs(abs(plane.d) - 4.4) < 0.01  # 4.4 m away
    assert plane.inliers <= 64 and plane.rms < 1.2 * 0.005  # the 64 returns of the face, not the row
    assert polish_models(ctx, labels, {1: cylinder}, resolve_bends=1.0, along_rays=True)[1].kind == "plane"
    assert polish_models(ctx, labels, {1: cylinder}, resolve_bends=1.0)[1].kind != "plane"  # not a laser's


@pytest.mark.parametrize("seed", [2, 3])
def test_a_pipe_facing_the_sensor_within_the_threshold_stays_curved(seed, monkeypatch):
    ctx, labels = _pipe_facing_the_sensor(seed)
    idx = np.flatnonzero(labels.ravel())
    assert np.count_nonzero(labels[20]) == 8
    cylinder = _cylinder(ctx, labels)
    # the premises: the pipe's plane is within the threshold and _unbent keeps it curved
    assert _within_threshold(ctx, idx)
    assert polish._unbent(ctx, labels, [1], 1.0) == {}
    assert isinstance(cylinder, Cylinder) and abs(cylinder.radius - 0.05) < 0.02
    # its fit spans more than a quarter turn, and its returns lie on its near half
    assert polish.arc_around_axis(ctx.xyz[idx], cylinder.axis, cylinder.point) > polish.TWO_SIDES_ARC
    assert not behind_own_front(ctx, idx, ctx.xyz[idx], cylinder).any()
    assert bent_at_border_lines(ctx, labels, {1: cylinder}, 1.0) == {}
    # what keeps it: every other test passes one side of it, so were its arc shallow it would be freed
    monkeypatch.setattr(polish, "TWO_SIDES_ARC", 2.0 * np.pi + 1.0)
    assert isinstance(bent_at_border_lines(ctx, labels, {1: cylinder}, 1.0)[1], Plane)


def _one_row(points: np.ndarray, sigma: float) -> Context:
    """A context of one grid row holding ``points`` (rays from the origin), ``sigma`` of range noise each."""
    xyz = np.asarray(points, float)[None]
    fitter = rs.Pipeline(load_config("lms200")).fitter
    return Context(rs.OrganizedCloud(xyz), fitter, np.full(xyz.shape[:2], sigma), 10)


def test_behind_own_front_is_a_return_on_the_far_half_beyond_the_range_noise():
    cylinder = Cylinder(axis=np.array([0.0, 1.0, 0.0]), point=np.array([0.0, 0.0, 5.0]), radius=0.5, rms=0.0, inliers=0)
    sphere = Sphere(center=np.array([0.0, 0.0, 5.0]), radius=0.5, rms=0.0, inliers=0)
    # near half (4.5 m), far half (5.5 m: the ray met the front 1 m nearer), far half off the axis
    # (x = 0.3: the front at 4.58 m along the ray, the return at 5.41 m), a ray that misses (x = 2)
    points = np.array([[0.0, 0.0, 4.5], [0.0, 0.0, 5.5], [0.3, 0.0, 5.4], [2.0, 0.0, 5.0]])
    idx = np.arange(4)
    for model in (cylinder, sphere):
        ctx = _one_row(points, 0.01)
        assert behind_own_front(ctx, idx, points, model).tolist() == [False, True, True, False]
        # 0.83 m behind the front is within 4 range sigmas of 0.22 m (0.88 m), 1 m is not
        ctx = _one_row(points, 0.22)
        assert behind_own_front(ctx, idx, points, model).tolist() == [False, True, False, False]
    # from inside the model (a tunnel, a room-sized sphere) no ray meets a front
    inside = Sphere(center=np.zeros(3), radius=10.0, rms=0.0, inliers=0)
    assert not behind_own_front(_one_row(points, 0.01), idx, points, inside).any()


def test_behind_own_front_refuses_bad_input():
    points = np.array([[0.0, 0.0, 4.5], [0.0, 0.0, 5.5]])
    ctx = _one_row(points, 0.01)
    sphere = Sphere(center=np.array([0.0, 0.0, 5.0]), radius=0.5, rms=0.0, inliers=0)
    with pytest.raises(ValueError, match=r"points must be \(len\(idx\), 3\) = \(2, 3\)"):
        behind_own_front(ctx, np.arange(2), points[:1], sphere)
    with pytest.raises(ValueError, match="model must be a Cylinder or a Sphere; got Plane"):
        behind_own_front(ctx, np.arange(2), points, Plane(normal=np.array([0.0, 0.0, 1.0]), d=5.0, rms=0.0, inliers=0))
