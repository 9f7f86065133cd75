"""Depth bias of a located point source, and where the old bias came from.

The ideal input of localisation: the true incident field at the wall (cell averages of the
continuous renderer's ground truth, a 1.5 mm disc) seen through a truncation at P angular
orders, with the cosine-weighted basis of the reconstruction (eq. 2-18).

History: the conventional stack's peak sits nearer the wall (its height scales as W/|z|);
weighting it by |z| (the matched filter, module doc of ``analysis.lightfield.localize``)
removed most of that, but the depth filter still came out 0.3 δz (P = 18) to 0.6 δz
(P = 5) towards the wall.  Cause (derived in the module doc): its band of spatial
frequencies reached 1/δy, twice the angular cut-off ``(P + ½)/((B − A)|z0|) = 1/(2 δy)``
mapped to the object's depth; the frequencies above the cut-off carry signal only at trial
depths nearer the wall, so their z-profiles peak there.  Ending the band at 1/(2 δy)
removes the pull.
"""

from __future__ import annotations

import numpy as np
import pytest

from analysis.lightfield import (
    FocalStack,
    LightField2D,
    coefficients,
    depth_profile,
    detect_objects,
    fourier_orders,
    material,
    refocus,
    synthesize,
    theoretical_resolution,
    theta_grid,
)
from hw_mocks.sim.lightfield_scene import HiddenScene, PointObject, Wall

DOMAIN = (-0.6, 0.6)
SOLVABLE = (-0.5, 0.5)
N = 128
Y0 = -8.0


def _filtered_truth(y0: float, z0: float, p: int, half_wall: float = 29.0) -> LightField2D:
    scene = HiddenScene((PointObject(y0, z0, 1.5, 1.0, "disc"),),
                        Wall(-150.0, 150.0, material("brushed_metal")), d2_mm=30.0)
    c = np.arange(-half_wall, half_wall + 0.01, 1.0)
    th = theta_grid(DOMAIN, N)
    w = (DOMAIN[1] - DOMAIN[0]) / N
    sub = (np.arange(41) / 40 - 0.5) * w
    truth = np.mean([scene.incident_radiance(c[:, None], th[None, :] + s) for s in sub], axis=0)
    phi = (np.abs(fourier_orders(N)) <= p).astype(float)
    g = synthesize(coefficients(truth * np.cos(th)[None, :], axis=-1) * phi, axis=-1).real
    return LightField2D(g / np.cos(th)[None, :], c, th, DOMAIN, 0.0)


@pytest.mark.parametrize(("p", "z0", "quality"), [
    (18, -150.0, "resolved"), (18, -200.0, "resolved"), (18, -260.0, "resolved"),
    (5, -150.0, "resolved"),
    # P = 5 at 260 mm: the point response's half-maximum reaches past any finite depth
    # (2.4 δz > D), so the depth is flagged although the estimate is accurate
    (5, -260.0, "unresolved"),
])
def test_point_depth_bias_below_a_seventh_of_the_depth_blur(p, z0, quality):
    lf = _filtered_truth(Y0, z0, p)
    phi = (np.abs(fourier_orders(N)) <= p).astype(float)
    # the far end of the interval at P = 5, 260 mm is 507 mm: the search must reach it
    det = detect_objects(lf, p_max=p, y_mm=np.arange(-40.0, 25.0, 0.5),
                         z_mm=np.arange(-560.0, -80.0, 1.0), solvable_domain_rad=SOLVABLE,
                         filter_factors=phi, min_measure_fraction=0.1)
    assert det.count == 1
    assert det.quality == (quality,)
    (y, z), res = det.positions_mm[0], det.resolutions[0]
    assert abs(y - Y0) < 0.1 * res.transverse_mm
    # measured: |Δz| ≤ 0.08 δz for P = 5 … 18 at 150 … 260 mm (was 0.29 … 0.6 δz)
    assert abs(z - z0) < 0.15 * res.depth_mm
    far, near = det.depth_interval_mm[0]
    assert far < z0 < near


@pytest.mark.parametrize("p", [5, 18])
def test_depth_filter_band_beyond_the_angular_cutoff_pulls_towards_the_wall(p):
    """The derivation, checked: the same depth filter, band (0.1, 1]/δy against
    (0.1, ½]/δy, on the |z|-weighted stack of the filtered renderer truth."""
    z0 = -200.0
    z = np.arange(-330.0, -60.0, 1.0)
    st = refocus(_filtered_truth(Y0, z0, p), y_mm=np.arange(-80.0, 80.0, 0.5), z_mm=z,
                 solvable_domain_rad=SOLVABLE)
    weighted = FocalStack(st.y_mm, z, st.conventional * np.abs(z)[:, None],
                          st.radiance_preserving, st.measure_rad, SOLVABLE)
    res = theoretical_resolution(p, domain_rad=DOMAIN, distance_mm=200.0, aperture_mm=58.0,
                                 solvable_domain_rad=SOLVABLE)

    def peak(top: float, window: float) -> float:
        prof, _ = depth_profile(weighted, Y0, window_halfwidth_mm=window * res.transverse_mm,
                                max_frequency_per_mm=top / res.transverse_mm,
                                min_frequency_per_mm=0.1 / res.transverse_mm)
        return float(z[np.argmax(prof)])

    assert (peak(1.0, 1.5) - z0) / res.depth_mm > 0.2  # the old band: towards the wall
    assert abs(peak(0.5, 3.0) - z0) / res.depth_mm < 0.1


def test_matched_filter_column_peaks_at_the_depth_where_the_conventional_does_not():
    z0 = -200.0
    z = np.arange(-330.0, -60.0, 1.0)
    st = refocus(_filtered_truth(Y0, z0, 18), y_mm=np.array([Y0]), z_mm=z,
                 solvable_domain_rad=SOLVABLE)
    res = theoretical_resolution(18, domain_rad=DOMAIN, distance_mm=200.0, aperture_mm=58.0,
                                 solvable_domain_rad=SOLVABLE)
    assert abs(z[np.argmax(st.matched_filter[:, 0])] - z0) < 0.1 * res.depth_mm
    assert (z[np.argmax(st.conventional[:, 0])] - z0) > 0.3 * res.depth_mm


@pytest.mark.parametrize("z0", [-150.0, -260.0])
def test_exact_matched_filter_is_unbiased_where_the_domain_limits_the_aperture(z0):
    """200 mm of wall and a ±0.3 rad solvable domain: the trial point sees W = D·2 tan 0.3
    of wall, more the farther it is.  Scoring every trial point on the same rays (the
    exact form, with the filter factors) keeps the column peak at the depth; the
    projector form leans away from the wall."""
    p, solvable = 5, (-0.3, 0.3)
    lf = _filtered_truth(0.0, z0, p, half_wall=100.0)
    phi = (np.abs(fourier_orders(N)) <= p).astype(float)
    z = np.arange(-600.0, -60.0, 1.0)
    res = theoretical_resolution(p, domain_rad=DOMAIN, distance_mm=abs(z0), aperture_mm=200.0,
                                 solvable_domain_rad=solvable)
    assert res.aperture_mm < 200.0  # the domain, not the wall, sets W
    exact = refocus(lf, y_mm=np.array([0.0]), z_mm=z, solvable_domain_rad=solvable,
                    filter_factors=phi)
    approx = refocus(lf, y_mm=np.array([0.0]), z_mm=z, solvable_domain_rad=solvable)
    # measured: +0.01 δz against −0.29 / −0.24 δz (away from the wall)
    assert abs(z[np.argmax(exact.matched_filter[:, 0])] - z0) < 0.1 * res.depth_mm
    assert (z[np.argmax(approx.matched_filter[:, 0])] - z0) < -0.15 * res.depth_mm


@pytest.mark.parametrize("p", [5, 10, 18])
def test_depth_response_is_wider_than_the_edge_ray_resolution(p):
    """The matched filter's column of a point: half width at half maximum ≈ 2.4 δz/D² in
    inverse depth (the parallax grows linearly from the aperture's centre, so only its
    edge rays shift by δθ when 1/D moves by δz/D²); this is why detections carry the
    half-maximum span in their depth interval."""
    z0 = -200.0
    lf = _filtered_truth(0.0, z0, p)
    phi = (np.abs(fourier_orders(N)) <= p).astype(float)
    z = np.arange(-1500.0, -60.0, 0.5)
    st = refocus(lf, y_mm=np.array([0.0]), z_mm=z, solvable_domain_rad=SOLVABLE,
                 filter_factors=phi)
    col = st.matched_filter[:, 0]
    inv = 1.0 / np.abs(z[col >= 0.5 * col.max()])
    res = theoretical_resolution(p, domain_rad=DOMAIN, distance_mm=200.0, aperture_mm=58.0,
                                 solvable_domain_rad=SOLVABLE)
    hwhm_cells = 0.5 * (inv.max() - inv.min()) / (res.depth_mm / 200.0**2)
    assert 2.0 < hwhm_cells < 2.8  # measured 2.33 … 2.41
