"""join_trimmed_pieces: a curved region takes the part of a piece beside it that its model
explains; the returns of no surface along the limb are freed, a face beyond a crease stays."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.fitting import fit_cylinder, fit_plane
from rangeseg_o3d.refinement.context import TRIM_SIGMAS
from rangeseg_o3d.refinement.merge import pieces_near
from rangeseg_o3d.refinement.trimmed_pieces import _trimmed_union, join_trimmed_pieces

RADIUS, AXIS_Z = 0.3, 3.0


def _column(columns: int, noise: float, seed: int, flank_from: int | None = None) -> np.ndarray:
    """A 40-row grid on a cylinder of radius 0.3 m (axis along y, 3 m ahead), 100 degrees of
    arc over 60 columns; with ``flank_from``, the columns from there on a plane leaving the
    arc at a 50-degree crease. Noise along z."""
    v, u = np.mgrid[0:40, 0:columns].astype(float)
    last = u if flank_from is None else np.minimum(u, flank_from - 1)
    angle = np.radians(-50.0 + 100.0 * last / 59.0)
    x, z = RADIUS * np.sin(angle), AXIS_Z - RADIUS * np.cos(angle)
    if flank_from is not None:
        edge = np.radians(-50.0 + 100.0 * (flank_from - 1) / 59.0) + np.radians(50.0)
        run = (u - flank_from + 1).clip(min=0) * 0.012
        x, z = x + run * np.cos(edge), z + run * np.sin(edge)
    z = z + np.random.default_rng(seed).normal(0.0, noise, u.shape)
    return np.dstack([x, v * 0.02, z])


def _with_mixed_returns(xyz: np.ndarray, seed: int) -> np.ndarray:
    """``xyz`` and one more column past its last: mixed returns, each along the ray of the
    arc's next point, 5-15 cm behind it (the beam half on the column, half behind)."""
    rows = xyz.shape[0]
    angle = np.radians(-50.0 + 100.0 * xyz.shape[1] / 59.0)
    edge = np.stack([np.full(rows, RADIUS * np.sin(angle)), np.arange(rows) * 0.02,
                     np.full(rows, AXIS_Z - RADIUS * np.cos(angle))], axis=1)
    behind = np.random.default_rng(seed + 100).uniform(0.05, 0.15, rows)
    mixed = edge * (1.0 + behind / np.linalg.norm(edge, axis=1))[:, None]
    return np.concatenate([xyz, mixed[:, None, :]], axis=1)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_limb_piece_joins_its_column_and_its_mixed_returns_are_freed(context, seed):
    noise = 0.002
    xyz = _with_mixed_returns(_column(45, noise, seed), seed)  # columns 0-44 the arc, 45 mixed
    labels = np.ones(xyz.shape[:2], np.int32)
    labels[:, 34:] = 2  # the limb's last 11 columns of arc and the mixed column
    fits = {1: fit_cylinder(xyz[labels == 1]), 2: fit_plane(xyz[labels == 2])}
    assert fits[1].kind == "cylinder"
    ctx = context(rs.OrganizedCloud(xyz), sigma=np.full(labels.shape, noise))
    # the premise: the plain union is beyond the merge's rms bound (1.3 times the column's)
    union = ctx.fitter.refit(xyz[labels > 0], fits[1])
    assert not union or union.rms > 1.3 * fits[1].rms
    out, out_fits, adjacency = join_trimmed_pieces(ctx, labels, fits, {(1, 2)}, rms_factor=1.3)
    assert (out[:, :45] == 1).all() and (out[:, 45] == 0).all()
    assert set(out_fits) == {1} and adjacency == set()
    assert out_fits[1].kind == "cylinder" and abs(out_fits[1].radius - RADIUS) < 0.01
    assert abs(abs(out_fits[1].axis[1]) - 1.0) < 1e-3
    assert set(fits) == {1, 2} and (labels[:, 34:] == 2).all()  # inputs left alone


@pytest.mark.parametrize("seed", [0, 1])
def test_a_face_beyond_a_crease_stays_whole_though_its_crease_column_lies_on_the_column(context, seed):
    noise = 0.004  # three sigmas reach the face's first column, 9 mm off the arc
    xyz = _column(60, noise, seed, flank_from=45)
    labels = np.where(np.arange(60)[None, :] >= 45, 2, 1).repeat(40, axis=0).astype(np.int32)
    fits = {1: fit_cylinder(xyz[labels == 1]), 2: fit_plane(xyz[labels == 2])}
    assert fits[1].kind == "cylinder" and fits[2].rms < 2 * noise
    ctx = context(rs.OrganizedCloud(xyz), min_size=10, sigma=np.full(labels.shape, noise))
    # the premise: the face's returns within three sigmas of the column are more than the size floor
    near = np.abs(fits[1].distances(xyz[labels == 2])) <= TRIM_SIGMAS * noise
    assert near.sum() >= 10 and near.sum() < (labels == 2).sum() / 2
    out, out_fits, adjacency = join_trimmed_pieces(ctx, labels, fits, {(1, 2)}, rms_factor=1.3)
    assert (out == labels).all() and out_fits == fits and adjacency == {(1, 2)}


def test_planes_alone_are_not_asked(context):
    # two plane regions of one flat wall: asked, the larger's plane would take the other whole
    v, u = np.mgrid[0:40, 0:45].astype(float)
    xyz = np.dstack([u * 0.01, v * 0.02, 3.0 + np.random.default_rng(0).normal(0.0, 0.002, u.shape)])
    labels = np.where(np.arange(45)[None, :] >= 30, 2, 1).repeat(40, axis=0).astype(np.int32)
    fits = {k: fit_plane(xyz[labels == k]) for k in (1, 2)}
    ctx = context(rs.OrganizedCloud(xyz), sigma=np.full(labels.shape, 0.002))
    out, out_fits, adjacency = join_trimmed_pieces(ctx, labels, fits, {(1, 2)}, rms_factor=1.3)
    assert out is labels and out_fits == fits and adjacency == {(1, 2)}


def test_a_piece_under_the_size_floor_is_not_asked(context):
    noise = 0.002
    xyz = _with_mixed_returns(_column(45, noise, 0), 0)
    labels = np.ones(xyz.shape[:2], np.int32)
    labels[:, 34:] = 2
    fits = {1: fit_cylinder(xyz[labels == 1]), 2: fit_plane(xyz[labels == 2])}
    ctx = context(rs.OrganizedCloud(xyz), min_size=int((labels == 2).sum()) + 1, sigma=np.full(labels.shape, noise))
    out, out_fits, _ = join_trimmed_pieces(ctx, labels, fits, {(1, 2)}, rms_factor=1.3)
    assert out is labels and set(out_fits) == {1, 2}


def _column_behind_an_occluder(seed: int, beside: float = 0.0):
    """The column with its mixed-return column (46 columns, 40 rows): rows 0-21 region 1 (the
    arc), rows 22-27 in no region (a pipe crossing before it), rows 28-39 region 2 (the arc
    and the mixed returns), moved ``beside`` metres along x (another column)."""
    noise = 0.002
    xyz = _with_mixed_returns(_column(45, noise, seed), seed)
    xyz[28:, :, 0] += beside
    labels = np.zeros(xyz.shape[:2], np.int32)
    labels[:22, :45] = 1
    labels[28:, :] = 2
    fits = {1: fit_cylinder(xyz[labels == 1]), 2: fit_cylinder(xyz[labels == 2])}
    return xyz, labels, fits, noise


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_piece_apart_joins_its_column_when_asked_and_its_mixed_returns_are_freed(context, seed):
    xyz, labels, fits, noise = _column_behind_an_occluder(seed)
    assert fits[1].kind == "cylinder"
    ctx = context(rs.OrganizedCloud(xyz), sigma=np.full(labels.shape, noise))
    # the premise: the plain union is beyond the merge's rms bound (1.3 times the column's)
    union = ctx.fitter.refit(xyz[labels > 0], fits[1])
    assert not union or union.rms > 1.3 * fits[1].rms
    out, out_fits, _ = join_trimmed_pieces(ctx, labels, fits, set(), rms_factor=1.3)
    assert out is labels and set(out_fits) == {1, 2}  # apart and not offered: left alone
    out, out_fits, adjacency = join_trimmed_pieces(ctx, labels, fits, set(), rms_factor=1.3, apart={(1, 2)})
    assert (out[:22, :45] == 1).all() and (out[28:, :45] == 1).all()
    assert (out[22:28] == 0).all() and (out[:, 45] == 0).all()
    assert set(out_fits) == {1} and adjacency == set()
    assert out_fits[1].kind == "cylinder" and abs(out_fits[1].radius - RADIUS) < 0.01
    assert abs(abs(out_fits[1].axis[1]) - 1.0) < 1e-3


@pytest.mark.parametrize("seed", [0, 1])
def test_a_column_apart_beside_it_is_not_joined(context, seed):
    # the same piece 5 cm along x: another column of the same radius, 25 noise sigmas off
    xyz, labels, fits, noise = _column_behind_an_occluder(seed, beside=0.05)
    ctx = context(rs.OrganizedCloud(xyz), sigma=np.full(labels.shape, noise))
    # the premise: the trimmed union alone would take the piece's returns where the two arcs
    # cross; the pretest at the median refuses the pair
    regions = {k: np.flatnonzero(labels.ravel() == k) for k in (1, 2)}
    assert _trimmed_union(ctx, fits[1], regions[1], regions[2], 1.3) is not None
    assert pieces_near(ctx, fits, regions, [(regions[2].size, 1, 2)], 3.0) == [False]
    out, out_fits, _ = join_trimmed_pieces(ctx, labels, fits, set(), rms_factor=1.3, apart={(1, 2)})
    assert out is labels and out_fits == fits


@pytest.mark.parametrize("k, surface", [(0, 7), (1, 10)])
def test_a_column_seen_above_and_below_what_crosses_before_it_is_one_cylinder(k, surface):
    # nodding_1deg study seed 1456: columns of r 0.17 m at 4.6-5.0 m (scan 0) and r 0.13 m at
    # 3.9-4.3 m (scan 1), three and four returns wide, cut by a nearer surface into pieces of
    # 96 and 24 px of them, and of 82 and 28, each piece a cylinder; the smaller held 2-3
    # mixed returns along a limb, 14-41 mm off the union's surface, and the merge refused them
    from matrix_helpers import matrix_result, surface_feature
    from rangeseg_o3d.evaluation.metrics import parameter_errors

    scan, result = matrix_result("nodding_1deg", 1456, k)
    feature = surface_feature(scan, result, surface, of_surface=0.95)
    truth = scan.truth[surface]
    errors = parameter_errors(truth, feature.model)
    assert feature.kind == "cylinder"
    assert errors["radius_error"] <= 0.25 * truth.radius and errors["axis_error_deg"] < 5.0
