"""Step 9, ``rays``: a laser's border pixels go to the neighbouring plane their range explains."""

import numpy as np
import pytest

from rangeseg_o3d.fitting import fit_plane
from rangeseg_o3d.kernels import settle_moves_along_rays
from rangeseg_o3d.refinement.along_rays import settle_along_rays
from rangeseg_o3d.scales import GRAZING_COSINE
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


def _one_row(offsets_beyond, cosines, sigma=0.01, labels=(1, 2, 2)):
    """A row of pixels whose rays (from the origin) meet the plane z = 2 at incidence
    ``cosines``, each ``offsets_beyond`` metres beyond it along its ray; label 1 holds the
    plane z = 2, label 2 a plane 1 m away (z = 3)."""
    c = np.asarray(cosines, float)
    rays = np.stack([np.zeros_like(c), np.sqrt(1 - c ** 2), c], axis=1)
    points = rays * (2.0 / c + np.asarray(offsets_beyond, float))[:, None]
    normals = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    ranges = np.linalg.norm(points, axis=1)
    return (np.ascontiguousarray(points), np.array([labels], np.int32), normals, np.array([0.0, 2.0, 3.0]),
            np.full(len(c), sigma), ranges)


def _ask(xyz, labels, normals, offsets, sigma, ranges, k_sigma=3.0, wrap=False):
    # (no range step counts as a jump here: the pixels' ranges differ by up to 100 m)
    return settle_moves_along_rays(xyz, labels, normals, offsets, sigma, ranges, np.zeros((0, 3)), k_sigma, 1.0,
                                   1e3, 1e3, GRAZING_COSINE, wrap)


def test_a_pixel_goes_to_the_plane_its_range_lies_on_in_range_sigmas():
    # pixels 1 and 2 lie on z = 2 (label 1's plane) within 0.5 range sigma, 1 m off label 2's
    # z = 3: both go to label 1, whose pixel 0 neighbours pixel 1 only, so only pixel 1 moves
    xyz, labels, normals, offsets, sigma, ranges = _one_row([0.0, 0.005, 0.005], [0.9, 0.9, 0.9])
    pixels, targets = _ask(xyz, labels, normals, offsets, sigma, ranges)
    assert pixels.tolist() == [1] and targets.tolist() == [1]
    # 4 cm beyond z = 2 at incidence cosine 0.8 (3.2 cm off the plane): 4 range sigmas, out of k_sigma 3
    xyz, labels, normals, offsets, sigma, ranges = _one_row([0.0, 0.04, 0.0], [0.8, 0.8, 0.8])
    assert _ask(xyz, labels, normals, offsets, sigma, ranges)[0].size == 0
    assert _ask(xyz, labels, normals, offsets, sigma, ranges, k_sigma=4.5)[0].tolist() == [1]
    # near grazing the cosine is floored: at cosine 0.02, 0.1 m along the ray is 2 mm off the
    # plane, 0.2 / GRAZING_COSINE = 1.2 range sigmas by the floor (5 by the ray's own cosine)
    xyz, labels, normals, offsets, sigma, ranges = _one_row([0.0, 0.1, 0.0], [0.8, 0.02, 0.8])
    assert _ask(xyz, labels, normals, offsets, sigma, ranges)[1].tolist() == [1]
    assert 0.002 / (0.01 * GRAZING_COSINE) < 3.0 < 0.002 / (0.01 * 0.02)


def test_a_pixel_its_own_plane_explains_or_a_jump_stays():
    # pixel 1 on z = 3, its own label 2's plane: it stays although label 1 is its neighbour
    xyz, labels, normals, offsets, sigma, ranges = _one_row([0.0, 0.0, 0.0], [0.9, 0.9, 0.9], labels=(1, 2, 2))
    xyz[1] *= 3.0 / 2.0  # onto z = 3
    ranges = np.linalg.norm(xyz, axis=1)
    assert _ask(xyz, labels, normals, offsets, sigma, ranges)[0].size == 0
    # a pixel on label 1's plane behind a range jump from its neighbour stays too
    xyz, labels, normals, offsets, sigma, ranges = _one_row([0.0, 0.0, 0.0], [0.9, 0.9, 0.9])
    far = ranges.copy()
    far[0] = 1.0  # 1.2 m nearer than pixel 1: a jump
    moves = settle_moves_along_rays(xyz, labels, normals, offsets, sigma, far, np.zeros((0, 3)), 3.0, 1.0,
                                    0.08, 0.05, GRAZING_COSINE, False)
    assert moves[0].size == 0


@pytest.mark.parametrize("row_labels, moved", [((1, 2, 2), 2), ((2, 2, 1), 0)])
def test_the_first_and_last_columns_are_neighbours_on_a_full_turn(row_labels, moved):
    # the pixel at one end lies on label 1's plane; its only label-1 neighbour is the pixel
    # at the other end, across the seam (the last column looks right, the first one left)
    xyz, labels, normals, offsets, sigma, ranges = _one_row([0.0, 0.3, 0.0], [0.9, 0.9, 0.9], labels=row_labels)
    xyz[1] *= 3.0 / 2.0  # pixel 1 on z = 3, label 2's own plane
    ranges = np.linalg.norm(xyz, axis=1)
    assert _ask(xyz, labels, normals, offsets, sigma, ranges)[0].size == 0
    pixels, targets = _ask(xyz, labels, normals, offsets, sigma, ranges, wrap=True)
    assert pixels.tolist() == [moved] and targets.tolist() == [1]


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


def _moves_every_pixel(xyz, labels, normals, offsets, sigma, ranges, origins, k_sigma, margin, jump_ratio,
                       jump_min, cos_floor, wrap):
    # settle_moves_along_rays as it reads, every plane pixel's four neighbours looked at (no
    # skip of the pixels inside their region): the reference the kernel must equal
    from rangeseg_o3d.kernels.rays import _range_sigmas

    h, w = labels.shape
    n = normals.shape[0]
    pixels, targets = [], []
    for r in range(h):
        ox, oy, oz = origins[r] if origins.shape[0] else (0.0, 0.0, 0.0)
        for c in range(w):
            own = labels[r, c]
            if own <= 0 or own >= n or not normals[own].any():
                continue
            i, mine, best, best_k = r * w + c, -1.0, np.inf, 0
            for rr, cc in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)):
                cc = cc % w if wrap else cc
                if not (0 <= rr < h and 0 <= cc < w):
                    continue
                k = labels[rr, cc]
                if k == own or k <= 0 or k >= n or not normals[k].any():
                    continue
                j = rr * w + cc
                if not abs(ranges[i] - ranges[j]) <= max(jump_min, jump_ratio * min(ranges[i], ranges[j])):
                    continue
                if mine < 0.0:
                    mine = _range_sigmas.py_func(xyz, i, normals, offsets, own, sigma, ox, oy, oz, cos_floor)
                    if mine <= margin:
                        break
                score = _range_sigmas.py_func(xyz, i, normals, offsets, k, sigma, ox, oy, oz, cos_floor)
                if score < best:
                    best, best_k = score, k
            if best_k > 0 and best <= k_sigma and best < mine - margin:
                pixels.append(i)
                targets.append(best_k)
    return np.array(pixels, np.int64), np.array(targets, np.int64)


@pytest.mark.parametrize("wrap", [False, True])
def test_the_ring_skips_only_pixels_inside_their_region(wrap):
    # the kernel passes over the pixels whose neighbours all hold their label: the same moves
    # as looking at every pixel's neighbours, across the seam of a full turn too, on grids
    # of blocky regions, some without a plane, 1 and 2 columns wide
    rng = np.random.default_rng(7 + wrap)
    for h, w in [(9, 13), (6, 1), (5, 2), (12, 20)]:
        labels = np.repeat(np.repeat(rng.integers(0, 6, (h // 3 + 1, w // 3 + 1)), 3, 0), 3, 1)[:h, :w]
        labels = np.ascontiguousarray(np.where(rng.random((h, w)) < 0.1, rng.integers(0, 6, (h, w)), labels),
                                      dtype=np.int32)
        xyz = np.dstack([*np.meshgrid(np.arange(w) * 0.05, np.arange(h) * 0.05), 2.0 + rng.normal(0, 0.02, (h, w))])
        xyz = np.ascontiguousarray(xyz.reshape(-1, 3))
        normals = rng.normal(size=(6, 3))
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        normals[3] = 0.0  # a region without a plane
        offsets = xyz[rng.integers(0, h * w, 6)] @ normals.T
        offsets = np.ascontiguousarray(np.diag(offsets))
        sigma = np.full(h * w, 0.01)
        ranges = np.linalg.norm(xyz, axis=1)
        origins = np.zeros((h, 3)) if wrap else np.zeros((0, 3))
        args = (xyz, labels, normals, offsets, sigma, ranges, origins, 3.0, 1.0, 0.08, 0.05, 0.1, wrap)
        got = settle_moves_along_rays(*args)
        want = _moves_every_pixel(*args)
        assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])
        assert want[0].size or (h, w) != (12, 20)  # (the large grid moves pixels: the test bites)


@pytest.mark.parametrize("seed", [4, 5, 6])
def test_each_ring_reads_the_planes_as_refitted_after_the_ring_before(context, monkeypatch, seed):
    # the planes' table is kept and its refitted rows replaced, not built again each ring:
    # every ring's table equals _plane_table of the models as they are then
    import rangeseg_o3d.refinement.along_rays as along_rays

    cloud, truth = _box_seen_from_above(seed)
    labels, _, _ = _top_took_front_rows(truth, rows=4)
    fits = _fits(cloud, labels)
    ctx = context(cloud, sigma=np.full(cloud.shape, NOISE))
    tables, refits = [], []
    moves, refit_regions = along_rays._moves, ctx.fitter.refit_regions
    monkeypatch.setattr(along_rays, "_moves", lambda c, lab, table, *a, **k: (
        tables.append(tuple(t.copy() for t in table)), moves(c, lab, table, *a, **k))[1])
    monkeypatch.setattr(ctx.fitter, "refit_regions", lambda *a, **k: (
        refits.append(refit_regions(*a, **k)), refits[-1])[1])
    ranges = np.where(cloud.valid, cloud.range_image(), np.nan)
    settle_along_rays(ctx, labels, fits, ranges=ranges, iterations=3, k_sigma=3.0, jump_ratio=0.08, jump_min=0.05)
    assert len(tables) >= 2 and refits  # rings after a refit were run
    now, n = dict(fits), tables[0][0].shape[0]
    for i, (normals, offsets) in enumerate(tables):
        want_normals, want_offsets = along_rays._plane_table(now, n)
        assert normals.tobytes() == want_normals.tobytes() and offsets.tobytes() == want_offsets.tobytes()
        for k, refit in (refits[i] if i < len(refits) else {}).items():
            if refit and refit.kind == "plane":
                now[k] = refit
