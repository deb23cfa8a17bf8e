import numpy as np
import pytest

from rangeseg_o3d.segmentation.edges import close_residual, edge_mask, jump_edges
from rangeseg_o3d.segmentation.regions import join_wrapped, label_regions, relabel_sequential, wrap_columns


def test_jump_edges_mark_the_far_side_and_scale_with_range():
    r = np.full((4, 8), 2.0)
    r[:, 4:] = 2.5
    mask = jump_edges(r, jump_ratio=0.08, jump_min=0.05)
    assert mask[:, 4].all()
    assert not mask[:, :4].any() and not mask[:, 5:].any()
    vertical = jump_edges(r.T, jump_ratio=0.08, jump_min=0.05)
    assert vertical[4].all() and vertical.sum() == 4
    # The same 0.5 m step far away (8 m) is within 8 % of the range: not a jump.
    far = r + 6.0
    assert not jump_edges(far, jump_ratio=0.08, jump_min=0.05).any()


def test_a_surface_seen_at_a_grazing_angle_is_no_jump_but_an_occlusion_onto_it_is():
    # a plane at 3 deg from grazing, seen by a 0.25 deg grid: every step is ~8 % of the range
    # (over jump_ratio) and the steps change slowly along the row
    angle, step = np.radians(3.0), np.radians(0.25)
    plane = 2.0 / (1.0 - np.arange(12) * step / np.tan(angle))  # r_k = r_0 / (1 - k step cot a)
    ranges = np.tile(plane[:8], (3, 1))
    steps = np.diff(ranges[0]) / ranges[0, :-1]
    deltas = np.diff(ranges[0])
    assert (steps > 0.08).all() and (np.abs(np.diff(deltas)) <= 0.5 * deltas[:-1]).all()
    assert jump_edges(ranges, jump_ratio=0.08, jump_min=0.05, continuation=0).sum() > 10
    # only the steps at the row's ends, which have no step on one side, stay jumps
    grazing = jump_edges(ranges, jump_ratio=0.08, jump_min=0.05)
    assert grazing[:, 1].all() and grazing[:, 7].all() and grazing.sum() == 6
    # an occluder at 1 m in front of the first four pixels: the step onto the plane has the
    # occluder's flat steps on one side, so it stays a jump (the plane's pixel is marked)
    occluded = ranges.copy()
    occluded[:, :4] = 1.0
    mask = jump_edges(occluded, jump_ratio=0.08, jump_min=0.05)
    assert mask[:, 4].all() and not mask[:, :4].any()


def test_jump_edges_ignore_nan():
    r = np.full((3, 3), 1.0)
    r[1, 1] = np.nan
    assert not jump_edges(r).any()


def test_closing_bridges_a_gap_in_an_edge_line():
    res = np.zeros((7, 7))
    res[:, 3] = 100.0
    res[3, 3] = 0.0  # a one-pixel break in the line
    closed = close_residual(res, iterations=2)
    assert closed[3, 3] == pytest.approx(100.0)
    assert closed[3, 0] == 0.0


def test_closing_clips_infinite_residuals():
    res = np.full((3, 3), np.inf)
    assert np.isfinite(close_residual(res)).all()


def test_edge_mask_and_regions():
    closed = np.zeros((6, 9), dtype=np.float32)
    closed[:, 4] = 50.0
    valid = np.ones((6, 9), bool)
    valid[0, 0] = False
    edges = edge_mask(closed, threshold=4.0, valid=valid)
    labels = label_regions(edges, min_size=5)
    assert labels.dtype == np.int32
    assert labels.max() == 2
    assert (labels[:, 4] == 0).all() and labels[0, 0] == 0
    assert np.unique(labels[:, :4][valid[:, :4]]).tolist() == [1]
    assert np.unique(labels[:, 5:]).tolist() == [2]


def test_min_size_drops_small_regions_and_diagonal_line_separates():
    edges = np.zeros((5, 5), bool)
    edges[np.arange(5), np.arange(5)] = True  # a diagonal line
    labels = label_regions(edges, min_size=1, connectivity=4)
    assert labels.max() == 2
    labels = label_regions(edges, min_size=20)
    assert labels.max() == 0


def test_label_regions_validates():
    with pytest.raises(ValueError, match="connectivity"):
        label_regions(np.zeros((3, 3), bool), connectivity=6)
    with pytest.raises(ValueError, match="shape"):
        label_regions(np.zeros(9, bool))


@pytest.mark.parametrize("call, fragment", [
    (lambda: jump_edges(np.ones((4, 4)), jump_ratio=-0.1), "jump_ratio must be a finite number >= 0; got -0.1"),
    (lambda: jump_edges(np.ones((4, 4)), jump_min=float("nan")), "jump_min must be a finite number >= 0; got nan"),
    (lambda: close_residual(np.ones((4, 4)), kernel=0), "kernel must be an integer >= 1; got 0"),
    (lambda: edge_mask(np.ones(4), threshold=0.5), r"closed must have shape \(H, W\); got \(4,\)"),
    (lambda: edge_mask(np.ones((4, 4)), threshold=0.5, valid=np.ones((3, 4), bool)),
     r"valid must have the shape of closed \(4, 4\); got \(3, 4\)"),
    (lambda: edge_mask(np.ones((4, 4)), threshold=0.5, jumps=np.ones((4, 4, 1), bool)),
     r"jumps must have the shape of closed \(4, 4\); got \(4, 4, 1\)"),
])
def test_edge_stages_name_a_bad_argument(call, fragment):
    with pytest.raises(ValueError, match=fragment):
        call()


def test_relabel_sequential():
    out = relabel_sequential(np.array([[0, 7, 7], [3, 0, 9]]))
    assert out.tolist() == [[0, 2, 2], [1, 0, 3]]


def test_region_helpers_name_a_bad_argument():
    with pytest.raises(ValueError, match="labels must be integers; got dtype float64"):
        relabel_sequential(np.array([[0.0, 2.5]]))
    with pytest.raises(ValueError, match=r"padded must be \(H, W\) integer labels; got shape \(6,\)"):
        join_wrapped(np.arange(6), 1)
    with pytest.raises(ValueError, match="pad must be an integer >= 1; got 0"):
        join_wrapped(np.zeros((2, 6), np.int32), 0)
    # the flood fill of a padded grid (wrap_columns) joins each pad to its neighbour: one region
    # across the seam, numbered 1 on the left, 2 on the right
    assert wrap_columns(np.array([[5, 0, 0, 6]]), 1).tolist() == [[6, 5, 0, 0, 6, 5]]
    assert join_wrapped(np.array([[1, 1, 0, 0, 2, 2]], np.int32), 1).tolist() == [[1, 0, 0, 1]]


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("connectivity", [4, 8])
@pytest.mark.parametrize("compiled", [False, True])
def test_label_regions_matches_the_numpy_count_and_renumbering(seed, connectivity, compiled):
    # the renumbering by lut.take, or the compiled count and renumbering (kernels.label_counts,
    # relabel), give np.bincount's sizes and lut[labels]: components of random edges, small ones dropped
    import cv2

    rng = np.random.default_rng(seed)
    edges = rng.random((37, 53)) < 0.45
    n, components = cv2.connectedComponents((~edges).astype(np.uint8), connectivity=connectivity, ltype=cv2.CV_32S)
    keep = np.zeros(n, bool)
    keep[1:] = np.bincount(components.ravel(), minlength=n)[1:] >= 3
    lut = np.zeros(n, np.int32)
    lut[keep] = np.arange(1, keep.sum() + 1, dtype=np.int32)
    labels = label_regions(edges, min_size=3, connectivity=connectivity, compiled=compiled)
    assert labels.dtype == np.int32 and np.array_equal(labels, lut[components])
    assert 1 <= labels.max() == keep.sum() < n - 1  # some components kept, some dropped
    all_edges = label_regions(np.ones((4, 5), bool), min_size=1, compiled=compiled)
    assert all_edges.dtype == np.int32 and np.array_equal(all_edges, np.zeros((4, 5), np.int32))


@pytest.mark.parametrize("ranges, quadratic", [(None, 0.0), (None, 0.002), ("image", 0.002), ("image", "image"), (2.5, 0.002)])
def test_residual_image_without_normals_takes_numbers_or_images_alike(ranges, quadratic):
    # the one-pass residual (with_normals=False) fills a number's grid itself: the same values
    # as the numpy steps (with_normals=True), for ranges and noise scales given as numbers or images
    from rangeseg_o3d.segmentation.residual import _grid_of, residual_image

    rng = np.random.default_rng(3)
    xyz = np.dstack([*np.meshgrid(np.linspace(-1, 1, 9), np.linspace(-0.5, 0.5, 7)), np.full((7, 9), 3.0)])
    xyz = xyz + rng.normal(0.0, 0.004, xyz.shape)
    xyz[2, 3] = np.nan
    r = np.linalg.norm(xyz, axis=2) if ranges == "image" else ranges
    scale = rng.uniform(0.5, 1.0, (7, 9)) if quadratic == "image" else 1.0
    q = 0.002 if quadratic == "image" else quadratic
    fast, _ = residual_image(xyz, ranges=r, sigma_quadratic=q, noise_scale=scale, with_normals=False)
    slow, _ = residual_image(xyz, ranges=r, sigma_quadratic=q, noise_scale=scale, with_normals=True)
    assert np.allclose(fast, slow, rtol=1e-9) and np.isinf(fast[2, 3]) and np.isfinite(fast[3:5, 4:6]).all()
    for value in (0.0, 2.5, np.full((7, 9), 1.5)):
        grid = _grid_of(value, (7, 9))
        assert grid.shape == (7, 9) and grid.dtype == np.float64 and grid.flags.c_contiguous
        assert np.array_equal(grid, np.broadcast_to(value, (7, 9)))


def _narrow_grazing_face(width):
    # a row of a 0.5-deg grid: a front face at 2 m (flat steps), a face ``width`` pixels wide
    # (pixels 4 .. 3 + width; pixel 4 is the corner) seen 8 deg from grazing (each step
    # ~7 % of the range, over jump_ratio), then a wall 1.2 m behind the face's far end
    angle, step = np.radians(8.0), np.radians(0.5)
    front = np.full(5, 2.0)
    face = 2.0 / (1.0 - np.arange(1, width) * step / np.tan(angle))
    wall = np.full(5, face[-1] + 1.2)
    return np.tile(np.concatenate([front, face, wall]), (4, 1))


@pytest.mark.parametrize("width", [3, 4])
def test_a_narrow_face_near_grazing_is_no_jump_when_one_side_continues_its_steps(width):
    ranges = _narrow_grazing_face(width)
    steps = np.diff(ranges[0])
    assert (steps[4:3 + width] / ranges[0, 4:3 + width] > 0.06).all()  # every step of the face is over the ratio
    both = jump_edges(ranges, jump_ratio=0.06, jump_min=0.05)
    # both sides asked: the face's first step has the front face's flat steps before it, its
    # last the jump onto the wall after it; only a middle step (width 4) has its own steps on
    # both sides: the face is cut into grid lines
    assert both[:, 5].all() and both[:, 3 + width].all() and both[:, 4 + width].all()
    assert both[:, :4 + width].sum() == 4 * 2
    # one side: each step of the face continues the next one or the one before, so none of
    # its pixels is marked; the wall's first pixel, 1.2 m behind, still is (its step
    # continues neither the face's last step nor the wall's flat ones)
    one = jump_edges(ranges, jump_ratio=0.06, jump_min=0.05, single_return_noise=0.005)
    assert not one[:, :4 + width].any()
    assert one[:, 4 + width].all() and one.sum() == 4


def test_an_occlusion_between_flat_surfaces_stays_a_jump_with_one_side_continued():
    # flat occluder at 1 m, flat background at 2 m: neither side continues the 1 m step
    ranges = np.full((3, 10), 2.0)
    ranges[:, :5] = 1.0
    for noise in (0.0, 0.005):
        mask = jump_edges(ranges, jump_ratio=0.08, jump_min=0.05, single_return_noise=noise)
        assert mask[:, 5].all() and mask.sum() == 3
    # continuation 0 turns the grazing test off, one side or not
    face = _narrow_grazing_face(3)
    assert np.array_equal(jump_edges(face, jump_ratio=0.08, jump_min=0.05, continuation=0, single_return_noise=0.005),
                          jump_edges(face, jump_ratio=0.08, jump_min=0.05, continuation=0))


def test_a_mixed_return_between_two_flat_surfaces_stays_a_jump_with_one_side_continued():
    # a flat occluder at 2 m, one mixed return at 2.5 m (its footprint half on each), a flat
    # wall at 3 m: its two steps continue each other, but no jump flanks the pair
    ranges = np.full((3, 10), 3.0)
    ranges[:, :5] = 2.0
    ranges[:, 5] = 2.5
    mask = jump_edges(ranges, jump_ratio=0.06, jump_min=0.05, single_return_noise=0.005)
    assert np.array_equal(mask, jump_edges(ranges, jump_ratio=0.06, jump_min=0.05))
    assert mask[:, 5].all() and mask[:, 6].all() and mask.sum() == 6
