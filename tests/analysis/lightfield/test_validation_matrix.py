"""The localisation validation matrix, reduced (benchmarks/bench_lightfield_validation.py).

Its scoring is checked on hand-made detections (each kind of confident error counted as
that kind), then a reduced matrix runs on renderer scenes: no scan may hold a confidently
wrong object, and the objects bright enough to be found must be found within the blur.
The matrix (seven walls, eleven scenes; the seeds run so far) is in BENCHMARKS.md
(lightfield_validation).
"""

from __future__ import annotations

import numpy as np
import pytest

from analysis.lightfield import Resolution
from analysis.lightfield.localize import Detection, FocalStack
from hw_mocks.sim.lightfield_scene import PointObject


def _det(positions, intervals, quality, brightness, significance=None) -> Detection:
    n = len(positions)
    res = Resolution(8.0, 30.0, 0.04, 15.0, 200.0, 200.0)
    empty = np.zeros((0, 0))
    stack = FocalStack(np.zeros(0), np.zeros(0), empty, empty, empty, (-0.5, 0.5))
    return Detection(
        count=n, positions_mm=np.asarray(positions, float).reshape(n, 2),
        brightness_rp=np.asarray(brightness, float), brightness_conventional=np.zeros(n),
        resolutions=(res,) * n, stack=stack, depth_profiles=np.zeros((n, 0)),
        depth_interval_mm=np.asarray(intervals, float).reshape(n, 2), quality=tuple(quality),
        depth_estimates_mm=np.zeros((n, 3)), depth_open=np.zeros((n, 2), bool),
        significance=np.asarray(significance if significance is not None else [10.0] * n),
        extent_mm=np.zeros((n, 2)), below_positions_mm=np.array([[40.0, -200.0]]),
        below_significance=np.array([3.1]))


def _blur(z):
    return Resolution(8.0, 30.0, 0.04, 15.0, abs(z), 200.0)


def test_each_kind_of_confident_error_is_counted_as_itself(bench):
    truth = [PointObject(0.0, -200.0, 1.5, 1.0), PointObject(40.0, -200.0, 1.5, 0.01)]
    cases = {
        # right: one object found, the dim one below the threshold (its 3.1σ recorded)
        "right": (_det([(1.0, -205.0)], [(-240, -170)], ["resolved"], [0.3]),
                  dict(detected=1, within_blur=1, split=0, phantom_resolved=0,
                       wrong_sign=0, excluded=0, phantoms=0)),
        "split": (_det([(1.0, -205.0), (-3.0, -195.0)], [(-240, -170), (-230, -160)],
                       ["resolved", "resolved"], [0.3, 0.1], [10.0, 5.0]),
                  dict(detected=1, split=1, phantoms=0)),
        "phantom": (_det([(1.0, -205.0), (-80.0, -300.0)], [(-240, -170), (-350, -260)],
                         ["resolved", "resolved"], [0.3, 0.1]),
                    dict(phantoms=1, phantom_resolved=1)),
        "flagged phantom": (_det([(1.0, -205.0), (-80.0, -300.0)],
                                 [(-240, -170), (-350, -260)],
                                 ["resolved", "unresolved"], [0.3, 0.1]),
                            dict(phantoms=1, phantom_resolved=0)),
        "wrong sign": (_det([(1.0, -205.0)], [(-240, -170)], ["resolved"], [-0.3]),
                       dict(wrong_sign=1)),
        "excluded": (_det([(1.0, -400.0)], [(-420, -380)], ["resolved"], [0.3]),
                     dict(detected=0, excluded=1, phantoms=1)),
    }
    for name, (det, want) in cases.items():
        s = bench.Score()
        bench.score(det, truth, _blur, s)
        for field, value in want.items():
            assert getattr(s, field) == value, (name, field, getattr(s, field))
        assert s.scans == 1 and s.truths == 2
    s = bench.Score()
    bench.score(cases["right"][0], truth, _blur, s)
    assert s.truth_significance == [(10.0, True), (3.1, False)]


def test_detection_table_bins_by_significance(bench):
    rows = bench.detection_table([(np.nan, False), (2.5, False), (4.5, True), (4.2, False),
                                  (20.0, True)])
    assert "| none examined | 1 | 0 | 0.00 |" in rows
    assert "| 4 – 5 | 2 | 1 | 0.50 |" in rows
    assert "| 10 – inf | 1 | 1 | 1.00 |" in rows


def _run(bench, wall: str, scene: str, seeds) -> object:
    brdf = bench.walls()[wall]
    blur = bench.wall_blur(brdf, None, wall)
    objects = bench.scenes(blur)[scene]
    lf = bench.render(brdf, objects, None, "")
    s = bench.Score()
    for seed in seeds:
        det, p_hat, solvable, _ = bench.locate(lf, brdf, seed)
        bench.score(det, objects, bench.blur_of(p_hat, solvable), s)
    return s


# slow: 9.7 s CPU; the cheaper
# test_extended.py::test_a_bar_across_seen_as_two_points_in_depth_is_one_extended_object checks
# the same case (two components on one line of sight, as the near-mirror search left this disc)
# becoming one extended object of its width, and
# test_a_bar_twice_the_blur_is_one_extended_object_with_its_width the width through the renderer,
# in the default run
@pytest.mark.slow
def test_a_disc_wider_than_the_blur_before_a_near_mirror_is_one_object_of_its_size(bench):
    """The 3 mm disc before the 0.1° wall (blur 2.6 mm at −200 mm) was two "resolved"
    points on its line of sight, 6.5 mm apart in depth, in every seed: now one extended
    object, its width 3 mm within the blur, and nothing confidently wrong."""
    brdf = bench.walls()["brushed_metal_0.1deg"]
    blur = bench.wall_blur(brdf, None, "brushed_metal_0.1deg")
    objects = bench.scenes(blur)["one"]
    lf = bench.render(brdf, objects, None, "")
    det, p_hat, solvable, oracle = bench.locate(lf, brdf, 1, objects)
    res = bench.blur_of(p_hat, solvable)(-200.0)
    assert det.count == 1 and det.quality == ("extended",)
    assert abs(det.extent_mm[0, 0] - 3.0) < res.transverse_mm
    assert abs(det.positions_mm[0, 0]) < res.transverse_mm
    assert abs(det.positions_mm[0, 1] + 200.0) < res.depth_mm
    s = bench.Score()
    bench.score(det, objects, bench.blur_of(p_hat, solvable), s)
    assert s.confidently_wrong == 0 and s.detected == 1
    assert oracle[0] > det.threshold_sigma


def test_a_silent_miss_below_the_detection_limit_is_counted_as_such(bench):
    rec = {"truth_significance": [[20.0, True], [None, False], [None, False]],
           "truth_limit_sigma": [150.0, 1.2, 7.5], "threshold_sigma": 4.9}
    assert bench.missed_silently(rec) == 2
    assert bench.missed_below_limit(rec) == 1
    # the older field (no leak share: an upper bound) is read where the new one is absent
    old = {**rec, "truth_oracle_sigma": rec.pop("truth_limit_sigma")}
    assert bench.missed_below_limit(old) == 1
    # lines written before the field: none claimed below the limit
    assert bench.missed_below_limit({"truth_significance": [[None, False]]}) == 0


@pytest.mark.parametrize(("wall", "scene"), [
    ("brushed_metal", "empty"),
    ("brushed_metal", "three"),
    # a disc 100 mm from the wall, larger than the blur there: its residual on its own ray
    # fan made a phantom at 4.5σ until each amplitude was judged on its own rays
    ("brushed_metal", "near"),
    ("coated_paper_glossy", "ratio_10"),
])
def test_reduced_matrix_has_no_confident_error_and_finds_what_is_bright(bench, wall, scene):
    s = _run(bench, wall, scene, seeds=(1, 2))
    assert s.confidently_wrong == 0
    assert s.phantoms == 0
    assert s.detected == s.truths and s.within_blur == s.detected


@pytest.mark.slow
@pytest.mark.parametrize(("wall", "scene"), [
    ("coated_paper_matte", "one"),
    ("coated_paper_matte", "pair_2blur"),
    ("coated_paper_matte", "ratio_100"),
    ("brushed_metal_0.01deg", "one"),
])
def test_matrix_walls_have_no_confident_error(bench, wall, scene):
    """The matte and the near-mirror ends of the matrix (BENCHMARKS.md)."""
    s = _run(bench, wall, scene, seeds=(1, 2))
    assert s.confidently_wrong == 0
    assert s.phantoms == 0
    assert s.within_blur == s.detected


def test_clopper_pearson_interval_of_the_false_alarm_rate(bench):
    # no event in n trials: the upper end solves (1 − p)^n = 0.025 (two-sided 95 %)
    lo, hi = bench.clopper_pearson(0, 300)
    assert lo == 0.0 and hi == pytest.approx(1 - 0.025 ** (1 / 300), rel=1e-9)
    # the textbook case 1 of 10: 0.25 % to 44.5 %
    lo, hi = bench.clopper_pearson(1, 10)
    assert lo == pytest.approx(0.00253, abs=1e-5) and hi == pytest.approx(0.4450, abs=1e-4)
    rows = bench.false_alarm_table({"matte": (0, 300), "mirror": (1, 10)})
    assert rows[2].startswith("| matte | 300 | 0 | 0.00 % | 0.00 – 1.22 % |")
    assert rows[-1].startswith("| all | 310 | 1 | 0.32 % |")


def test_off_blur_and_silent_misses_count_as_confident_errors(bench):
    truth = [PointObject(0.0, -200.0, 1.5, 1.0), PointObject(60.0, -200.0, 1.5, 0.01)]
    # resolved, over the truth, interval holding it, but 40 mm deep of it (δz = 30 mm);
    # the dim object has no candidate near it (the one below sits at y = 40)
    det = _det([(1.0, -240.0)], [(-260, -190)], ["resolved"], [0.3])
    s = bench.Score()
    rec = bench.score(det, truth, _blur, s)
    assert (s.off_blur, s.missed_silently, s.confidently_wrong) == (1, 1, 2)
    assert bench.from_record({**rec, "seconds": 0.0}).confidently_wrong == 2


def test_the_strongest_candidate_away_from_the_truths_leaves_out_their_shadows(bench):
    """The noise's maximum of a scan with objects: reported objects and candidates below
    the threshold more than three blurs across from every true object (the blur: 8 mm)."""
    truth = [PointObject(0.0, -200.0, 1.5, 1.0)]
    det = _det([(0.0, -200.0), (20.0, -200.0)], [(-220, -180)] * 2, ["resolved"] * 2,
               [1.0, 0.1], significance=[50.0, 5.0])
    # the reported one at 20 mm is within 24 mm: left out; the candidate at 40 mm is not
    assert bench.strongest_away(det, truth, _blur) == pytest.approx(3.1)
    assert bench.strongest_away(det, [], _blur) == pytest.approx(50.0)
    far = [PointObject(40.0, -200.0, 1.5, 1.0), *truth]
    assert bench.strongest_away(det, far, _blur) == float("-inf")
