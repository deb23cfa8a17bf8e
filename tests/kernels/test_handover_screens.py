"""The fragment step's compiled pretest (kernels.fragments_may_pass) against its numpy tests."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d import kernels
from rangeseg_o3d.fitting import fit_plane
from rangeseg_o3d.fitting.primitives import Cylinder, Plane, Sphere
from rangeseg_o3d.fitting.region_fitter import model_table, region_indices
from rangeseg_o3d.refinement import dissolve
from rangeseg_o3d.refinement.context import Context
from rangeseg_o3d.refinement.merge import region_adjacency, region_adjacency_matrix

K_SIGMA = 3.0
NOISE = 0.005


def _scene(seed: int):
    # a noisy 30 x 40 plane z = 3 (x, y on a 2 cm grid) under a background region (1) and
    # rectangles of other labels, each region with a model near the surface or off it: its
    # own plane, a plane moved by 0-4 noise sigmas or tilted, a large sphere or cylinder
    # touching the surface at the rectangle (part of its pixels within the noise)
    rng = np.random.default_rng(seed)
    h, w = 30, 40
    v, u = np.mgrid[0:h, 0:w].astype(float)
    xyz = np.dstack([u * 0.02, v * 0.02, 3.0 + rng.normal(0.0, NOISE, (h, w))])
    labels = np.ones((h, w), np.int32)
    for k in range(2, 2 + int(rng.integers(3, 8))):
        r, c = int(rng.integers(0, h - 3)), int(rng.integers(0, w - 3))
        labels[r:r + int(rng.integers(2, 14)), c:c + int(rng.integers(2, 20))] = k
    fits = {}
    for k in np.unique(labels).tolist():
        pts = xyz[labels == k]
        if pts.shape[0] < 3:
            continue
        centre = pts.mean(axis=0)
        choice = rng.integers(0, 5)
        if choice == 0:
            fits[k] = fit_plane(pts)
        elif choice == 1:
            normal = np.array([0.0, 0.0, 1.0]) + rng.normal(0.0, 0.01, 3)
            normal /= np.linalg.norm(normal)
            fits[k] = Plane(normal=normal, d=float(normal @ centre) + rng.uniform(-4, 4) * NOISE,
                            rms=float(rng.uniform(0.5, 1.5) * NOISE), inliers=len(pts))
        elif choice == 2:
            radius = float(rng.uniform(0.3, 3.0))
            fits[k] = Sphere(center=centre + [0.0, 0.0, radius + rng.uniform(-2, 2) * NOISE], radius=radius,
                             rms=NOISE, inliers=len(pts))
        elif choice == 3:
            radius = float(rng.uniform(0.3, 3.0))
            axis = np.array([np.cos(rng.uniform(0, np.pi)), np.sin(rng.uniform(0, np.pi)), 0.0])
            fits[k] = Cylinder(axis=axis, point=centre + [0.0, 0.0, radius], radius=radius, rms=NOISE,
                               inliers=len(pts))
        # (choice 4: no model)
    sigma = rng.uniform(0.6, 1.4, h * w) * NOISE
    jumps = rng.random(h * w) < 0.1
    return xyz.reshape(-1, 3), labels, fits, sigma, jumps


def _numpy_verdicts(xyz, labels, fits, sigma, jumps):
    # per label: whether dissolve_fragments' numpy tests (the sample's share, the half,
    # FRAGMENT_SHARE) leave the region to be handed to its larger fitted neighbours, before
    # any region changed (None: no such neighbour)
    sizes = np.bincount(labels.ravel())
    neighbours = {}
    for a, b in region_adjacency(labels):
        if fits.get(a) and fits.get(b):
            neighbours.setdefault(a, set()).add(b)
            neighbours.setdefault(b, set()).add(a)
    regions = region_indices(labels)
    ctx = type("Ctx", (), {"xyz": xyz, "sigma": sigma})()
    verdicts = {}
    for k, idx in regions.items():
        hosts = [h for h in sorted(neighbours.get(k, ())) if sizes[h] > sizes[k]]
        if not hosts:
            verdicts[k] = None
            continue
        scatter = np.array([fits[h].rms for h in hosts])[:, None]
        if idx.size > dissolve._FRAGMENT_SAMPLE:
            sample = idx[:: idx.size // dissolve._FRAGMENT_SAMPLE]
            explained = dissolve.explained_by_hosts(ctx, sample, fits, hosts, scatter, K_SIGMA)[0]
            share = np.count_nonzero(explained) / sample.size
            if share < 0.5 - 1.5 / np.sqrt(sample.size):
                verdicts[k] = False
                continue
        explained = dissolve.explained_by_hosts(ctx, idx, fits, hosts, scatter, K_SIGMA)[0]
        n = int(explained.sum())
        counted = int(np.count_nonzero(explained | ~jumps[idx]))
        verdicts[k] = not (n < dissolve.FRAGMENT_SHARE * counted or 2 * n <= idx.size)
    return verdicts


def _compiled_verdicts(xyz, labels, fits, sigma, jumps, slack):
    n = int(labels.max()) + 1
    kinds, params, rms = model_table(fits, n)
    fitted = np.zeros(n, bool)
    fitted[[k for k, m in fits.items() if m and 0 < k < n]] = True
    return kernels.fragments_may_pass(labels.ravel(), xyz, sigma, jumps, region_adjacency_matrix(labels, n), fitted,
                                      kinds, params, rms, np.bincount(labels.ravel(), minlength=n).astype(np.int64),
                                      K_SIGMA, dissolve.FRAGMENT_SHARE, dissolve._FRAGMENT_SAMPLE, slack)


def test_the_pretest_answers_as_the_numpy_tests_on_random_scenes():
    # without slack the compiled counts are numpy's (no distance lies within rounding of its
    # bound here): the verdicts are the same, True where numpy's tests pass, False where
    # they refuse or there is no larger fitted neighbour
    outcomes = {None: 0, False: 0, True: 0}
    for seed in range(40):
        xyz, labels, fits, sigma, jumps = _scene(seed)
        expected = _numpy_verdicts(xyz, labels, fits, sigma, jumps)
        got = _compiled_verdicts(xyz, labels, fits, sigma, jumps, slack=0.0)
        for k, verdict in expected.items():
            assert bool(got[k]) == bool(verdict), (seed, k)
            outcomes[verdict] += 1
        assert not got[0] and not any(got[k] for k in range(got.size) if k not in expected)
    assert min(outcomes.values()) >= 10  # each kind of answer is asked


def test_the_pretest_refuses_only_what_the_numpy_tests_refuse():
    # with the slack (the step's): a pixel within the widened bound counts, so a refusal is
    # numpy's refusal; here with a large slack too
    for slack in (dissolve.SCREEN_SLACK, 0.3):
        for seed in range(20):
            xyz, labels, fits, sigma, jumps = _scene(seed)
            expected = _numpy_verdicts(xyz, labels, fits, sigma, jumps)
            got = _compiled_verdicts(xyz, labels, fits, sigma, jumps, slack=slack)
            assert all(got[k] for k, verdict in expected.items() if verdict), (slack, seed)


def test_a_host_the_table_cannot_hold_explains_every_pixel():
    # a model of another plugin (kind NONE in the table): the pretest cannot judge it
    xyz, labels, fits, sigma, jumps = _scene(3)
    fits = {k: fit_plane(xyz[(labels == k).ravel()]) for k in np.unique(labels).tolist()}
    for k in fits:  # each far off the surface: no region is explained by another
        fits[k] = Plane(normal=np.array([0.0, 0.0, 1.0]), d=5.0 + k, rms=NOISE, inliers=fits[k].inliers)
    assert not _compiled_verdicts(xyz, labels, fits, sigma, jumps, 1e-9).any()

    class Foreign:  # a plugin's model: truthy, not a Plane, Sphere or Cylinder
        rms = NOISE

    fits[1] = Foreign()
    got = _compiled_verdicts(xyz, labels, fits, sigma, jumps, 1e-9)
    touching_one = {b if a == 1 else a for a, b in region_adjacency(labels) if 1 in (a, b)}
    smaller = [k for k in touching_one if (labels == k).sum() < (labels == 1).sum()]
    assert smaller and all(got[k] for k in smaller)


@pytest.fixture(scope="module")
def fitter():
    return rs.Pipeline("lms200").fitter


@pytest.mark.parametrize("seed", range(12))
def test_dissolve_fragments_answers_as_without_the_pretest(seed, monkeypatch, fitter):
    # the step with its pretest and without it (None: every candidate read) hand over the
    # same pixels and keep the same models
    xyz, labels, fits, sigma, jumps = _scene(seed)
    ctx = Context(rs.OrganizedCloud(xyz.reshape(*labels.shape, 3)), fitter, sigma.reshape(labels.shape), 10)
    jumps = jumps.reshape(labels.shape)
    out, kept = dissolve.dissolve_fragments(ctx, labels, fits, k_sigma=K_SIGMA, jumps=jumps)
    monkeypatch.setattr(dissolve, "_may_dissolve", lambda *args: (None, None))
    out_all, kept_all = dissolve.dissolve_fragments(ctx, labels, fits, k_sigma=K_SIGMA, jumps=jumps)
    np.testing.assert_array_equal(out, out_all)
    assert kept.keys() == kept_all.keys()
    for k in kept:
        assert kept[k] is kept_all[k] or kept[k].params() == kept_all[k].params()


# -- ripples: whether a larger plane may hold half of a curved patch ------------------------
def _ripple_scene(seed: int):
    # the noisy plane of _scene under its regions; planes of the even labels (each near the
    # surface or moved off it by 0-4 noise sigmas, with a scatter of 0.5-2 sigmas), the odd
    # labels the candidates
    xyz, labels, _, sigma, _ = _scene(seed)
    rng = np.random.default_rng(100 + seed)
    sizes = np.bincount(labels.ravel())
    plane_labels = [k for k in range(1, sizes.size) if k % 2 == 0 and sizes[k] > 0] + [1]
    normals, offsets = [], []
    for _ in plane_labels:
        normal = np.array([0.0, 0.0, 1.0]) + rng.normal(0.0, 0.005, 3)
        normal /= np.linalg.norm(normal)
        normals.append(normal)
        offsets.append(float(normal @ [0.4, 0.3, 3.0]) + rng.uniform(-4, 4) * NOISE)
    candidates = np.zeros(sizes.size, bool)
    candidates[[k for k in range(1, sizes.size) if k % 2 == 1 and sizes[k] > 0]] = True
    return (xyz, labels, sigma, candidates, np.array(normals), np.array(offsets),
            rng.uniform(0.5, 2.0, len(plane_labels)) * NOISE, sizes[plane_labels].astype(np.int64))


def _ripple_reference(xyz, labels, sigma, candidates, normals, offsets, scatter, plane_sizes):
    # per candidate: whether the numpy scores of some larger plane may have their median
    # within K_SIGMA (dissolve.median_may_pass at the largest spread, max(sigma, scatter))
    out = {}
    for k, idx in region_indices(labels).items():
        if not candidates[k]:
            continue
        larger = plane_sizes > idx.size
        if not larger.any():
            out[k] = False
            continue
        points = xyz[idx]
        scores = np.abs(points @ normals[larger].T - offsets[larger]) / np.maximum(sigma[idx][:, None],
                                                                                  scatter[larger][None, :])
        out[k] = bool(dissolve.median_may_pass(scores, K_SIGMA).any())
    return out


def test_the_ripple_pretest_answers_as_the_numpy_median_test_on_random_scenes():
    answers = {False: 0, True: 0}
    for seed in range(40):
        xyz, labels, sigma, candidates, normals, offsets, scatter, plane_sizes = _ripple_scene(seed)
        expected = _ripple_reference(xyz, labels, sigma, candidates, normals, offsets, scatter, plane_sizes)
        got = kernels.ripples_may_pass(labels.ravel(), xyz, sigma, candidates, normals, offsets, scatter, plane_sizes,
                                       K_SIGMA, 0.0)
        assert {k: bool(got[k]) for k in expected} == expected, seed
        assert not got[~candidates].any()
        for verdict in expected.values():
            answers[verdict] += 1
        # with the slack (the step's, and a large one) it refuses only what numpy refuses
        for slack in (dissolve.SCREEN_SLACK, 0.3):
            wider = kernels.ripples_may_pass(labels.ravel(), xyz, sigma, candidates, normals, offsets, scatter,
                                             plane_sizes, K_SIGMA, slack)
            assert all(wider[k] for k, verdict in expected.items() if verdict)
    assert min(answers.values()) >= 10  # both answers are asked


@pytest.mark.parametrize("seed", range(12))
def test_absorb_ripples_answers_as_without_the_pretest(seed, monkeypatch):
    # the step with the pretest and without it (every candidate looked at) hand over the
    # same pixels: curved patches (the odd labels) beside the planes of _ripple_scene, every
    # third scene with the planes 20 cm off (there the pretest alone answers)
    xyz, labels, sigma, candidates, normals, offsets, scatter, _ = _ripple_scene(seed)
    far = seed % 3 == 0
    offsets = offsets + 0.2 * far
    sizes = np.bincount(labels.ravel())
    plane_labels = [k for k in range(1, sizes.size) if k % 2 == 0 and sizes[k] > 0] + [1]
    fits = {k: Plane(normal=normals[i], d=offsets[i], rms=scatter[i], inliers=int(sizes[k]))
            for i, k in enumerate(plane_labels)}
    for k in np.flatnonzero(candidates).tolist():
        fits[k] = Sphere(center=np.array([0.4, 0.3, 5.0]), radius=2.0, rms=NOISE, inliers=int(sizes[k]))
    answers = []
    pretest = dissolve._no_ripple_host
    monkeypatch.setattr(dissolve, "_no_ripple_host", lambda *args: answers.append(pretest(*args)) or answers[-1])
    out, kept, changed = dissolve.absorb_ripples(xyz, labels, fits, sigma, {}, k_sigma=K_SIGMA)
    assert (answers == [True] and out is labels) if far else True not in answers
    monkeypatch.setattr(dissolve, "_no_ripple_host", lambda *args: False)
    out_all, kept_all, changed_all = dissolve.absorb_ripples(xyz, labels, fits, sigma, {}, k_sigma=K_SIGMA)
    np.testing.assert_array_equal(out, out_all)
    assert kept.keys() == kept_all.keys() and changed == changed_all
