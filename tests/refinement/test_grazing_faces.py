"""Faces seen near grazing on a depth camera (range noise growing with depth squared): the
range noise moves their points along the rays, off their planes only by its incidence
cosine, and a search whose band is three range-noise sigmas wide takes two faces as one
plane (Context.grazing_search, Context.grazing_piece)."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.fitting.robust import distance_noise
from rangeseg_o3d.refinement.context import Context
from rangeseg_o3d.synthetic.matrix import get_sensor, matrix_rng

KINECT = "kinect_640x480"


@pytest.fixture(scope="module")
def kinect():
    spec = get_sensor(KINECT)
    pipeline = rs.Pipeline(rs.load_config(spec.preset, overrides={
        f"sensor.{key}": value for key, value in spec.sensor_facts().items()}))
    return spec, pipeline


def _blob(kinect, seed, scan, faces):
    # the matrix's scan, the flat pixels of ``faces`` (truth ids) with a return, the noise
    spec, pipeline = kinect
    made = spec.simulate(matrix_rng(seed, KINECT, scan), False)
    cloud = made.cloud
    sigma = pipeline.sensor.noise.sigma(np.where(cloud.valid, cloud.range_image(), np.nan))
    truth = made.truth_ids.ravel()
    pool = np.flatnonzero(np.isin(truth, faces) & cloud.valid.ravel())
    return made, cloud, np.asarray(sigma, float), truth, pool


# (seed, scan, the face to find, the other face in the blob), matrix scans whose faces
# the tile grid lost: a box top 2.8 m away seen 85 degrees from head-on (12 mm range
# noise) beside a face of another box, and a face 5 m away (86 degrees, 37 mm) beside
# another box's top
CASES = [(89, 4, 9, 7), (89, 4, 16, 13)]


@pytest.mark.parametrize("seed, scan, face, other", CASES)
def test_a_grazing_face_beside_another_is_found_at_the_noise_of_its_distances(kinect, seed, scan, face, other):
    made, cloud, sigma, truth, pool = _blob(kinect, seed, scan, [face, other])
    fitter = kinect[1].fitter
    plain = Context(cloud, fitter, sigma, 288)
    piece, model = plain.dominant_piece(pool)
    # the premise: the range-noise search takes a plane over both faces, along the rays
    # (beyond the noise of its distances)
    assert (truth[piece] == other).any() and plain.plane_along_rays(model, piece)
    ctx = Context(cloud, fitter, sigma, 288, grazing_search=True)
    piece, model = ctx.dominant_piece(pool)
    on_face = truth[piece] == face
    assert model.kind == "plane" and on_face.mean() > 0.95
    assert on_face.sum() > 0.75 * (truth[pool] == face).sum()
    true_plane = made.truth[face]
    assert abs(float(model.normal @ true_plane.normal)) > np.cos(np.radians(1.0))
    noise = distance_noise(model, ctx.xyz[piece], ctx.sigma[piece])
    assert np.sqrt(np.mean(model.distances(ctx.xyz[piece]) ** 2)) < 1.5 * np.sqrt(np.mean(noise ** 2))


def test_a_face_seen_head_on_is_not_searched_again(kinect):
    # the trigger: a pool whose distances keep most of the range noise is no grazing pool
    made, cloud, sigma, truth, _ = _blob(kinect, 23, 5, [])
    counts = np.bincount(truth, minlength=max(made.truth) + 1)
    ctx = Context(cloud, kinect[1].fitter, sigma, 288, grazing_search=True)
    rays = ctx.xyz / np.linalg.norm(ctx.xyz, axis=1, keepdims=True)
    checked = 0
    for face, model in made.truth.items():
        if model.kind != "plane" or counts[face] < 2000:
            continue
        pool = np.flatnonzero((truth == face) & cloud.valid.ravel())
        cosine = np.median(np.abs(rays[pool] @ model.normal))
        if cosine > 0.6:
            assert ctx.grazing_piece(pool, float(np.median(sigma.ravel()[pool])), model) is None
            assert not ctx.seen_along_rays(model, pool)
            checked += 1
    assert checked >= 2  # the walls and the floor near the camera
