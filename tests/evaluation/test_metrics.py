"""Hoover metrics on hand-made label images, and parameter errors / Table 1 via evaluate()."""

import numpy as np
import pytest

from rangeseg_o3d.evaluation.metrics import (connected_patches, evaluate, hoover, parameter_errors,
                                             surface_breakdown)
from rangeseg_o3d.fitting.primitives import Cylinder, Plane, Sphere
from rangeseg_o3d.result import Feature, Result
from rangeseg_o3d.synthetic.scene import SyntheticScan


def _truth_two_halves():
    t = np.zeros((20, 20), dtype=np.int32)
    t[:, :10] = 1
    t[:, 10:] = 2
    return t  # two regions of 200 px


def test_identical_segmentation_all_correct():
    t = _truth_two_halves()
    s = hoover(t, t * 7)
    assert s.counts() == {"n_truth": 2, "n_machine": 2, "correct": 2, "over": 0, "under": 0, "missed": 0, "noise": 0}
    assert s.correct == {1: 7, 2: 14}
    assert s.percent_correct == 100.0


def test_correct_at_tolerance_boundary():
    t = _truth_two_halves()
    m = t.copy()
    m[:, 8:10] = 2  # region 2 grows by 40 px: O = 200 = 200/240 = 0.833 Pn; region 1 loses 40: 160 = 0.8 Pm
    s = hoover(t, m, tolerance=0.8)
    assert s.n_correct == 2
    s = hoover(t, m, tolerance=0.85)
    assert s.n_correct == 0 and s.n_missed + s.n_over + s.n_under > 0


def test_over_segmentation():
    t = _truth_two_halves()
    m = t.copy()
    m[:10, :10] = 3  # truth 1 split into machine 3 (100 px) and 1 (100 px)
    s = hoover(t, m)
    assert s.over == {1: [1, 3]}
    assert s.correct == {2: 2}
    assert s.n_missed == 0 and s.n_noise == 0


def test_under_segmentation():
    t = _truth_two_halves()
    m = np.full_like(t, 5)
    s = hoover(t, m)
    assert s.under == {5: [1, 2]}
    assert s.n_correct == 0 and s.n_missed == 0 and s.n_noise == 0


def test_missed_and_noise():
    t = _truth_two_halves()
    m = np.zeros_like(t)
    m[:, 10:] = 2
    m[:5, :5] = 9  # 25 px inside truth 1: too small to cover it
    m[5:10, :5] = 8
    s = hoover(t, m)
    assert s.correct == {2: 2}
    assert s.missed == [1]
    # 9 and 8 lie wholly inside truth 1 (O >= T*Pn) but sum only 50 px < 0.8*200 -> not over: noise.
    assert sorted(s.noise) == [8, 9]


def test_noise_region_spanning_two_truths():
    t = _truth_two_halves()
    m = t.copy()
    m[:4, 8:12] = 6  # 16 px, half on each truth: inside neither
    s = hoover(t, m)
    assert s.noise == [6]
    assert s.n_correct == 2  # each truth keeps 192 px of 200


def test_tie_resolved_by_higher_averaged_overlap():
    # Truth 1 (200 px) is machine 1 (170 px inside truth 1) plus machine 3 (30 px, all in truth 1).
    # Both "correct (1,1)" and "over 1 -> [1, 3]" qualify; over has the higher averaged overlap
    # ((200/200 + (1 + 1)/2)/2 = 1.0 against (170/200 + 1)/2 = 0.925) and wins.
    t = _truth_two_halves()
    m = t.copy()
    m[:3, :10] = 3
    s = hoover(t, m)
    assert s.over == {1: [1, 3]}
    assert 1 not in s.correct and s.correct == {2: 2}
    assert s.n_noise == 0
    # Machine 1 leaking 20 px into truth 2 lowers both scores (0.872 vs 0.974): over still wins,
    # and truth 2 stays correct with what is left of machine 2 (180 px).
    m2 = m.copy()
    m2[:, 10:11] = 1
    s2 = hoover(t, m2)
    assert s2.over == {1: [1, 3]} and s2.correct == {2: 2}


def test_dont_care_pixels_and_small_regions_excluded():
    t = _truth_two_halves()
    t[:, 9:11] = 0  # mixed pixels: don't care
    t[:5, :5] = 3  # 25-px truth region: below min_region
    m = np.where(t == 3, 4, np.where(t == 0, 1, t))  # machine absorbs the mixed pixels into region 1
    s = hoover(t, m, min_region=60)
    assert s.n_truth == 2  # truth 3 is not scored
    assert s.correct == {1: 1, 2: 2}
    assert s.noise == []  # machine 4 lies on the small truth: ignored, not noise
    assert s.n_machine == 2
    s1 = hoover(t, m, min_region=1)
    assert s1.n_truth == 3 and s1.correct[3] == 4


def test_edge_cases_empty_single_and_no_truth():
    t = _truth_two_halves()
    empty = hoover(t, np.zeros_like(t))
    assert empty.n_correct == 0 and sorted(empty.missed) == [1, 2] and empty.n_machine == 0
    one = hoover(np.ones((10, 10), np.int32), np.ones((10, 10), np.int32))
    assert one.correct == {1: 1}
    none = hoover(np.zeros((10, 10), np.int32), np.ones((10, 10), np.int32))
    assert none.n_truth == 0 and none.n_machine == 0 and np.isnan(none.percent_correct)
    small = hoover(np.ones((5, 5), np.int32), np.ones((5, 5), np.int32))  # 25 px < 60
    assert small.n_truth == 0 and small.noise == []


def test_bad_input():
    t = _truth_two_halves()
    with pytest.raises(ValueError, match="shape"):
        hoover(t, t[:5])
    with pytest.raises(ValueError, match="tolerance"):
        hoover(t, t, tolerance=0.4)
    with pytest.raises(ValueError, match="integer"):
        hoover(t, t.astype(float))
    with pytest.raises(ValueError, match=r"\(H, W\)"):
        hoover(t.ravel(), t.ravel())
    with pytest.raises(ValueError, match=">= 0"):
        hoover(t, -t)


def test_parameter_errors_values():
    p_true = Plane(normal=(0, 0, 1), d=1.0, rms=0, inliers=0)
    tilt = np.deg2rad(0.3)
    p_fit = Plane(normal=(0, -np.sin(tilt), -np.cos(tilt)), d=-1.02, rms=0, inliers=0)
    e = parameter_errors(p_true, p_fit)
    assert e["normal_error_deg"] == pytest.approx(0.3, abs=1e-9)
    assert e["offset_error"] == pytest.approx(0.02, abs=1e-12)
    s = parameter_errors(Sphere((1, 2, 3), 0.5, 0, 0), Sphere((1, 2, 3.01), 0.49, 0, 0))
    assert s["radius_error"] == pytest.approx(0.01) and s["center_error"] == pytest.approx(0.01)
    c = parameter_errors(
        Cylinder((0, 0, 1), (1, 0, 0.5), 0.3, 0, 0),
        Cylinder((0, 0, -1), (1.02, 0, 3.0), 0.31, 0, 0),
    )
    assert c["axis_error_deg"] == pytest.approx(0.0, abs=1e-6)
    assert c["center_error"] == pytest.approx(0.02)
    assert c["radius_error"] == pytest.approx(0.01)
    assert parameter_errors(p_true, Sphere((0, 0, 0), 1, 0, 0)) == {}


def test_evaluate_errors_false_fittings_and_table1():
    t = np.zeros((20, 30), np.int32)
    t[:, :10], t[:, 10:20], t[:, 20:] = 1, 2, 3
    truth = {
        1: Plane((0, 0, 1), 0.5, 0, 0),
        2: Sphere((2, 0, 0), 0.3, 0, 0),
        3: Cylinder((0, 0, 1), (3, 1, 0), 0.25, 0, 0),
    }
    scan = SyntheticScan(cloud=None, truth_ids=t, truth=truth)
    labels = t.copy()
    features = [
        Feature(1, Plane((0, 0, 1), 0.51, 0.001, 200), 200),
        Feature(2, Plane((1, 0, 0), 1.7, 0.01, 200), 200),  # sphere fitted as a plane: false fitting
        Feature(3, Cylinder((0, 0, 1), (3, 1, 0.2), 0.26, 0.002, 200), 200),
    ]
    ev = evaluate(scan, Result(labels=labels, features=features))
    assert ev.hoover.n_correct == 3
    assert ev.false_fittings == 1
    assert ev.errors("offset_error", "plane") == pytest.approx([0.01])
    assert ev.errors("radius_error", "cylinder") == pytest.approx([0.01])
    assert ev.table1() == {"features": 3, "under": 0, "under_pct": 0.0, "over": 0, "over_pct": 0.0, "false_fittings": 1}
    # A correct region left unfitted is reported, not a false fitting.
    ev2 = evaluate(scan, Result(labels=labels, features=features[:1]))
    assert ev2.unfitted_correct == [2, 3] and ev2.false_fittings == 0
    assert ev2.to_dict()["hoover"]["correct"] == 3
    # No feature extracted: the percentages are undefined, reported as NaN.
    ev3 = evaluate(scan, Result(labels=np.full_like(labels, 1), features=[]))
    assert ev3.table1()["under"] == 1 and np.isnan(ev3.table1()["under_pct"])
    with pytest.raises(TypeError):
        evaluate(object(), Result(labels=labels, features=[]))


# -- SegComp's compare rules (count_unlabelled=True) ------------------------------------
def _truth_with_unlabelled_band():
    t = np.zeros((20, 30), dtype=np.int32)
    t[:, :10] = 1  # 200 px
    t[:, 20:] = 2  # 200 px; columns 10..19 (200 px) left unlabelled by the annotators
    return t


def test_segcomp_spill_onto_unlabelled_pixels_counts_against_a_region():
    t = _truth_with_unlabelled_band()
    m = np.zeros_like(t)
    m[:, :13] = 1  # truth 1 plus 60 unlabelled px: 200 / 260 = 0.77 < 0.8
    m[:, 18:] = 2  # truth 2 plus 40 unlabelled px: 200 / 240 = 0.83
    default = hoover(t, m, min_region=1)
    assert default.correct == {1: 1, 2: 2}  # unlabelled pixels are don't care
    segcomp = hoover(t, m, min_region=1, count_unlabelled=True)
    assert segcomp.correct == {2: 2}
    assert segcomp.missed == [1] and segcomp.noise == [1]
    assert segcomp.n_machine == 2 and segcomp.percent_correct == 50.0


def test_segcomp_region_on_unlabelled_pixels_only_is_noise():
    t = _truth_with_unlabelled_band()
    m = t.copy()
    m[:, 12:18] = 5  # 120 px, all on unlabelled pixels
    assert hoover(t, m, min_region=1).counts() == {
        "n_truth": 2, "n_machine": 2, "correct": 2, "over": 0, "under": 0, "missed": 0, "noise": 0}
    s = hoover(t, m, min_region=1, count_unlabelled=True)
    assert s.counts() == {"n_truth": 2, "n_machine": 3, "correct": 2, "over": 0, "under": 0,
                          "missed": 0, "noise": 1}
    assert s.noise == [5]


def test_segcomp_under_and_over_segmentation_use_whole_region_sizes():
    t = _truth_with_unlabelled_band()
    m = np.full_like(t, 4)  # one region over everything: 400 labelled of 600 px
    assert hoover(t, m, min_region=1).under == {4: [1, 2]}
    s = hoover(t, m, min_region=1, count_unlabelled=True)
    assert s.under == {} and s.missed == [1, 2] and s.noise == [4]
    m = t.copy()
    m[:10, :10] = 3  # truth 1 split in two halves of 100 px ...
    m[:10, 10:13] = 3  # ... one of which spills 30 px onto unlabelled: 100 / 130 = 0.77 < 0.8
    assert hoover(t, m, min_region=1).over == {1: [1, 3]}
    s = hoover(t, m, min_region=1, count_unlabelled=True)
    assert s.over == {} and s.missed == [1] and sorted(s.noise) == [1, 3]
    assert s.correct == {2: 2}


def test_surface_breakdown_lists_each_surface_not_correct_with_its_pixels():
    t = np.zeros((20, 30), dtype=np.int32)
    t[:, :10], t[:, 10:20], t[:, 20:] = 1, 2, 3  # three surfaces of 200 px
    m = np.zeros_like(t)
    m[:, :10] = 4                 # truth 1: correct
    m[:10, 10:20] = 5             # truth 2: two halves -> over
    m[10:, 10:20] = 6
    m[:8, 20:] = 7                # truth 3: 80 px in region 7, 20 px in region 4's stray pixels,
    m[8:10, 20:] = 4              # 100 px in no region -> missed
    score = hoover(t, m)
    assert score.correct == {1: 4} and score.over == {2: [5, 6]} and score.missed == [3]
    rows = surface_breakdown(t, m, score, kinds={4: "plane", 5: "plane", 6: "cylinder"})
    assert [(r["truth_id"], r["pixels"], r["status"]) for r in rows] == [(2, 200, "over"), (3, 200, "missed")]
    assert rows[0]["parts"] == [(5, "plane", 100, 1.0), (6, "cylinder", 100, 1.0)]
    # largest share first; label 0 has no kind and no share; region 4 (220 px) has 20 on truth 3;
    # region 7 has no kind given
    assert rows[1]["parts"] == [(0, "", 100, 0.0), (7, "?", 80, 1.0), (4, "plane", 20, pytest.approx(20 / 220))]
    assert surface_breakdown(t, m, score, parts=1)[1]["parts"] == [(0, "", 100, 0.0)]


def test_surface_breakdown_lists_under_segmented_surfaces_and_refuses_bad_input():
    t = _truth_two_halves()
    m = np.full_like(t, 5)
    rows = surface_breakdown(t, m, hoover(t, m))
    assert [(r["truth_id"], r["status"], r["parts"]) for r in rows] == [
        (1, "under", [(5, "?", 200, 0.5)]), (2, "under", [(5, "?", 200, 0.5)])]
    assert surface_breakdown(t, t, hoover(t, t)) == []  # everything correct: nothing to list
    with pytest.raises(ValueError, match="parts must be at least 1; got 0"):
        surface_breakdown(t, m, hoover(t, m), parts=0)
    with pytest.raises(ValueError, match="labels must have the shape"):
        surface_breakdown(t, m[:5], hoover(t, m))


def test_connected_patches_gives_each_piece_of_a_surface_its_own_id():
    t = np.zeros((6, 9), dtype=np.int32)
    t[:, :3] = t[:, 6:] = 1      # one surface in two pieces (an object in front of it)
    t[:, 3:6] = 2
    t[0, 4] = 0                  # a don't-care pixel stays 0
    t[5, 4] = 1                  # a one-pixel piece of surface 1 inside surface 2 (diagonal: not 4-connected)
    patches, origin = connected_patches(t)
    assert origin.tolist() == [0, 1, 1, 1, 2]
    # a surface's patches in raster order of their first pixel, then the next surface's
    assert set(np.unique(patches[:, :3]).tolist()) == {1} and set(np.unique(patches[:, 6:]).tolist()) == {2}
    assert patches[5, 4] == 3 and patches[0, 4] == 0 and (patches[1:5, 3:6] == 4).all()
    assert (origin[patches] == t).all()  # every pixel maps back to its surface
    # scored against the patches, one region over both pieces is an under-segmentation, as SegComp counts it
    m = np.where(t == 1, 7, np.where(t == 2, 8, 0))
    assert hoover(t, m, min_region=1).correct == {1: 7, 2: 8}
    assert hoover(patches, m, min_region=4).under == {7: [1, 2]}
    with pytest.raises(ValueError, match="truth_ids must be a"):
        connected_patches(np.ones((2, 2, 2), np.int32))
    with pytest.raises(ValueError, match="truth_ids must be a"):
        connected_patches(-np.ones((2, 2), np.int32))


def test_the_evaluation_package_re_exports_the_metrics():
    from rangeseg_o3d import evaluation
    from rangeseg_o3d.evaluation import metrics

    assert set(evaluation.__all__) == set(metrics.__all__)
    assert all(getattr(evaluation, name) is getattr(metrics, name) for name in metrics.__all__)
