"""The spectral sample of the virtual bench: its configuration, its agreement with the
analysis model that fits it (written independently), and that every detector sees the BRDF
at the wavelength of the light reaching the sample."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from analysis.brdf import get_model
from hw_mocks.sim.goniometer_scene import GoniometerScene, brdf_from_model
from hw_mocks.sim.photodiode import split_power_w
from hw_mocks.sim.spectral_sample import SpectralSample
from hw_mocks.sim.world import VirtualBench

GLASS = {"albedo": [0.2, 0.5, 0.3], "albedo_nm": [450.0, 550.0, 650.0],
         "cauchy_a": 1.5046, "cauchy_b_um2": 0.0042, "alpha": 0.15}
ALUMINIUM = {"albedo": 0.05, "index_nm": [450.0, 550.0, 650.0],
             "index_n": [0.62, 0.96, 1.47], "index_k": [5.47, 6.69, 7.79], "alpha": 0.1}


def _angles(n: int = 60, seed: int = 0):
    rng = np.random.default_rng(seed)
    return (rng.uniform(0, 1.45, n), rng.uniform(-np.pi, np.pi, n), rng.uniform(0, 1.45, n),
            rng.uniform(-np.pi, np.pi, n))


@pytest.mark.parametrize(("cfg", "model", "names"), [
    (GLASS, "lambert+ggx_fresnel", ("rho", "n", "alpha")),
    (ALUMINIUM, "lambert+ggx_conductor", ("rho", "n", "k", "alpha")),
])
@pytest.mark.parametrize("lam", [450.0, 520.0, 650.0])
def test_sample_agrees_with_the_analysis_model(cfg, model, names, lam) -> None:
    s = SpectralSample.from_config(cfg)
    truth = s.truth(lam)
    ti, pi_, tr, pr = _angles()
    ours = s.at_light(lam, 0.0)(ti, pi_, tr, pr)
    theirs = get_model(model).evaluate([truth[k] for k in names], ti, pi_, tr, pr)
    np.testing.assert_allclose(ours, theirs, rtol=1e-10)


def test_cauchy_index_and_interpolated_albedo() -> None:
    s = SpectralSample.from_config(GLASS)
    assert s.truth(500.0)["n"] == pytest.approx(1.5046 + 0.0042 / 0.25)
    assert s.truth(500.0)["rho"] == pytest.approx(0.35)
    assert s.truth(800.0)["rho"] == pytest.approx(0.3)  # constant beyond the table


def test_band_average_is_the_average_over_the_band() -> None:
    s = SpectralSample.from_config(ALUMINIUM)
    ti, pi_, tr, pr = _angles(20, seed=2)
    # a band inside one segment of the index table (Gauss–Legendre is for smooth
    # integrands; a table node inside the band costs ~1e-4)
    got = s.at_light(600.0, 40.0)(ti, pi_, tr, pr)
    lams = np.linspace(580.0, 620.0, 2001)
    brute = np.trapezoid([s.at_light(x, 0.0)(ti, pi_, tr, pr) for x in lams], lams,
                         axis=0) / 40.0
    np.testing.assert_allclose(got, brute, rtol=1e-6)


def _bench(scene, lam: float, bandwidth: float = 0.0) -> VirtualBench:
    w = VirtualBench("spectral-test", roles={"sample_theta": 25.0, "detector_theta": 52.0},
                     scene=scene)
    w.update_source(on=True, wavelength_nm=lam, bandwidth_nm=bandwidth)
    return w


@pytest.mark.parametrize("lam", [450.0, 650.0])
def test_power_meter_photodiode_and_camera_see_the_light_s_wavelength(lam: float) -> None:
    spectral = GoniometerScene.from_config({"brdf": "spectral", "spectral": GLASS,
                                            "spot_samples": 16})
    t = SpectralSample.from_config(GLASS).truth(lam)
    fixed = GoniometerScene(brdf=brdf_from_model("lambert+ggx_fresnel",
                                                 [t["rho"], t["n"], t["alpha"]]),
                            spot_samples=16)
    a, b = _bench(spectral, lam), _bench(fixed, lam)
    assert a.optical_power_w() == pytest.approx(b.optical_power_w(), rel=1e-12)
    assert split_power_w(a)[0] == pytest.approx(split_power_w(b)[0], rel=1e-12)
    # the camera renders scene.radiance: rays from the detector towards the sample
    state_a, state_b = a.snapshot(), b.snapshot()
    origin = state_a.pose.detector_dir * 300.0
    rng = np.random.default_rng(0)
    d = -state_a.pose.detector_dir + 0.01 * rng.standard_normal((50, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    np.testing.assert_allclose(spectral.radiance(origin, d, state_a),
                               fixed.radiance(origin, d, state_b), rtol=1e-12)


def test_the_specular_power_changes_with_the_filter() -> None:
    scene = GoniometerScene.from_config({"brdf": "spectral", "spectral": ALUMINIUM,
                                         "spot_samples": 16})
    blue, red = _bench(scene, 450.0, 10.0), _bench(scene, 650.0, 10.0)
    # aluminium reflects more in the red at these indices (R(0) 0.92 vs 0.91)
    assert red.optical_power_w() != pytest.approx(blue.optical_power_w(), rel=1e-3)


@pytest.mark.parametrize(("changes", "match"), [
    ({"alpha": None}, "alpha"),
    ({"albedo": None}, "albedo"),
    ({"alpha": 0.0}, "alpha"),
    ({"albedo": [0.2, 1.5, 0.3]}, r"albedo must lie in \[0, 1\]"),
    ({"albedo_nm": [450.0, 550.0]}, "same length"),
    ({"albedo_nm": [450.0, 440.0, 650.0]}, "increasing"),
    ({"cauchy_a": 0.9}, "cauchy_a ≥ 1"),
    ({"index_nm": [500.0], "index_n": [1.5]}, "not both"),
    ({"colour": "red"}, "unknown"),
])
def test_configuration_errors_name_the_key(changes: dict, match: str) -> None:
    cfg = dict(GLASS)
    for k, v in changes.items():
        if v is None:
            cfg.pop(k)
        else:
            cfg[k] = v
    with pytest.raises(ValueError, match=match):
        SpectralSample.from_config(cfg)


def test_scene_keys_go_together() -> None:
    with pytest.raises(ValueError, match="spectral"):
        GoniometerScene.from_config({"brdf": "spectral"})
    with pytest.raises(ValueError, match="params"):
        GoniometerScene.from_config({"spectral": GLASS, "params": [0.5]})
    with pytest.raises(ValueError, match="one of them"):
        SpectralSample.from_config({"albedo": 0.5, "alpha": 0.2})


@settings(max_examples=60, deadline=None)
@given(albedo=st.floats(0.0, 1.0), a=st.floats(1.0, 3.0), b=st.floats(0.0, 0.05),
       alpha=st.floats(1e-3, 2.0), lam=st.floats(200.0, 2000.0))
def test_any_valid_configuration_gives_a_finite_energy_bounded_brdf(albedo, a, b, alpha,
                                                                     lam) -> None:
    s = SpectralSample.from_config({"albedo": albedo, "cauchy_a": a, "cauchy_b_um2": b,
                                    "alpha": alpha})
    ti, pi_, tr, pr = _angles(16, seed=1)
    f = s.at_light(lam, 5.0)(ti, pi_, tr, pr)
    assert np.all(np.isfinite(f)) and np.all(f >= albedo / np.pi - 1e-12)
