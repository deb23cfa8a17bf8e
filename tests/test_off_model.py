"""The off-model group test (rangeseg_o3d.off_model): the tile sums label_pixels gathers, the
tiles whose pixels lie off their model as a group, and the groups worth a recovery."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.fitting.primitives import Cylinder, Plane
from rangeseg_o3d.fullres import label_pixels
from rangeseg_o3d.result import INLIER_SIGMAS


def _noisy_wall(h, w, sigma, seed, z=2.0):
    # a wall facing the sensor at z, 1 cm pixel spacing, with range noise sigma
    v, u = np.mgrid[0:h, 0:w].astype(float)
    xyz = np.dstack([(u - w / 2) * 0.01, (v - h / 2) * 0.01, np.full((h, w), z)])
    xyz[..., 2] += np.random.default_rng(seed).normal(0.0, sigma, (h, w))
    return xyz


def _wall_release(xyz, fits, sigma, tile=6, spread=1.0, k_sigma=10.0, tile_fits=None, tile_labels=None):
    # label_pixels' labels and tile sums (every tile of label 1 unless given), then the release
    from rangeseg_o3d.cloud import OrganizedCloud
    from rangeseg_o3d.off_model import off_model_blocks

    cloud = OrganizedCloud(xyz)
    h, w = cloud.shape
    if tile_labels is None:
        tile_labels = np.ones((-(-h // tile), -(-w // tile)), np.int32)
    noise = np.full((h, w), sigma)
    labels, _, blocks = label_pixels(cloud, tile_labels, fits, tile=tile, sigma=noise, k_sigma=k_sigma,
                                     inlier_factor=INLIER_SIGMAS, with_blocks=True)
    out, released, freed = off_model_blocks(labels, blocks, fits, fits if tile_fits is None else tile_fits,
                                            tile=tile, spread=spread)
    return labels, out, released, freed, blocks


def test_label_pixels_block_sums_are_the_sums_of_each_tiles_pixels_per_label():
    # two planes side by side, cut at a column inside a tile: each tile's slots hold the count,
    # the signed distances, the coordinates and the squared noise of the pixels each label took
    h, w, tile, sigma = 18, 24, 6, 0.01
    xyz = _noisy_wall(h, w, sigma, 7)
    xyz[:, 14:, 2] += 0.2
    fits = {1: Plane(np.array([0.0, 0.0, 1.0]), 2.0, rms=0.0, inliers=0),
            2: Plane(np.array([0.0, 0.0, 1.0]), 2.2, rms=0.0, inliers=0)}
    tile_labels = np.ones((3, 4), np.int32)
    tile_labels[:, 2:] = 2
    cloud = rs.OrganizedCloud(xyz)
    labels, _, (first, owners, taken, sums, whole) = label_pixels(
        cloud, tile_labels, fits, tile=tile, sigma=np.full((h, w), sigma), k_sigma=3.0,
        inlier_factor=INLIER_SIGMAS, with_blocks=True)
    assert first.size == 13 and first[-1] == owners.size
    for t in range(12):
        r0, c0 = (t // 4) * tile, (t % 4) * tile
        for s in range(first[t], first[t + 1]):
            k = owners[s]
            mine = labels[r0:r0 + tile, c0:c0 + tile] == k
            points = xyz[r0:r0 + tile, c0:c0 + tile][mine]
            assert taken[s] == mine.sum()
            assert sums[s, 0] == pytest.approx((points[:, 2] - fits[k].d).sum(), abs=1e-9)
            assert sums[s, 1:4] == pytest.approx(points.sum(axis=0), abs=1e-9)
            assert sums[s, 4] == pytest.approx(mine.sum() * sigma ** 2, rel=1e-12)
    # whole: every pixel of the tile taken by its one candidate (the tiles beside the cut hold two)
    assert whole.tolist() == [[True, False, False, True]] * 3


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_off_model_blocks_frees_a_tile_that_lies_beside_the_plane_as_a_group(seed):
    # a wall head-on (incidence cosine about 1): pixels 1.5 noise sigmas off the model, each
    # within any per-pixel bound, are freed in the tile at the image's edge that holds them;
    # the same offset in a tile inside the region (it and the 8 around it whole) is not
    # tested, and the tiles on the model keep theirs
    h, w, sigma = 36, 36, 0.01
    xyz = _noisy_wall(h, w, sigma, seed)
    xyz[6:12, 0:6, 2] += 1.5 * sigma
    xyz[18:24, 12:18, 2] += 1.5 * sigma
    fits = {1: Plane(np.array([0.0, 0.0, 1.0]), 2.0, rms=0.0, inliers=0)}
    labels, out, released, freed, _ = _wall_release(xyz, fits, sigma)
    assert (labels == 1).all()
    expected = np.zeros((h, w), bool)
    expected[6:12, 0:6] = True
    assert np.array_equal(out == 0, expected)
    assert np.array_equal(released, np.where(expected, 1, 0))
    assert freed.tolist() == np.flatnonzero(expected).tolist()
    # a camera whose tile means err three times as much as independent returns: within it
    labels, out, released, freed, _ = _wall_release(xyz, fits, sigma, spread=3.0)
    assert released is None and freed is None and out is labels


def test_off_model_blocks_skips_labels_without_a_model_or_whose_model_changed():
    h, w, sigma = 24, 24, 0.01
    xyz = _noisy_wall(h, w, sigma, 5)
    xyz[0:6, 0:6, 2] += 5 * sigma
    plane = Plane(np.array([0.0, 0.0, 1.0]), 2.0, rms=0.0, inliers=0)
    # the model the sums were taken against is not the label's model any more: not tested
    moved = Plane(np.array([0.0, 0.0, 1.0]), 2.001, rms=0.0, inliers=0)
    labels, out, released, _, _ = _wall_release(xyz, {1: moved}, sigma, tile_fits={1: plane})
    assert released is None and out is labels
    # the same model with its pixels' rms (what the recovery before gives it): tested, freed
    labels, out, released, _, _ = _wall_release(xyz, {1: Plane(plane.normal, plane.d, rms=0.002, inliers=0)},
                                                sigma, tile_fits={1: plane})
    assert (out[0:6, 0:6] == 0).all() and (out == 0).sum() == 36
    # a region without a model keeps its tiles
    tile_labels = np.ones((4, 4), np.int32)
    tile_labels[0, 0] = 2
    labels, out, released, _, _ = _wall_release(xyz, {1: plane, 2: None}, sigma, tile_labels=tile_labels)
    assert (labels[0:6, 0:6] == 2).all() and released is None and out is labels


def test_off_model_blocks_leaves_a_surface_that_stands_off_its_model_everywhere():
    # a real wall bent away from its plane tile after tile (depth distortion): every tile mean
    # is beyond the noise of a mean, and so is the region's spread of them; a tile off by as
    # little as the others is no group beside it
    h, w, sigma = 36, 36, 0.01
    xyz = _noisy_wall(h, w, sigma, 6)
    v, u = np.mgrid[0:h, 0:w]
    xyz[..., 2] += 0.01 * np.sin(u / 5.0) * np.cos(v / 7.0)
    xyz[::6, ::6, 2] = np.nan  # a missing return in every tile: no tile is whole, every tile is tested
    labels, out, released, _, _ = _wall_release(xyz, {1: Plane(np.array([0.0, 0.0, 1.0]), 2.0, rms=0.0,
                                                                inliers=0)}, sigma)
    assert (labels[np.isfinite(xyz[..., 2])] == 1).all()
    assert released is None and out is labels


def test_off_model_blocks_frees_an_end_cap_a_cylinder_took():
    # a pipe along x seen from above and its end cap seen face-on beside it: the cylinder
    # took the cap's pixels nearest its axis one by one (within 3 noise sigmas); as tiles
    # they stand off it and are freed, the pipe's own pixels stay
    h, w, tile, sigma, radius, depth = 24, 36, 6, 0.004, 0.05, 2.0
    v, u = np.mgrid[0:h, 0:w].astype(float)
    x, y = (u - w / 2) * 0.004, (v - h / 2) * 0.004
    z = depth - np.sqrt(np.maximum(radius ** 2 - y ** 2, 0.0))  # the pipe's top half, axis along x
    cap = u >= 24
    z[cap] = depth - radius + 0.008  # the cap, facing the sensor, 8 mm behind the pipe's top
    z += np.random.default_rng(3).normal(0.0, sigma, z.shape)
    pipe = Cylinder(np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, depth]), radius, rms=0.0, inliers=0)
    labels, out, released, _, _ = _wall_release(np.dstack([x, y, z]), {1: pipe}, sigma, k_sigma=3.0)
    taken = cap & (labels == 1)
    assert taken[6:18].sum() >= 0.8 * cap[6:18].sum()  # near the axis the pipe took the cap one by one
    freed = (labels == 1) & (out == 0)
    assert (freed <= cap).all()  # cap pixels only
    assert np.array_equal(freed[6:18], taken[6:18])  # the tiles within 2.4 cm of the axis: 4-8 mm off
    assert np.array_equal(released, np.where(freed, 1, 0))


def test_off_model_blocks_returns_its_inputs_when_nothing_lies_off():
    h, w, sigma = 18, 18, 0.01
    labels, out, released, freed, _ = _wall_release(
        _noisy_wall(h, w, sigma, 4), {1: Plane(np.array([0.0, 0.0, 1.0]), 2.0, rms=0.0, inliers=0)}, sigma)
    assert out is labels and released is None and freed is None


def test_turned_groups_frees_only_groups_turned_from_their_model_and_large_enough():
    # two groups of tiles of label 1: one whose pixels lie on a face at right angles to its
    # plane (kept), one on the plane's orientation 3 mm off it (a bend: not kept); with a floor
    # above the first group's pixels, neither
    from rangeseg_o3d.off_model import _turned_groups

    h, w, tile = 12, 36, 6
    xyz = np.zeros((h, w, 3))
    v, u = np.mgrid[0:h, 0:w].astype(float)
    rng = np.random.default_rng(1)
    xyz[..., 0], xyz[..., 1], xyz[..., 2] = u * 0.004, v * 0.004, 2.0 + rng.normal(0.0, 0.002, (h, w))
    xyz[:, 0:12, 0] = 0.0  # tiles 0-1 and 6-7: the face x = 0, across the plane z = 2
    xyz[:, 0:12, 2] = 2.0 + u[:, 0:12] * 0.004
    xyz[:, 24:36, 2] += 0.003  # tiles 4-5 and 10-11: along the plane
    labels = np.ones((h, w), np.int32)
    fits = {1: Plane(np.array([0.0, 0.0, 1.0]), 2.0, rms=0.002, inliers=0)}
    tiles = np.array([0, 1, 6, 7, 4, 5, 10, 11])
    owners = np.ones(tiles.size, np.int32)
    flat = xyz.reshape(-1, 3)
    kept = _turned_groups(flat, labels, tiles, owners, fits, tile=tile, max_angle_deg=3.0)
    assert kept.tolist() == [True] * 4 + [False] * 4
    assert not _turned_groups(flat, labels, tiles, owners, fits, tile=tile, max_angle_deg=3.0,
                              min_pixels=145).any()


def _patch(normal_axis, n, seed, spacing=0.004, sigma=0.002):
    # n x n points of a plane through (0, 0, 2) whose normal is ``normal_axis``, with noise along it
    rng = np.random.default_rng(seed)
    u, v = np.meshgrid(np.arange(n) * spacing, np.arange(n) * spacing)
    axes = [a for a in range(3) if a != normal_axis]
    points = np.zeros((n * n, 3))
    points[:, axes[0]], points[:, axes[1]] = u.ravel(), v.ravel()
    points[:, normal_axis] += rng.normal(0.0, sigma, n * n)
    points[:, 2] += 2.0
    return points


@pytest.mark.parametrize("seed", [0, 1])
def test_turned_from_source_keeps_a_face_across_the_model_and_drops_a_bend_along_it(seed):
    from rangeseg_o3d.off_model import _turned_from_source

    # blob 5: pixels on a face at right angles to the plane they were freed from; blob 6: pixels
    # on that plane's orientation, 3 mm off it (a bend); blob 7: 2 pixels, no plane
    across, along = _patch(0, 12, seed), _patch(2, 12, seed + 10)
    along[:, 2] += 0.003
    tiny = _patch(0, 2, seed + 20)[:2]
    xyz = np.concatenate([across, along, tiny])
    candidates = np.concatenate([np.full(144, 5), np.full(144, 6), np.full(2, 7)]).astype(np.int32)
    freed = np.arange(xyz.shape[0])
    sources = np.ones(freed.size, np.int64)
    fits = {1: Plane(np.array([0.0, 0.0, 1.0]), 2.0, rms=0.002, inliers=0)}
    kept = _turned_from_source(np.array([5, 6, 7]), candidates, xyz, freed, sources, fits, 3.0)
    assert kept.tolist() == [5]
    # a model whose normal at the freed pixels is the face's own: not turned
    fits = {1: Plane(np.array([1.0, 0.0, 0.0]), 0.0, rms=0.002, inliers=0)}
    assert _turned_from_source(np.array([5]), candidates, xyz, freed, sources, fits, 3.0).size == 0


def test_refit_apart_of_a_face_holding_no_pixel_is_none():
    # a face whose held pixels all went to other labels has no ray sums: no plane comes out
    # (the solve of its zero sums raised LinAlgError: kinect fresh seed 1025), and one holding
    # its pixels gets its plane back
    from rangeseg_o3d.fitting.primitives import Plane
    from rangeseg_o3d.off_model import _refit_apart

    h, w = 6, 8
    v, u = np.mgrid[0:h, 0:w].astype(float)
    xyz = np.ascontiguousarray(np.dstack([(u - 3.5) * 0.01, (v - 2.5) * 0.01, np.full((h, w), 2.0)]).reshape(-1, 3))
    noise = np.full(h * w, 0.004)
    face = Plane(normal=np.array([0.0, 0.0, 1.0]), d=2.0, rms=0.001, inliers=h * w)
    held = np.arange(h * w, dtype=np.int64)
    others = np.full(h * w, 3, np.int32)
    assert _refit_apart(xyz, noise, others, held, 5, face, None, 3.0, 10) is None
    assert _refit_apart(xyz, noise, others, held[:0], 5, face, None, 3.0, 10) is None
    mine = np.full(h * w, 5, np.int32)
    plane = _refit_apart(xyz, noise, mine, held, 5, face, None, 3.0, 10)
    assert plane is not None and abs(plane.normal[2]) == pytest.approx(1.0) and plane.d == pytest.approx(2.0)
