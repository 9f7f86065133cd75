"""Objects near the detection threshold: found where the data put them, never "resolved"
in depth beyond what their significance allows.

* :func:`analysis.lightfield.significance.depth_span` — the depths an object's data do not
  exclude at the detection's own confidence (Δχ² below the threshold's square), checked on
  a synthetic profile;
* renderer scenes of the validation matrix (benchmarks/bench_lightfield_validation.py,
  BENCHMARKS.md lightfield_validation) whose dim object was handled confidently wrong:
  behind the brushed metal a 100× dimmer disc above the threshold at its true position was
  scored off it and dropped; behind the glossy paper one at 4.8σ was called "resolved"
  1.4 depth cells from its true depth.
"""

from __future__ import annotations

import numpy as np
import pytest

from analysis.lightfield.significance import depth_span, likelihood_region

ZS = np.arange(-400.0, -59.0, 4.0)


def _profile(z0: float, width: float) -> np.ndarray:
    """A matched-filter column: a smooth peak at z0, ``width`` mm at half maximum."""
    return np.exp(-4.0 * np.log(2.0) * ((ZS - z0) / width) ** 2)


def _bounds(s: float, threshold: float) -> tuple[float, float]:
    prof = _profile(-200.0, 60.0)
    lo, hi = depth_span(prof, int(np.argmin(np.abs(ZS + 200.0))), s, threshold)
    return float(ZS[lo]), float(ZS[hi])


def test_a_bright_object_keeps_the_depths_within_the_threshold_chi2():
    # s = 40, s* = 4.4: kept where profile² ≥ 1 − (4.4/40)², a few mm of a 60 mm wide peak
    lo, hi = _bounds(40.0, 4.4)
    prof = _profile(-200.0, 60.0)
    floor = 1.0 - (4.4 / 40.0) ** 2
    idx = np.flatnonzero((lo <= ZS) & (hi >= ZS))
    assert np.all(prof[idx] ** 2 >= floor)
    # the grid points just outside are excluded by the same Δχ² bound
    assert prof[idx[0] - 1] ** 2 < floor and prof[idx[-1] + 1] ** 2 < floor
    assert hi - lo <= 8.0


def test_the_span_grows_as_the_significance_nears_the_threshold():
    spans = [_bounds(s, 4.4) for s in (40.0, 10.0, 6.0, 4.8, 4.5)]
    widths = [hi - lo for lo, hi in spans]
    assert widths == sorted(widths) and widths[0] < widths[-1]
    # at 4.8σ against 4.4σ the profile may fall to √(1 − 0.84) = 0.40 of its peak:
    # beyond the half maximum (±30 mm)
    lo, hi = spans[3]
    assert lo < -230.0 and hi > -170.0


def test_at_or_below_the_threshold_every_positive_depth_of_the_run_is_allowed():
    prof = np.where(np.abs(ZS + 200.0) <= 100.0, _profile(-200.0, 60.0), -0.1)
    lo, hi = depth_span(prof, int(np.argmin(np.abs(ZS + 200.0))), 4.0, 4.4)
    assert ZS[lo] == -300.0 and ZS[hi] == -100.0


def test_without_a_significance_the_span_is_the_point_itself():
    prof = _profile(-200.0, 60.0)
    i = int(np.argmin(np.abs(ZS + 200.0)))
    assert depth_span(prof, i, float("nan"), 4.4) == (i, i)
    assert depth_span(np.zeros_like(prof), i, 10.0, 4.4) == (i, i)


def _two_peaks() -> np.ndarray:
    """Significance on a 9 × 9 trial grid: a 6σ peak at (2, 2) and a 5.5σ one at (6, 6)
    with a negative valley between (two places one dim object's light allows)."""
    i, j = np.mgrid[0:9, 0:9]
    return (6.0 * np.exp(-((i - 2) ** 2 + (j - 2) ** 2) / 2.0)
            + 5.5 * np.exp(-((i - 6) ** 2 + (j - 6) ** 2) / 2.0)
            - 1.0 * np.exp(-((i - 4) ** 2 + (j - 4) ** 2) / 0.5))


def test_the_region_holds_every_position_within_the_threshold_chi2():
    sig = _two_peaks()
    region = likelihood_region(sig, (2, 2), 4.2)
    # Δχ² = 36 − 30.25 < 4.2²: the second peak is allowed, the valley between is not
    assert region[2, 2] and region[6, 6] and not region[4, 4]
    assert np.array_equal(region, sig**2 > 36.0 - 4.2**2)


def test_a_bright_object_keeps_only_its_peak():
    sig = 40.0 * _two_peaks() / 6.0
    region = likelihood_region(sig, (2, 2), 4.2)
    assert region[2, 2] and not region[6, 6]
    assert region.sum() == 1


def test_without_significances_the_region_is_the_point_itself():
    region = likelihood_region(np.full((5, 5), np.nan), (2, 3), 4.2)
    assert region.sum() == 1 and region[2, 3]


@pytest.mark.slow
def test_a_dim_object_placed_beside_its_true_place_carries_a_region_holding_it(bench):
    """Glossy paper, brightness ratio 100, seed 6: the dim disc at (20, −220) mm (5.0σ
    there) was reported at (8.2, −179.0) mm, 4.4σ, 1.03 blurs across from it — counted a
    phantom and the disc missed.  Its data allow both places within the threshold's Δχ²:
    the reported region holds the truth, and the object is flagged unresolved."""
    brdf = bench.walls()["coated_paper_glossy"]
    objects = bench.scenes(11.4)["ratio_100"]
    det, p_hat, solvable, _ = bench.locate(bench.render(brdf, objects, None, ""), brdf, 6,
                                           objects)
    s = bench.Score()
    bench.score(det, objects, bench.blur_of(p_hat, solvable), s)
    assert s.confidently_wrong == 0 and s.phantoms == 0 and s.detected == 2
    k = int(np.argmin(det.significance))
    assert det.quality[k] == "unresolved"
    y_lo, y_hi = det.across_interval_mm[k]
    far, near = det.depth_interval_mm[k]
    assert y_lo <= 20.0 <= y_hi and far <= -220.0 <= near
    # the bright disc keeps a region within its cell
    b = int(np.argmax(det.significance))
    assert np.ptp(det.across_interval_mm[b]) < det.resolutions[b].transverse_mm
    assert det.quality[b] == "resolved"


@pytest.mark.slow
def test_a_dim_object_above_the_threshold_at_its_place_is_found_beside_a_bright_one(bench):
    """Brushed metal, brightness ratio 100, seed 4: the dim disc at (20, −220) mm is 4.7σ at
    its true position against a 4.5σ threshold; the search first scored it at 4.1σ where the
    residual peaked (17.8, −208) mm.  Its position is now fitted before it is judged.

    The threshold is that of a false-alarm rate of 0.06 per scan (4.50σ here); the default
    0.01 sets 4.89σ since the threshold counts the noise field's expected Euler
    characteristic (ADR 0032), and the disc is then below the detection limit."""
    brdf = bench.walls()["brushed_metal"]
    objects = bench.scenes(6.5)["ratio_100"]
    det, p_hat, solvable, oracle = bench.locate(bench.render(brdf, objects, None, ""), brdf,
                                                4, objects, false_alarm=0.06)
    assert det.threshold_sigma == pytest.approx(4.5, abs=0.05)
    assert oracle[1] > det.threshold_sigma
    s = bench.Score()
    bench.score(det, objects, bench.blur_of(p_hat, solvable), s)
    assert det.count == 2 and s.detected == 2 and s.confidently_wrong == 0
    k = int(np.argmin(det.significance))
    assert abs(det.positions_mm[k, 0] - 20.0) < det.resolutions[k].transverse_mm
    far, near = det.depth_interval_mm[k]
    assert far <= -220.0 <= near
    assert det.brightness_rp[k] > 0


@pytest.mark.slow
def test_a_dim_object_near_the_threshold_is_not_resolved_in_depth(bench):
    """Glossy paper, brightness ratio 100, seed 1: the dim disc at (20, −220) mm comes out
    at (12, −240) mm with 4.8σ against 4.2σ; its data allow −264…−216 mm at the threshold's
    Δχ², more than one depth cell: flagged unresolved, its interval holding the truth.

    The threshold is that of a false-alarm rate of 0.05 per scan (4.2σ here; the default
    0.01 sets 4.6σ since the threshold counts the noise field's expected Euler
    characteristic, ADR 0032)."""
    brdf = bench.walls()["coated_paper_glossy"]
    objects = bench.scenes(11.4)["ratio_100"]
    det, p_hat, solvable, _ = bench.locate(bench.render(brdf, objects, None, ""), brdf, 1,
                                           objects, false_alarm=0.05)
    assert det.threshold_sigma == pytest.approx(4.2, abs=0.05)
    s = bench.Score()
    bench.score(det, objects, bench.blur_of(p_hat, solvable), s)
    assert s.confidently_wrong == 0
    dim = [k for k in range(det.count) if det.significance[k] < 2 * det.threshold_sigma]
    assert dim
    for k in dim:
        assert det.quality[k] != "resolved"
        far, near = det.depth_interval_mm[k]
        if abs(det.positions_mm[k, 0] - 20.0) < det.resolutions[k].transverse_mm:
            assert far <= -220.0 <= near
    assert any("too faint to fix its" in n for n in det.notes)
    # the bright disc keeps its resolved depth
    k = int(np.argmax(det.significance))
    assert det.quality[k] == "resolved" and abs(det.positions_mm[k, 1] + 200.0) < 5.0
