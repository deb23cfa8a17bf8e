"""_within_reach, the pass crease_moves and cap_moves share: the pixels within a number of
4-steps of the seeds, on values and against the 4-step distance in numpy; and cap_moves'
seeds (a border pixel and its right, lower and left neighbours) mark the pixels its own
diamond did before the pass was shared (kept here in plain Python)."""

import numpy as np
import pytest

from rangeseg_o3d.kernels.creases import _within_reach


def _flat(w, pixels):
    return np.array(sorted(r * w + c for r, c in pixels), np.int64)


def test_one_seed_marks_its_clipped_diamond():
    seeds = np.zeros((5, 7), bool)
    seeds[2, 3] = True
    assert np.array_equal(_within_reach(seeds, 1), _flat(7, [(1, 3), (2, 2), (2, 3), (2, 4), (3, 3)]))
    assert np.array_equal(_within_reach(seeds, 0), _flat(7, [(2, 3)]))
    corner = np.zeros((5, 7), bool)
    corner[0, 0] = True  # the diamond clipped at the image's edges
    assert np.array_equal(_within_reach(corner, 2), _flat(7, [(0, 0), (0, 1), (0, 2), (1, 0), (1, 1), (2, 0)]))


def test_no_seed_marks_nothing_and_seeds_share_their_pixels_once():
    assert _within_reach(np.zeros((4, 4), bool), 2).size == 0
    seeds = np.zeros((1, 6), bool)
    seeds[0, 1] = seeds[0, 2] = True
    assert np.array_equal(_within_reach(seeds, 1), np.array([0, 1, 2, 3], np.int64))


@pytest.mark.parametrize("seed", range(6))
def test_the_pixels_within_spread_of_a_seed_by_the_4_step_distance(seed):
    rng = np.random.default_rng(seed)
    h, w = rng.integers(3, 20, 2)
    seeds = rng.random((h, w)) < 0.05
    rows, cols = np.mgrid[0:h, 0:w]
    sr, sc = np.nonzero(seeds)
    dist = (np.abs(rows[..., None] - sr) + np.abs(cols[..., None] - sc)).min(-1, initial=h + w)
    for spread in range(4):
        assert np.array_equal(_within_reach(seeds, spread), np.flatnonzero(dist <= spread))


def _cap_near_before(edges, spread):
    # cap_moves' marking before the pass was shared: the diamond of spread + 1 4-steps about
    # each border pixel (r, c) from row r - spread on (both pixels of the pair and more)
    h, w = edges.shape
    near = np.zeros(h * w, bool)
    for r, c in zip(*np.nonzero(edges)):
        for dr in range(-spread, spread + 2):
            if 0 <= r + dr < h:
                left = spread + 1 - abs(dr)
                near[(r + dr) * w + max(c - left, 0): (r + dr) * w + min(c + left + 1, w)] = True
    return np.flatnonzero(near)


@pytest.mark.parametrize("seed", range(8))
def test_cap_moves_seeds_mark_the_pixels_its_own_diamond_did(seed):
    rng = np.random.default_rng(100 + seed)
    for _ in range(50):
        h, w = rng.integers(1, 14, 2)
        edges = rng.random((h, w)) < rng.uniform(0.0, 0.2)
        seeds = edges.copy()
        seeds[:, 1:] |= edges[:, :-1]  # right neighbours
        seeds[1:, :] |= edges[:-1, :]  # lower ones
        seeds[:, :-1] |= edges[:, 1:]  # left ones
        for spread in range(4):
            assert np.array_equal(_within_reach(seeds, spread), _cap_near_before(edges, spread))
