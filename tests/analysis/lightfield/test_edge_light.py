"""Light from outside the solvable angles (analysis/lightfield/edge_light.py).

An object 100 mm before the wall sends part of its fan in beyond the solvable domain; the
reconstruction has no model for that light, and the detector used to report 2–5 extra
"unresolved" objects for it.  Now: one object, flagged, with a note; and a real second
object beside it is still reported.  Renderer scenes (the validation matrix's geometry,
``benchmarks/bench_lightfield_validation.py``), seeded noise.
"""

from __future__ import annotations

import numpy as np
import pytest

from analysis.lightfield.edge_light import judged_on_clean_rows, line_of_sight, outside_rows
from hw_mocks.sim.lightfield_scene import PointObject

NEAR = PointObject(-30.0, -100.0, 1.5, 1.0)


def test_outside_rows_are_where_the_ray_leaves_the_solvable_domain():
    wall = np.array([-100.0, -60.0, -30.0, 0.0, 10.0, 100.0])
    # from (−30, −100) the rays arrive at atan((c + 30)/100): −35°, −16.7°, 0°, 16.7°,
    # 21.8°, 52.4°; the domain ±17.19° leaves out the first and the last two
    rows = outside_rows(wall, np.array([[-30.0, -100.0]]), (-0.3, 0.3))
    assert rows.tolist() == [True, False, False, False, True, True]
    # a far object on the axis is inside everywhere; the union over objects is taken
    assert not outside_rows(wall, np.array([[0.0, -400.0]]), (-0.3, 0.3)).any()
    both = outside_rows(wall, np.array([[0.0, -400.0], [-30.0, -100.0]]), (-0.3, 0.3))
    assert both.tolist() == rows.tolist()


def test_a_weaker_candidate_is_judged_on_the_rows_a_stronger_ones_outside_light_misses():
    wall = np.linspace(-100.0, 100.0, 201)
    pos = np.array([[-30.0, -100.0],   # near the wall: rows c > 0.6 and c < −60 outside
                    [70.0, -210.0],    # an artefact: no evidence on the clean rows
                    [-40.0, -300.0],   # a real object: evidence there
                    [0.0, -400.0]])    # far, all rows inside: not a source itself
    seen = []

    def significance_on(rows, idx):
        seen.append((rows.copy(), list(idx)))
        return np.array([30.0] * (len(idx) - 1) + [{1: 0.5, 2: 9.0, 3: 6.0}[idx[-1]]])

    reported, attributed = judged_on_clean_rows([0, 1, 2, 3], wall, pos, (-0.3, 0.3), 4.3,
                                                significance_on)
    assert reported == [0, 2, 3]
    assert attributed == {0: [(1, 0.5)]}
    # judged jointly with the reported stronger objects, on the clean rows of the sources
    # (the source at (−40, −300) has none outside: the rows are those of (−30, −100))
    rows, idx = seen[-1]
    assert idx == [0, 2, 3]
    assert rows.tolist() == (~outside_rows(wall, pos[:1], (-0.3, 0.3))).tolist()


def test_without_a_source_outside_nothing_is_rejudged():
    wall = np.linspace(-100.0, 100.0, 201)
    pos = np.array([[0.0, -400.0], [30.0, -380.0]])

    def never(rows, idx):
        raise AssertionError("no source: no refit")

    assert judged_on_clean_rows([0, 1], wall, pos, (-0.3, 0.3), 4.3, never) == ([0, 1], {})


def test_line_of_sight_groups_components_across_within_the_blur_at_any_depth():
    pos = np.array([[-30.0, -100.0], [-30.0, -92.0], [-30.4, -108.0], [40.0, -250.0],
                    [-30.0, -95.0]])
    groups = line_of_sight(pos, [0, 4], lambda z: 2.0)
    # the second source is already a member of the first's line of sight
    assert groups == {0: [1, 2, 4]}
    assert line_of_sight(pos, [3], lambda z: 2.0) == {}


def _locate(bench, wall: str, objects, seed: int):
    brdf = bench.walls()[wall]
    lf = bench.render(brdf, objects, None, "")
    return bench.locate(lf, brdf, seed)[0]


def _holds(det, k: int, obj) -> bool:
    """Object k lies over the truth (within its blur across) and its interval holds it."""
    far, near = det.depth_interval_mm[k]
    return (abs(det.positions_mm[k, 0] - obj.y_mm) < det.resolutions[k].transverse_mm
            and far <= obj.z_mm <= near)


@pytest.mark.parametrize("wall", [
    "coated_paper_matte",
    # the near-mirror end: the disc spans more than the blur there, and the fit hung point
    # components before and behind it on its line of sight
    pytest.param("brushed_metal_0.01deg", marks=pytest.mark.slow),
    pytest.param("pearl_paint_glass", marks=pytest.mark.slow),
])
def test_an_object_near_the_wall_is_one_object_flagged_partly_outside(bench, wall):
    for seed in (1,) if wall == "coated_paper_matte" else (1, 2):
        det = _locate(bench, wall, [NEAR], seed)
        assert det.count == 1, (seed, det.positions_mm)
        assert det.quality[0] == "unresolved"
        assert _holds(det, 0, NEAR)
        assert any("partly outside the measured angles" in n for n in det.notes)


# slow: 9.3 s CPU; the cheaper
# test_a_weaker_candidate_is_judged_on_the_rows_a_stronger_ones_outside_light_misses checks the
# same re-judging (a candidate with evidence on the clean rows is reported, not attributed to the
# near object's outside light) in the default run
@pytest.mark.slow
@pytest.mark.parametrize("wall", ["coated_paper_matte", "pearl_paint_glass"])
def test_a_real_second_object_beside_a_near_one_is_still_reported(bench, wall):
    second = PointObject(40.0, -250.0, 1.5, 1.0)
    det = _locate(bench, wall, [NEAR, second], 1)
    assert det.count == 2, det.positions_mm
    for obj in (NEAR, second):
        assert any(_holds(det, k, obj) for k in range(det.count)), (obj, det.positions_mm)


def _cand(y, z, quality, interval):
    from analysis.lightfield.localize import _Candidate

    return _Candidate(y, z, quality, (z, z, z), interval, np.zeros(0), None)


def test_two_objects_on_one_line_of_sight_with_unresolved_depths_are_said_to_be_inseparable():
    from analysis.lightfield import Resolution
    from analysis.lightfield.localize import _inseparable_notes

    res = [Resolution(7.1, 30.0, 0.04, 17.0, 200.0, 200.0)] * 2
    # the brushed metal's pair one blur apart: two components at y = 0, both unresolved,
    # intervals overlapping around the true −200 mm
    pair = [_cand(0.0, -207.5, "unresolved", (-228.0, -192.0)),
            _cand(-0.0, -190.7, "unresolved", (-208.0, -176.0))]
    (note,) = _inseparable_notes(pair, res)
    assert "two objects, not separable in depth" in note
    assert "z = -228.0…-176.0 mm" in note
    # resolved in depth, apart across, or with disjoint intervals: nothing to say
    assert not _inseparable_notes([pair[0], _cand(0.0, -190.7, "resolved", (-208.0, -176.0))],
                                  res)
    assert not _inseparable_notes([pair[0], _cand(20.0, -190.7, "unresolved",
                                                  (-208.0, -176.0))], res)
    assert not _inseparable_notes([pair[0], _cand(0.0, -150.0, "unresolved",
                                                  (-160.0, -140.0))], res)


@pytest.mark.slow
def test_brushed_metal_pair_one_blur_apart_is_one_extended_object_over_both(bench):
    """Two discs one blur apart side by side behind the brushed metal (±3.2 mm, blur
    6.5 mm): the resolution limit.  The search leaves two points on their common line of
    sight (z ≈ −207 and −191 mm); the test across fits the two points at the true places,
    but a bar 12 mm across explains the data within Δ ≈ 6.4 noise variances of them,
    under the ln n_eff ≈ 8.7 bound: the data do not separate the pair, so the report is
    one object flagged "extended" whose width covers both discs — not a place claimed
    resolved (ADR 0032, "Line of sight and across")."""
    brdf = bench.walls()["brushed_metal"]
    objects = bench.scenes(bench.wall_blur(brdf, None, "brushed_metal"))["pair_1blur"]
    det = _locate(bench, "brushed_metal", objects, 1)
    # "extended", or "unresolved" where one component's fan leaves the solvable angles (the
    # fit run to convergence puts it at −179 mm, ADR 0109): never "resolved"
    assert det.count == 1 and det.quality[0] in ("extended", "unresolved"), det.positions_mm
    ((*_, stat, bound),) = det.extended_tests
    assert stat <= bound
    y0, width = det.positions_mm[0, 0], det.extent_mm[0, 0]
    blur = det.resolutions[0].transverse_mm
    # the segment spans both discs across, and is no wider than the pair and a blur
    assert all(abs(obj.y_mm - y0) <= 0.5 * width for obj in objects), (y0, width)
    assert width <= abs(objects[1].y_mm - objects[0].y_mm) + blur
    far, near = det.depth_interval_mm[0]
    assert all(far <= obj.z_mm <= near for obj in objects)
    # not reported as two objects stacked on the line of sight
    assert not any("intervals: two objects, not separable in depth" in n for n in det.notes)
