"""Compiled kernels and the batched (moment-based) fits checked against per-region numpy."""

import numpy as np
import pytest

from rangeseg_o3d.fitting.region_fitter import model_table
from rangeseg_o3d.fitting import fit_cylinder, fit_plane, fit_sphere
from rangeseg_o3d.fitting.classify import (
    fit_planes_batch,
    fit_primitive,
    quadric_shape,
    refit_planes_from_moments,
)
from rangeseg_o3d.fitting.primitives import FitFailure, Plane
from rangeseg_o3d.fitting.batch_planes import plane_rms_from_moments, planes_from_moments, quadric_gains, region_moments
from rangeseg_o3d.kernels import adjacency_matrix, block_means, count_inliers, group_by_label, grow_rings
from rangeseg_o3d.refinement.merge import region_adjacency
from rangeseg_o3d.segmentation.residual import block_means as tile_means


def _plane_points(rng, n, normal, d, noise):
    normal = np.asarray(normal, float) / np.linalg.norm(normal)
    helper = np.eye(3)[np.argmin(np.abs(normal))]
    e1 = np.cross(normal, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    uv = rng.uniform(-1, 1, (n, 2))
    return d * normal + uv[:, :1] * e1 + uv[:, 1:] * e2 + rng.normal(0, noise, (n, 1)) * normal


def _labelled(rng, groups):
    """Shuffle groups of points into one (N, 3) array with labels 1..len(groups), NaN rows as 0."""
    pts = np.vstack(groups + [np.full((7, 3), np.nan)])
    labels = np.concatenate([np.full(len(g), k, np.int32) for k, g in enumerate(groups, 1)]
                            + [np.zeros(7, np.int32)])
    order = rng.permutation(len(pts))
    return pts[order], labels[order]


def test_label_moments_equal_per_label_sums():
    rng = np.random.default_rng(1)
    groups = [rng.normal(k, 1.0, (50 + 10 * k, 3)) for k in range(3)]
    pts, labels = _labelled(rng, groups)
    moments = region_moments(pts, labels)
    assert moments.shape == (4, 10) and (moments[0] == 0).all()
    for k, g in enumerate(groups, 1):
        outer = g.T @ g
        expected = [len(g), *g.sum(0), outer[0, 0], outer[0, 1], outer[0, 2], outer[1, 1], outer[1, 2],
                    outer[2, 2]]
        np.testing.assert_allclose(moments[k], expected, rtol=1e-12)


def test_planes_from_moments_match_fit_plane():
    rng = np.random.default_rng(2)
    specs = [([0, 0, 1], 2.0, 0.005), ([1, 2, -0.5], 4.0, 0.01), ([0.3, -1, 0.1], 0.5, 0.0)]
    groups = [_plane_points(rng, 200, *s) for s in specs]
    pts, labels = _labelled(rng, groups)
    table = planes_from_moments(region_moments(pts, labels))
    for k, g in enumerate(groups, 1):
        ref = fit_plane(g)
        assert table.ok[k]
        np.testing.assert_allclose(table.normal[k], ref.normal, atol=1e-9)
        assert table.d[k] == pytest.approx(ref.d, abs=1e-9)
        assert table.rms[k] == pytest.approx(ref.rms, rel=1e-6, abs=1e-7)


def test_planes_from_moments_flag_degenerate_rows():
    line = np.outer(np.linspace(0, 1, 20), [1.0, 2.0, 3.0])
    pts = np.vstack([line, [[0, 0, 1], [1, 0, 1]]])
    labels = np.r_[np.full(20, 1, np.int32), [2, 2]]
    table = planes_from_moments(region_moments(pts, labels, 4))
    assert not table.ok[1]  # collinear
    assert not table.ok[2]  # two points
    assert not table.ok[3]  # empty
    with pytest.raises(ValueError, match=r"\(K, 10\)"):
        planes_from_moments(np.zeros((3, 9)))


def test_plane_rms_from_moments_is_the_tables_rms():
    # the merge loop's one-union rms (no table): the same values as the table's, the same check
    rng = np.random.default_rng(4)
    groups = [_plane_points(rng, 100, [0, 0, 1], 2.0, 0.005), _plane_points(rng, 50, [1, 2, -0.5], 4.0, 0.02)]
    pts, labels = _labelled(rng, groups)
    moments = region_moments(pts, labels)
    np.testing.assert_array_equal(plane_rms_from_moments(moments), planes_from_moments(moments).rms)
    assert plane_rms_from_moments(moments[1:2] + moments[2:3])[0] == planes_from_moments(moments[1:2] + moments[2:3]).rms[0]
    with pytest.raises(ValueError, match=r"\(K, 10\); got \(10,\)"):
        plane_rms_from_moments(moments[1])


def test_quadric_gains_match_quadric_shape():
    rng = np.random.default_rng(3)
    t = rng.uniform(0, np.pi / 2, 300)
    z = rng.uniform(0, 1, 300)
    cyl = np.stack([0.3 * np.cos(t), 0.3 * np.sin(t), z], 1) + rng.normal(0, 0.002, (300, 3))
    sph_dir = rng.normal(size=(300, 3))
    sph_dir[:, 2] = np.abs(sph_dir[:, 2]) + 2
    sph = 0.4 * sph_dir / np.linalg.norm(sph_dir, axis=1, keepdims=True) + rng.normal(0, 0.002, (300, 3))
    flat = _plane_points(rng, 300, [0, 1, 1], 3.0, 0.005)
    groups = [cyl, sph, flat]
    pts, labels = _labelled(rng, groups)
    table = planes_from_moments(region_moments(pts, labels))
    gain, roundness = quadric_gains(pts, labels, table, np.array([False, True, True, True]))
    for k, g in enumerate(groups, 1):
        ref_gain, ref_round = quadric_shape(g, fit_plane(g))
        assert gain[k] == pytest.approx(ref_gain, rel=1e-6)
        assert roundness[k] == pytest.approx(ref_round, rel=1e-6, abs=1e-9)
    assert gain[0] == 1.0 and roundness[0] == 0.5  # inactive row


def test_fit_planes_batch_settles_exactly_the_planes_fit_primitive_accepts():
    rng = np.random.default_rng(4)
    t = rng.uniform(0, np.pi, 400)
    cyl = np.stack([0.2 * np.cos(t), 0.2 * np.sin(t) + 2, rng.uniform(0, 1, 400)], 1)
    cyl += rng.normal(0, 0.003, cyl.shape)
    groups = [_plane_points(rng, 300, [0, 0, 1], 1.5, 0.004), cyl,
              _plane_points(rng, 300, [1, 1, 0], 2.0, 0.03),  # too rough for plane_rms 0.01
              _plane_points(rng, 5, [1, 0, 0], 2.0, 0.0)]     # fewer than min_points
    pts, labels = _labelled(rng, groups)
    settled = fit_planes_batch(pts, labels)
    assert set(settled) == {1}
    ref = fit_primitive(groups[0])
    assert isinstance(ref, Plane)
    np.testing.assert_allclose(settled[1].normal, ref.normal, atol=1e-9)
    assert settled[1].rms == pytest.approx(ref.rms, rel=1e-6)
    assert settled[1].inliers == ref.inliers
    with pytest.raises(ValueError, match="labels"):
        fit_planes_batch(pts, labels[:-1])


def test_refit_planes_from_summed_moments_is_the_union_fit():
    rng = np.random.default_rng(5)
    a = _plane_points(rng, 100, [0, 0, 1], 2.0, 0.004)
    b = _plane_points(rng, 150, [0, 0, 1], 2.0, 0.004) + [3, 0, 0]
    moments = region_moments(np.vstack([a, b]), np.r_[np.ones(100, np.int32), np.full(150, 2, np.int32)])
    union = fit_plane(np.vstack([a, b]))
    sphere = fit_sphere(rng.normal(size=(50, 3)) / 10 + [0, 0, 3])
    out = refit_planes_from_moments(np.stack([moments[1] + moments[2], moments[1], moments[1]]),
                                    [union, sphere, union], plane_rms=0.001)
    assert out[1] is None  # not a plane: needs its points
    # union rms ~0.004 > plane_rms 0.001: refused with the reason
    assert isinstance(out[0], FitFailure) and "rms" in out[0].reason
    ok = refit_planes_from_moments(moments[1] + moments[2], [union])[0]
    np.testing.assert_allclose(ok.normal, union.normal, atol=1e-9)
    assert ok.rms == pytest.approx(union.rms, rel=1e-6) and ok.inliers == 250
    with pytest.raises(ValueError, match="one moments row per model"):
        refit_planes_from_moments(moments, [union])


def _numpy_refits(moments, models, *, plane_rms, rms_per_range2, min_points, noise_floor):
    # refit_planes_from_moments as it was before its thresholds were compiled (numpy over
    # every row): the reference the compiled form must equal to the bit
    from rangeseg_o3d.kernels.linalg import NOISE_CHI2_SIGMAS, noise_rms_bound
    from rangeseg_o3d.fitting.plane import UNDETERMINED

    planes = planes_from_moments(moments)
    counts = planes.count.astype(np.float64)
    floor = np.full(counts.shape, float(plane_rms))
    if noise_floor > 0.0:
        floor = np.maximum(floor, noise_rms_bound.py_func(float(noise_floor), counts - 3.0, NOISE_CHI2_SIGMAS))
    tol = (floor + rms_per_range2 * np.square(planes.centroid).sum(axis=1)).tolist()
    minimum = max(int(min_points), 3)
    out = []
    for i, model in enumerate(models):
        if not isinstance(model, Plane):
            out.append(None)
        elif planes.count[i] < minimum:
            out.append(FitFailure("plane", f"a plane fit needs at least {minimum} points; got {int(planes.count[i])}"))
        elif not planes.ok[i]:
            out.append(FitFailure("plane", UNDETERMINED))
        elif planes.rms[i] > tol[i]:
            out.append(FitFailure("plane", f"plane rms {planes.rms[i]:.3g} > {tol[i]:.3g}"))
        else:
            out.append(Plane(normal=planes.normal[i], d=float(planes.d[i]), rms=float(planes.rms[i]),
                             inliers=int(planes.count[i])))
    return out


def test_refit_planes_from_moments_equals_the_numpy_thresholds_to_the_bit():
    # noisy planes of 1-3000 points, 1-25 mm noise, 0.3-40 m away, turned every way, with
    # collinear and coincident sets among them: the compiled thresholds (kernels.plane_refit_rows)
    # give the same planes, the same verdicts and the same reasons as numpy's did
    from rangeseg_o3d.kernels import plane_refit_rows

    rng = np.random.default_rng(23)
    groups = []
    for size in rng.integers(1, 3000, 120).tolist() + [1, 2, 3, 4, 6, 10]:
        normal = rng.normal(size=3)
        pts = _plane_points(rng, size, normal, rng.uniform(0.3, 40.0), rng.uniform(0.001, 0.025))
        groups.append(pts * rng.uniform(0.2, 3.0, 3))  # stretched: some planes bend off their fit
    groups.append(np.outer(np.linspace(0, 1, 40), [1.0, 2.0, 0.5]) + [0.0, 0.0, 5.0])  # collinear
    groups.append(np.tile([[1.0, 2.0, 3.0]], (30, 1)))  # coincident
    pts = np.vstack(groups)
    labels = np.concatenate([np.full(len(g), k, np.int32) for k, g in enumerate(groups, 1)])
    moments = region_moments(pts, labels)[1:]
    moments = np.vstack([moments, moments[3] + moments[7], np.zeros(10)])  # a union, an empty row
    plane = Plane(normal=[0.0, 0.0, 1.0], d=1.0, rms=0.0, inliers=3)
    sphere = fit_sphere(rng.normal(size=(50, 3)) / 10 + [0, 0, 3])
    models = [sphere if i % 17 == 5 else plane for i in range(len(moments))]
    verdicts = set()
    for params in (dict(plane_rms=0.01, rms_per_range2=0.0, min_points=10, noise_floor=0.005),
                   dict(plane_rms=0.004, rms_per_range2=1.425e-3, min_points=5, noise_floor=0.0),
                   dict(plane_rms=0.002, rms_per_range2=2e-4, min_points=3, noise_floor=0.02)):
        got = refit_planes_from_moments(moments, models, **params)
        want = _numpy_refits(moments, models, **params)
        for g, w in zip(got, want):
            assert type(g) is type(w)
            if isinstance(w, Plane):
                assert g.normal.tobytes() == w.normal.tobytes()
                assert (g.d, g.rms, g.inliers) == (w.d, w.rms, w.inliers)
            elif isinstance(w, FitFailure):
                assert (g.kind, g.reason) == (w.kind, w.reason)
            verdicts.add(type(w).__name__ if w is None or isinstance(w, Plane) else w.reason.split(" ")[0])
        # the kernel's rows: planes_from_moment_rows' to the bit, its thresholds numpy's
        normal, d, rms, tol, ok = plane_refit_rows(moments, params["plane_rms"], params["noise_floor"],
                                                   params["rms_per_range2"])
        planes = planes_from_moments(moments)
        assert normal.tobytes() == planes.normal.tobytes() and d.tobytes() == planes.d.tobytes()
        assert rms.tobytes() == planes.rms.tobytes() and ok.tolist() == planes.ok.tolist()
    # every path was taken: planes, not planes, too few points ("a plane fit needs"), undetermined
    # ("points are coincident"), over the threshold ("plane rms")
    assert verdicts == {"Plane", "NoneType", "a", "points", "plane"}


def test_refit_planes_from_moments_refuses_moments_of_another_shape():
    plane = Plane(normal=[0.0, 0.0, 1.0], d=1.0, rms=0.0, inliers=3)
    with pytest.raises(ValueError, match=r"shape \(K, 10\); got \(2, 9\)"):
        refit_planes_from_moments(np.ones((2, 9)), [plane, plane])
    with pytest.raises(ValueError, match="one moments row per model"):
        refit_planes_from_moments(np.ones((2, 10)), [plane])


def test_count_inliers_matches_model_distances():
    rng = np.random.default_rng(6)
    t = rng.uniform(0, 2 * np.pi, 200)
    cyl_pts = np.stack([0.3 * np.cos(t), 0.3 * np.sin(t), rng.uniform(0, 1, 200)], 1)
    cyl_pts += rng.normal(0, 0.01, cyl_pts.shape)
    cylinder = fit_cylinder(cyl_pts)
    sph_pts = rng.normal(size=(200, 3))
    sph_pts = 0.5 * sph_pts / np.linalg.norm(sph_pts, axis=1, keepdims=True) + rng.normal(0, 0.01, (200, 3))
    sphere = fit_sphere(sph_pts)
    pl_pts = _plane_points(rng, 200, [1, 0, 1], 1.0, 0.01)
    plane = fit_plane(pl_pts)
    pts = np.vstack([cyl_pts, sph_pts, pl_pts])
    labels = np.repeat(np.arange(1, 4, dtype=np.int32), 200)
    sigma = rng.uniform(0.002, 0.02, len(pts))
    kinds, params, rms = model_table({1: cylinder, 2: sphere, 3: plane, 4: FitFailure("x", "y")}, 5)
    assert kinds.tolist() == [0, 3, 2, 1, 0]
    got = count_inliers(pts, labels, kinds, params, rms, sigma, 1.5)
    for k, model in enumerate([cylinder, sphere, plane], 1):
        sel = labels == k
        expected = np.count_nonzero(np.abs(model.distances(pts[sel])) <= 1.5 * np.maximum(sigma[sel], model.rms))
        assert got[k] == expected
    assert got[0] == 0 and got[4] == 0


def test_grow_rings_adds_one_ring_per_iteration_and_respects_the_model():
    h, w = 9, 9
    v, u = np.mgrid[0:h, 0:w].astype(float)
    xyz = np.dstack([u * 0.05, v * 0.05, np.full((h, w), 2.0)])
    xyz[0, 0, 2] = 2.2  # off the plane: never taken
    labels = np.zeros((h, w), np.int32)
    labels[4, 4] = 1
    kinds, params, rms = model_table({1: Plane([0, 0, 1], 2.0, 0.001, 1)}, 2)
    sigma = np.full(h * w, 0.002)
    ranges = np.linalg.norm(xyz, axis=2).ravel()
    added = grow_rings(xyz.reshape(-1, 3), labels, kinds, params, rms, sigma, ranges, 2, 3.0, 0.1, 0.05)
    manhattan = np.abs(v - 4) + np.abs(u - 4)
    assert added == 12 and ((labels == 1) == (manhattan <= 2)).all()
    grow_rings(xyz.reshape(-1, 3), labels, kinds, params, rms, sigma, ranges, 20, 3.0, 0.1, 0.05)
    assert labels[0, 0] == 0 and (labels.ravel()[1:] == 1).all()


@pytest.mark.parametrize("seed", range(3))
def test_grow_rings_in_a_box_holding_the_growing_regions_equals_the_whole_grid(seed):
    # regions that do not grow all over a plane, leftovers everywhere, two growing blobs:
    # looking for the growth in the blobs' box grown by the rings gives the same labels,
    # and a box that cuts the blobs off grows nothing beyond it
    rng = np.random.default_rng(seed)
    h, w = 40, 60
    v, u = np.mgrid[0:h, 0:w].astype(float)
    xyz = np.dstack([u * 0.01, v * 0.01, 2.0 + rng.normal(0, 0.001, (h, w))])
    labels = rng.integers(1, 4, (h, w)).astype(np.int32)
    labels[rng.random((h, w)) < 0.3] = 0
    labels[10:16, 20:27] = 0
    labels[12:14, 22:25] = 7
    labels[20:24, 30:33] = 8
    models = {k: Plane([0, 0, 1], 2.0, 0.001, 1) for k in (7, 8)}
    kinds, params, rms = model_table(models, 9)
    sigma = np.full(h * w, 0.002)
    ranges = np.linalg.norm(xyz, axis=2).ravel()
    whole = labels.copy()
    added = grow_rings(xyz.reshape(-1, 3), whole, kinds, params, rms, sigma, ranges, 2, 3.0, 0.1, 0.05)
    boxed = labels.copy()
    again = grow_rings(xyz.reshape(-1, 3), boxed, kinds, params, rms, sigma, ranges, 2, 3.0, 0.1, 0.05,
                       12 - 2, 24 + 2, 22 - 2, 33 + 2)
    assert added > 10 and again == added
    np.testing.assert_array_equal(boxed, whole)
    cut = labels.copy()
    grow_rings(xyz.reshape(-1, 3), cut, kinds, params, rms, sigma, ranges, 1, 3.0, 0.1, 0.05, 0, 18, 0, w)
    assert (cut[18:] == labels[18:]).all() and (cut == 7).sum() > (labels == 7).sum()
    # each blob's own box grown by the rings (overlapping or not) gives the same labels as
    # the box holding both; leaving the second blob's box out leaves that blob ungrown
    from rangeseg_o3d.kernels import grow_rings_in_boxes

    for boxes in ([[12 - 2, 14 + 2, 22 - 2, 25 + 2], [20 - 2, 24 + 2, 30 - 2, 33 + 2]],
                  [[12 - 2, 14 + 2, 22 - 2, 25 + 2], [20 - 2, 24 + 2, 30 - 2, 33 + 2], [11, 22, 21, 32]]):
        each = labels.copy()
        grown = grow_rings_in_boxes(xyz.reshape(-1, 3), each, kinds, params, rms, sigma, ranges, 2, 3.0, 0.1, 0.05,
                                    np.array(boxes, np.int64))
        assert grown == added
        np.testing.assert_array_equal(each, whole)
    first = labels.copy()
    grow_rings_in_boxes(xyz.reshape(-1, 3), first, kinds, params, rms, sigma, ranges, 2, 3.0, 0.1, 0.05,
                        np.array([[10, 16, 20, 27]], np.int64))
    assert (first == 8).sum() == (labels == 8).sum() and (first == 7).sum() == (whole == 7).sum()


@pytest.mark.parametrize("layout", ["speckle", "blocks"])
def test_adjacency_matrix_agrees_with_shifted_pairs(layout):
    rng = np.random.default_rng(7)
    if layout == "speckle":  # runs of one pixel
        labels = rng.integers(0, 6, (30, 40)).astype(np.int32)
        labels[rng.random((30, 40)) < 0.7] = 0
    else:  # long runs: rectangles 1 to 4 pixels apart, diagonal neighbours included
        labels = np.zeros((30, 40), np.int32)
        for k, (r0, r1, c0, c1) in enumerate([(0, 10, 0, 12), (0, 10, 14, 30), (12, 20, 0, 9), (13, 29, 12, 16),
                                              (22, 30, 19, 40), (3, 8, 34, 40)], start=1):
            labels[r0:r1, c0:c1] = k
    for reach in (1, 2, 3):
        adj = adjacency_matrix(labels, int(labels.max()) + 1, reach)
        pairs = set()
        for dy in range(-reach, reach + 1):
            for dx in range(-reach, reach + 1):
                a = labels[max(0, -dy):30 - max(0, dy), max(0, -dx):40 - max(0, dx)]
                b = labels[max(0, dy):30 - max(0, -dy), max(0, dx):40 - max(0, -dx)]
                touch = (a > 0) & (b > 0) & (a != b)
                pairs.update(zip(np.minimum(a, b)[touch].tolist(), np.maximum(a, b)[touch].tolist()))
        got = set(zip(*np.nonzero(np.triu(adj))))
        assert got == {(int(p), int(q)) for p, q in pairs}
        assert (adj == adj.T).all()
        assert region_adjacency(labels, reach=reach) == pairs


def test_block_means_are_nan_aware_tile_means():
    rng = np.random.default_rng(8)
    xyz = rng.normal(size=(25, 31, 3))
    xyz[rng.random((25, 31)) < 0.3] = np.nan
    xyz[:6, :6] = np.nan     # an empty tile
    xyz[6:12, :4] = np.nan   # a tile with 12 of 36 valid: under min_fraction 0.5
    xyz[6:12, 4:6] = 1.0
    means, counts = block_means(xyz, 6, 0.0)
    assert means.shape == (5, 6, 3) and counts.dtype == np.int64
    for br in range(5):
        for bc in range(6):
            tile = xyz[6 * br:6 * br + 6, 6 * bc:6 * bc + 6].reshape(-1, 3)
            ok = ~np.isnan(tile[:, 2])
            assert counts[br, bc] == ok.sum()
            if ok.any():
                np.testing.assert_allclose(means[br, bc], tile[ok].mean(0), rtol=1e-12)
                # bit for bit the sums in raster order (rows in turn, each left to right)
                # over the count: the means the tile models were fitted on
                sums = [0.0, 0.0, 0.0]
                for point in tile[ok]:
                    sums = [total + float(v) for total, v in zip(sums, point)]
                assert means[br, bc].tolist() == [total / int(ok.sum()) for total in sums]
    assert np.isnan(means[0, 0]).all() and counts[0, 0] == 0
    half, half_counts = tile_means(xyz, 6, min_fraction=0.5)
    assert half_counts[1, 0] == 12 and np.isnan(half[1, 0]).all()
    # NaN exactly where fewer than half of the 36 tile pixels are valid (the partial last
    # row of tiles counts its missing pixels as invalid)
    assert (np.isnan(half[..., 2]) == (half_counts < 18)).all()
    kept = half_counts >= 18
    np.testing.assert_allclose(half[kept], means[kept], rtol=1e-12)
    with pytest.raises(ValueError, match="block must be >= 1"):
        tile_means(xyz, 0)


def test_region_indices_group_pixels_by_label_in_order():
    from rangeseg_o3d.fitting.region_fitter import region_indices

    rng = np.random.default_rng(9)
    labels = rng.integers(0, 7, (13, 17)).astype(np.int32)
    labels[labels == 4] = 0  # a gap in the numbering
    groups = region_indices(labels)
    assert sorted(groups) == [k for k in range(1, 7) if k != 4]
    for k, idx in groups.items():
        np.testing.assert_array_equal(idx, np.flatnonzero(labels.ravel() == k))
    assert region_indices(np.zeros((3, 3), np.int32)) == {}
    assert region_indices(np.zeros((0, 3), np.int32)) == {}
    big = region_indices(np.full((2, 2), 70000, np.int64))
    assert list(big) == [70000] and big[70000].tolist() == [0, 1, 2, 3]


def test_region_adjacency_beyond_the_matrix_limit_uses_shifted_pairs():
    # more than 4096 labels: pairs are collected per shift instead of in an n x n matrix
    labels = np.zeros((6, 9), np.int32)
    labels[:, :3] = 5000
    labels[:, 4:] = 5001  # pixels two columns apart: within reach 2, not within reach 1
    labels[0, 8] = 7
    assert region_adjacency(labels, reach=2) == {(5000, 5001), (7, 5001)}
    assert region_adjacency(labels, reach=1) == {(7, 5001)}


def test_largest_piece_matches_opencv_components():
    import cv2

    from rangeseg_o3d.kernels import largest_piece

    rng = np.random.default_rng(7)
    checked = 0
    for _ in range(300):
        h, w = rng.integers(1, 20, 2)
        mask = rng.random((h, w)) < rng.random()
        idx = np.flatnonzero(mask)
        if idx.size == 0:
            assert largest_piece(idx.astype(np.int64), int(w)).size == 0
            continue
        n, comp = cv2.connectedComponents(mask.astype(np.uint8), connectivity=4)
        sizes = np.bincount(comp.ravel(), minlength=n)
        sizes[0] = 0  # background
        expected = np.flatnonzero(comp.ravel() == np.argmax(sizes))  # ties: first in raster order
        assert np.array_equal(largest_piece(idx.astype(np.int64), int(w)), expected)
        checked += 1
    assert checked > 250


def test_member_pixels_are_the_flat_indices_of_the_chosen_labels():
    from rangeseg_o3d.kernels import member_pixels

    rng = np.random.default_rng(8)
    labels = rng.integers(-1, 6, (7, 9)).astype(np.int32)
    members = np.array([True, False, True, False, False, True])  # label 0 never counts
    expected = np.flatnonzero(np.isin(labels, [2, 5]))
    np.testing.assert_array_equal(member_pixels(labels, members), expected)
    assert member_pixels(labels, np.zeros(6, bool)).size == 0


@pytest.mark.parametrize("seed", range(3))
def test_member_pixels_and_label_boxes_on_runs_of_labels(seed):
    # labels in runs along the rows, as a label image has them (the kernels take a run at a
    # time), runs crossing row ends, labels 0, negative and beyond the table left out
    from rangeseg_o3d.kernels import label_boxes, member_pixels

    rng = np.random.default_rng(seed)
    runs = rng.integers(1, 30, 200)
    flat = np.repeat(rng.integers(-1, 9, runs.size), runs)[:24 * 31].astype(np.int32)
    labels = flat.reshape(24, 31)
    members = rng.random(7) < 0.5
    wanted = [k for k in range(1, 7) if members[k]]
    np.testing.assert_array_equal(member_pixels(labels, members), np.flatnonzero(np.isin(labels, wanted)))
    boxes = label_boxes(labels, 7)
    for k in range(7):
        rows, cols = np.nonzero(labels == k)
        if k == 0 or not rows.size:
            assert boxes[k].tolist() == [24, 0, 31, 0]
        else:
            assert boxes[k].tolist() == [rows.min(), rows.max() + 1, cols.min(), cols.max() + 1]


@pytest.mark.parametrize("seed", range(4))
def test_label_boxes_on_long_runs_against_numpy(seed):
    # runs longer than the kernel's eight-pixel test, ending anywhere in a block of eight
    # and at rows' ends (widths not a multiple of eight), against each label's nonzero
    from rangeseg_o3d.kernels import label_boxes

    rng = np.random.default_rng(seed)
    h, w = 41, [61, 64, 67, 9][seed]
    runs = rng.integers(1, 90, 600)
    labels = np.repeat(rng.integers(-1, 12, runs.size), runs)[:h * w].astype(np.int32).reshape(h, w)
    labels[7] = 3  # a whole row of one label
    boxes = label_boxes(labels, 10)
    assert boxes.shape == (10, 4)
    for k in range(10):
        rows, cols = np.nonzero(labels == k)
        if k == 0 or not rows.size:
            assert boxes[k].tolist() == [h, 0, w, 0]
        else:
            assert boxes[k].tolist() == [rows.min(), rows.max() + 1, cols.min(), cols.max() + 1]


@pytest.mark.parametrize("seed", range(4))
def test_group_by_label_matches_a_stable_sort(seed):
    # runs of one label (as along image rows) and labels outside 0..n-1 (left out)
    rng = np.random.default_rng(seed)
    runs = rng.integers(1, 40, 400)
    labels = np.repeat(rng.integers(-2, 9, runs.size), runs).astype(np.int32)
    n = 7
    order, starts = group_by_label(labels, n)
    for k in range(n):
        np.testing.assert_array_equal(order[starts[k]:starts[k + 1]], np.flatnonzero(labels == k))
    assert starts[-1] == np.count_nonzero((labels >= 0) & (labels < n))
    empty_order, empty_starts = group_by_label(np.zeros(0, np.int32), 3)
    assert empty_order.size == 0 and (empty_starts == 0).all()


def _runs_and_members(seed):
    # label runs along a flat image (negatives, 0 and labels beyond the mask among them) and
    # a mask of labels 0, 2, 5 and 8
    rng = np.random.default_rng(seed)
    runs = rng.integers(1, 40, 400)
    labels = np.repeat(rng.integers(-2, 12, runs.size), runs).astype(np.int32)
    members = np.zeros(9, bool)
    members[[0, 2, 5, 8]] = True
    return labels, members


@pytest.mark.parametrize("seed", range(3))
def test_group_members_and_region_indices_of_some_labels_match_the_full_grouping(seed):
    # only the member labels are grouped (each in increasing order); others, 0, negative
    # labels and labels beyond the mask are left out; region_indices(only=) is the full
    # grouping's restriction, a wanted label without pixels absent as in the full one
    from rangeseg_o3d.fitting.region_fitter import region_indices
    from rangeseg_o3d.kernels import group_members

    labels, members = _runs_and_members(seed)
    order, starts = group_members(labels, members)
    for k in range(9):
        expected = np.flatnonzero(labels == k) if k in (2, 5, 8) else np.zeros(0, np.int64)
        np.testing.assert_array_equal(order[starts[k]:starts[k + 1]], expected)
    assert starts[-1] == np.count_nonzero(np.isin(labels, [2, 5, 8]))
    grid = labels[:(labels.size // 20) * 20].reshape(-1, 20)
    grid = np.where(grid == 7, 0, grid)
    full = region_indices(grid)
    some = region_indices(grid, only={3, 7, 11, 40})
    assert sorted(some) == [k for k in (3, 11) if k in full]
    for k, idx in some.items():
        np.testing.assert_array_equal(idx, full[k])


@pytest.mark.parametrize("seed", range(3))
def test_member_counts_then_group_counted_of_fewer_labels_match_group_members(seed):
    # the counts of some labels (0, negatives and labels beyond the mask not counted), then
    # the grouping of a subset of them from those counts: group_members of the subset
    from rangeseg_o3d.kernels import group_counted, group_members, member_counts

    labels, members = _runs_and_members(seed)
    counts = member_counts(labels, members)
    assert counts.shape == (9,)
    np.testing.assert_array_equal(counts, [np.count_nonzero(labels == k) if k in (2, 5, 8) else 0 for k in range(9)])
    fewer = np.zeros(9, bool)
    fewer[[0, 5, 8]] = True
    order, starts = group_counted(labels, fewer, counts)
    expected_order, expected_starts = group_members(labels, fewer)
    np.testing.assert_array_equal(order, expected_order)
    np.testing.assert_array_equal(starts, expected_starts)
    assert order.size == np.count_nonzero(np.isin(labels, [5, 8]))


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("target", [1, 3, 7, 50, 10_000])
def test_even_samples_are_every_step_th_of_group_members(seed, target):
    # each member label's every max(1, count // target)-th flat index, in increasing order,
    # and its count (0, negatives and labels beyond the mask left out); region_samples is
    # region_indices' restriction sliced the same way
    from rangeseg_o3d.fitting.region_fitter import region_indices, region_samples
    from rangeseg_o3d.kernels import even_samples, group_members

    labels, members = _runs_and_members(seed)
    order, starts, counts = even_samples(labels, members, target)
    full_order, full_starts = group_members(labels, members)
    for k in range(9):
        idx = full_order[full_starts[k]:full_starts[k + 1]]
        assert counts[k] == (np.count_nonzero(labels == k) if k in (2, 5, 8) else 0)
        np.testing.assert_array_equal(order[starts[k]:starts[k + 1]], idx[:: max(1, idx.size // target)])
    grid = labels[:(labels.size // 20) * 20].reshape(-1, 20)
    grid = np.where(grid < 0, 0, grid)
    full = region_indices(grid, only={2, 3, 11, 40})
    some = region_samples(grid, {2, 3, 11, 40}, target)
    assert sorted(some) == sorted(full)
    for k, (sample, count) in some.items():
        assert count == full[k].size
        np.testing.assert_array_equal(sample, full[k][:: max(1, count // target)])


@pytest.mark.parametrize("only", [{2}, {5, 3}, {3, 10**9}, {11, -4, 0}, set(), {2**40}])
def test_region_indices_and_samples_of_labels_below_or_beyond_the_grids_largest(only):
    # the mask reaches the largest wanted label, not the grid's: larger labels on the grid are
    # passed over, a wanted label beyond the pixel count is bounded by the grid's largest
    from rangeseg_o3d.fitting.region_fitter import region_indices, region_samples

    labels, _ = _runs_and_members(4)
    grid = np.where(labels < 0, 0, labels)[:(labels.size // 20) * 20].reshape(-1, 20)
    full = region_indices(grid)
    expected = {k: full[k] for k in sorted(only) if k in full}
    got = region_indices(grid, only=only)
    assert list(got) == list(expected)
    for k in expected:
        np.testing.assert_array_equal(got[k], expected[k])
    samples = region_samples(grid, only, 5)
    assert list(samples) == list(expected)
    for k, idx in expected.items():
        np.testing.assert_array_equal(samples[k][0], idx[:: max(1, idx.size // 5)])


def test_batched_planes_of_a_few_blobs_in_a_large_image_are_those_of_the_blobs_alone():
    # Mostly unlabelled images (refinement's leftovers) are summed over their labelled
    # pixels only: the answer must be the one for those pixels given on their own.
    rng = np.random.default_rng(3)
    xyz = rng.normal(size=(5000, 3))
    labels = np.zeros(5000, np.int32)
    for k, (normal, d) in enumerate([((0, 0, 1), 2.0), ((1, 0.2, 0), 1.5), ((0, 1, 1), 3.0)], start=1):
        where = rng.choice(np.flatnonzero(labels == 0), 300, replace=False)
        labels[where] = k
        xyz[where] = _plane_points(rng, 300, normal, d, 0.002)
    sparse = fit_planes_batch(xyz, labels)
    inside = labels > 0
    dense = fit_planes_batch(xyz[inside], labels[inside])
    assert sorted(sparse) == sorted(dense) == [1, 2, 3]
    for k in sparse:
        np.testing.assert_array_equal(sparse[k].normal, dense[k].normal)
        assert (sparse[k].d, sparse[k].rms, sparse[k].inliers) == (dense[k].d, dense[k].rms, dense[k].inliers)
        assert sparse[k].inliers == 300 and sparse[k].rms < 0.003


def test_piece_ids_number_the_pieces_as_opencv_does():
    import cv2

    from rangeseg_o3d.kernels import largest_piece, piece_ids

    rng = np.random.default_rng(7)
    for density in (0.3, 0.5, 0.6, 0.9):
        mask = (rng.random((30, 41)) < density).astype(np.uint8)
        idx = np.flatnonzero(mask)
        ids, sizes = piece_ids(idx, mask.shape[1])
        n, comp = cv2.connectedComponents(mask, connectivity=4, ltype=cv2.CV_32S)
        assert np.array_equal(ids, comp.ravel()[idx] - 1)
        assert np.array_equal(sizes, np.bincount(comp.ravel()[idx] - 1, minlength=n - 1))
        biggest = np.flatnonzero(comp.ravel() == 1 + int(np.argmax(sizes)))
        assert np.array_equal(largest_piece(idx, mask.shape[1]), biggest)
    # pixels scattered over a wide grid (no piece crosses a row's end), and one column
    for shape, density in (((60, 640), 0.05), ((60, 640), 0.7), ((25, 1), 0.6)):
        mask = (rng.random(shape) < density).astype(np.uint8)
        idx = np.flatnonzero(mask)
        ids, sizes = piece_ids(idx, shape[1])
        n, comp = cv2.connectedComponents(mask, connectivity=4, ltype=cv2.CV_32S)
        assert np.array_equal(ids, comp.ravel()[idx] - 1)
        assert np.array_equal(sizes, np.bincount(comp.ravel()[idx] - 1, minlength=n - 1))
    ids, sizes = piece_ids(np.array([], np.int64), 5)
    assert ids.size == 0 and sizes.size == 0
    ids, sizes = piece_ids(np.array([12], np.int64), 5)
    assert ids.tolist() == [0] and sizes.tolist() == [1]
    assert largest_piece(np.array([], np.int64), 5).size == 0


def test_labels_near_are_the_labels_under_the_dilated_mask():
    import cv2

    from rangeseg_o3d.kernels import labels_near

    rng = np.random.default_rng(5)
    for trial in range(60):
        h, w = rng.integers(1, 30), rng.integers(1, 40)
        # labels beyond the kernel's first mask (64) and far beyond its doubling
        top = rng.choice([rng.integers(1, 90), 100_000])
        labels = rng.integers(0, top, (h, w)).astype(np.int32)
        mask = (rng.random((h, w)) < rng.uniform(0.01, 0.6)).astype(np.uint8)
        idx = np.flatnonzero(mask)
        for reach in (0, 1, 2, 3):
            near = cv2.dilate(mask, np.ones((2 * reach + 1, 2 * reach + 1), np.uint8)).astype(bool)
            expected = np.unique(labels[near])
            np.testing.assert_array_equal(labels_near(labels, idx, reach), expected[expected > 0])
    assert labels_near(np.ones((3, 3), np.int32), np.array([], np.int64), 2).size == 0


def test_free_pixels_is_numpys():
    from rangeseg_o3d.kernels import free_pixels

    rng = np.random.default_rng(11)
    for trial in range(20):
        shape = (int(rng.integers(1, 30)), int(rng.integers(1, 40)))
        labels = np.where(rng.random(shape) < 0.4, 0, rng.integers(1, 200, shape)).astype(np.int32)
        valid = rng.random(shape) < 0.8
        np.testing.assert_array_equal(free_pixels(labels, valid), np.flatnonzero((labels == 0) & valid))


def _reference_ray_steps(xyz):
    # the angles between neighbouring viewing directions, pair by pair in numpy
    def angle(a, b):
        na, nb = np.linalg.norm(a, axis=-1), np.linalg.norm(b, axis=-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            chord = np.linalg.norm(a / na[..., None] - b / nb[..., None], axis=-1)
            out = 2.0 * np.arcsin(np.minimum(chord / 2.0, 1.0))
        return np.where((na > 0) & (nb > 0), out, np.nan)

    h, w = xyz.shape[:2]
    out = np.full((2, h, w), np.nan)
    if h > 1:
        out[0, :-1] = angle(xyz[:-1], xyz[1:])
        out[0, -1] = out[0, -2]
    if w > 1:
        out[1, :, :-1] = angle(xyz[:, :-1], xyz[:, 1:])
        out[1, :, -1] = out[1, :, -2]
    return out


def test_ray_steps_equal_the_pairwise_angles_with_invalid_and_zero_points():
    from rangeseg_o3d.kernels import ray_steps

    rng = np.random.default_rng(8)
    for shape in ((12, 17), (1, 9), (9, 1), (2, 2), (1, 1)):
        xyz = rng.normal(0.0, 1.0, (*shape, 3)) + (0.0, 0.0, 3.0)
        xyz[rng.random(shape) < 0.2] = np.nan
        xyz[rng.random(shape) < 0.1] = 0.0  # a zero point has no direction
        got, want = ray_steps(xyz), _reference_ray_steps(xyz)
        assert np.array_equal(np.isnan(got), np.isnan(want))
        assert np.allclose(got[~np.isnan(got)], want[~np.isnan(want)], rtol=1e-9, atol=1e-12)
    opposite = np.array([[[1.0, 0, 0], [-2.0, 0, 0]]])  # antiparallel: pi, chord clipped
    assert ray_steps(opposite)[1, 0, 0] == pytest.approx(np.pi)


def test_ranges_and_noise_equal_numpys_where_and_noise_model_bit_for_bit():
    from rangeseg_o3d.kernels import ranges_and_noise
    from rangeseg_o3d.sensor import NoiseModel

    rng = np.random.default_rng(9)
    ranges = rng.uniform(0.3, 9.0, (37, 23))
    valid = rng.random(ranges.shape) < 0.8
    ranges[~valid & (rng.random(ranges.shape) < 0.5)] = np.nan  # invalid pixels hold anything
    for model in (NoiseModel(0.001, 0.001425), NoiseModel(0.005, 0.0), NoiseModel(0.0, 2.5e-3)):
        got_ranges, got_sigma = ranges_and_noise(ranges, valid, model.sigma0, model.sigma_quadratic)
        want_ranges = np.where(valid, ranges, np.nan)
        assert np.array_equal(got_ranges, want_ranges, equal_nan=True)
        assert np.array_equal(got_sigma, model.sigma(want_ranges), equal_nan=True)
    none = ranges_and_noise(ranges, np.zeros(ranges.shape, bool), 0.001, 0.0)
    assert np.isnan(none[0]).all() and np.isnan(none[1]).all()


def _settle_row(points, labels, *, margin=1.0, plane_margin=0.0, wrap=False, sigma=0.01):
    """settle_borders on a 1 x n row: label 1 the cylinder sqrt(x^2 + z^2) = 1 (axis y),
    label 2 the plane z = 1 (they touch along x = 0, z = 1); returns the new labels."""
    from rangeseg_o3d.fitting.primitives import Cylinder
    from rangeseg_o3d.kernels import settle_borders

    models = {1: Cylinder(axis=np.array([0.0, 1.0, 0.0]), point=np.zeros(3), radius=1.0, rms=0.0, inliers=0),
              2: Plane(normal=np.array([0.0, 0.0, 1.0]), d=1.0, rms=0.0, inliers=0)}
    kinds, params, rms = model_table(models, 3)
    out = np.array([labels], dtype=np.int32)
    n = out.shape[1]
    settle_borders(np.asarray(points, dtype=np.float64), out, kinds, params, rms, np.full(n, sigma),
                   np.ones(n), 1, 3.0, margin, 0.1, 0.05, plane_margin, wrap)
    return out[0].tolist()


def _off_cylinder(off):  # on the plane z = 1, `off` from the cylinder
    return [np.sqrt((1 + off) ** 2 - 1), 0.0, 1.0]


def _off_plane(off):  # on the cylinder, `off` below the plane
    return [np.sqrt(1 - (1 - off) ** 2), 0.0, 1 - off]


def test_settle_borders_gives_ties_between_a_curved_region_and_a_plane_to_the_plane():
    sigma = 0.01
    # column 1 (the cylinder's) lies on the plane, half a sigma off the cylinder; column 2
    # (the plane's) on the cylinder, half a sigma off the plane
    row = [_off_plane(0.2), _off_cylinder(0.5 * sigma), _off_plane(0.5 * sigma), _off_cylinder(0.2)]
    assert _settle_row(row, [1, 1, 2, 2], plane_margin=0.0) == [1, 2, 2, 2]
    # with the margin both ways nothing moves; a plane never gives a tie to a curved region
    assert _settle_row(row, [1, 1, 2, 2], plane_margin=1.0) == [1, 1, 2, 2]
    assert _settle_row(row, [1, 1, 2, 2], margin=0.0, plane_margin=0.0) == [1, 2, 1, 2]


def test_settle_borders_crosses_the_seam_of_a_full_turn_only_when_asked():
    sigma = 0.01
    # the last column (the cylinder's) lies on the plane 3 sigmas off the cylinder; its
    # neighbour across the seam is the plane's first column
    row = [_off_cylinder(0.2), _off_cylinder(0.2), _off_plane(0.2), _off_cylinder(3 * sigma)]
    assert _settle_row(row, [2, 2, 1, 1], wrap=False) == [2, 2, 1, 1]
    assert _settle_row(row, [2, 2, 1, 1], wrap=True) == [2, 2, 1, 2]


def _settle_by_passes(xyz, labels, kinds, params, rms, sigma, ranges, iterations, k_sigma, margin, jump_ratio,
                      jump_min, plane_margin, wrap):
    # settle_borders' rule as its docstring states it, one pass over the whole grid per
    # iteration, in numpy; returns (labels, moved)
    h, w = labels.shape
    labels = labels.copy()
    points = xyz.reshape(h, w, 3)
    sig, rng = sigma.reshape(h, w), ranges.reshape(h, w)

    def distance(k, p):  # (planes only here: normal . x = d)
        return abs(float(np.dot(params[k][:3], p)) - params[k][3])

    moved = 0
    for _ in range(iterations):
        new = labels.copy()
        for r in range(h):
            for c in range(w):
                own = labels[r, c]
                if own <= 0 or kinds[own] == 0:
                    continue
                steps = [(r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)]
                if wrap:
                    steps[2], steps[3] = (r, (c - 1) % w), (r, (c + 1) % w)
                steps = [(a, b) for a, b in steps if 0 <= a < h and 0 <= b < w]
                own_score = distance(own, points[r, c]) / max(sig[r, c], rms[own])
                best, best_score = 0, k_sigma
                for a, b in steps:
                    k = labels[a, b]
                    if k == own or k <= 0 or kinds[k] == 0:
                        continue
                    if abs(rng[r, c] - rng[a, b]) > max(jump_min, jump_ratio * min(rng[r, c], rng[a, b])):
                        continue
                    score = distance(k, points[r, c]) / max(sig[r, c], rms[k])
                    if score < best_score and score < own_score - margin:
                        best, best_score = k, score
                if best:
                    new[r, c] = best
        changed = int(np.count_nonzero(new != labels))
        if not changed:
            break
        labels, moved = new, moved + changed
    return labels, moved


@pytest.mark.parametrize("seed, wrap", [(0, False), (1, True), (2, False)])
def test_settle_borders_asks_again_only_where_labels_changed_with_the_same_answers(seed, wrap):
    # the kernel asks, after its first pass, only the pixels that moved and their neighbours:
    # the same labels and count as a pass over the grid per iteration (planes tilted against
    # each other, noisy points, range jumps and unlabelled pixels among them)
    from rangeseg_o3d.kernels import settle_borders

    rng = np.random.default_rng(seed)
    h, w, n = 24, 31, 6
    labels = np.repeat(np.repeat(rng.integers(0, n, (6, 8)), 4, axis=0), 4, axis=1)[:h, :w].astype(np.int32)
    models = {k: Plane(normal=(v := rng.normal(size=3)) / np.linalg.norm(v), d=float(rng.normal()), rms=0.0, inliers=0)
              for k in range(1, n)}
    kinds, params, rms = model_table(models, n)
    rms = rng.uniform(0.0, 0.3, n)
    xyz = rng.normal(0.0, 1.0, (h * w, 3))
    sigma = rng.uniform(0.2, 0.6, h * w)
    ranges = np.linalg.norm(xyz, axis=1) + rng.uniform(0.0, 0.5, h * w)
    for iterations in (1, 3, 20):
        expected, expected_moved = _settle_by_passes(xyz, labels, kinds, params, rms, sigma, ranges, iterations,
                                                     3.0, 0.5, 0.3, 0.2, 0.5, wrap)
        out = labels.copy()
        moved = settle_borders(xyz, out, kinds, params, rms, sigma, ranges, iterations, 3.0, 0.5, 0.3, 0.2, 0.5, wrap)
        assert moved == expected_moved and np.array_equal(out, expected)
    assert expected_moved > 20  # (the case moves pixels over several iterations)


def _runs_of_labels(rng, n_pixels=3000, n_labels=6):
    # label runs of random lengths (as along image rows), zeros and NaN points among them
    labels = np.repeat(rng.integers(0, n_labels, 200), rng.integers(1, 40, 200))[:n_pixels].astype(np.int32)
    pts = rng.normal(0.0, 3.0, (labels.size, 3))
    pts[rng.random(labels.size) < 0.05] = np.nan
    return pts, labels


def test_label_moments_sum_in_pixel_order_exactly():
    # the kernel keeps a run's sums in registers: the same additions, in pixel order, as one by one
    from rangeseg_o3d.kernels import label_moments

    pts, labels = _runs_of_labels(np.random.default_rng(5))
    expected = np.zeros((6, 10))
    for (x, y, z), k in zip(pts.tolist(), labels.tolist()):
        if k > 0 and np.isfinite([x, y, z]).all():
            row = expected[k]
            for j, value in enumerate((1.0, x, y, z, x * x, x * y, x * z, y * y, y * z, z * z)):
                row[j] = row[j] + value
    assert np.array_equal(label_moments(pts, labels, 6), expected)



@pytest.mark.parametrize("seed", range(3))
def test_member_moments_are_the_members_rows_of_label_moments_exactly(seed):
    # the members' rows to the bit (their pixels added in the same order), zero rows for the
    # other labels; negative labels and labels beyond the table left out; region_moments'
    # ``only`` and the refits from moments give the same values as over every label
    from rangeseg_o3d.fitting.batch_planes import region_moments
    from rangeseg_o3d.kernels import label_moments, member_moments

    rng = np.random.default_rng(seed)
    pts, labels = _runs_of_labels(rng)
    labels[rng.random(labels.size) < 0.05] = -1
    every = label_moments(pts, labels, 6)
    for members in (np.ones(6, bool), np.zeros(6, bool), rng.random(6) < 0.5, rng.random(4) < 0.7):
        got = member_moments(pts, labels, members)
        assert got.shape == (members.size, 10)
        for k in range(members.size):
            expected = every[k] if members[k] and k > 0 else np.zeros(10)
            assert np.array_equal(got[k], expected)
    only = [2, 5, 9]  # (9: no such label)
    rows = region_moments(pts, labels, only=only)
    assert np.array_equal(rows[[2, 5]], every[[2, 5]]) and not rows[[1, 3, 4]].any()


def test_member_centres_are_the_means_of_the_gathered_points_exactly():
    # planes_into_curved's convex test reads these centres where it read the mean of each
    # region's gathered points: the same sums, so the same labels; NaN points count (a NaN mean)
    from rangeseg_o3d.kernels import member_centres

    pts, labels = _runs_of_labels(np.random.default_rng(7))
    pts = np.nan_to_num(pts) * 37.0 + 1000.0  # far from the origin: another order of additions would show
    pts[np.flatnonzero(labels == 3)[:1]] = np.nan
    members = np.array([False, True, False, True, True, True])
    sums = member_centres(pts, labels, members)
    for k in range(6):
        idx = np.flatnonzero(labels == k)
        if not members[k] or k == 0:
            assert (sums[k] == 0).all()
            continue
        assert sums[k, 0] == idx.size > 0
        assert np.array_equal(sums[k, 1:] / sums[k, 0], pts[idx].mean(axis=0), equal_nan=True)
    assert np.isnan(sums[3, 1:]).all() and np.isfinite(sums[[1, 4, 5], 1:]).all()


def test_distance_stats_sum_in_pixel_order_exactly():
    from rangeseg_o3d.kernels import distance_stats

    rng = np.random.default_rng(6)
    pts, labels = _runs_of_labels(rng)
    models = {1: Plane(normal=np.array([0.0, 0.0, 1.0]), d=1.0, rms=0.5, inliers=0),
              2: Plane(normal=np.array([0.6, 0.8, 0.0]), d=0.5, rms=2.0, inliers=0),
              4: Plane(normal=np.array([1.0, 0.0, 0.0]), d=2.0, rms=1.0, inliers=0)}  # 3, 5: no model
    kinds, params, rms = model_table(models, 6)
    sigma = rng.uniform(0.5, 3.0, labels.size)
    inliers, squares, counts = distance_stats(pts, labels, kinds, params, rms, sigma, 2.0)
    expected_in, expected_sq, expected_n = np.zeros(6, np.int64), np.zeros(6), np.zeros(6, np.int64)
    for i, ((x, y, z), k) in enumerate(zip(pts.tolist(), labels.tolist())):
        if k not in models or not np.isfinite([x, y, z]).all():
            continue
        a, b, c = params[k, :3].tolist()
        dist = abs((x * a + y * b + z * c) - float(params[k, 3]))  # the kernel's operations, in order
        expected_n[k] += 1
        expected_sq[k] = expected_sq[k] + dist * dist
        expected_in[k] += dist <= 2.0 * max(float(sigma[i]), float(rms[k]))
    assert np.array_equal(counts, expected_n) and np.array_equal(inliers, expected_in)
    assert np.array_equal(squares, expected_sq)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_label_noise_sums_equal_the_bincount_of_the_finite_noise_bit_for_bit(seed):
    # merge's per-label noise sums: one compiled pass in pixel order, numpy's bincount of
    # the noise with non-finite values as 0 (its first n rows: labels past them skipped)
    from rangeseg_o3d.kernels import label_noise_sums

    rng = np.random.default_rng(seed)
    labels = rng.integers(0, 40, 5000).astype(np.int32 if seed % 2 else np.int64)
    sigma = rng.uniform(0.001, 0.05, 5000) * 10.0 ** rng.uniform(-3, 3, 5000)
    sigma[rng.random(5000) < 0.1] = np.nan
    sigma[rng.random(5000) < 0.02] = np.inf
    for n in (40, 25, 60):
        want = np.bincount(labels, weights=np.where(np.isfinite(sigma), sigma, 0.0), minlength=n)[:n]
        got = label_noise_sums(labels, sigma, n)
        assert got.shape == (n,) and got.tobytes() == want.tobytes()


def _random_boxes(rng, shape, k):
    # k boxes (row0, row1, col0, col1) anywhere around a grid of ``shape``: overlapping,
    # empty, reaching past the border and wholly outside it
    rows = np.sort(rng.integers(-5, shape[0] + 5, (k, 2)), axis=1)
    cols = np.sort(rng.integers(-5, shape[1] + 5, (k, 2)), axis=1)
    return np.stack([rows[:, 0], rows[:, 1], cols[:, 0], cols[:, 1]], axis=1).astype(np.int64)


def _inside(shape, boxes):
    # the reference: a mask of the pixels within one of the boxes
    mask = np.zeros(shape, bool)
    for r0, r1, c0, c1 in boxes.tolist():
        mask[max(r0, 0):max(r1, 0), max(c0, 0):max(c1, 0)] = True
    return mask


def test_pixels_in_boxes_equal_numpys_within_the_boxes():
    from rangeseg_o3d.kernels import differing_in_boxes, free_pixels_in_boxes, member_pixels_in_boxes

    rng = np.random.default_rng(21)
    for trial in range(40):
        shape = (int(rng.integers(1, 30)), int(rng.integers(1, 40)))
        boxes = _random_boxes(rng, shape, int(rng.integers(0, 6)))
        inside = _inside(shape, boxes)
        a = np.where(rng.random(shape) < 0.4, 0, rng.integers(-1, 8, shape)).astype(np.int32)
        b = np.where(rng.random(shape) < 0.3, rng.integers(0, 8, shape), a).astype(np.int32)
        members = rng.random(6) < 0.5
        wanted = [k for k in range(1, 6) if members[k]]
        np.testing.assert_array_equal(member_pixels_in_boxes(a, members, boxes),
                                      np.flatnonzero(np.isin(a, wanted) & inside))
        np.testing.assert_array_equal(differing_in_boxes(a, b, boxes), np.flatnonzero((a != b) & inside))
        # the free pixels of ``b`` from those of ``a`` where the labels changed only in the boxes
        valid = rng.random(shape) < 0.8
        after = np.where(inside, b, a)
        free = np.flatnonzero((a == 0) & valid)
        got = free_pixels_in_boxes(after, valid, free, boxes)
        assert got.dtype == np.int64
        np.testing.assert_array_equal(got, np.flatnonzero((after == 0) & valid))


def test_pixels_in_no_box_are_none_and_outside_boxes_stay_as_listed():
    from rangeseg_o3d.kernels import differing_in_boxes, free_pixels_in_boxes, member_pixels_in_boxes

    labels = np.zeros((4, 5), np.int32)
    none = np.zeros((0, 4), np.int64)
    assert member_pixels_in_boxes(labels + 1, np.ones(2, bool), none).size == 0
    assert differing_in_boxes(labels, labels + 1, none).size == 0
    # no box: the listed free pixels are the answer, whatever the labels say now
    listed = np.array([0, 7, 19], np.int64)
    np.testing.assert_array_equal(free_pixels_in_boxes(labels, np.ones((4, 5), bool), listed, none), listed)
    # a box off the grid reads nothing
    off = np.array([[10, 12, 0, 5], [0, 4, -9, -1]], np.int64)
    np.testing.assert_array_equal(free_pixels_in_boxes(labels, np.ones((4, 5), bool), listed, off), listed)
