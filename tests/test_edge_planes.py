"""Plane regions beside a curved region, or cut by the frame's edge, settled by the range
noise of a Kinect-type camera (rangeseg_o3d.edge_planes)."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.edge_planes import edge_planes_to_curved
from rangeseg_o3d.fullres import region_stats
from rangeseg_o3d.result import INLIER_SIGMAS


def _pipe_before_a_wall(seed):
    # A pipe (radius 0.2 m, upright) 3.5 m from a Kinect-type camera before a wall 4.5 m away,
    # the pipe's right edge cut by the frame's right edge (the pipe's axis 12 columns inside
    # it). Region 2 is the pipe's cylinder (fitted to its pixels) but for a strip of its left
    # flank in the upper half, region 3, under that strip's own plane; region 1 is the wall,
    # region 4 the wall's band beside the pipe's flank in the lower half (touching region 2),
    # under its own plane.
    from rangeseg_o3d.fitting import fit_cylinder
    from rangeseg_o3d.synthetic.depth_camera import camera_pose_scene, simulate_depth_camera
    from rangeseg_o3d.synthetic.scene import Scene, cylinder, patch

    world = Scene(patch((4.5, 0.0, 0.0), (0, 1, 0), (0, 0, 1), 3.0, 1.0, first_id=1)
                  + cylinder((3.5, -0.0, -0.6), (0, 0, 1), 0.2, 1.2, caps=False, first_id=2))
    # the pipe's axis at y = 0 projects onto column cx: the frame ends 12 columns right of it
    scan = simulate_depth_camera(camera_pose_scene(world), width=140, height=60, cx=127.5, cy=29.5, seed=seed)
    pipeline = rs.Pipeline("rgbd_vga")
    cloud, truth = scan.cloud, scan.truth_ids
    cols = np.arange(truth.shape[1])[None, :]
    pipe_cols = np.flatnonzero((truth == 2).any(axis=0))
    left = pipe_cols.min()
    labels = np.where(truth == 1, 1, np.where(truth == 2, 2, 0)).astype(np.int32)
    rows = np.arange(truth.shape[0])[:, None]
    labels[(truth == 2) & (cols < left + 5) & (rows < 30)] = 3
    labels[(truth == 1) & (cols >= left - 6) & (cols < left) & (rows >= 30)] = 4
    fits = {2: fit_cylinder(cloud.xyz[labels == 2])}
    for k in (1, 3, 4):
        fits[k] = rs.fitting.fit_plane(cloud.xyz[labels == k])
    ranges = np.where(cloud.valid, cloud.range_image(), np.nan)
    sigma = pipeline.sensor.noise.sigma(ranges)
    stats = region_stats(cloud.xyz, labels, fits, sigma, INLIER_SIGMAS)
    return scan, pipeline, labels, fits, stats, sigma


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_flank_strip_joins_its_pipe_and_the_wall_beside_it_stays_a_plane(seed):
    scan, pipeline, labels, fits, stats, sigma = _pipe_before_a_wall(seed)
    assert fits[2].kind == "cylinder" and abs(fits[2].radius - 0.2) < 0.05
    assert fits[3].kind == "plane" and fits[4].kind == "plane"
    assert (labels == 2)[:, -1].any()  # the pipe's region touches the frame's right edge
    out, models, out_stats = edge_planes_to_curved(scan.cloud, labels, fits, stats, sigma=sigma,
                                                   fitter=pipeline.fitter, samples=1.0, min_size=20,
                                                   inlier_factor=INLIER_SIGMAS)
    pipe = scan.truth_ids == 2
    assert 3 not in models and not (out == 3).any()
    assert np.mean(out[pipe] == 2) == 1.0  # the strip's pixels are the pipe's region's
    assert models[2].kind == "cylinder" and abs(models[2].radius - 0.2) < 0.05
    assert out_stats.counts[2] == int(pipe.sum())
    # the wall's band beside the pipe is a plane of its own, the wall a plane: unchanged
    assert models[4] is fits[4] and models[1] is fits[1]
    assert np.array_equal(out == 4, labels == 4) and np.array_equal(out == 1, labels == 1)


def test_without_a_curved_neighbour_or_fitter_nothing_changes():
    scan, pipeline, labels, fits, stats, sigma = _pipe_before_a_wall(0)
    planes_only = {k: m for k, m in fits.items() if k != 2}
    flat = np.where(labels == 2, 0, labels)
    stats_flat = region_stats(scan.cloud.xyz, flat, planes_only, sigma, INLIER_SIGMAS)
    out, models, out_stats = edge_planes_to_curved(scan.cloud, flat, planes_only, stats_flat, sigma=sigma,
                                                   inlier_factor=INLIER_SIGMAS)
    assert out is flat and models is planes_only and out_stats is stats_flat


def test_edge_planes_to_curved_rejects_mismatched_shapes():
    scan, pipeline, labels, fits, stats, sigma = _pipe_before_a_wall(0)
    with pytest.raises(ValueError, match="one \\(H, W\\) shape"):
        edge_planes_to_curved(scan.cloud, labels, fits, stats, sigma=sigma[:-1], inlier_factor=INLIER_SIGMAS)


@pytest.mark.parametrize("seed", [0, 1])
def test_a_lone_plane_on_a_pipe_cut_by_the_edge_is_fitted_curved_and_the_wall_stays_a_plane(seed):
    # The whole pipe (cut by the frame's right edge) one region under its plane, as the
    # recovery leaves a blob the tile grid lost; the wall, also cut by the edges, under its
    # plane. The pipe's pixels resolve its bend under a cylinder within the noise of their
    # distances: it becomes that cylinder. The wall's resolve none: it stays its plane.
    scan, pipeline, labels, fits, stats, sigma = _pipe_before_a_wall(seed)
    pipe = scan.truth_ids == 2
    lone = np.where(pipe, 2, np.where(scan.truth_ids == 1, 1, 0)).astype(np.int32)
    planes = {1: rs.fitting.fit_plane(scan.cloud.xyz[lone == 1]), 2: rs.fitting.fit_plane(scan.cloud.xyz[pipe])}
    lone_stats = region_stats(scan.cloud.xyz, lone, planes, sigma, INLIER_SIGMAS)
    out, models, out_stats = edge_planes_to_curved(scan.cloud, lone, planes, lone_stats, sigma=sigma,
                                                   fitter=pipeline.fitter, samples=1.0, min_size=20,
                                                   inlier_factor=INLIER_SIGMAS)
    assert np.array_equal(out, lone)
    assert models[2].kind == "cylinder" and abs(models[2].radius - 0.2) < 0.08
    assert models[1] is planes[1]
    assert out_stats.counts[2] == int(pipe.sum())
    # without the fitter (no bend asked) the lone plane stays
    same = edge_planes_to_curved(scan.cloud, lone, planes, lone_stats, sigma=sigma, inlier_factor=INLIER_SIGMAS)
    assert same[1] is planes
