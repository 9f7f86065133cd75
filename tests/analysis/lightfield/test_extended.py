"""One extended object or two points, decided by the data (analysis/lightfield/extended.py).

The two cases that bounded the old fixed spacing rule (ADR 0032): a uniform bar twice the
blur wide fits as two points ≈ 1.09 δy apart and must be one extended object; two discs
1.13 δy apart fit 1.13 δy apart and must stay two.  Spacing alone separates them by 4 %;
the model comparison's statistic Δ (residual difference in noise variances per independent
sample) must separate them with a margin on each side of its bound ln n_eff that the noise
cannot bridge: Δ's own noise is ≈ 2√|Δ| (the difference of two χ² sums sharing their
noise, whose noncentral part is |Δ|), so each case is required beyond its bound by
3 × 2√|Δ|, three standard deviations.  Scenes from the continuous renderer.
"""

from __future__ import annotations

import numpy as np
import pytest

from analysis.lightfield import theoretical_resolution
from analysis.lightfield.extended import SEGMENT_NODES, one_or_two
from analysis.lightfield.localize import _ray_model, detect_objects, effective_p_max
from hw_mocks.sim.lightfield_scene import BarObject, PointObject
from tests.analysis.lightfield.test_validation import D1, DOMAIN, GLOSSY, _reconstructed


def _located(objects):
    rec = _reconstructed(objects, GLOSSY, 0.01, 5)
    p2 = effective_p_max(rec.regularization.filter_factors, rec.orders)
    res = theoretical_resolution(p2, domain_rad=DOMAIN, distance_mm=D1, aperture_mm=200.0,
                                 solvable_domain_rad=rec.solvable_domain_rad)
    # 0.5 mm lateral grid: the pair and the bar's segment are fitted off the grid, and
    # the refocused stacks cost in proportion to it (0.25 mm doubled these tests' time)
    det = detect_objects(rec.incident_field, p_max=p2, y_mm=np.linspace(-60, 60, 241),
                         z_mm=np.linspace(-330, -120, 211),
                         solvable_domain_rad=rec.solvable_domain_rad)
    return det, res


def _margin_ok(stat: float, bound: float, side: str) -> bool:
    """Δ on ``side`` of ``bound`` by three of its standard deviations (module doc)."""
    sd = 2.0 * np.sqrt(abs(stat))
    return stat > bound + 3 * sd if side == "two" else stat < bound - 3 * sd


def test_a_bar_twice_the_blur_is_one_extended_object_with_its_width():
    width = 32.0  # ≈ 2 δy (δy ≈ 15.9 mm at p̂ = 9)
    det, res = _located([BarObject(-width / 2, width / 2, -D1, 1.0 / width)])
    assert det.count == 1 and det.quality == ("extended",)
    ((y1, _, y2, _, stat, bound),) = det.extended_tests
    # the point model's components sit closer than the 1.12-cell bound of old
    assert abs(y2 - y1) < 1.12 * res.transverse_mm
    assert _margin_ok(stat, bound, "one")
    assert abs(det.extent_mm[0, 0] - width) < res.transverse_mm
    assert abs(det.positions_mm[0, 0]) < 0.25 * res.transverse_mm


def test_two_discs_113_cells_apart_stay_two_points():
    sep = 18.0  # 1.13 δy
    det, res = _located([PointObject(-sep / 2, -D1, 1.0, 1.0, "gaussian"),
                         PointObject(sep / 2, -D1, 1.0, 1.0, "gaussian")])
    assert det.count == 2 and set(det.quality) == {"resolved"}
    ((y1, _, y2, _, stat, bound),) = det.extended_tests
    assert 1.1 < abs(y2 - y1) / res.transverse_mm < 1.2
    assert _margin_ok(stat, bound, "two")
    assert np.allclose(np.sort(det.positions_mm[:, 0]), [-sep / 2, sep / 2],
                       atol=0.1 * res.transverse_mm)


def _synthetic(truth: str, amp_noise: float, seed: int, start=None, across_mm: float = 0.0):
    """Exact model rays (segment or two points, equal flux) behind the glossy wall's
    filter, with white noise of ``amp_noise`` per ray; the test started from the truth's
    own pair or from ``start`` (2, 2)."""
    from analysis.lightfield import LightField2D, theta_grid

    th = theta_grid(DOMAIN, 128)
    c = np.arange(-100.0, 100.1, 1.0)
    lf = LightField2D(np.zeros((c.size, th.size)), c, th, DOMAIN)
    phi = (np.abs(np.fft.fftfreq(th.size, 1.0 / th.size)) <= 9).astype(float)
    use = (th >= -0.5) & (th <= 0.5)
    if truth == "segment":
        t = (np.arange(4 * SEGMENT_NODES) + 0.5) / (4 * SEGMENT_NODES)
        pos = np.column_stack([-16.0 + 32.0 * t, np.full(t.size, -D1)])
        r, _, _ = _ray_model(lf, use, phi, pos)
        g = r.mean(axis=0)
        pair = np.array([[-9.2, -D1], [9.2, -D1]])
    else:
        pos = np.array([[-9.0, -D1], [9.0, -D1]])
        r, _, _ = _ray_model(lf, use, phi, pos)
        g = 0.5 * r.sum(axis=0)
        pair = pos
    rng = np.random.default_rng(seed)
    g = g + rng.normal(0.0, amp_noise, g.shape)
    box = ((-60.0, 60.0), (-330.0, -120.0))
    # white noise per ray: every ray is an independent sample
    return one_or_two(g, lf, use, phi, pair if start is None else np.asarray(start, float),
                      sigma2=amp_noise**2, n_eff=float(g.size), bounds=box,
                      across_mm=across_mm)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_statistic_follows_the_noise_model_on_exact_rays(seed):
    """On rays that are exactly one of the two models plus white noise, the truth wins:
    a segment gives Δ near 0 (below the bound ln n_eff ≈ 10), two points a Δ that grows
    as the noise falls — the decision tightens with the data instead of sitting at a
    fixed spacing."""
    seg = _synthetic("segment", 2e-4, seed)
    assert seg.extended and seg.statistic < seg.penalty
    assert abs(seg.size_mm[0] - 32.0) < 1.0
    two_loud = _synthetic("two", 2e-4, seed)
    two_quiet = _synthetic("two", 1e-4, seed)
    assert not two_loud.extended and not two_quiet.extended
    # Δ ∝ 1/σ²: halving the noise quadruples it, within three of the ratio's standard
    # deviations (each Δ's relative noise is 2/√Δ)
    quiet, loud = two_quiet.statistic, two_loud.statistic
    rel_sd = np.hypot(2 / np.sqrt(quiet), 2 / np.sqrt(loud))
    assert abs(quiet / loud / 4.0 - 1.0) < 3 * rel_sd


def test_one_or_two_refuses_a_noise_variance_that_is_not_positive():
    from analysis.lightfield import LightField2D, theta_grid

    th = theta_grid(DOMAIN, 16)
    lf = LightField2D(np.zeros((3, 16)), np.array([-1.0, 0.0, 1.0]), th, DOMAIN)
    with pytest.raises(ValueError, match="sigma2"):
        one_or_two(np.zeros((3, 16)), lf, np.ones(16, bool), np.ones(16),
                   np.array([[-1.0, -200.0], [1.0, -200.0]]), sigma2=0.0, n_eff=40.0,
                   bounds=((-60.0, 60.0), (-330.0, -120.0)))


#: Two components on the bar's line of sight, 1.9 depth cells apart (δz/D² = δθ/W ≈
#: 3.2·10⁻⁴ /mm at p̂ = 9): where the search on a near-mirror wall left a disc wider than
#: the blur (2.5 cells apart there).
ON_SIGHT = [[0.0, -1.0 / (1.0 / D1 - 3e-4)], [0.0, -1.0 / (1.0 / D1 + 3e-4)]]


@pytest.mark.parametrize("seed", [1, 2])
def test_a_bar_across_seen_as_two_points_in_depth_is_one_extended_object(seed):
    """Started from two components on its line of sight, the 32 mm bar across (≈ 2 δy) is
    still one extended object of its width once the fits are also started across."""
    t = _synthetic("segment", 2e-4, seed, start=ON_SIGHT, across_mm=16.0)
    assert t.extended and t.statistic < t.penalty
    assert abs(t.size_mm[0] - 32.0) < 1.0 and t.size_mm[1] < 5.0


@pytest.mark.parametrize("seed", [1, 2])
def test_a_pair_side_by_side_seen_in_depth_stays_two_at_its_true_places(seed):
    """Two points 18 mm apart side by side (1.13 δy), started on one line of sight: two
    points, fitted where they are (the across start), not one object."""
    t = _synthetic("two", 2e-4, seed, start=ON_SIGHT, across_mm=16.0)
    assert not t.extended and t.statistic > t.penalty
    assert np.allclose(np.sort(t.points_mm[:, 0]), [-9.0, 9.0], atol=0.5)
    assert np.allclose(t.points_mm[:, 1], -D1, atol=5.0)


def test_two_components_on_one_line_of_sight_that_fit_better_side_by_side_are_flagged():
    """The pair 18 mm apart side by side, left by the search as two "resolved" components
    on one line of sight (ON_SIGHT, depth intervals overlapping): its test fits two points
    across, more than a blur apart, so both depths are flagged unresolved and a note names
    both arrangements (ADR 0032, "Line of sight and across")."""
    from analysis.lightfield.localize import _Candidate, _side_by_side

    t = _synthetic("two", 2e-4, 1, start=ON_SIGHT, across_mm=16.0)
    assert not t.extended

    def cand(y, z):
        return _Candidate(y, z, "resolved", (z, z, z), (z - 40.0, z + 40.0), np.zeros(0), None)

    on_sight = [cand(*ON_SIGHT[0]), cand(*ON_SIGHT[1])]
    out, notes = _side_by_side(on_sight, {(0, 1): t}, lambda z: 16.0)
    assert [c.quality for c in out] == ["unresolved", "unresolved"]
    (note,) = notes
    assert "side by side" in note and "flagged unresolved" in note
    # the same test on components already side by side (not on one line of sight), or
    # with a blur wider than the fitted pair, flags nothing
    apart = [cand(-9.0, -D1), cand(9.0, -D1)]
    assert _side_by_side(apart, {(0, 1): t}, lambda z: 16.0)[1] == []
    assert _side_by_side(on_sight, {(0, 1): t}, lambda z: 20.0)[1] == []
