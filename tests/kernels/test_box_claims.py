"""box_claims: claim_along_rays' mask of the pixels a grazing region's plane may claim in its
box, against the numpy form it replaced (box terms, both planes' distances along the rays
gathered a neighbouring region at a time)."""

import numpy as np
import pytest

from rangeseg_o3d.kernels.claims import box_claims
from rangeseg_o3d.kernels.rays import box_ray_terms

TRIM = 3.0


def _numpy_claims(xyz, sigma, valid, owner, k, a, planes):
    # claim_along_rays before the kernel (planes: label -> a = n / d of the plane regions)
    ok, u, q, wt = box_ray_terms(xyz, sigma, valid)
    mine = np.sqrt(wt) * np.abs(q - u @ a)
    theirs = np.full(mine.size, np.inf)
    flat = owner.reshape(-1)
    for j in np.unique(flat).tolist():
        if j in planes and j != k:
            at = flat == j
            theirs[at] = np.sqrt(wt[at]) * np.abs(q[at] - u[at] @ planes[j])
    free = (flat == 0) | np.isfinite(theirs)
    return (ok & free & (mine <= TRIM) & (mine < theirs)).reshape(owner.shape)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_box_claims_are_the_numpy_claims(seed):
    rng = np.random.default_rng(seed)
    h, w = 50, 70
    # a far wall z = 4 and a grazing floor y = 1 seen by a pinhole camera, their pixels
    # within a few range sigmas of both near the crease
    rows, cols = np.mgrid[0:h, 0:w]
    rays = np.stack([(cols - w / 2) / w, (rows - h / 2) / h, np.ones((h, w))], axis=-1)
    floor = 1.0 / np.maximum(rays[..., 1], 1e-3)
    rng_range = np.where((rays[..., 1] > 0) & (floor * np.linalg.norm(rays, axis=-1) < 4.0 * np.linalg.norm(rays, axis=-1)),
                         floor, 4.0)
    sigma = rng.uniform(0.01, 0.08, (h, w))
    xyz = rays * (rng_range + rng.normal(size=(h, w)) * sigma)[..., None]
    owner = np.where(rng_range < 4.0, 5, 2).astype(np.int32)
    owner[rng.uniform(size=(h, w)) < 0.15] = 0  # free pixels
    owner[:3] = 7  # a region without a plane along the rays
    owner[-3:, :5] = 40  # a label beyond the table of planes
    owner[10:14, 10:14] = 6  # a plane region whose row holds NaN
    valid = rng.uniform(size=(h, w)) > 0.05
    xyz[4, 4] = np.nan  # valid but not finite
    valid[4, 4] = True
    table = np.full((9, 3), np.nan)
    planes = {2: np.array([0.0, 0.0, 0.25]), 5: np.array([0.0, 1.0, 0.0]) + rng.normal(size=3) * 1e-3}
    for j, aj in planes.items():
        table[j] = aj
    table[6, 1] = np.nan
    planes[6] = table[6]
    for k, a in ((5, planes[5]), (2, planes[2])):
        for r0, r1, c0, c1 in ((0, h, 0, w), (3, 41, 5, 66)):  # the whole box and a view
            want = _numpy_claims(xyz[r0:r1, c0:c1], sigma[r0:r1, c0:c1], valid[r0:r1, c0:c1],
                                 owner[r0:r1, c0:c1], k, a, planes)
            got = box_claims(xyz[r0:r1, c0:c1], sigma[r0:r1, c0:c1], valid[r0:r1, c0:c1], owner[r0:r1, c0:c1],
                             k, a, table, TRIM)
            assert got.shape == want.shape and np.array_equal(got, want)
            # both kinds of pixel claimed: free ones, and another plane region's
            assert got[owner[r0:r1, c0:c1] == 0].any() and got[owner[r0:r1, c0:c1] == (7 - k)].any()
            assert not got[owner[r0:r1, c0:c1] == k].any() and not got[owner[r0:r1, c0:c1] == 7].any()
