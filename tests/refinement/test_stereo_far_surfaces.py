"""Far surfaces within a noisy sensor's range noise of their neighbours: a pipe's end cap
stays its own surface (merge_into_curved, dissolve_small), a pipe's cylinder pulled over
the wall beside it is refitted when the wall takes its pixels back (facets._nearest), and
two pieces of one pipe seen apart are merge candidates though their axes differ by
several degrees (merge.similar_models)."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.fitting import fit_cylinder, fit_plane
from rangeseg_o3d.fitting.primitives import Cylinder
from rangeseg_o3d.fitting.robust import beyond_noise
from rangeseg_o3d.refinement.context import Context
from rangeseg_o3d.refinement.dissolve import dissolve_small
from rangeseg_o3d.refinement.facets import _nearest
from rangeseg_o3d.refinement.merge import merge_into_curved, similar_models
from rangeseg_o3d.synthetic.depth_camera import simulate_depth_camera
from rangeseg_o3d.synthetic.scene import Scene, cylinder, patch

NOISE = 0.04  # range noise over a quarter of the pipe's radius: the cap lies within it of the cylinder
PIPE, CAP = 1, 3  # cylinder() ids: the side, the far end's cap (facing the camera here)


def _fitter():
    return rs.Pipeline("spinning_lidar").fitter


def _pipe_and_cap(seed: int, min_size: int = 10):
    """A capped pipe (radius 15 cm, 1.2 m) pointing at a camera 2.6-3.2 m away with 4 cm
    noise, its side (label 1) and far cap (label 2) each fitted on its own:
    ``(context, labels, fits)``."""
    axis = np.array([0.5, 0.0, -1.0]) / np.hypot(0.5, 1.0)
    scene = Scene([cylinder((-0.4, 0.0, 3.2), axis, 0.15, 1.2, caps=True, first_id=1)])
    scan = simulate_depth_camera(scene, width=160, height=120, fx=150.0, fy=150.0, cx=79.5, cy=59.5,
                                 noise_coeff=0.0, noise_sigma0=NOISE, seed=seed)
    labels = np.where(scan.truth_ids == PIPE, 1, np.where(scan.truth_ids == CAP, 2, 0)).astype(np.int32)
    ctx = Context(scan.cloud, _fitter(), np.full(labels.shape, NOISE), min_size)
    fits = {1: fit_cylinder(ctx.xyz[labels.ravel() == 1]), 2: fit_plane(ctx.xyz[labels.ravel() == 2])}
    assert fits[1].kind == "cylinder" and abs(fits[1].radius - 0.15) < 0.01
    return ctx, labels, fits


@pytest.mark.parametrize("seed", [0, 1, 3])
def test_an_end_cap_within_the_range_noise_of_its_pipe_stays_apart(seed):
    ctx, labels, fits = _pipe_and_cap(seed)
    # the premise: the pipe's cylinder refitted to both passes the other tests (rms within
    # 1.3 x the parts', at the range noise): only the cap's own plane tells them apart
    idx = np.flatnonzero(labels.ravel())
    union = ctx.fitter.refit(ctx.fitter.points(ctx.xyz, idx), fits[1])
    assert union.kind == "cylinder" and union.rms <= 1.3 * max(fits[1].rms, fits[2].rms)
    assert not beyond_noise(union.rms, NOISE, idx.size)
    out, out_fits, adjacency = merge_into_curved(ctx, labels, fits, {(1, 2)}, rms_factor=1.3)
    assert (out == labels).all() and set(out_fits) == {1, 2} and adjacency == {(1, 2)}


@pytest.mark.parametrize("seed", [0, 1, 3])
def test_a_small_end_cap_is_not_dissolved_into_its_pipe(seed):
    ctx, labels, fits = _pipe_and_cap(seed, min_size=110)  # the cap (308 pixels) is small
    assert (labels == 2).sum() < 3 * ctx.min_size
    out, out_fits = dissolve_small(ctx, labels, fits, {(1, 2)}, k_sigma=3.0)
    assert (out == labels).all() and set(out_fits) == {1, 2}


def test_a_small_blob_of_a_pipe_still_dissolves_into_it():
    # the failure path: a piece of the pipe's own side fitted as a plane goes back to it
    ctx, labels, fits = _pipe_and_cap(0, min_size=110)
    side = np.flatnonzero(labels.ravel() == 1)
    rows = side // labels.shape[1]
    piece = side[np.abs(rows - int(np.median(rows))) <= 3]  # a band across the middle of the pipe
    flat = labels.copy().ravel()
    flat[np.flatnonzero(labels.ravel() == 2)] = 0
    flat[piece] = 2
    labels = flat.reshape(labels.shape)
    fits = {1: fit_cylinder(ctx.xyz[labels.ravel() == 1]), 2: fit_plane(ctx.xyz[piece])}
    out, out_fits = dissolve_small(ctx, labels, fits, {(1, 2)}, k_sigma=3.0)
    assert set(out_fits) == {1} and (out.ravel()[piece] == 1).mean() > 0.9


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_cylinder_pulled_over_the_wall_is_refitted_when_the_wall_takes_its_pixels(seed):
    # a pipe of radius 20 cm standing before a wall 3 m away; the split's first surface took
    # a wall strip 8 pixels wide beside it, which pulls its cylinder to a 31 cm radius
    scene = Scene(patch((0.0, 0.0, 3.0), (1, 0, 0), (0, 1, 0), 1.5, 1.5, first_id=1)
                  + cylinder((0.0, -0.6, 2.75), (0, 1, 0), 0.2, 1.2, caps=False, first_id=2))
    scan = simulate_depth_camera(scene, width=160, height=120, fx=150.0, fy=150.0, cx=79.5, cy=59.5,
                                 noise_coeff=0.0, noise_sigma0=0.01, seed=seed)
    truth = scan.truth_ids
    ctx = Context(scan.cloud, _fitter(), np.full(truth.shape, 0.01), 10)
    cols = np.arange(truth.shape[1])[None, :]
    edge = int(np.nonzero(np.any(truth == 2, axis=0))[0].max())
    rows = np.any(truth == 2, axis=1)[:, None]
    band = rows & (truth == 1) & (cols > edge) & (cols <= edge + 8)
    rest = rows & (truth == 1) & (cols > edge + 8) & (cols <= edge + 30)
    first, second = np.flatnonzero(((truth == 2) | band).ravel()), np.flatnonzero(rest.ravel())
    pulled = fit_cylinder(ctx.xyz[first])
    assert pulled.kind == "cylinder" and pulled.radius > 0.28  # the premise
    out = _nearest(ctx, [(first, pulled), (second, fit_plane(ctx.xyz[second]))])
    assert [m.kind for _, m in out] == ["cylinder", "plane"]
    (pipe, model), (wall, _) = out
    assert np.array_equal(pipe, np.flatnonzero((truth == 2).ravel()))  # the pipe, and only it
    assert np.array_equal(wall, np.sort(np.concatenate([np.flatnonzero(band.ravel()), second])))
    assert abs(model.radius - 0.2) < 0.01 and model.rms < 0.5 * pulled.rms


def test_pieces_of_one_pipe_with_axes_apart_by_degrees_are_merge_candidates():
    axis = np.array([0.0, 1.0, 0.0])
    tilted = np.array([np.sin(np.radians(5.5)), np.cos(np.radians(5.5)), 0.0])
    lower = Cylinder(axis=axis, point=[2.0, -1.0, 3.5], radius=0.17, rms=0.02, inliers=100)
    # 1.2 m along the pipe, its axis passes 5 cm from the lower piece's axis there
    upper = Cylinder(axis=tilted, point=[2.05, 0.2, 3.5], radius=0.175, rms=0.02, inliers=100)
    assert similar_models(lower, upper, max_angle_deg=3.0, tolerance=0.15)
    # the failure paths: another radius, or a parallel pipe 30 cm aside
    assert not similar_models(lower, Cylinder(axis=axis, point=[2.0, 0.2, 3.5], radius=0.4, rms=0.02,
                                              inliers=100), max_angle_deg=3.0, tolerance=0.15)
    assert not similar_models(lower, Cylinder(axis=axis, point=[2.3, 0.2, 3.5], radius=0.17, rms=0.02,
                                              inliers=100), max_angle_deg=3.0, tolerance=0.15)
