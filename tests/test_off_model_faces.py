"""Faces along the rays (rangeseg_o3d.off_model.faces_along_rays): a wall cut by the image's
edge, a strip a few pixels wide beside the wall it meets, under a depth camera's noise."""

import numpy as np
import pytest

from rangeseg_o3d.cloud import OrganizedCloud
from rangeseg_o3d.fitting.primitives import Plane
from rangeseg_o3d.fullres import region_stats
from rangeseg_o3d.result import INLIER_SIGMAS

KINECT = 1.425e-3  # range noise sigma = KINECT z^2 (metres)


def _corner(seed, strip_cols=8, h=120, w=160, focal=525.0, distance=6.5, turn_deg=25.0, side=True):
    # a wall turned by turn_deg from facing the camera at `distance`, and (side) the wall it
    # meets at a right angle in a concave corner seen strip_cols columns from the image's left
    # edge; the nearer plane along each ray is the one seen; range noise along the rays
    theta = np.radians(turn_deg)
    n1, d1 = np.array([np.sin(theta), 0.0, np.cos(theta)]), distance
    u, v = np.meshgrid((np.arange(w) - w / 2) / focal, (np.arange(h) - h / 2) / focal)
    rays = np.dstack([u, v, np.ones_like(u)])
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    t1 = d1 / (rays @ n1)
    t, truth = t1, np.ones((h, w), np.int32)
    n2, d2 = None, None
    if side:
        corner = t1[h // 2, strip_cols] * rays[h // 2, strip_cols]
        n2 = np.array([-np.cos(theta), 0.0, np.sin(theta)])
        d2 = float(n2 @ corner)
        if d2 < 0:
            n2, d2 = -n2, -d2
        t2 = d2 / (rays @ n2)
        seen = (t2 > 0) & (t2 < t1)
        t, truth = np.where(seen, t2, t1), np.where(seen, 2, 1)
    depth = t * rays[..., 2]
    noisy = t + np.random.default_rng(seed).normal(0.0, 1.0, t.shape) * KINECT * depth ** 2
    xyz = noisy[..., None] * rays
    sigma = KINECT * np.linalg.norm(xyz, axis=2) ** 2
    return xyz, sigma, truth, Plane(n1, d1, rms=0.0, inliers=0), (None if n2 is None else Plane(n2, d2, rms=0.0, inliers=0))


def _run(xyz, sigma, wall, tile_rows, tile=6):
    # every pixel taken by the wall's model; the strip's tiles in tile_rows of the first tile
    # column flagged off the model (as kernels.off_model_tiles flags them)
    from rangeseg_o3d.off_model import faces_along_rays

    h, w = sigma.shape
    labels = np.ones((h, w), np.int32)
    fits = {1: wall}
    stats = region_stats(xyz, labels, fits, sigma, INLIER_SIGMAS)
    tiles = np.array([r * -(-w // tile) for r in tile_rows], np.int64)
    owners = np.ones(tiles.size, np.int32)
    out, fits_out, stats_out = faces_along_rays(OrganizedCloud(xyz), labels, fits, stats, tiles, owners, tile=tile,
                                                sigma=sigma, k_sigma=3.0, inlier_factor=INLIER_SIGMAS,
                                                max_angle_deg=3.0, floor=20)
    return labels, out, fits_out, stats_out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_faces_along_rays_finds_a_wall_cut_by_the_image_edge(seed):
    xyz, sigma, truth, wall, side = _corner(seed)
    strip = truth == 2
    # the strip: the first 7-9 columns, 7.5-8 m off: range noise 80-90 mm, near the strip's width (~12 cm)
    assert 7 * 120 <= strip.sum() <= 9 * 120 and not strip[:, 12:].any()
    assert 0.075 < sigma[strip].mean() < 0.095
    _, out, fits, stats = _run(xyz, sigma, wall, tile_rows=[8, 9, 10])
    faces = [k for k in fits if k != 1]
    assert len(faces) == 1
    face = out == faces[0]
    # the face is the strip: 80 % of it (Hoover's tolerance) and 80 % of the face on it
    assert (face & strip).sum() >= 0.8 * strip.sum()
    assert (face & strip).sum() >= 0.8 * face.sum()
    # its plane is the side wall's, within a few degrees (the least-squares plane of its
    # pixels in xyz lies tens of degrees off: the range noise spreads them along the rays)
    angle = np.degrees(np.arccos(min(abs(float(fits[faces[0]].normal @ side.normal)), 1.0)))
    assert angle < 5.0
    points = xyz[strip]
    centred = points - points.mean(axis=0)
    least_squares = np.linalg.svd(centred, full_matrices=False)[2][-1]
    assert np.degrees(np.arccos(min(abs(float(least_squares @ side.normal)), 1.0))) > 4 * angle
    # the statistics follow the pixels
    assert stats.counts[faces[0]] == face.sum() and stats.counts[1] == (out == 1).sum()


def test_faces_along_rays_leaves_a_wall_without_a_face_beside_it():
    # the same tiles of a wall with nothing beside it: its own pixels, no face turned from it
    xyz, sigma, truth, wall, _ = _corner(0, side=False)
    labels, out, fits, stats = _run(xyz, sigma, wall, tile_rows=[8, 9, 10])
    assert out is labels and list(fits) == [1]


def _numpy_gates(xyz, sigma, idx, owner, floor=20, max_angle_deg=3.0):
    # faces_along_rays' first gates in numpy: (passes them, angle to the owner, bound)
    from rangeseg_o3d.fitting.robust import CHI_SQUARE_SIGMAS
    from rangeseg_o3d.kernels.linalg import noise_rms_bound
    from rangeseg_o3d.off_model import _tilt_bound
    from rangeseg_o3d.ray_planes import ray_terms, robust_ray_plane

    rays, inverse, weight = ray_terms(xyz.reshape(-1, 3)[idx], sigma.ravel()[idx])
    found = robust_ray_plane(rays, inverse, weight, *np.divmod(idx, sigma.shape[1]))
    if found is None:
        return False, None, None
    a, keep, mean_square = found
    n = int(keep.sum())
    if 2 * n <= idx.size or n < floor or mean_square > noise_rms_bound.py_func(1.0, n, CHI_SQUARE_SIGMAS) ** 2:
        return False, None, None
    tilt = _tilt_bound(a, rays[keep], weight[keep], max_angle_deg)
    angle = float(np.arccos(min(abs(float(tilt[0] @ owner.normal)), 1.0)))
    return angle > tilt[1], angle, tilt[1]


def _blocks(h, w, corners, rows=18, cols=6):
    # groups of pixels: a rows x cols block at each (row, col) corner, as faces_along_rays orders them
    idx = [np.flatnonzero(((np.arange(h)[:, None] >= r) & (np.arange(h)[:, None] < r + rows)
                           & (np.arange(w)[None] >= c) & (np.arange(w)[None] < c + cols)).ravel())
           for r, c in corners]
    return np.concatenate(idx), np.cumsum([0] + [len(i) for i in idx]), idx


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_screen_rules_out_only_groups_the_numpy_gates_refuse(seed):
    from rangeseg_o3d.off_model import _ruled_out

    xyz, sigma, truth, wall, _ = _corner(seed)
    h, w = sigma.shape
    # the strip cut by the image's edge (a face) in three places, and blocks of the wall itself
    corners = [(48, 0), (30, 0), (70, 0), (48, 30), (10, 60), (90, 100), (60, 150)]
    idx, bounds, groups = _blocks(h, w, corners)
    out = _ruled_out(np.ascontiguousarray(xyz.reshape(-1, 3)), sigma.ravel(), idx, bounds, w, 20,
                     [wall] * len(groups), 3.0)
    passes = [_numpy_gates(xyz, sigma, g, wall)[0] for g in groups]
    assert not any(out[j] and passes[j] for j in range(len(groups)))  # never a face numpy would keep
    assert all(passes[:3]) and not any(out[:3])  # the strip's faces go on to numpy
    assert out[3:].all()  # the wall's own blocks: its plane, ruled out without numpy


def test_screen_leaves_a_turn_at_its_bound_to_numpy():
    # the strip's face turned from the wall by exactly the bound: within the screen's
    # tolerance of either answer, so it is not ruled out; clear of it either way, it decides
    from rangeseg_o3d.fitting.robust import CHI_SQUARE_SIGMAS
    from rangeseg_o3d.kernels import ray_groups_ruled_out
    from rangeseg_o3d.off_model import SCREEN_TOLERANCE
    from rangeseg_o3d.ray_planes import ROBUST_CHUNKS, TRIM_PASSES
    from rangeseg_o3d.refinement.context import TRIM_SIGMAS

    xyz, sigma, truth, wall, _ = _corner(0)
    h, w = sigma.shape
    idx, bounds, groups = _blocks(h, w, [(48, 0)])
    passes, angle, bound = _numpy_gates(xyz, sigma, groups[0], wall)
    assert passes and angle > np.radians(45.0)  # (the turn itself is the bound below)

    def screen(max_angle):
        return bool(ray_groups_ruled_out(np.ascontiguousarray(xyz.reshape(-1, 3)), sigma.ravel(), idx, bounds, w, 20,
                                         wall.normal[None].astype(float), max_angle, float(CHI_SQUARE_SIGMAS),
                                         float(TRIM_SIGMAS), ROBUST_CHUNKS, TRIM_PASSES, SCREEN_TOLERANCE)[0])

    assert not screen(angle)
    assert screen(angle * (1.0 + 10 * SCREEN_TOLERANCE))
    assert not screen(angle * (1.0 - 10 * SCREEN_TOLERANCE))
    # groups under the floor, or under the chunks' three pixels each, are out before any fit
    small = np.asarray(groups[0][:3 * ROBUST_CHUNKS - 1])
    assert ray_groups_ruled_out(np.ascontiguousarray(xyz.reshape(-1, 3)), sigma.ravel(), small,
                                np.array([0, small.size]), w, 20, np.full((1, 3), np.nan), 0.05,
                                float(CHI_SQUARE_SIGMAS), float(TRIM_SIGMAS), ROBUST_CHUNKS, TRIM_PASSES,
                                SCREEN_TOLERANCE)[0]


def _wall_and_face(offset_sigmas, turn_deg=0.0, seed=0, h=60, w=80, focal=525.0, distance=3.0):
    # a head-on wall at `distance` (range noise along the rays); region 1 holds its left half
    # with a plane moved offset_sigmas of the range noise (and turned by turn_deg) from the
    # truth, the face 2 its right half with the true plane
    from rangeseg_o3d.kernels.linalg import noise_rms_bound
    from rangeseg_o3d.fitting.robust import CHI_SQUARE_SIGMAS

    u, v = np.meshgrid((np.arange(w) - w / 2) / focal, (np.arange(h) - h / 2) / focal)
    rays = np.dstack([u, v, np.ones_like(u)])
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    t = distance / rays[..., 2]
    noisy = t + np.random.default_rng(seed).normal(0.0, 1.0, t.shape) * KINECT * distance ** 2
    xyz = np.ascontiguousarray((noisy[..., None] * rays).reshape(-1, 3))
    sigma = KINECT * np.linalg.norm(xyz, axis=1) ** 2
    labels = np.ones((h, w), np.int32)
    labels[:, w // 2:] = 2
    theta = np.radians(turn_deg)
    moved = Plane(np.array([np.sin(theta), 0.0, np.cos(theta)]), distance + offset_sigmas * KINECT * distance ** 2,
                  rms=0.0, inliers=0)
    fits = {1: moved, 2: Plane(np.array([0.0, 0.0, 1.0]), distance, rms=0.0, inliers=0)}
    bound = noise_rms_bound.py_func(1.0, float(h * w // 2), CHI_SQUARE_SIGMAS) ** 2
    return xyz, sigma, labels, fits, np.flatnonzero(labels.ravel() == 2), bound


def test_a_face_the_touching_region_explains_by_the_merge_rule_joins_it():
    # the region's plane half a sigma off: its mean square on the face (~1.25) misses the
    # chi-square bound of plane_beside (~1.1 for 2400 px), but lies within merge_rms_factor
    # (1.3) squared of the face's own plane's (~1.0): one surface, the face joins the region
    from rangeseg_o3d.off_model import _fates

    xyz, sigma, labels, fits, face, bound = _wall_and_face(0.5)
    assert bound < 1.15
    assert _fates(xyz, sigma, labels, fits, 2, [face], 1.3) == [1]
    # not asked (no merge in the config): the face stands as before
    assert _fates(xyz, sigma, labels, fits, 2, [face], None) == [2]


@pytest.mark.parametrize("offset, turn", [(1.5, 0.0), (0.0, 30.0)])
def test_a_face_the_touching_region_explains_worse_than_the_merge_rule_stands(offset, turn):
    # the region's plane 1.5 sigma off (mean square ~3 against 1.69), or turned by 30 degrees
    # about the face's edge (off by more than 3 sigma beyond its first ~12 columns): the face
    # stands on its own
    from rangeseg_o3d.off_model import _fates, _merged_into
    from rangeseg_o3d.ray_planes import ray_terms

    xyz, sigma, labels, fits, face, _ = _wall_and_face(offset, turn)
    assert _fates(xyz, sigma, labels, fits, 2, [face], 1.3) == [2]
    rays, inverse, weight = ray_terms(xyz[face], sigma[face])
    assert _merged_into(labels, 2, face, rays, inverse, weight, {1: fits[1]}, fits[2], 1.3) == 0
    # a merge factor wide enough takes the offset one (the turned one keeps too few pixels)
    assert _merged_into(labels, 2, face, rays, inverse, weight, {1: fits[1]}, fits[2], 3.0) == (1 if turn == 0 else 0)
