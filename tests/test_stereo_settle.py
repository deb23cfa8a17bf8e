"""On a stereo camera (NoiseModel.matched_window) the pipeline ends by joining pieces of a wall
to it along the rays and settling the pixels beside plane creases by the rays
(rangeseg_o3d.fullres.settle_creases): a far box corner's band of its grazing side face that
the front face's region took goes back to the side face."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.fitting.primitives import Plane
from rangeseg_o3d.fullres import region_stats, settle_creases
from rangeseg_o3d.result import INLIER_SIGMAS
from rangeseg_o3d.synthetic.depth_camera import _unit_noise

COEFF = 0.1 / (640 * 0.05)  # the sensor matrix's stereo row: range sigma per squared metre


def _convex_corner(seed, *, rows=120, cols=80, crease=40, z=3.5, turn_deg=20.0, f=640.0):
    """A box corner at 3.5 m (range sigma 3.8 cm a pixel, erring together over 3 x 3 pixels):
    left of column ``crease`` the front face turned ``turn_deg`` from head-on, right of it the
    side face at 90 degrees to it (seen near grazing), meeting at a convex crease through the
    rays half a pixel left of column ``crease`` at depth ``z``. Returns ``(cloud, sigma, truth, fits)``, truth 1 / 2."""
    v, u = np.mgrid[0:rows, 0:cols].astype(float)
    # the crease half a pixel left of column ``crease`` (a ray along it meets both planes at once)
    rays = np.dstack([(u - crease + 0.5) / f, (v - rows / 2) / f, np.ones((rows, cols))])
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    turn = np.radians(turn_deg)
    # normals pointing to the camera's side (a convex corner: each face behind the other's plane)
    normals = [np.array([np.sin(turn), 0.0, -np.cos(turn)]), np.array([np.cos(turn), 0.0, np.sin(turn)])]
    normals = [n if n @ np.array([0.0, 0.0, -z]) > 0 else -n for n in normals]
    on_line = np.array([0.0, 0.0, z])
    truth = np.where(u < crease, 1, 2)
    ranges = np.empty((rows, cols))
    fits = {}
    for k, normal in enumerate(normals, start=1):
        d = float(normal @ on_line)
        ranges[truth == k] = (d / (rays @ normal))[truth == k]
        fits[k] = Plane(normal=normal, d=d, rms=0.0, inliers=1)
    sigma = COEFF * ranges ** 2
    noisy = ranges + _unit_noise(np.random.default_rng(seed), ranges.shape, 3) * sigma
    return rs.OrganizedCloud(rays * noisy[..., None]), sigma, truth, fits


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_side_faces_band_the_front_face_took_goes_back_by_the_rays(seed):
    cloud, sigma, truth, fits = _convex_corner(seed)
    # the premise: the side face is seen near grazing and the front face's plane explains its
    # first columns within 3 range sigmas (the band the noise gives the nearer model)
    xyz = cloud.xyz
    band = (truth == 2) & (np.arange(truth.shape[1])[None, :] < 42)
    off = np.abs(xyz[band] @ fits[1].normal - fits[1].d)
    assert np.mean(off <= 3 * sigma[band]) > 0.95
    labels = np.where(band, 1, truth).astype(np.int32)
    stats = region_stats(xyz, labels, fits, sigma, INLIER_SIGMAS)
    out, out_stats = settle_creases(cloud, labels, fits, stats, sigma=sigma, k_sigma=3.0, min_angle_deg=20.0,
                                    inlier_factor=INLIER_SIGMAS)
    assert np.mean(out[band] == 2) > 0.95
    assert np.mean(out == truth) > 0.99
    assert out_stats.counts[2] == np.count_nonzero(out == 2)


def test_the_stereo_pipeline_ends_with_the_join_and_the_settling_and_a_kinects_does_not():
    cloud, _, _, _ = _convex_corner(0, rows=96, cols=120, crease=60)
    stereo = rs.load_config({"name": "rgbd_vga", "tile": 6, "sensor": {
        "sigma0": 0.001, "sigma_quadratic": COEFF, "noise_correlation_px": 3}})
    kinect = rs.load_config({"name": "rgbd_vga", "tile": 6, "sensor": {"sigma0": 0.001, "sigma_quadratic": COEFF}})
    timed = [[k for k in rs.Pipeline(c).run(cloud).timings if k.startswith("full.")] for c in (stereo, kinect)]
    assert timed[0][-6:] == ["full.join_pieces", "full.occluders", "full.settle", "full.caps", "full.bent_planes",
                             "full.curved_pairs"]
    assert "full.free_faces" in timed[0]
    stereo_only = {"full.join_pieces", "full.occluders", "full.settle", "full.caps", "full.free_faces",
                   "full.bent_planes", "full.curved_pairs"}
    assert not stereo_only & set(timed[1])


def _floor_and_grazing_face(seed, *, f=640.0, rows=200, cols=200, cx=50.0, cy=20.0):
    """A box side face standing on the floor, seen near grazing (the plane x = 0.9 m, z 4.5-6 m,
    y 0.5-1.0 m; incidence about 80 degrees), and the floor y = 1.0 m around it (a concave
    crease), ray-cast on a pinhole camera with the stereo row's range noise erring together over
    3 x 3 pixels. Returns ``(cloud, sigma, truth, planes)``: truth 1 the floor, 2 the face, 0 no
    return; planes the true ones (normals towards the camera)."""
    v, u = np.mgrid[0:rows, 0:cols].astype(float)
    rays = np.dstack([(u - cx) / f, (v - cy) / f, np.ones((rows, cols))])
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_floor = np.where(rays[..., 1] > 0, 1.0 / rays[..., 1], np.inf)
        t_face = np.where(rays[..., 0] > 0, 0.9 / rays[..., 0], np.inf)
    with np.errstate(invalid="ignore"):
        hit = rays * t_face[..., None]
    on_face = (hit[..., 2] >= 4.5) & (hit[..., 2] <= 6.0) & (hit[..., 1] >= 0.5) & (hit[..., 1] <= 1.0)
    face_first = on_face & (t_face < t_floor)
    ranges = np.where(face_first, t_face, t_floor)
    truth = np.where(face_first, 2, np.where(np.isfinite(ranges) & (ranges < 12.0), 1, 0))
    ranges = np.where(truth > 0, ranges, np.nan)
    sigma = COEFF * np.nan_to_num(ranges, nan=1.0) ** 2
    noisy = ranges + _unit_noise(np.random.default_rng(seed), ranges.shape, 3) * sigma
    planes = {1: Plane(normal=np.array([0.0, -1.0, 0.0]), d=-1.0, rms=0.0, inliers=1),
              2: Plane(normal=np.array([-1.0, 0.0, 0.0]), d=-0.9, rms=0.0, inliers=1)}
    return rs.OrganizedCloud(rays * noisy[..., None]), sigma, truth, planes


def _along_ray_sigmas(xyz, sigma, plane):
    # how far the plane meets each point's ray from the point, in its range sigmas
    ranges = np.linalg.norm(xyz, axis=-1)
    meet = plane.d / ((xyz / ranges[..., None]) @ plane.normal)
    return np.abs(ranges - meet) / sigma


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_along_the_rays_a_grazing_planes_crease_takes_no_pixel_beyond_the_range_noise(seed):
    cloud, sigma, truth, planes = _floor_and_grazing_face(seed)
    # the face's plane as fitted near grazing: 1.5 degrees off about the vertical, 3 cm nearer
    turn = np.radians(1.5)
    normal = np.array([-np.cos(turn), 0.0, np.sin(turn)])
    fits = {1: planes[1], 2: Plane(normal=normal, d=float(normal @ np.array([0.87, 0.75, 5.25])), rms=0.0, inliers=1)}
    xyz = cloud.xyz
    labels = truth.astype(np.int32)
    stats = region_stats(xyz, labels, fits, sigma, INLIER_SIGMAS)
    kwargs = dict(sigma=sigma, k_sigma=3.0, min_angle_deg=3.0, inlier_factor=INLIER_SIGMAS)
    by_distance, _ = settle_creases(cloud, labels, fits, stats, **kwargs)
    along, along_stats = settle_creases(cloud, labels, fits, stats, **kwargs, along_rays=True)
    off = _along_ray_sigmas(xyz, sigma, fits[2])
    # the premise: by distances, the face's plane takes floor pixels its plane meets beyond 3
    # range sigmas along their rays (within 3 sigmas of distance at about 80 degrees)
    wrong = (by_distance == 2) & (truth == 1)
    assert np.count_nonzero(wrong & (off > 3.0)) >= 20
    # along the rays, every pixel that moves lies within 3 range sigmas of both planes there
    moved = along != labels
    assert np.all(off[moved] <= 3.0 + 1e-9)
    assert np.all(_along_ray_sigmas(xyz, sigma, fits[1])[moved] <= 3.0 + 1e-9)
    assert np.count_nonzero((along == 2) & (truth == 1)) < 0.5 * np.count_nonzero(wrong)
    assert np.mean(along[truth > 0] == truth[truth > 0]) > np.mean(by_distance[truth > 0] == truth[truth > 0])
    assert along_stats.counts[2] == np.count_nonzero(along == 2)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_along_the_rays_the_side_faces_band_still_goes_back(seed):
    # the convex corner above, judged along the rays: the band within the noise of both planes
    cloud, sigma, truth, fits = _convex_corner(seed)
    band = (truth == 2) & (np.arange(truth.shape[1])[None, :] < 42)
    labels = np.where(band, 1, truth).astype(np.int32)
    stats = region_stats(cloud.xyz, labels, fits, sigma, INLIER_SIGMAS)
    out, _ = settle_creases(cloud, labels, fits, stats, sigma=sigma, k_sigma=3.0, min_angle_deg=20.0,
                            inlier_factor=INLIER_SIGMAS, along_rays=True)
    assert np.mean(out[band] == 2) > 0.95
    assert np.mean(out == truth) > 0.99
