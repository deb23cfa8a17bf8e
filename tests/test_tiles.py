"""Tile means (OrganizedCloud.tile_means) and the pipeline's tile grid brought back to full resolution."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.fitting.region_fitter import model_table
from rangeseg_o3d.fitting.primitives import Plane


def _wall(h=48, w=60, z=2.0, noise=0.0, seed=0):
    v, u = np.mgrid[0:h, 0:w].astype(float)
    xyz = np.dstack([(u - w / 2) * 0.01, (v - h / 2) * 0.01, np.full((h, w), z)])
    xyz[..., 2] += np.random.default_rng(seed).normal(0, noise, (h, w)) if noise else 0.0
    return xyz


def test_tile_means_average_valid_pixels_and_record_samples():
    xyz = _wall(12, 13)
    xyz[0, 0] = np.nan
    xyz[6:12, 0:6] = np.nan
    xyz[6:9, 6:12] = np.nan  # 18 of 36 valid: exactly min_fraction 0.5, kept
    tiles = rs.OrganizedCloud(xyz).tile_means(6)
    assert tiles.shape == (2, 3) and tiles.tile == 6
    np.testing.assert_array_equal(tiles.samples, [[35, 36, 6], [0, 18, 6]])
    np.testing.assert_allclose(tiles.xyz[0, 1], np.nanmean(xyz[0:6, 6:12].reshape(-1, 3), axis=0))
    # a tile with fewer than half of its 36 pixels valid (the last column has 6) is invalid
    assert tiles.valid.tolist() == [[True, True, False], [False, True, False]]
    assert tiles.ranges is None and tiles.geometry is None
    sub = tiles.crop(cols=slice(1, 3))
    assert sub.tile == 6 and sub.samples.tolist() == [[36, 6], [18, 6]]


def test_tile_means_refuse_bad_sizes_and_means_of_means():
    cloud = rs.OrganizedCloud(_wall(12, 12))
    assert cloud.tile_means(1) is cloud
    for bad in (0, -2, 2.5):
        with pytest.raises(ValueError, match="size must be a positive integer"):
            cloud.tile_means(bad)
    with pytest.raises(ValueError, match="already holds means"):
        cloud.tile_means(2).tile_means(2)
    with pytest.raises(ValueError, match="tile must be a positive integer"):
        rs.OrganizedCloud(_wall(4, 4), tile=0)
    with pytest.raises(ValueError, match="samples must have shape"):
        rs.OrganizedCloud(_wall(4, 4), samples=np.ones((3, 4)))


def test_pipeline_on_tiles_reports_full_resolution_labels_and_pixel_rms():
    noise = 0.004
    xyz = _wall(96, 120, z=2.0, noise=noise, seed=3)
    cfg = rs.load_config({"tile": 6, "sensor": {"sigma0": noise}, "segmenter": {
        "name": "residual_edges", "params": {"threshold": 4.0, "min_region_size": 300}}})
    result = rs.Pipeline(cfg).run(rs.OrganizedCloud(xyz))
    assert result.labels.shape == (96, 120)
    assert {image.shape for image in result.stages.values()} == {(96, 120)}
    assert "full_resolution" in result.timings
    # its steps, each timed under full.<step>, in run order, together within the stage's time
    steps = [k for k in result.timings if k.startswith("full.")]
    assert steps[:5] == ["full.noise", "full.label_pixels", "full.detached", "full.recover", "full.off_model"]
    assert all(result.timings[k] >= 0 for k in steps)
    assert sum(result.timings[k] for k in steps) <= result.timings["full_resolution"]
    (plane,) = result.features
    assert plane.kind == "plane" and abs(plane.normal[2]) > 0.9999
    assert plane.d == pytest.approx(2.0, abs=1e-3)
    # the rms is the pixels' (the tile means are 6x smoother): within 10 % of the noise
    assert plane.rms == pytest.approx(noise, rel=0.1)
    assert plane.n_pixels >= 0.99 * 96 * 120


def test_pipeline_on_tiles_refuses_a_cloud_without_a_valid_tile():
    xyz = _wall(12, 12)
    xyz[::2, :] = np.nan  # every tile half empty... and then some
    xyz[1::4, :] = np.nan
    cfg = rs.load_config({"tile": 4})
    with pytest.raises(ValueError, match="use a smaller tile"):
        rs.Pipeline(cfg).run(rs.OrganizedCloud(xyz))


def _ramp_band_scene(seed=0):
    # A wall, a 9-row band leaning towards the sensor (creases at rows 40 and 49), and a
    # nearer wall below: the band is thinner than two 6x6 tiles.
    h, w = 96, 120
    v, u = np.mgrid[0:h, 0:w].astype(float)
    x, y = (u - w / 2) * 0.01, (v - h / 2) * 0.01
    z = np.full((h, w), 2.0)
    band = (v >= 40) & (v < 49)
    z[band] = 2.0 - 0.6 * (y[band] - y[band].min())
    z[v >= 49] = z[band].min()
    rng = np.random.default_rng(seed)
    xyz = np.dstack([x * z / 2, y * z / 2, z + rng.normal(0, 0.002, (h, w))])
    cfg = rs.load_config({"tile": 6, "sensor": {"sigma0": 0.002}, "segmenter": {
        "name": "residual_edges", "params": {"threshold": 4.0, "min_region_size": 60}}})
    return rs.OrganizedCloud(xyz), band, cfg


def test_surfaces_thinner_than_the_tiles_are_recovered_at_full_resolution():
    cloud, band, cfg = _ramp_band_scene()
    result = rs.Pipeline(cfg).run(cloud)
    labels, counts = np.unique(result.labels[band], return_counts=True)
    strip = labels[np.argmax(counts)]
    assert strip > 0 and counts.max() >= 0.8 * band.sum()
    assert (result.labels == strip)[band].sum() >= 0.9 * (result.labels == strip).sum()
    (feature,) = [f for f in result.features if f.label == strip]
    assert feature.kind == "plane"
    # the band leans 31 deg from the walls (dz/dy = -0.6 in camera coordinates)
    assert np.degrees(np.arccos(abs(feature.normal[2]))) == pytest.approx(31.0, abs=2.0)
    # without leftover recovery the tile grid alone never sees it
    cfg.refine.recover_leftovers = False
    alone = rs.Pipeline(cfg).run(cloud)
    assert (alone.labels[band] == 0).mean() > 0.6


def test_claim_rings_moves_only_pixels_the_challenger_explains_better():
    from rangeseg_o3d.kernels import claim_rings

    xyz = _wall(10, 12)
    xyz[:, 6:, 2] = 2.01  # right half: 1 cm behind
    labels = np.ones((10, 12), np.int32)
    labels[:, 9:] = 2       # the challenger holds only columns 9..11 of the right half
    kinds, params, rms = model_table({1: Plane([0, 0, 1], 2.0, 0.001, 1),
                                      2: Plane([0, 0, 1], 2.01, 0.001, 1)}, 3)
    sigma = np.full(120, 0.004)  # 3 sigma = 12 mm: region 1 explains the right half too
    challengers = np.array([False, False, True])
    box = np.array([0, 10, 0, 12], np.int64)
    moved = claim_rings(xyz.reshape(-1, 3), labels, kinds, params, rms, sigma, challengers, 5, 3.0, box)
    assert moved == 30 and (labels[:, 6:] == 2).all() and (labels[:, :6] == 1).all()
    # a box that leaves out the columns: nothing moves there
    labels[:, :9] = 1
    claim_rings(xyz.reshape(-1, 3), labels, kinds, params, rms, sigma, challengers, 5, 3.0,
                np.array([0, 10, 0, 8], np.int64))
    assert (labels[:, :9] == 1).all()


def _claim_rings_by_scans(xyz, labels, kinds, params, rms, sigma, challengers, iterations, k_sigma, box):
    # the rule of kernels.claim_rings as stated, by whole scans of the box per ring (numpy)
    h, w = labels.shape
    n = len(kinds)
    r0, r1, c0, c1 = max(box[0], 0), min(box[1], h), max(box[2], 0), min(box[3], w)
    moved = 0
    for _ in range(iterations):
        new = labels.copy()
        for r in range(r0, r1):
            for c in range(c0, c1):
                own = labels[r, c]
                if own <= 0 or challengers[own]:
                    continue
                near = [labels[rr, cc] for rr, cc in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1))
                        if 0 <= rr < h and 0 <= cc < w]
                if not any(0 < k < n and challengers[k] for k in near):
                    continue
                point = xyz[r * w + c]
                model = {k: Plane(params[k, :3], params[k, 3], rms[k], 0) for k in range(1, n)}
                score = {k: abs(model[k].distances(point[None])[0]) / max(sigma[r * w + c], rms[k])
                         for k in range(1, n)}
                best, best_score = 0, min(score[own], k_sigma)
                for k in near:
                    if 0 < k < n and challengers[k] and score[k] < best_score:
                        best, best_score = k, score[k]
                if best:
                    new[r, c] = best
        changed = int((new != labels).sum())
        if not changed:
            break
        labels[:] = new
        moved += changed
    return moved


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_claim_rings_equals_the_scan_of_every_pixel_every_ring(seed):
    # random tilted planes in random blocks, some of them challengers: the kernel, which decides
    # only the pixels next to those just moved, moves exactly the pixels whole scans move
    from rangeseg_o3d.kernels import claim_rings

    rng = np.random.default_rng(seed)
    h, w, n = 24, 30, 7
    blocks = rng.integers(1, n, (4, 5))
    labels = np.kron(blocks, np.ones((6, 6), np.int32)).astype(np.int32)
    labels[rng.random((h, w)) < 0.05] = 0
    fits = {k: Plane([0.0, 0.0, 1.0], 2.0 + rng.uniform(-0.006, 0.006), 0.001, 1) for k in range(1, n)}
    kinds, params, rms = model_table(fits, n)
    xyz = _wall(h, w)
    xyz[..., 2] += rng.normal(0, 0.006, (h, w))
    sigma = np.full(h * w, 0.004)
    challengers = np.zeros(n, bool)
    challengers[rng.choice(np.arange(1, n), 2, replace=False)] = True
    box = np.array([2, h - 3, 1, w - 4], np.int64)
    expected = labels.copy()
    want = _claim_rings_by_scans(xyz.reshape(-1, 3), expected, kinds, params, rms, sigma, challengers, 4, 3.0, box)
    moved = claim_rings(np.ascontiguousarray(xyz.reshape(-1, 3)), labels, kinds, params, rms, sigma,
                        challengers, 4, 3.0, box)
    assert want > 5 and moved == want
    assert np.array_equal(labels, expected)


@pytest.mark.parametrize("seed", range(3))
def test_claim_rings_in_boxes_equals_the_box_holding_them(seed):
    # two challengers in opposite corners: each one's box grown by the rings (or boxes that
    # overlap them) moves the same pixels as the one box holding both; a box left out moves
    # nothing of its challenger
    from rangeseg_o3d.kernels import claim_rings, claim_rings_in_boxes

    rng = np.random.default_rng(seed)
    h, w, n = 30, 40, 5
    labels = rng.integers(1, 3, (h, w)).astype(np.int32)
    labels[2:6, 3:8] = 3
    labels[22:27, 30:36] = 4
    fits = {k: Plane([0.0, 0.0, 1.0], 2.0 + rng.uniform(-0.006, 0.006), 0.001, 1) for k in range(1, n)}
    kinds, params, rms = model_table(fits, n)
    xyz = _wall(h, w)
    xyz[..., 2] += rng.normal(0, 0.006, (h, w))
    xyz = np.ascontiguousarray(xyz.reshape(-1, 3))
    sigma = np.full(h * w, 0.004)
    challengers = np.array([False, False, False, True, True])
    rings = 3
    whole = labels.copy()
    moved = claim_rings(xyz, whole, kinds, params, rms, sigma, challengers, rings, 3.0,
                        np.array([2 - rings, 27 + rings, 3 - rings, 36 + rings], np.int64))
    assert moved > 5
    own = [[2 - rings, 6 + rings, 3 - rings, 8 + rings], [22 - rings, 27 + rings, 30 - rings, 36 + rings]]
    for boxes in (own, own + [[0, 12, 0, 12]], own[::-1]):
        each = labels.copy()
        assert claim_rings_in_boxes(xyz, each, kinds, params, rms, sigma, challengers, rings, 3.0,
                                    np.array(boxes, np.int64)) == moved
        np.testing.assert_array_equal(each, whole)
    alone = labels.copy()
    claim_rings_in_boxes(xyz, alone, kinds, params, rms, sigma, challengers, rings, 3.0, np.array(own[:1], np.int64))
    assert (alone[15:] == labels[15:]).all() and np.array_equal(alone[:15], whole[:15])


def test_cloud_points_are_c_ordered_and_ranges_computed_once():
    # a transposed (Fortran-ordered) input must not make every flat view a copy
    xyz = np.asfortranarray(_wall(8, 9, z=2.0))
    cloud = rs.OrganizedCloud(xyz)
    assert cloud.xyz.flags["C_CONTIGUOUS"] and not cloud.xyz.flags["WRITEABLE"]
    assert np.shares_memory(cloud.xyz.reshape(-1, 3), cloud.xyz)
    ranges = cloud.range_image()
    np.testing.assert_allclose(ranges, np.linalg.norm(xyz, axis=2), rtol=1e-12)
    assert cloud.range_image() is ranges and not ranges.flags["WRITEABLE"]


def test_box_members_gathers_each_blob_from_its_box_as_region_indices_does():
    # the full-resolution recovery takes each leftover blob's pixels from its bounding box;
    # they must be region_indices' (every pixel of the blob, increasing), blobs interleaved
    from rangeseg_o3d.fitting.region_fitter import region_indices
    from rangeseg_o3d.kernels import box_members

    rng = np.random.default_rng(5)
    labels = np.zeros((40, 50), np.int32)
    labels[rng.random(labels.shape) < 0.3] = 9  # a label below the blobs': left out
    labels[5:20, 3:30][rng.random((15, 27)) < 0.6] = 12
    labels[10:35, 20:45][rng.random((25, 25)) < 0.5] = 13  # boxes overlap the first
    labels[38:40, 0:2] = 14
    first, boxes = 12, []
    for k in (12, 13, 14):
        rows, cols = np.nonzero(labels == k)
        boxes.append([rows.min(), rows.max() + 1, cols.min(), cols.max() + 1])
    order, starts = box_members(labels, np.array(boxes, np.int64), first)
    expected = region_indices(labels)
    for j, k in enumerate((12, 13, 14)):
        np.testing.assert_array_equal(order[starts[j]:starts[j + 1]], expected[k])
    assert starts[-1] == sum(expected[k].size for k in (12, 13, 14))
