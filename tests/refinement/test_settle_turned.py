"""Borders settled again where polish changed a region's kind (refinement._settle_turned_by_polish)."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.fitting import fit_plane
from rangeseg_o3d.fitting.primitives import Plane
from rangeseg_o3d.refinement import _settle_turned_by_polish
from rangeseg_o3d.refinement.context import Context
from rangeseg_o3d.synthetic.depth_camera import simulate_depth_camera
from rangeseg_o3d.synthetic.scene import Scene, cylinder

NOISE = 0.015  # the spinning_lidar preset's range noise
PIPE, CAP = 1, 3  # cylinder() ids: the side, the far end's cap (facing the camera here)
RADIUS = 0.15


def _pipe_holding_the_caps_rim(seed: int):
    """A capped pipe (radius 15 cm) pointing at a camera 2.6-3.2 m away, labelled by its truth
    but for the cap's rim (the outer quarter of its radius), which the pipe's region holds:
    ``(context, labels, fits, rim, settle keywords)``, the pipe's model its true cylinder."""
    axis = np.array([0.5, 0.0, -1.0]) / np.hypot(0.5, 1.0)
    scene = Scene([cylinder((-0.4, 0.0, 3.2), axis, RADIUS, 1.2, caps=True, first_id=1)])
    scan = simulate_depth_camera(scene, width=160, height=120, fx=150.0, fy=150.0, cx=79.5, cy=59.5,
                                 noise_coeff=0.0, noise_sigma0=NOISE, seed=seed)
    cloud, truth = scan.cloud, scan.truth_ids
    pipe = scan.truth[PIPE]
    off_axis = pipe.distances(cloud.xyz.reshape(-1, 3)).reshape(truth.shape) + RADIUS  # distance to the axis
    rim = (truth == CAP) & (off_axis > 0.75 * RADIUS)
    labels = np.where(truth == CAP, 2, np.where(truth == PIPE, 1, 0)).astype(np.int32)
    labels[rim] = 1
    fits = {1: pipe, 2: fit_plane(cloud.xyz[labels == 2])}
    sigma = np.where(cloud.valid, NOISE, np.nan)
    ctx = Context(cloud, rs.Pipeline("spinning_lidar").fitter, sigma, 10)
    ranges = np.where(cloud.valid, np.linalg.norm(cloud.xyz, axis=2), np.nan)
    settle = dict(xyz=cloud.xyz, ranges=ranges, sigma=sigma, iterations=3, k_sigma=3.0, jump_ratio=0.1,
                  jump_min=0.05, wrap_columns=False)
    return ctx, labels, fits, rim, settle


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_pipe_turned_a_cylinder_by_polish_gives_the_caps_rim_back(seed):
    ctx, labels, fits, rim, settle = _pipe_holding_the_caps_rim(seed)
    assert rim.sum() > 20  # the premise: a rim of the cap in the pipe's region
    before = {1: fit_plane(ctx.xyz[labels.ravel() == 1]), 2: fits[2]}  # the pipe was a plane until polish
    out, _ = _settle_turned_by_polish(ctx, labels, fits, before, **settle)
    # the rim's pixels more than one noise sigma off the cylinder go back to the cap (81-100 %
    # on these seeds); nearer, the cylinder explains them as well and half of them stay
    off = np.abs(fits[1].distances(ctx.xyz.reshape(-1, 3))).reshape(labels.shape) > NOISE
    assert (out[rim & off] == 2).mean() > 0.8
    assert (out[rim] == 2).mean() > 0.6
    assert (out[labels == 2] == 2).all()  # the cap keeps its own pixels


def test_no_kind_changed_by_polish_leaves_the_borders_as_they_were():
    ctx, labels, fits, rim, settle = _pipe_holding_the_caps_rim(0)
    out, kept = _settle_turned_by_polish(ctx, labels, fits, dict(fits), **settle)
    assert out is labels and kept is fits


def test_a_spinning_lidars_cap_comes_back_from_the_pipe_polish_made_a_cylinder():
    # spinning_64x1024 study seed 1389 scan 0: a pipe of r 0.16 m settled as a plane over the
    # rim of its cap (31 of the cap's 133 px), made a cylinder by polish
    from matrix_helpers import matrix_result, region_holding

    scan, result = matrix_result("spinning_64x1024", 1389, 0)
    cap = scan.truth_ids == 30
    label, count = region_holding(result.labels, cap)
    assert count >= 0.9 * cap.sum()  # (before: 77 %)
    assert isinstance({f.label: f for f in result.features}[label].model, Plane)
    pipe_label, _ = region_holding(result.labels, scan.truth_ids == 29)
    assert {f.label: f for f in result.features}[pipe_label].kind == "cylinder"
