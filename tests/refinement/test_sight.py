"""Lines of sight: a plane region does not take a piece on its extension (a strip it would
claim, a region it would merge) that the camera sees past the plane to reach."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.fitting import fit_plane
from rangeseg_o3d.fitting.primitives import Plane
from rangeseg_o3d.refinement.context import Context
from rangeseg_o3d.refinement.merge import merge_regions
from rangeseg_o3d.refinement.recover import claim_occluded_strips
from rangeseg_o3d.refinement.sight import SEEN_PAST_SHARE, seen_past_plane

# a camera grid of 20 rows (-5..5 degrees) and 81 columns (-30..30 degrees, 0.75 degree apart)
_ELEVATION = np.radians(np.linspace(-5.0, 5.0, 20))[:, None]
_AZIMUTH = np.radians(np.linspace(-30.0, 30.0, 81))[None, :]
_RAYS = np.dstack(np.broadcast_arrays(np.sin(_AZIMUTH) * np.cos(_ELEVATION), np.sin(_ELEVATION),
                                      np.cos(_AZIMUTH) * np.cos(_ELEVATION)))
# a box face 0.8 x + 0.6 z = 1.6, seen at 2.2-2.4 m in columns 47-60 (5-15 degrees); its
# plane runs away to the left and passes 5.9 m away at columns 11-13 (-21.75..-20.25 degrees)
_NORMAL = np.array([0.8, 0.0, 0.6])
_FACE, _PATCH = slice(47, 61), slice(11, 14)
_SIGMA = 0.005


def _scene(between: str, seed: int = 0):
    """Ranges on the grid: the face, a patch of another surface on the face's extension,
    and between them (columns 14-46) a back wall 9 m away (``"wall"``: behind the face's
    plane, which would hide it had it reached there) or posts at 1.5 m (``"posts"``: in
    front of it, so the patch may be the face's own surface seen past them); the wall
    everywhere else. The face is region 1; nothing else is labelled."""
    meets = 1.6 / (_RAYS @ _NORMAL)  # the range at which each ray meets the face's plane
    ranges = 9.0 / _RAYS[..., 2]
    ranges[:, _FACE] = meets[:, _FACE]
    ranges[:, _PATCH] = meets[:, _PATCH]
    if between == "posts":
        ranges[:, 14:47] = 1.5
    ranges = ranges + np.random.default_rng(seed).normal(0.0, _SIGMA, ranges.shape)
    xyz = _RAYS * ranges[..., None]
    labels = np.zeros(ranges.shape, np.int32)
    labels[:, _FACE] = 1
    return xyz, labels


def _context(xyz, pipeline, *, wrap_columns=False):
    cloud = rs.OrganizedCloud(xyz)
    return Context(cloud, pipeline.fitter, np.full(xyz.shape[:2], _SIGMA), 20, wrap_columns=wrap_columns)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_face_plane_does_not_claim_a_patch_it_is_seen_past_to_reach(pipeline, seed):
    xyz, labels = _scene("wall", seed)
    fits = {1: fit_plane(xyz[labels == 1])}
    assert abs(fits[1].normal @ _NORMAL) > 0.999  # the face's plane, as the patch lies on it
    out, new_fits = claim_occluded_strips(_context(xyz, pipeline), labels, fits, valid=np.ones(labels.shape, bool),
                                          k_sigma=3.0)
    assert (out[:, _PATCH] == 0).all(), "the patch 3.5 m behind the face joined the face"
    assert (out == labels).all() and new_fits[1] is fits[1]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_patch_seen_past_posts_in_front_of_the_plane_joins_it(pipeline, seed):
    xyz, labels = _scene("posts", seed)
    fits = {1: fit_plane(xyz[labels == 1])}
    out, new_fits = claim_occluded_strips(_context(xyz, pipeline), labels, fits, valid=np.ones(labels.shape, bool),
                                          k_sigma=3.0)
    # its surface seen past the posts: the face's (but for a pixel or two its noise puts
    # outside the band of the face's plane extended 3.5 m)
    assert (out[:, _PATCH] == 1).mean() > 0.9 and set(np.unique(out[:, _PATCH])) <= {0, 1}
    assert (out[:, 14:47] == 0).all()  # the posts stay free
    assert abs(abs(new_fits[1].normal @ _NORMAL) - 1) < 1e-3


def test_a_glimpse_through_a_gap_does_not_refuse_the_patch(pipeline):
    # one column between the posts shows the wall behind the plane: one pixel of the 33 on
    # the line, under the share that refuses
    xyz, labels = _scene("posts")
    xyz[:, 30] = _RAYS[:, 30] * (9.0 / _RAYS[:, 30, 2:3])
    assert 1 / 33 < SEEN_PAST_SHARE
    plane = fit_plane(xyz[labels == 1])
    patch = np.flatnonzero(np.isin(np.arange(xyz[..., 0].size) % 81, [11, 12, 13]))
    assert not seen_past_plane(xyz.reshape(-1, 3), np.full(xyz[..., 0].size, _SIGMA), labels, patch, 1, plane, 3.0)
    xyz[:, 29] = xyz[:, 30]  # two columns of wall: two pixels of 33, still a glimpse
    assert not seen_past_plane(xyz.reshape(-1, 3), np.full(xyz[..., 0].size, _SIGMA), labels, patch, 1, plane, 3.0)
    xyz[:, 25:29] = xyz[:, 30:31]  # six of them: past the share
    assert seen_past_plane(xyz.reshape(-1, 3), np.full(xyz[..., 0].size, _SIGMA), labels, patch, 1, plane, 3.0)


def test_the_line_goes_the_short_way_round_a_360_degree_grid():
    # a wall 3 m away seen all around (one row of 360 columns, 1 degree apart); region 1 is
    # the wall in columns 0-9, the patch the wall in columns 350-354. Across the seam stand
    # posts in front of the wall; the long way round sees a room behind the wall's plane.
    azimuth = np.radians(np.arange(360.0))
    rays = np.stack([np.sin(azimuth), np.zeros(360), np.cos(azimuth)], axis=1)
    ranges = np.full(360, 20.0)  # behind the wall's plane where the rays meet it at all
    wall = np.r_[0:10, 350:355]
    ranges[wall] = 3.0 / rays[wall, 2]
    ranges[355:360] = 1.0
    xyz = (rays * ranges[:, None]).reshape(1, 360, 3)
    labels = np.zeros((1, 360), np.int32)
    labels[0, :10] = 1
    plane = Plane(normal=np.array([0.0, 0.0, 1.0]), d=3.0, rms=0.001, inliers=15)
    patch = np.arange(350, 355)
    sigma = np.full(360, _SIGMA)
    assert not seen_past_plane(xyz.reshape(-1, 3), sigma, labels, patch, 1, plane, 3.0, wrap_columns=True)
    assert seen_past_plane(xyz.reshape(-1, 3), sigma, labels, patch, 1, plane, 3.0, wrap_columns=False)


def test_nothing_between_or_no_region_is_no_sight_of_the_plane():
    xyz, labels = _scene("wall")
    plane = fit_plane(xyz[labels == 1])
    flat, sigma = xyz.reshape(-1, 3), np.full(xyz[..., 0].size, _SIGMA)
    beside = np.flatnonzero(np.isin(np.arange(flat.shape[0]) % 81, [46]))  # touching the face
    assert not seen_past_plane(flat, sigma, labels, beside, 1, plane, 3.0)
    patch = np.flatnonzero(np.isin(np.arange(flat.shape[0]) % 81, [11, 12, 13]))
    assert not seen_past_plane(flat, sigma, np.zeros_like(labels), patch, 1, plane, 3.0)
    invalid = flat.copy()
    invalid[np.isin(np.arange(flat.shape[0]) % 81, np.arange(14, 47))] = np.nan  # nothing seen between
    assert not seen_past_plane(invalid, sigma, labels, patch, 1, plane, 3.0)


@pytest.mark.parametrize("between, merged", [("wall", False), ("posts", True)])
def test_planes_apart_merge_only_where_nothing_is_seen_past_them(pipeline, between, merged):
    # the patch on the face's extension is a region of its own: with the back wall seen
    # between them behind the face's plane they are two surfaces (two box tops of one
    # height with the floor between, a face and a pipe far behind it); past posts in front
    # of the plane, pieces of one surface (a wall either side of a column)
    xyz, labels = _scene(between)
    labels[:, _PATCH] = 2
    fits = {k: fit_plane(xyz[labels == k]) for k in (1, 2)}
    out, new_fits, _ = merge_regions(_context(xyz, pipeline), labels, fits, set(), max_angle_deg=3.0,
                                     tolerance=0.05, disjoint=True, rms_factor=1.3)
    assert np.unique(out[labels > 0]).size == (1 if merged else 2)
    if merged:
        assert abs(abs(new_fits[int(out[0, 50])].normal @ _NORMAL) - 1) < 1e-3
    else:
        assert (out == labels).all()
