"""crease_moves skips the regions a pixel already refused: the same labels and moved pixels
as judging every step (the kernel's earlier form, kept here in plain Python)."""

import numpy as np
import pytest

from rangeseg_o3d.kernels.creases import _crease_pair, _judged_on_b_side, _plane_borders, crease_moves


def _reference(xyz, labels, is_plane, normals, offsets, rms, sigma, k_sigma, max_cos, least_cos, steps, reach,
               along_rays=False):
    # the kernel before the refused regions were skipped: every step judged afresh
    h, w = labels.shape
    n = is_plane.shape[0]
    out = labels.copy()
    sums = np.zeros((n, 4))
    borders = np.flatnonzero(_plane_borders(xyz, labels, is_plane, sums))
    if borders.size == 0:
        return out, np.empty(0, np.int64)
    centroids = sums[:, :3] / np.maximum(sums[:, 3:], 1.0)
    near = np.zeros(h * w, bool)
    spread = reach - 1
    for i in borders:
        r0, c0 = divmod(int(i), w)
        for dr in range(-spread, spread + 1):
            r = r0 + dr
            if 0 <= r < h:
                left = spread - abs(dr)
                near[r * w + max(c0 - left, 0): r * w + min(c0 + left + 1, w)] = True
    moved = []
    for i in np.flatnonzero(near):
        r0, c0 = divmod(int(i), w)
        a = labels[r0, c0]
        if a <= 0 or a >= n or not is_plane[a]:
            continue
        x, y, z = xyz[i]
        dist = np.sqrt(x * x + y * y + z * z)
        if not dist > 0.0:
            continue
        rx, ry, rz = x / dist, y / dist, z / dist
        noise = k_sigma * sigma[i]
        for dr, dc in steps:
            r, c = r0 + dr, c0 + dc
            if r < 0 or r >= h or c < 0 or c >= w:
                continue
            b = labels[r, c]
            if b == a or b <= 0 or b >= n or not is_plane[b]:
                continue
            crease = _crease_pair(a, b, normals, offsets, centroids, max_cos)
            if crease != 0 and _judged_on_b_side(rx, ry, rz, x, y, z, dist, a, b, crease > 0, noise, normals,
                                                 offsets, rms, k_sigma, least_cos, along_rays):
                out[r0, c0] = b
                moved.append(i)
                break
    return out, np.array(moved, np.int64)


def _random_case(seed, h=24, w=32, regions=6):
    # pixels of random patches on random planes seen by a pinhole camera, the noise wide
    # enough that pixels beside a border lie within it of both planes
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[0:h, 0:w]
    rays = np.stack([(cols - w / 2) / w, (rows - h / 2) / h, np.ones((h, w))], axis=-1).reshape(-1, 3)
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    centres = rng.uniform([0, 0], [h, w], size=(regions, 2))
    labels = 1 + np.argmin(((np.stack([rows, cols], -1)[:, :, None, :] - centres) ** 2).sum(-1), axis=-1)
    labels[rng.random((h, w)) < 0.03] = 0
    n = regions + 2
    normals = rng.normal(size=(n, 3)) + [0, 0, -2.0]
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    offsets = -rng.uniform(1.0, 3.0, n)  # the sensor's side of each plane positive, as settle_creases hands them
    is_plane = np.ones(n, bool)
    is_plane[0] = False
    is_plane[rng.integers(1, regions + 1)] = rng.random() < 0.5  # now and then a curved region
    flat = labels.ravel()
    t = np.abs(offsets[flat] / (rays @ normals.T)[np.arange(flat.size), flat])
    xyz = rays * (t + rng.normal(0, 0.02, flat.size))[:, None]
    rms = rng.uniform(0.005, 0.05, n)
    sigma = rng.uniform(0.02, 0.2, flat.size)
    reach = 3
    steps = np.array(sorted(((dr, dc) for dr in range(-reach, reach + 1) for dc in range(-reach, reach + 1)
                             if 0 < abs(dr) + abs(dc) <= reach), key=lambda s: (abs(s[0]) + abs(s[1]), s)),
                     dtype=np.int64)
    return (np.ascontiguousarray(xyz), labels.astype(np.int32), is_plane, normals, offsets, rms, sigma,
            3.0, float(np.cos(np.radians(10))), 0.05, steps, reach)


@pytest.mark.parametrize("seed", range(12))
def test_crease_moves_equals_judging_every_step(seed):
    args = _random_case(seed)
    want_labels, want_moved = _reference(*args)
    got_labels, got_moved = crease_moves(*args)
    assert np.array_equal(got_labels, want_labels)
    assert np.array_equal(got_moved, want_moved)


def test_the_random_cases_move_pixels():
    # the equality above is about moves, so the cases must hold some
    moved = [_reference(*_random_case(seed))[1].size for seed in range(12)]
    assert sum(m > 0 for m in moved) >= 6, moved


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_plane_borders_sums_are_the_pixel_by_pixel_sums_bit_for_bit(seed):
    # the sums carried along a row's runs are the additions into sums[label] pixel by pixel,
    # in raster order, the same bits; the border mask is every plane pixel 4-adjacent to
    # another plane region's
    rng = np.random.default_rng(seed)
    h, w, n = 30, 41, 7
    labels = np.repeat(rng.integers(-1, n + 2, size=(h, w // 3 + 1)), 3, axis=1)[:, :w].astype(np.int32)
    labels[rng.uniform(size=(h, w)) < 0.1] = 3  # runs broken by single pixels of another region
    is_plane = np.array([False, True, True, True, False, True, True])
    xyz = rng.normal(size=(h * w, 3)) * 1e3 + rng.normal(size=(h * w, 3)) * 1e-6
    want_sums, want = np.zeros((n, 4)), np.zeros((h, w), bool)
    for r in range(h):
        for c in range(w):
            a = labels[r, c]
            if not (0 < a < n and is_plane[a]):
                continue
            for k in range(3):
                want_sums[a, k] += xyz[r * w + c, k]
            want_sums[a, 3] += 1.0
            for rr, cc in ((r, c + 1), (r + 1, c), (r, c - 1), (r - 1, c)):
                if 0 <= rr < h and 0 <= cc < w:
                    b = labels[rr, cc]
                    if b != a and 0 < b < n and is_plane[b]:
                        want[r, c] = True
    sums = np.zeros((n, 4))
    got = _plane_borders(xyz, labels, is_plane, sums)
    assert want.any() and np.array_equal(got, want)
    assert np.array_equal(sums, want_sums)


@pytest.mark.parametrize("seed", range(12))
def test_crease_moves_along_the_rays_equals_judging_every_step(seed):
    args = _random_case(seed)
    want_labels, want_moved = _reference(*args, along_rays=True)
    got_labels, got_moved = crease_moves(*args, True)
    assert np.array_equal(got_labels, want_labels)
    assert np.array_equal(got_moved, want_moved)


def test_along_the_rays_a_move_is_within_the_noise_along_the_ray_of_both_planes():
    # each pixel moved along the rays lies within k_sigma of its range noise (or k_sigma rms over
    # the incidence cosine) of both planes where they meet its ray, and the cases move pixels
    total = 0
    for seed in range(12):
        xyz, labels, is_plane, normals, offsets, rms, sigma, k_sigma = _random_case(seed)[:8]
        out, moved = crease_moves(*_random_case(seed), True)
        total += moved.size
        flat = labels.ravel()
        for i in moved:
            ranges = np.linalg.norm(xyz[i])
            ray = xyz[i] / ranges
            for k in (flat[i], out.ravel()[i]):
                meet = offsets[k] / (ray @ normals[k])
                assert abs(ranges - meet) <= max(k_sigma * sigma[i], k_sigma * rms[k] / abs(ray @ normals[k])) + 1e-12
    assert total >= 20, total
