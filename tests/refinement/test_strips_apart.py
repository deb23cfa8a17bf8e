"""Leftover strips that range jumps set apart become blobs (refinement.recover.strips_apart_as_blobs,
kernels.leftovers.pieces_apart)."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.fitting import fit_plane
from rangeseg_o3d.kernels.leftovers import pieces_apart
from rangeseg_o3d.refinement.recover import strips_apart_as_blobs

NOISE = 0.002
JUMP_RATIO, JUMP_MIN = 0.05, 0.05
ROWS, COLS = 12, 24


def _grid(depths, step: float = 0.01):
    """Rays ``step`` radians apart meeting, column by column, the depths ``depths`` (one per
    column): ``(xyz, ranges)``."""
    r, c = np.mgrid[0:ROWS, 0:len(depths)].astype(float)
    depth = np.asarray(depths, float)[None, :].repeat(ROWS, axis=0)
    xyz = np.stack([(c - len(depths) / 2) * step * depth, (r - ROWS / 2) * step * depth, depth], axis=-1)
    return xyz, np.linalg.norm(xyz, axis=2)


def test_pieces_are_joined_across_no_jump_and_count_their_links():
    # a wall at 5 m (labels 1 and 2) with a column at 3 m between them (columns 5-7, free) and
    # a free band of the wall at its right edge (columns 12-13); column 0 is a blob's (taken)
    depths = [5.0] * 5 + [3.0] * 3 + [5.0] * 6
    _, ranges = _grid(depths)
    labels = np.zeros((ROWS, 14), np.int32)
    labels[:, 1:5], labels[:, 8:12] = 1, 2
    taken = np.zeros_like(labels)
    taken[:, 0] = 7
    valid = np.ones(labels.shape, bool)
    pixels, starts, contact, jumped = pieces_apart(labels, valid, taken, ranges, JUMP_RATIO, JUMP_MIN, 5, False)
    pieces = [pixels[a:b] for a, b in zip(starts[:-1], starts[1:])]
    assert len(pieces) == 2
    np.testing.assert_array_equal(pieces[0], np.sort((np.arange(ROWS)[:, None] * 14 + np.arange(5, 8)).ravel()))
    np.testing.assert_array_equal(pieces[1], np.sort((np.arange(ROWS)[:, None] * 14 + np.arange(12, 14)).ravel()))
    assert contact.tolist() == [0, ROWS] and jumped.tolist() == [2 * ROWS, 0]
    # under the size floor: not listed; an invalid pixel is no link
    _, _, contact, _ = pieces_apart(labels, valid, taken, ranges, JUMP_RATIO, JUMP_MIN, 2 * ROWS + 1, False)
    assert contact.tolist() == [0]
    valid[:, 12] = False
    pixels, starts, contact, jumped = pieces_apart(labels, valid, taken, ranges, JUMP_RATIO, JUMP_MIN, 5, False)
    assert contact.tolist() == [0, 0] and jumped.tolist() == [2 * ROWS, 0] and starts[-1] == 3 * ROWS + ROWS


def test_a_piece_crosses_the_seam_of_a_360_degree_grid():
    # the column at 3 m split by the seam (columns 0 and 13 of a full turn): one piece with
    # wrap, two without
    depths = [3.0] + [5.0] * 12 + [3.0]
    _, ranges = _grid(depths)
    labels = np.zeros((ROWS, 14), np.int32)
    labels[:, 1:13] = 1
    args = (labels, np.ones(labels.shape, bool), np.zeros_like(labels), ranges, JUMP_RATIO, JUMP_MIN, 5)
    _, starts, contact, jumped = pieces_apart(*args, True)
    assert starts.tolist() == [0, 2 * ROWS] and contact.tolist() == [0] and jumped.tolist() == [2 * ROWS]
    _, starts, _, jumped = pieces_apart(*args, False)
    assert starts.tolist() == [0, ROWS, 2 * ROWS] and jumped.tolist() == [ROWS, ROWS]


def _scene():
    """A wall at 5 m (regions 1: columns 0-3, 2: 13-15, 17-18, 22) before which two near faces
    at 3 m stand (regions 3: 4-6, 4: 10-12), the wall's strip between them free (7-9); a line
    of returns at 4 m (16, free: a limb's mixed returns), a far column's strip at 4.2 m (19-21,
    free) and a free band of the wall at the right edge (23)."""
    depths = [5.0] * 4 + [3.0] * 3 + [5.0] * 3 + [3.0] * 3 + [5.0] * 3 + [4.0] + [5.0] * 2 + [4.2] * 3 + [5.0] * 2
    xyz, ranges = _grid(depths)
    column_labels = [1] * 4 + [3] * 3 + [0] * 3 + [4] * 3 + [2] * 3 + [0] + [2] * 2 + [0] * 3 + [2, 0]
    labels = np.array(column_labels, np.int32)[None, :].repeat(ROWS, axis=0)
    return xyz, ranges, labels


@pytest.mark.parametrize("apart", [True, False])
def test_strips_set_apart_become_blobs_once_the_planes_took_theirs(context, apart):
    xyz, ranges, labels = _scene()
    fits = {k: fit_plane(xyz[labels == k]) for k in (1, 2, 3, 4)}
    ctx = context(rs.OrganizedCloud(xyz), sigma=np.full(ranges.shape, NOISE))
    candidates = np.zeros_like(labels)
    out, blobs = strips_apart_as_blobs(ctx, labels, fits, candidates, first=5, valid=np.ones(labels.shape, bool),
                                       ranges=ranges, jump_ratio=JUMP_RATIO, jump_min=JUMP_MIN, k_sigma=3.0,
                                       apart=apart)
    assert (labels[:, 7:10] == 0).all() and not candidates.any()  # (the inputs are left alone)
    column = np.zeros(labels.shape, bool)
    column[:, 19:22] = True
    wall_strip = np.zeros(labels.shape, bool)
    wall_strip[:, 7:10] = True
    if apart:  # the wall's strip between the faces joins a wall region; the column is a blob
        assert set(np.unique(out[wall_strip]).tolist()) <= {1, 2} and (out[wall_strip] > 0).all()
        assert set(np.unique(blobs).tolist()) == {0, 5} and np.array_equal(blobs == 5, column)
    else:  # (without merge_disjoint no region it does not touch takes it: a blob too)
        np.testing.assert_array_equal(out, labels)
        assert set(np.unique(blobs).tolist()) == {0, 5, 6}
        assert np.array_equal(blobs == 5, wall_strip) and np.array_equal(blobs == 6, column)
    # the line one return wide and the band touching its wall without a jump: no blob
    assert not blobs[:, 16].any() and not blobs[:, 23].any()
    assert (out[:, [16, 23]] == 0).all()


def test_blobs_are_numbered_on_from_those_there(context):
    xyz, ranges, labels = _scene()
    fits = {k: fit_plane(xyz[labels == k]) for k in (1, 2, 3, 4)}
    ctx = context(rs.OrganizedCloud(xyz), sigma=np.full(ranges.shape, NOISE))
    candidates = np.zeros_like(labels)
    candidates[0, 23] = 9  # a blob (of one pixel here) numbered 9
    _, blobs = strips_apart_as_blobs(ctx, labels, fits, candidates, first=5, valid=np.ones(labels.shape, bool),
                                     ranges=ranges, jump_ratio=JUMP_RATIO, jump_min=JUMP_MIN, k_sigma=3.0, apart=True)
    assert set(np.unique(blobs).tolist()) == {0, 9, 10} and (blobs[:, 19:22] == 10).all()


@pytest.mark.parametrize("k, surface", [(2, 8), (7, 15)])
def test_a_far_column_seen_between_nearer_ones_is_its_cylinder(k, surface):
    # nodding_1deg study seed 1288: columns of r 0.15 and 0.31 m at 3.8 and 4.6 m, a strip a
    # few returns wide between the columns in front (143 and 161 px), were in no region
    from matrix_helpers import matrix_result, region_holding

    scan, result = matrix_result("nodding_1deg", 1288, k)
    mask = scan.truth_ids == surface
    label, held = region_holding(result.labels, mask)
    assert label > 0
    region = result.labels == label
    # Hoover's correct detection at T = 0.8 both ways, and the surface's kind
    assert held >= 0.8 * mask.sum() and held >= 0.8 * region.sum()
    feature = next(f for f in result.features if f.label == label)
    truth = scan.truth[surface]
    assert feature.kind == "cylinder" == truth.kind
    assert abs(feature.model.radius - truth.radius) <= 0.5 * truth.radius


def test_jumps_to_free_returns_count_and_a_foot_without_one_does_not_outweigh_them():
    # a column at 3 m (columns 5-7, free) before a wall at 5 m whose returns beside it
    # (columns 4 and 8) are an edge band in no region, standing on a floor row (labelled 3)
    # it meets without a jump: its links out are 2 x 11 jumps to the free band and 3 links to
    # the floor without one (the jumps to the band were not counted: 0 against 3)
    depths = [5.0] * 5 + [3.0] * 3 + [5.0] * 6
    _, ranges = _grid(depths)
    labels = np.zeros((ROWS, 14), np.int32)
    labels[:, :4], labels[:, 9:] = 1, 2
    labels[-1, :] = 3
    valid = np.ones(labels.shape, bool)
    pixels, starts, contact, jumped = pieces_apart(labels, valid, np.zeros_like(labels), ranges, JUMP_RATIO,
                                                   JUMP_MIN, 5, False)
    pieces = [pixels[a:b] for a, b in zip(starts[:-1], starts[1:])]
    column = np.sort((np.arange(ROWS - 1)[:, None] * 14 + np.arange(5, 8)).ravel())
    found = [i for i, piece in enumerate(pieces) if np.array_equal(piece, column)]
    assert len(found) == 1 and len(pieces) == 3  # the column and the two bands
    assert contact[found[0]] == 3 and jumped[found[0]] == 2 * (ROWS - 1)
    for i in set(range(3)) - set(found):  # a band: its wall and the floor without a jump, the column across one
        assert contact[i] == (ROWS - 1) + 1 and jumped[i] == ROWS - 1


def test_a_far_column_on_the_floor_between_edge_bands_is_its_cylinder():
    # nodding_1deg study seed 1436 scan 1: a column of r 0.18 m at 5.1-5.6 m, four returns
    # wide, whose sides meet the wall's edge band and whose foot meets the floor, was in no
    # region (152 px)
    from matrix_helpers import matrix_result, surface_feature

    scan, result = matrix_result("nodding_1deg", 1436, 1)
    feature = surface_feature(scan, result, 13, of_surface=0.9)
    truth = scan.truth[13]
    assert feature.kind == "cylinder"
    assert abs(feature.model.radius - truth.radius) <= 0.25 * truth.radius
    assert abs(feature.model.axis @ truth.axis) > np.cos(np.radians(5.0))
