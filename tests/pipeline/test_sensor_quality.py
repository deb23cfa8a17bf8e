"""End to end on small generated scans of several sensors, with Hoover floors (T = 0.8).

The floors guard what the method reaches today on scans it was not tuned on (the matrix's
random rooms and the LMS200 scenes at other angular steps and noise); they are not the
project's targets (issue 13), which some sensors do not meet yet. Only the sensor section
changes between scanners of one family.
"""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.evaluation import evaluate, hoover
from rangeseg_o3d.synthetic.lms200 import simulate_lms200
from rangeseg_o3d.synthetic.matrix import get_sensor, matrix_rng
from rangeseg_o3d.synthetic.suite import lms200_scenes

pytestmark = pytest.mark.slow  # (files holding a slow test run first: tests/conftest.py)


def _percent_correct(pairs) -> float:
    correct = total = 0
    for scan, result in pairs:
        score = evaluate(scan, result).hoover
        correct += score.n_correct
        total += score.n_truth
    return 100.0 * correct / total


def _nodding(step_deg: float, noise: float):
    scenes = dict(lms200_scenes())
    config = rs.load_config("lms200", overrides={"sensor.sigma0": noise})
    pipe = rs.Pipeline(config)
    pairs = []
    for name in ("default", "boxes_yawed", "corridor_clutter"):
        scan = simulate_lms200(scenes[name], rows=int(round(70 / step_deg)), beam_step_deg=step_deg,
                               noise_sigma=noise, seed=1)
        pairs.append((scan, pipe.run(scan.cloud)))
    return pairs


@pytest.mark.parametrize("step_deg, noise, floor", [
    (0.5, 0.005, 90.0),    # today 31/31 (the lms200 preset, sensor noise 5 mm)
    (1.0, 0.01, 90.0),     # 1 cm range noise: today 28/29
])
def test_nodding_lasers_at_other_steps_and_noise(step_deg, noise, floor):
    pairs = _nodding(step_deg, noise)
    assert _percent_correct(pairs) >= floor
    for scan, result in pairs:
        assert evaluate(scan, result).false_fittings == 0


def _matrix_row(name: str, scans: int = 2):
    spec = get_sensor(name)
    config = rs.load_config(spec.preset, overrides={f"sensor.{key}": value
                                                     for key, value in spec.sensor_facts(True).items()})
    pipe = rs.Pipeline(config)
    pairs = []
    for k in range(scans):
        scan = spec.simulate(matrix_rng(0, name, k), True)
        pairs.append((scan, pipe.run(scan.cloud)))
    return pairs


# Every preset below takes its scales from the sensor (rangeseg_o3d.scales): only the
# sensor facts of each row differ. "today": the two quick scans on the commit that set the floor.
@pytest.mark.parametrize("name, floor", [
    ("spinning_64x1024", 85.0),   # today 27/27 (360 deg, wrap_columns)
    ("spinning_32x1024", 85.0),   # today 20/22 (3 cm noise; 18/22 before the steady-turn crease test)
    ("spinning_128x2048", 90.0),  # today 37/38 (33/38 before the steady-turn crease test)
    ("nodding_1deg", 85.0),       # today 18/19
    ("nodding_0.5deg", 85.0),     # today 16/17 (quick: 1 deg beams, 70 rows)
    ("nodding_0.25deg", 85.0),    # today 21/22 (quick: 0.5 deg beams, 140 rows)
    ("noise_2mm", 85.0),          # today 14/15
    ("noise_10mm", 80.0),         # today 16/18 (15/18 before the plane noise floor)
    ("noise_20mm", 85.0),         # today 22/24 (15/24 before the plane noise floor): target not met
    ("kinect_640x480", 60.0),     # today 19/28 on the quick (half-resolution) frames: target not met
    ("stereo_1280x720", 70.0),    # today 23/29 (20/29 before the tile fitter judged tile means by their noise)
    ("tabletop_abw", 80.0),       # today 23/26 (17/26 before this session): target not met
])
def test_matrix_sensors_end_to_end(name, floor):
    pairs = _matrix_row(name)
    assert _percent_correct(pairs) >= floor
    # noise_20mm: a box face fitted with a strip of its neighbour bends into a cylinder
    # within the noise (2 today, 1 before the plane noise floor): target not met
    assert sum(evaluate(scan, result).false_fittings for scan, result in pairs) <= (
        2 if name == "noise_20mm" else 0)


def test_abw_images_reach_a_floor():
    from rangeseg_o3d.io.abw import abw_images, load_abw

    paths = abw_images()
    if not paths:
        pytest.skip("no ABW images in ../shared/data/abw")
    pipe = rs.Pipeline("abw")
    correct = total = over = under = 0
    for path in paths:
        image = load_abw(path)
        # the preset leaves the tile to the camera's 1.29 mm depth step: 2 x 2 at 0.77-1.11 m
        assert pipe.scales(image.cloud).tile == 2
        labels = pipe.run(image.cloud).labels
        score = hoover(image.truth_ids, labels, tolerance=0.8, min_region=1, count_unlabelled=True)
        correct += score.n_correct
        total += score.n_truth
        over += score.n_over
        under += score.n_under
    # SegComp rules; today 172/192 (89.6 %) on the ten images, over 0.2 and under 0.1 per
    # image (targets: 90 %, 0.5, 0.3: the correct rate is not met). UE got 88.1 % in 1996.
    assert 100.0 * correct / total >= 88.5
    assert over / len(paths) <= 0.5 and under / len(paths) <= 0.3


def _matrix_scan(name: str, k: int, seed: int = 0):
    """Scan ``k`` of matrix row ``name`` (full size) and the row's pipeline result on it."""
    from matrix_helpers import matrix_result

    return matrix_result(name, seed, k)


def _assert_one_plane_region(scan, result, surface: int, share: float):
    """Truth ``surface`` is correctly detected, as a plane, by a region ``share`` of whose
    pixels lie on it (more)."""
    ev = evaluate(scan, result)
    assert surface in ev.hoover.correct
    region = result.labels == ev.hoover.correct[surface]
    assert (scan.truth_ids[region] == surface).mean() > share
    assert {f.label: f.kind for f in result.features}[ev.hoover.correct[surface]] == "plane"


def _correct_region(scan, result, surface: int, kind: str) -> np.ndarray:
    """The mask of the region that correctly detects truth ``surface``, which must be of
    ``kind`` in the truth and in the result."""
    assert scan.truth[surface].kind == kind
    ev = evaluate(scan, result)
    assert surface in ev.hoover.correct
    assert {f.label: f.kind for f in result.features}[ev.hoover.correct[surface]] == kind
    return result.labels == ev.hoover.correct[surface]


@pytest.mark.parametrize("seed, k, side", [(0, 0, 24), (11, 0, 11)])
def test_box_sides_seen_edge_on_come_back_whole_and_alone(seed, k, side):
    # tabletop_abw: a box side 56 x 4 pixels at 87.6 deg to the rays (seed 0, scan 0) and
    # one of 148 x 4 at 88.4 deg (seed 11, scan 0). No pixel of them has a 3x3
    # neighbourhood of leftover pixels and they are under the tile floor (128 pixels at
    # tile 4): they were lost whole (only thin blobs bring them back), and the first one
    # back took 97 pixels of the table and of the box's other faces by its rim and claims
    # (its plane lies along the rays beside its image line), 75 % of its region
    scan, result = _matrix_scan("tabletop_abw", k, seed)
    _assert_one_plane_region(scan, result, side, 0.95)


@pytest.mark.parametrize("seed, k, side, share", [(71, 1, 19, 0.85), (0, 4, 17, 0.9)])
def test_a_box_side_seen_edge_on_keeps_no_rim_of_its_neighbours(seed, k, side, share):
    # tabletop_abw: box sides seen edge-on, recovered from the blobs in pieces whose rims and
    # claims took pixels of the table and of the box's other faces; those were held to the
    # rms of the plane that took them, which they raised. Seed 71 scan 1: 293 pixels, 4-5
    # columns, 87 deg, three pieces merged (rms 0.10 mm, their own 0.05 mm): 76 % of its
    # region on it (missed at T = 0.8) before the rms as found was the floor. Seed 0 scan 4:
    # 197 pixels, 2 columns, 88.6 deg, a piece merged into the tile region holding the rest:
    # 82 % before that region was held to the rms of the piece as found
    scan, result = _matrix_scan("tabletop_abw", k, seed)
    _assert_one_plane_region(scan, result, side, share)


def test_a_floor_and_two_columns_in_one_region_come_back_as_three():
    # nodding_0.5deg, seed 0, scan 2: the floor and the two columns standing on it (truth
    # 1, 7, 14) leak into one region that no model explains; the trimmed fit's best plane is
    # the one tangent to both columns (beyond the noise, its inliers a strip of each joined
    # through the floor), and the split kept nothing of them. Local starts find each.
    scan, result = _matrix_scan("nodding_0.5deg", 2)
    ev = evaluate(scan, result)
    assert {1, 7, 14} <= set(ev.hoover.correct)
    kinds = {r.truth_id: r.kind for r in ev.regions}
    assert (kinds[1], kinds[7], kinds[14]) == ("plane", "cylinder", "cylinder")
    assert not result.unfitted


def test_a_column_against_a_box_in_one_large_region_comes_back_as_four_surfaces():
    # nodding_0.5deg, seed 1034, scan 1: a column (r 0.19 m) standing half sunk into a box's
    # face, with that face, the box's other side and its top, leaked into one region of 5878
    # px that no model explains. Neither trimmed search found a surface (the best three-point
    # plane takes a strip of the column beside the face: 10.2 mm rms at 5 mm noise), and the
    # local starts on every pixel (Context._start_pieces) were not run over 4000 px: the
    # region stayed unfitted and the four surfaces were missed.
    scan, result = _matrix_scan("nodding_0.5deg", 1, seed=1034)
    ev = evaluate(scan, result)
    assert {1, 8, 11, 13} <= set(ev.hoover.correct)
    kinds = {r.truth_id: r.kind for r in ev.regions}
    assert (kinds[1], kinds[8], kinds[11], kinds[13]) == ("plane", "plane", "plane", "cylinder")
    column = next(f for f in result.features if f.label == ev.hoover.correct[13])
    assert abs(column.radius - scan.truth[13].radius) < 0.1 * scan.truth[13].radius
    assert not result.unfitted


def test_a_box_and_a_column_in_a_region_too_large_for_the_starts_come_back():
    # nodding_0.25deg, seed 1036, scan 0: a column (truth 16, r 0.30 m), a box's two sides
    # (15, 13) and the floor beside them, one pool of 17196 px no search explains; over
    # _START_POOL_MAX the local starts were not run and 12 000 px were left in no region.
    # On every other row and column they find each.
    scan, result = _matrix_scan("nodding_0.25deg", 0, seed=1036)
    ev = evaluate(scan, result)
    assert {13, 15, 16} <= set(ev.hoover.correct)
    kinds = {r.truth_id: r.kind for r in ev.regions}
    assert (kinds[13], kinds[15], kinds[16]) == ("plane", "plane", "cylinder")
    column = next(f for f in result.features if f.label == ev.hoover.correct[16])
    assert abs(column.radius - scan.truth[16].radius) < 0.1 * scan.truth[16].radius
    assert not result.unfitted


def test_wall_strips_between_columns_of_a_nodding_scan_are_the_wall():
    # nodding_1deg, seed 0, scan 4: a wall 6 m away behind three columns. Before unlabelled
    # strips were claimed by the planes they lie on (refinement.recover.claim_occluded_strips),
    # its 2-pixel strips between the columns stayed free and its region held 76 % of it
    # (missed at T = 0.8).
    scan, result = _matrix_scan("nodding_1deg", 4)
    ev = evaluate(scan, result)
    sizes = np.bincount(scan.truth_ids.ravel())
    walls = [k for k, m in scan.truth.items() if m.kind == "plane" and k < sizes.size
             and abs(m.normal[0]) > 0.99 and sizes[k] > 500]
    assert walls, "the scan's far wall"
    for wall in walls:
        assert wall in ev.hoover.correct
        region = result.labels == ev.hoover.correct[wall]
        assert (scan.truth_ids[region] == wall).mean() > 0.95
    assert ev.hoover.n_correct == ev.hoover.n_truth and ev.false_fittings == 0


def test_a_tile_region_too_small_to_fit_leaves_its_pixels_to_the_full_resolution_steps():
    # stereo_1280x720, seed 1025, scan 3: eight 6 x 6 tiles of the floor beside a box at the
    # frame's edge, too few tile means for a fit, stayed a 288-px unfitted region inside the
    # floor's pixels, and the floor (299694 px) counted as over-segmented.
    scan, result = _matrix_scan("stereo_1280x720", 3, seed=1025)
    assert not result.unfitted
    _assert_one_plane_region(scan, result, 1, 0.95)


@pytest.mark.parametrize("seed, k, face", [(7, 3, 14), (7, 1, 17)])
def test_a_far_face_a_pipe_cuts_in_two_comes_back_as_one_region(seed, k, face):
    # stereo_1280x720: a pipe before a far box face cuts it in two on the grid (seed 7 scan 3:
    # 5536 + 2862 px; scan 1: 1399 + 1253 px), each piece under a tile model turned 9-11
    # degrees from the other's. The pieces touch not, so no merge joined them (over-segmented)
    # before occluded_planes.join_across_occluders joined them across the pipe
    _assert_one_plane_region(*_matrix_scan("stereo_1280x720", k, seed), face, 0.9)


def test_a_pipe_receding_from_a_stereo_camera_is_a_cylinder():
    # stereo_1280x720, seed 23, scan 3: a pipe (r 0.10 m, 3.7 m away, its axis 32 degrees from the
    # image plane) held as one plane region. bent_planes started its cylinder with the axis along
    # the region's longest extent across the view, 18 degrees off; the refit stopped 5 degrees off
    # in a local minimum whose squares exceeded the plane's: the pipe stayed a plane (a false fitting).
    # Turned into the region's plane along the rays, the start refits to the pipe.
    scan, result = _matrix_scan("stereo_1280x720", 3, 23)
    ev = evaluate(scan, result)
    pipe = next(r for r in ev.regions if r.truth_id == 7)
    assert scan.truth[7].kind == "cylinder"
    assert pipe.kind == "cylinder"
    assert pipe.radius_error < 0.01 and pipe.axis_error_deg < 3.0
    assert ev.false_fittings == 0


@pytest.mark.parametrize("seed, k, face", [(1070, 1, 15), (1091, 5, 13)])
def test_a_narrow_face_under_kinect_noise_keeps_the_plane_along_its_rays(seed, k, face):
    # kinect_640x480: box faces 8-9 px wide seen near head-on (seed 1070 scan 1: 1103 px,
    # 18 degrees, 3.5 m, 18 mm of range noise over a 5 cm width; seed 1091 scan 5: 1407 px,
    # 10 degrees, 4.1 m). Their least-squares planes turn towards the rays (seed 1070's by 54
    # degrees), beyond the noise of their distances, so the blobs were refused as bands and
    # freed whole (missed); fitted along their rays they are faces
    scan, result = _matrix_scan("kinect_640x480", k, seed=seed)
    assert scan.truth[face].kind == "plane"
    _assert_one_plane_region(scan, result, face, 0.95)
    region = next(r for r in evaluate(scan, result).regions if r.truth_id == face)
    assert region.normal_error_deg < 5.0
    assert (result.labels[scan.truth_ids == face] == region.label).mean() > 0.9


@pytest.mark.parametrize("seed, k, pipe", [(1079, 1, 7), (1076, 1, 24)])
def test_a_pipe_whose_blob_a_plane_along_the_rays_also_fits_stays_a_cylinder(seed, k, pipe):
    # kinect_640x480: pipes of r 0.14-0.18 m at 4.1-4.7 m left to the full-resolution blobs
    # (seed 1079 scan 1: 2535 px). Their planes along the rays explain them within the noise as
    # well; the fitter's bend test on block means is asked first and keeps them cylinders
    scan, result = _matrix_scan("kinect_640x480", k, seed=seed)
    truth = scan.truth[pipe]
    assert truth.kind == "cylinder"
    ev = evaluate(scan, result)
    assert pipe in ev.hoover.correct
    region = next(r for r in ev.regions if r.truth_id == pipe)
    assert region.kind == "cylinder"
    assert region.radius_error < 0.5 * truth.radius


@pytest.mark.parametrize("face", [10, 14])
def test_faces_under_correlated_kinect_noise_are_not_freed_as_bands(face):
    # kinect_real_640x480, seed 1069 scan 3: a box's faces at 4.1-4.3 m (1026 and 3302 px)
    # left to the full-resolution blobs. Their planes fit them 1.1-1.2 times the noise of their
    # distances (returns erring together over 9 px, in 1/8-px disparity steps): beyond the
    # chi-square bound over every pixel, they were refused as bands seen along the rays and
    # freed (missed, 795 and 2080 px in no region); over the independent returns they hold
    scan, result = _matrix_scan("kinect_real_640x480", 3, seed=1069)
    assert scan.truth[face].kind == "plane"
    _assert_one_plane_region(scan, result, face, 0.95)
    region = next(r for r in evaluate(scan, result).regions if r.truth_id == face)
    assert (result.labels[scan.truth_ids == face] == region.label).mean() > 0.85
    assert region.normal_error_deg < 3.0


def test_a_tile_region_the_split_found_nothing_in_is_searched_at_sensor_resolution():
    # kinect_real_640x480, seed 1168 scan 5: a box's three faces 3-4 m away (truth 9, 11, 13;
    # 1006, 2788 and 1687 px) in one tile region of 102 tile means, which no model explained
    # and the tile grid's split found nothing in: it was reported unfitted (2826 px) and all
    # three faces were missed. Its pixels now go to the full-resolution recovery, whose split
    # finds the largest face; no region is left unfitted
    scan, result = _matrix_scan("kinect_real_640x480", 5, seed=1168)
    assert scan.truth[11].kind == "plane"
    _assert_one_plane_region(scan, result, 11, 0.9)
    assert not result.unfitted


def test_a_short_pipe_at_the_frames_edge_is_a_cylinder_not_a_ball():
    # kinect_real_640x480, seed 1079 scan 1: a pipe (truth 22, r 0.12 m, 2 m away) seen over
    # 0.21 m of its length at the frame's left edge. Its tile means made it a ball of r 0.15 m
    # (6.6 mm rms on its pixels, where its cylinder leaves 4.4 mm): a false fitting
    scan, result = _matrix_scan("kinect_real_640x480", 1, seed=1079)
    truth = scan.truth[22]
    assert truth.kind == "cylinder"
    ev = evaluate(scan, result)
    assert 22 in ev.hoover.correct
    region = next(r for r in ev.regions if r.truth_id == 22)
    assert region.kind == "cylinder"
    assert region.radius_error < 0.1 * truth.radius


def test_a_column_and_a_wall_a_box_cuts_apart_come_back_as_one_region_each():
    # kinect_640x480, seed 1043, scan 4: a box before a column (truth 17, r 0.25 m, 4.4 m
    # away) cuts it into pieces of 7247 and 1505 px whose cylinders' axes are 2.9 degrees
    # apart: the merge's pre-test carried the short piece's axis a metre to the long one's
    # point and missed it by 6 cm, so no union was tried (over-segmented). And a 204-px strip
    # of the far wall (truth 4, 5.2 m) at the frame's left edge, cut from the wall's region by
    # the column, stood as a face of its own found along the rays, on the wall's plane within
    # 2 mm on the mean (over-segmented under the tie rule)
    scan, result = _matrix_scan("kinect_640x480", 4, seed=1043)
    _assert_one_plane_region(scan, result, 4, 0.95)
    ev = evaluate(scan, result)
    assert 17 in ev.hoover.correct
    column = next(f for f in result.features if f.label == ev.hoover.correct[17])
    assert column.kind == "cylinder"
    assert abs(column.radius - scan.truth[17].radius) < 0.1 * scan.truth[17].radius
    assert (result.labels == ev.hoover.correct[17]).sum() > 0.95 * (scan.truth_ids == 17).sum()


def test_a_balls_limb_left_in_a_blob_beside_another_ball_goes_back_to_it():
    # kinect_640x480, seed 1042, scan 3: a ball (truth 24, r 0.31 m, 4.3 m away) whose tile
    # region stops short of its limb; 489 limb pixels, on its sphere within 0.26 noise sigmas
    # on the median, were left in a blob with a farther ball it hides in part (877 px, 58 %
    # of the blob). No search explained that blob, both stayed unlabelled, and the near ball's
    # region held 79.6 % of it (missed at T = 0.8).
    scan, result = _matrix_scan("kinect_640x480", 3, seed=1042)
    ev = evaluate(scan, result)
    assert 24 in ev.hoover.correct
    ball = result.labels == ev.hoover.correct[24]
    assert (scan.truth_ids[ball] == 24).mean() > 0.95
    assert ball.sum() > 0.95 * (scan.truth_ids == 24).sum()
    assert {f.label: f.kind for f in result.features}[ev.hoover.correct[24]] == "sphere"


@pytest.mark.parametrize("k, face", [(1, 19), (3, 15)])
def test_a_face_under_correlated_noise_and_depth_steps_keeps_its_plane(k, face):
    # kinect_real_640x480, seed 1046: faces 3.9 and 4.5 m away (8086 and 9691 px) whose
    # correlated noise and 1/8-px depth steps bent_planes took for a bend, fitting cylinders of
    # 3.2 and 2.9 m over 14.5 and 17.3 degrees of their arcs (false fittings): a cylinder the
    # fitter would refuse for its arc, under its min_arc_deg of 30
    scan, result = _matrix_scan("kinect_real_640x480", k, seed=1046)
    assert scan.truth[face].kind == "plane"
    region = next(r for r in evaluate(scan, result).regions if r.truth_id == face)
    assert region.kind == "plane"


def test_a_ceiling_piece_polish_makes_a_plane_joins_the_ceiling_apart_from_it():
    # spinning_64x1024, seed 1045, scan 3: 33 px of the ceiling at 6.3 m (truth 2), cut off
    # by an occluder on the top two rows, were recovered as a cylinder and made a plane in
    # polish, after the merge that pairs pieces apart: a region of their own beside the
    # ceiling's 2008 px (over-segmented)
    _assert_one_plane_region(*_matrix_scan("spinning_64x1024", 3, seed=1045), 2, 0.95)


def test_a_pipe_and_its_end_cap_in_one_region_come_back_as_both():
    # spinning_64x1024, study seed 1181, scan 3: a horizontal pipe (truth 20, r 0.20 m, 398 px)
    # and its end cap (truth 22, 490 px) under 15 mm of noise, 476 px of them in one region no
    # model explained. The trimmed search's local starts found a ball over both that fitted
    # neither piece; the dominant plane's three-sigma band lay along the pipe and took a strip
    # of the cap, which the fitter refused, and the region was left unfitted (both missed). The
    # one-sigma face band now finds the cap, and the pipe's search follows
    scan, result = _matrix_scan("spinning_64x1024", 3, seed=1181)
    _assert_one_plane_region(scan, result, 22, 0.95)
    _correct_region(scan, result, 20, "cylinder")
    assert not result.unfitted


def test_a_pipe_settles_off_its_end_cap_until_its_refit_stops_moving_the_border():
    # spinning_128x2048, study seed 1183, scan 0: a pipe (truth 11, r 0.21 m, 448 px) and its
    # end cap seen near head-on (truth 13, 899 px). The split's cylinder took 189 px of the
    # cap's rim, growth more; one round of settling gave 138 back and left 147 (25 % of the
    # pipe's region: missed). The pipe's refit without the rim gives back more: 70 after
    # three rounds
    scan, result = _matrix_scan("spinning_128x2048", 0, seed=1183)
    pipe = _correct_region(scan, result, 11, "cylinder")
    _correct_region(scan, result, 13, "plane")
    assert (scan.truth_ids[pipe] == 13).sum() < 0.1 * (scan.truth_ids == 13).sum()


def test_a_column_a_pipe_crosses_keeps_its_piece_above_the_pipe():
    # noise_20mm, study seed 1182, scan 3: a column (truth 18, r 0.16 m, 4 columns wide at
    # 4.5 m) crossed in front by a pipe: 114 px below it a cylinder, 33 px above it a plane of
    # its own (over-segmented). The merge of a piece into a curved region asked only regions
    # that touch; with merge_disjoint the curved regions apart are asked too
    scan, result = _matrix_scan("noise_20mm", 3, seed=1182)
    column = _correct_region(scan, result, 18, "cylinder")
    assert column.sum() > 0.95 * (scan.truth_ids == 18).sum()


def test_a_line_of_mixed_returns_beside_a_column_is_no_surface():
    # noise_2mm, study seed 1187, scan 5: a column (truth 7, r 0.17 m at 3.4 m, 344 px) before
    # a wall 1.1 m behind it. The returns the beam mixed between them along its limb (one
    # column, 27 px) were recovered as a thin plane, which the settling then fed 8 of the
    # column's limb pixels: the column counted as split. That region is released, the limb
    # pixels rejoin the column and the mixed returns stay in no region
    scan, result = _matrix_scan("noise_2mm", 5, seed=1187)
    column = _correct_region(scan, result, 7, "cylinder")
    assert column.sum() > 0.98 * (scan.truth_ids == 7).sum()
    mixed = (scan.truth_ids == 0) & scan.cloud.valid  # (the simulator's mixed returns)
    beside = np.zeros_like(mixed)
    beside[:, 1:] |= column[:, :-1]
    beside[:, :-1] |= column[:, 1:]
    assert (result.labels[mixed & beside & ~column] == 0).all()


@pytest.mark.parametrize("seed, k, face", [(1212, 1, 22), (1214, 2, 24)])
def test_a_narrow_face_is_a_plane_once_its_mixed_returns_are_left_out(seed, k, face):
    # noise_20mm, study seeds: a box face five returns wide at 4.5 m (seed 1212 scan 1, truth 22,
    # 72 px) and at 3.9 m (seed 1214 scan 2, truth 24, 74 px) held 13 and 4 returns its edges
    # mixed with the wall behind, which bent its fit to a sphere of 1.5 m and a cylinder of
    # 0.32 m (false fittings). Without them the fitter gives the face's plane
    scan, result = _matrix_scan("noise_20mm", k, seed=seed)
    region = _correct_region(scan, result, face, "plane")
    assert (scan.truth_ids[region] == face).mean() > 0.9


@pytest.mark.parametrize("row, seed, k, pipe", [("nodding_1deg", 1211, 3, 7), ("noise_20mm", 1210, 5, 10)])
def test_a_pipe_whose_limbs_look_mixed_keeps_its_cylinder(row, seed, k, pipe):
    # study seeds. nodding_1deg seed 1211 scan 3: a column of 0.17 m at 4.6 m, four returns
    # across (truth 7, 224 px); its two limbs pass the mixed-return test, and the two returns
    # left between them lie on a line whatever the surface: they do not decide its kind.
    # noise_20mm seed 1210 scan 5: a pipe of 0.15 m at 3.1 m (truth 10) whose limbs pass the test
    # too; the fitter gives the other returns a plane within the noise, but the pipe's cylinder
    # refitted to them resolves its bend (an F-test)
    scan, result = _matrix_scan(row, k, seed=seed)
    region = _correct_region(scan, result, pipe, "cylinder")
    assert (scan.truth_ids[region] == pipe).sum() > 0.8 * (scan.truth_ids == pipe).sum()


def test_a_box_top_recovered_at_full_resolution_takes_back_its_band_from_the_face_beside_it():
    # kinect_640x480, study seed 1190, scan 3: a box top (truth 17, 722 px at 3.2-3.8 m, seen at
    # 75 deg) the tile grid did not see, recovered from the pixels its tile models left. The
    # plane beside it had taken 141 of its pixels along the crease at labelling, within the
    # noise: its region held 575 (80 %: missed). Its border settles back as close_gaps settles
    # the abw preset's planes
    scan, result = _matrix_scan("kinect_640x480", 3, seed=1190)
    top = _correct_region(scan, result, 17, "plane")
    assert (scan.truth_ids[top] == 17).sum() > 0.84 * (scan.truth_ids == 17).sum()


@pytest.mark.parametrize("seed, k, top, side", [(1228, 5, 7, 8), (1224, 2, 21, 25)])
def test_a_far_box_corner_seen_near_grazing_is_its_two_faces_not_one_curved_region(seed, k, top, side):
    # kinect_640x480, study seeds: a box's top and side at 4.1 m seen 82-83 deg from head-on
    # (seed 1228 scan 5, truth 7 and 8: 356 and 446 px) and at 4.1-4.8 m (seed 1224 scan 2,
    # truth 21 and 25: 522 and 1296 px), recovered from one blob, whose search answered a
    # sphere of r 0.29 m (30 mm rms) and a cylinder of r 0.21 m (23 mm rms) within the range
    # noise over both faces (false fittings, both faces missed). Each face's plane fits it at
    # 3-6 mm, the noise of its distances: the faces come back as two planes
    scan, result = _matrix_scan("kinect_640x480", k, seed=seed)
    for face in (top, side):
        region = _correct_region(scan, result, face, "plane")
        assert (scan.truth_ids[region] == face).mean() > 0.8
    near = np.isin(scan.truth_ids, [top, side])
    curved = [f.label for f in result.features if f.kind != "plane"]
    assert not np.isin(result.labels[near], curved).any()


def test_a_far_box_a_ripples_host_leaves_is_recovered_as_its_faces():
    # stereo_1280x720, study seed 1262, scan 0: a box 5.2-5.8 m away (front face, truth 17,
    # 5105 px nearly head-on; side, truth 14, 1415 px) and the wall 1.2 m behind it (truth 4)
    # under one cylinder region. The wall's plane explained the region at the median as a
    # ripple and took the wall's pixels; the box's were left in no region (both missed).
    # They are recovered as the leftover blobs are: the two faces as planes
    scan, result = _matrix_scan("stereo_1280x720", 0, seed=1262)
    for face, share in ((17, 0.95), (14, 0.9)):  # (today 0.98 and 0.98 of their pixels)
        region = _correct_region(scan, result, face, "plane")
        assert (scan.truth_ids[region] == face).sum() > share * (scan.truth_ids == face).sum()


@pytest.mark.parametrize("seed, k, surface", [(1258, 3, 2), (1263, 2, 1)])
def test_a_strip_of_a_large_plane_beside_none_of_its_pixels_joins_it(seed, k, surface):
    # kinect_640x480, study seeds: a far wall's strip between two pipes at the frame's top
    # edge (seed 1258 scan 3, 103 px of truth 2, 10231 px) and a floor's strip at 5.4-6.3 m
    # (seed 1263 scan 2, 180 px of truth 1) were regions of their own, 7-8 mm rms, 8 and 4.6 cm off
    # the wall's and floor's planes, within the noise of their distances to them: the large
    # plane counted as over-segmented. They join it
    scan, result = _matrix_scan("kinect_640x480", k, seed=seed)
    region = _correct_region(scan, result, surface, "plane")
    # no other region lies mostly on the surface
    for label in np.unique(result.labels[(scan.truth_ids == surface) & ~region]):
        if label:
            assert (scan.truth_ids[result.labels == label] == surface).mean() < 0.8


def test_a_balls_piece_joins_its_region_once_that_region_is_a_sphere_too():
    # kinect_640x480, study seed 1260, scan 0: a ball at 4.3-4.7 m the frame's left edge cuts
    # (truth 16, 2104 px). Its tile region was a cylinder when the recovery found its
    # right-hand piece (652 px) a sphere; the cylinder became a sphere after (the other curved
    # kind), and the two stayed apart (1424 and 652 px). Offered again, the piece joins it
    scan, result = _matrix_scan("kinect_640x480", 0, seed=1260)
    ball = scan.truth_ids == 16
    labels, counts = np.unique(result.labels[ball], return_counts=True)
    largest = labels[np.argmax(counts)]
    assert counts.max() > 0.95 * ball.sum()  # (today 2076 of 2104)
    assert {f.label: f.kind for f in result.features}[int(largest)] == "sphere"


def test_a_pipe_before_a_far_wall_is_not_merged_into_the_walls_bent_model():
    # kinect_real_640x480, study seed 1260, scan 0: a side wall 6.4-7.7 m away (truth 6, 5590
    # px) that polish bent into a cylinder of r 4.6 m took the pipe of r 0.12 m at 2.9 m
    # before it (truth 17, 2636 px) in the merge after polish: the union's rms was within the
    # wall's, the pipe's pixels 64 mm rms off it (12.7 mm of range noise). Both were under-
    # segmented; now each is its own region
    scan, result = _matrix_scan("kinect_real_640x480", 0, seed=1260)
    pipe = _correct_region(scan, result, 17, "cylinder")
    assert (scan.truth_ids[pipe] == 17).sum() > 0.95 * (scan.truth_ids == 17).sum()
    ev = evaluate(scan, result)
    assert 6 in ev.hoover.correct
    wall = result.labels == ev.hoover.correct[6]
    assert not (scan.truth_ids[wall] == 17).any()


def test_a_box_top_seen_near_grazing_grows_into_its_free_pixels_and_takes_back_its_band():
    # kinect_640x480, study seed 1181, scan 5: a box top (truth 10, 405 px at 4.7-5.2 m, seen at
    # 82 deg) recovered from the blobs: 272 px in its region, 116 in the plane of the face beside
    # it (missed). The settling of plane borders gives it 319 (79 %), its growth into the free
    # pixels beside it that its plane explains 328
    scan, result = _matrix_scan("kinect_640x480", 5, seed=1181)
    top = _correct_region(scan, result, 10, "plane")
    assert (scan.truth_ids[top] == 10).sum() > 0.8 * (scan.truth_ids == 10).sum()


def test_kind_changed_names_the_cylinders_turned_spheres_and_the_spheres_turned_cylinders():
    from rangeseg_o3d.fitting.primitives import Cylinder, Plane, Sphere
    from rangeseg_o3d.pipeline import _kind_changed

    cylinder = Cylinder(np.array([0.0, 1.0, 0.0]), np.zeros(3), 0.2, 0.01, 100)
    sphere = Sphere(np.zeros(3), 0.2, 0.01, 100)
    plane = Plane(np.array([0.0, 0.0, 1.0]), 2.0, 0.01, 100)
    assert _kind_changed({1: cylinder, 2: plane, 3: sphere}, {1: sphere, 2: plane, 3: sphere}) == {1}
    assert _kind_changed({1: sphere}, {1: cylinder}) == {1}
    assert _kind_changed({1: cylinder, 2: plane}, {1: cylinder, 2: plane}) == set()
    assert _kind_changed({1: cylinder}, {1: plane}) == set()  # (a curved model given up for its plane)
    assert _kind_changed({1: cylinder}, {2: sphere}) == set()  # (a new region)
