"""The polish step on its own: spheres and cylinders refitted on their final pixels, and
given up for a plane where they no longer resolve a curvature."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.fitting import fit_cylinder, fit_plane, fit_sphere
from rangeseg_o3d.refinement.polish import polish_models
from refinement_helpers import folded_strip


def _ball_beside_a_wall():
    # the near cap of a ball of radius 0.5 m centred 3 m away (label 1) beside a wall (label 2)
    v, u = np.mgrid[0:30, 0:40].astype(float)
    x, y = (u - 15) * 0.02, (v - 15) * 0.02
    rng = np.random.default_rng(6)
    z = np.where(u < 30, 3.0 - np.sqrt(np.clip(0.25 - x ** 2 - y ** 2, 0, None)), 3.0)
    xyz = np.dstack([x, y, z + rng.normal(0.0, 0.001, z.shape)])
    labels = np.where(u < 30, 1, 2).astype(np.int32)
    return xyz, labels


def test_a_sphere_fitted_on_part_of_its_region_is_refitted_on_all_of_it(context):
    xyz, labels = _ball_beside_a_wall()
    part = fit_sphere(xyz[:10, :10].reshape(-1, 3))  # a corner of the cap: 100 of 900 pixels
    wall = fit_plane(xyz[labels == 2])
    fits = {1: part, 2: wall}
    polished = polish_models(context(rs.OrganizedCloud(xyz)), labels, fits)
    assert fits[1] is part  # the input is left alone
    assert polished[2] is wall  # planes are not polished
    assert polished[1].kind == "sphere" and polished[1].inliers == (labels == 1).sum()
    # all 900 pixels pin the ball down better than a corner of it (noise 1 mm)
    assert abs(polished[1].radius - 0.5) < 0.5 * abs(part.radius - 0.5)
    assert np.linalg.norm(polished[1].center - [0, 0, 3]) < 0.5 * np.linalg.norm(part.center - [0, 0, 3])


def test_a_sphere_that_kept_its_points_is_not_refitted(context):
    xyz, labels = _ball_beside_a_wall()
    whole = fit_sphere(xyz[labels == 1])
    polished = polish_models(context(rs.OrganizedCloud(xyz)), labels, {1: whole})
    assert polished[1] is whole


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_cylinder_bent_over_a_crease_is_a_plane_on_the_flat_face_it_kept(context, seed):
    # a cylinder fitted over a flat face and three columns of the 45-degree face beside it
    # (5 mm noise, the lms200 sensor's); the region keeps only the flat face
    xyz, truth, normals = folded_strip(0.005, seed)
    columns = np.mgrid[0:60, 0:90][1]
    bent = fit_cylinder(xyz[(truth == 1) | ((truth == 2) & (columns < 33))])
    assert bent.kind == "cylinder" and bent.radius < 5.0  # the premise: a bend, not a plane
    labels = np.where(truth == 1, 1, 0).astype(np.int32)
    polished = polish_models(context(rs.OrganizedCloud(xyz)), labels, {1: bent})
    assert polished[1].kind == "plane"
    assert abs(float(polished[1].normal @ normals[1])) > np.cos(np.radians(0.5))


def _pipe_before_a_wall(seed: int):
    # a vertical pipe of radius 0.15 m whose front is 3.35 m away (label 1) before a wall at
    # 3.7 m (label 2), seen along z; 5 mm range noise, the lms200 sensor's
    v, u = np.mgrid[0:40, 0:60].astype(float)
    x, y = (u - 30) * 0.01, (v - 20) * 0.02
    on_pipe = np.abs(x) < 0.14
    z = np.where(on_pipe, 3.5 - np.sqrt(np.clip(0.15 ** 2 - x ** 2, 0, None)), 3.7)
    z = z + np.random.default_rng(seed).normal(0.0, 0.005, z.shape)
    return np.dstack([x, y, z]), np.where(on_pipe, 1, 2).astype(np.int32), np.abs(x) < 0.04


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_plane_decided_on_a_flat_piece_of_a_pipe_is_decided_again_on_the_whole_pipe(context, seed):
    xyz, labels, middle = _pipe_before_a_wall(seed)
    ctx = context(rs.OrganizedCloud(xyz))
    # the premise: the fitter decides the pipe's middle third (a split's piece) is a plane
    piece = ctx.fitter.fit(xyz[middle & (labels == 1)])
    assert piece.kind == "plane"
    wall = fit_plane(xyz[labels == 2])
    polished = polish_models(ctx, labels, {1: piece, 2: wall})
    assert polished[2] is wall  # a plane its pixels still settle as one is left alone
    assert polished[1].kind == "cylinder"
    assert abs(polished[1].radius - 0.15) < 0.1 * 0.15
    assert abs(abs(polished[1].axis[1]) - 1.0) < 1e-3


def test_a_plane_whose_pixels_stay_flat_is_not_decided_again(context):
    xyz, labels, _ = _pipe_before_a_wall(0)
    wall = fit_plane(xyz[labels == 2])
    polished = polish_models(context(rs.OrganizedCloud(xyz)), np.where(labels == 2, 2, 0).astype(np.int32),
                             {2: wall})
    assert polished[2] is wall


def _wall_strip_with_a_neighbours_pixels(seed: int):
    # a 12 x 30 wall strip 3 m away (5 mm noise, the lms200 sensor's) whose last column holds,
    # on ten rows, pixels of a face 2-3 cm behind it (one region, label 1)
    v, u = np.mgrid[0:30, 0:12].astype(float)
    rng = np.random.default_rng(seed)
    z = 3.0 + rng.normal(0.0, 0.005, u.shape)
    z[8:18, 11] += rng.uniform(0.02, 0.03, 10)
    return np.dstack([(u - 6) * 0.02, (v - 15) * 0.02, z])


@pytest.mark.parametrize("seed", [2, 8, 28])
def test_a_cylinder_only_a_neighbours_pixels_bend_is_a_plane_where_bends_are_resolved(context, seed):
    xyz = _wall_strip_with_a_neighbours_pixels(seed)
    bent = fit_cylinder(xyz.reshape(-1, 3))
    assert bent.kind == "cylinder" and bent  # the premise: the ten pixels bend a cylinder (1-1.5 m)
    labels = np.ones(xyz.shape[:2], np.int32)
    ctx = context(rs.OrganizedCloud(xyz))
    # its curvature is resolved over the strip's plane (the F-test on all pixels): kept as it is
    assert polish_models(ctx, labels, {1: bent})[1].kind == "cylinder"
    # without the pixels beyond 2 plane rms no bend is left: the plane of the strip's
    # pixels (the ten tilt it by a degree or so)
    polished = polish_models(ctx, labels, {1: bent}, resolve_bends=True)[1]
    assert polished.kind == "plane" and abs(polished.normal[2]) > np.cos(np.radians(2.0))
