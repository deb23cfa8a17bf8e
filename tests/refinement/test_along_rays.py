"""Step 9, ``rays``: a laser's border pixels go to the neighbouring plane their range explains."""

import numpy as np
import pytest

from rangeseg_o3d.fitting import fit_plane
from rangeseg_o3d.refinement.along_rays import range_sigmas, settle_along_rays
from rangeseg_o3d.refinement.grow import settle_regions
from rangeseg_o3d.synthetic.lms200 import simulate_lms200
from rangeseg_o3d.synthetic.scene import Scene, box

NOISE = 0.02  # the noise_20mm row's LMS200
TOP, FRONT = 1, 2  # box() numbers the top first, then the face at -x (towards the sensor)


def _box_seen_from_above(seed=4):
    """A nodding LMS200 (20 mm noise) over a box 2 m ahead whose top it sees near grazing
    (incidence cosine ~0.15) above its front face (~0.95); the truth ids of both."""
    scene = Scene(box((2.0, 0.0, -0.35), (0.6, 1.0, 0.3), first_id=1))
    scan = simulate_lms200(scene, noise_sigma=NOISE, seed=seed)
    truth = np.where(np.isin(scan.truth_ids, (TOP, FRONT)), scan.truth_ids, 0)
    return scan.cloud, truth


def _top_took_front_rows(truth, rows=3):
    """Labels as growth leaves them: the top's region holds the front face's first ``rows``
    rows below the edge (within three range sigmas of the top's distances); ``(labels,
    taken, crease)``, ``crease`` the first of those rows (its footprint straddles the
    edge: its returns mix both faces' ranges and lie within the noise of either plane)."""
    labels = truth.copy()
    front_rows = np.flatnonzero((truth == FRONT).any(axis=1))
    edge = front_rows.min() if front_rows[0] > np.flatnonzero((truth == TOP).any(axis=1))[0] else front_rows.max()
    step = 1 if edge == front_rows.min() else -1
    taken = np.zeros(truth.shape, bool)
    for r in range(edge, edge + step * rows, step):
        taken[r] = truth[r] == FRONT
    labels[taken] = TOP
    crease = np.zeros(truth.shape, bool)
    crease[edge] = taken[edge]
    return labels, taken, crease


def _fits(cloud, labels):
    return {k: fit_plane(cloud.xyz[labels == k]) for k in (TOP, FRONT)}


def test_range_sigmas_measures_the_distance_along_the_ray_in_range_noise():
    rays = np.array([[0.0, 0.0, 1.0], [0.0, 0.6, 0.8], [0.0, 0.999, np.sqrt(1 - 0.999 ** 2)]])
    normal = np.tile([0.0, 0.0, 1.0], (3, 1))
    # each point 2 cm beyond where its ray meets z = 2 (along the ray)
    meet = 2.0 / rays[:, 2]
    points = rays * (meet + 0.02)[:, None]
    got = range_sigmas(points, rays, np.full(3, 0.01), normal, np.full(3, 2.0))
    # head-on and at cosine 0.8: 2 sigmas of range; near grazing (cosine 0.045) the cosine
    # is floored at GRAZING_COSINE, so the distance (0.02 x 0.045) counts for less
    from rangeseg_o3d.scales import GRAZING_COSINE

    np.testing.assert_allclose(got[:2], [2.0, 2.0], rtol=1e-9)
    np.testing.assert_allclose(got[2], 0.02 * rays[2, 2] / (0.01 * GRAZING_COSINE), rtol=1e-9)


def test_the_front_rows_a_grazing_top_took_go_back_to_the_front_face(context):
    cloud, truth = _box_seen_from_above()
    labels, taken, crease = _top_took_front_rows(truth)
    below = taken & ~crease
    assert below.sum() >= 40
    fits = _fits(cloud, labels)
    ctx = context(cloud, sigma=np.full(cloud.shape, NOISE))
    ranges = np.where(cloud.valid, cloud.range_image(), np.nan)
    settled, new = settle_along_rays(ctx, labels, fits, ranges=ranges, iterations=3, k_sigma=3.0,
                                     jump_ratio=0.08, jump_min=0.05)
    assert (labels[taken] == TOP).all()  # the input is left alone
    # the rows below the crease row go back (5-10 range sigmas off the top's plane)
    assert (settled[below] == FRONT).mean() >= 0.95
    # the top keeps its own pixels, and its plane, refitted, turns back to the top's (z = -0.2):
    # fitted over the taken rows it was tilted by about 3 degrees, its offset 0.1 m off
    assert np.degrees(np.arccos(abs(fits[TOP].normal[2]))) > 2.0
    assert (settled[truth == TOP] == TOP).mean() >= 0.95
    assert np.degrees(np.arccos(min(1.0, abs(new[TOP].normal[2])))) < 0.6
    assert abs(new[TOP].d - 0.2) < 0.02
    # settle, in units of the range noise, moves far fewer of them
    classic, _ = settle_regions(ctx, labels, fits, xyz=cloud.xyz, ranges=ranges, sigma=np.full(cloud.shape, NOISE),
                                iterations=3, k_sigma=3.0, jump_ratio=0.08, jump_min=0.05)
    assert (classic[below] == FRONT).mean() < 0.5


def test_a_right_border_stays_where_it_is(context):
    cloud, truth = _box_seen_from_above(seed=7)
    fits = _fits(cloud, truth)
    ctx = context(cloud, sigma=np.full(cloud.shape, NOISE))
    ranges = np.where(cloud.valid, cloud.range_image(), np.nan)
    settled, new = settle_along_rays(ctx, truth, fits, ranges=ranges, iterations=3, k_sigma=3.0,
                                     jump_ratio=0.08, jump_min=0.05)
    moved = (settled != truth) & (truth > 0)
    # one range sigma of margin: noise moves at most a few pixels of the 'crease' row
    assert moved.sum() <= 0.02 * (truth > 0).sum()


def test_a_region_emptied_loses_its_model_and_bad_input_is_refused(context):
    cloud, truth = _box_seen_from_above()
    labels = truth.copy()
    # a third region: three pixels of the front face fitted with the top's plane
    front = np.argwhere(truth == FRONT)
    middle = front[len(front) // 2]
    labels[middle[0], middle[1]:middle[1] + 3] = 3
    fits = _fits(cloud, truth)
    fits[3] = fits[TOP]
    ctx = context(cloud, sigma=np.full(cloud.shape, NOISE))
    ranges = np.where(cloud.valid, cloud.range_image(), np.nan)
    settled, new = settle_along_rays(ctx, labels, fits, ranges=ranges, iterations=3, k_sigma=3.0,
                                     jump_ratio=0.08, jump_min=0.05)
    assert not (settled == 3).any() and 3 not in new and 3 in fits
    with pytest.raises(ValueError, match="iterations"):
        settle_along_rays(ctx, labels, fits, ranges=ranges, iterations=-1, k_sigma=3.0, jump_ratio=0.08,
                          jump_min=0.05)
    with pytest.raises(ValueError, match="shape"):
        settle_along_rays(ctx, labels, fits, ranges=ranges[:-1], iterations=3, k_sigma=3.0, jump_ratio=0.08,
                          jump_min=0.05)


def test_borders_and_neighbours_meet_across_the_seam_of_a_full_turn():
    from rangeseg_o3d.refinement.along_rays import _borders, _neighbours

    labels = np.array([[1, 1, 1, 2], [1, 1, 1, 1]], np.int32)
    planar = np.array([False, True, True])
    # without the seam: the 2 and the pixels beside and below it
    assert _borders(labels, planar, wrap=False).tolist() == [2, 3, 7]
    # with it, column 0 of row 0 touches the 2 across the seam too
    assert _borders(labels, planar, wrap=True).tolist() == [0, 2, 3, 7]
    np.testing.assert_array_equal(_neighbours(np.array([0, 3, 4]), (0, -1), labels.shape, wrap=False), [-1, 2, -1])
    np.testing.assert_array_equal(_neighbours(np.array([0, 3, 4]), (0, -1), labels.shape, wrap=True), [3, 2, 7])
    np.testing.assert_array_equal(_neighbours(np.array([0, 7]), (1, 0), labels.shape, wrap=True), [4, -1])
