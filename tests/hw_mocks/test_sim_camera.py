"""The simulated camera: contract, geometry, radiometry, EMVA 1288 sensor and validation of
the analysis (photon transfer, HDR, dark + flat) against the simulator's ground truth."""

from __future__ import annotations

import itertools
import math
from dataclasses import replace

import numpy as np
import pytest

from analysis.hdr import merge_hdr
from analysis.photon_transfer import pair_statistics, photon_transfer
from analysis.radiometry import (
    apply_dark_flat,
    flat_field,
    master_dark,
    rate_to_radiance,
    to_radiance,
)
from drivers.base import PixelFormat, Roi
from hw_mocks.sim.camera import OpticsParams, SimulatedCamera, open_from_url
from hw_mocks.sim.goniometer_scene import GoniometerScene, brdf_from_model
from hw_mocks.sim.sensor import SensorParams
from hw_mocks.sim.world import VirtualBench, configure_world, reset_worlds
from tests.drivers.camera_contract import CameraContract, closing_factory

SMALL = SensorParams(width=128, height=96)


@pytest.fixture(autouse=True)
def _fresh_worlds():
    reset_worlds()
    yield
    reset_worlds()


def lit_bench(theta_s=0.0, theta_d=30.0, scene=None, power_w=1e-3) -> VirtualBench:
    world = VirtualBench("t", roles={"sample_theta": theta_s, "detector_theta": theta_d},
                         scene=scene)
    world.update_source(on=True, power_w=power_w)
    return world


def flat_bench(radiance: float) -> VirtualBench:
    """Uniform radiance over the field: ambient light only (no sample, no beam)."""
    return VirtualBench("flat", roles={"detector_theta": 30.0},
                        scene=GoniometerScene(target="none", ambient_radiance=radiance))


class TestSimulatedCameraContract(CameraContract):
    def change_scene(self, camera):
        camera.world.update_source(on=False)  # the lit sample goes dark

    def stop_frames(self, camera):
        camera.realtime = True  # exposures take wall time: 5 s is past any short timeout
        camera.exposure_us = 5e6

    @pytest.fixture
    def camera_factory(self):
        def make():
            cam = SimulatedCamera("cam", world=lit_bench(), seed=3, sensor=SMALL,
                                  ring_capacity=4)
            cam.exposure_us = 200.0
            return cam

        yield from closing_factory(make)


def test_open_from_url_options():
    configure_world("lab", {"roles": {"detector_theta": 40.0}})
    cam = open_from_url("simcam://cam1?world=lab&seed=7&width=64&height=32&format=mono16"
                        "&stale=2&focal_length_mm=35&aperture_mm=5")
    with cam:
        assert cam.name == "cam1" and cam.world.name == "lab"
        assert cam.sensor_shape == (32, 64)
        assert cam.pixel_format is PixelFormat.MONO16
        assert cam.stale_buffers == 2 and cam.optics.focal_length_mm == 35.0
        assert cam.identity.serial == "SIM000007"
    for bad in ("simcam://c?colour=1", "simsource://c", "simcam://c?format=RGB8"):
        with pytest.raises(ValueError):
            open_from_url(bad)
    # A bad value names its option; an impossible sensor is refused.
    with pytest.raises(ValueError, match="option width='wide'"):
        open_from_url("simcam://c?width=wide")
    with pytest.raises(ValueError, match="sensor size"):
        open_from_url("simcam://c?width=0")
    with pytest.raises(ValueError, match="quantum_efficiency"):
        SensorParams(quantum_efficiency=1.5)


def test_deterministic_for_a_seed():
    world = lit_bench()
    a = SimulatedCamera(world=world, seed=5, sensor=SMALL).acquire(2)
    b = SimulatedCamera(world=world, seed=5, sensor=SMALL).acquire(2)
    c = SimulatedCamera(world=world, seed=6, sensor=SMALL).acquire(1)
    np.testing.assert_array_equal(a[0].data, b[0].data)
    np.testing.assert_array_equal(a[1].data, b[1].data)
    assert not np.array_equal(a[0].data, a[1].data)  # fresh temporal noise per frame
    assert not np.array_equal(a[0].data, c[0].data)


def test_dark_frame_has_black_level_and_dark_current():
    world = lit_bench()
    world.update_source(on=False)
    cam = SimulatedCamera(world=world, seed=1, sensor=SMALL)
    cam.exposure_us = 1e6  # 1 s: 20 e⁻ of dark current
    frame = cam.acquire(1)[0]
    p = SMALL
    expected = p.black_level_dn + p.system_gain_dn_per_e * p.dark_current_e_per_s * 1.0
    assert frame.data.mean() == pytest.approx(expected, abs=0.05)
    assert frame.metadata["source_on"] is False


def test_dark_signal_and_its_shot_noise_grow_linearly_with_exposure():
    """EMVA 1288 R3.1 §3: μ_y.dark = black + K μ_d t and σ²_y.dark = K² (σ_d² + μ_d t) + 1/12."""
    world = lit_bench()
    world.update_source(on=False)
    cam = SimulatedCamera(world=world, seed=2, sensor=SMALL)
    p, k = SMALL, SMALL.system_gain_dn_per_e
    n_px = p.width * p.height
    for t_s in (1.0, 4.0):
        cam.exposure_us = t_s * 1e6
        mean, var = pair_statistics(np.stack([f.data for f in cam.acquire(2)]))
        dark_e = p.dark_current_e_per_s * t_s
        expected_var = k * k * (p.read_noise_e**2 + dark_e) + 1.0 / 12.0
        # σ of the pixel mean: the temporal noise and the DSNU over n_px pixels; ×4.
        tol = 4.0 * math.sqrt((expected_var + (k * p.dsnu_e) ** 2) / n_px)
        assert mean == pytest.approx(p.black_level_dn + k * dark_e, abs=tol)
        # The pair variance has a relative standard error of √(2 / n_px); ×4.
        assert var == pytest.approx(expected_var, rel=4.0 * math.sqrt(2.0 / n_px))


@pytest.mark.parametrize("dsnu_e", [1.5, 4.0])
def test_dsnu_is_the_fixed_dark_pattern_of_the_set_size(dsnu_e):
    """EMVA 1288 R3.1 §4: spatial variance of an averaged dark = K² DSNU² + σ²_temporal / N."""
    world = lit_bench()
    world.update_source(on=False)
    sensor = replace(SMALL, dsnu_e=dsnu_e)
    cam = SimulatedCamera(world=world, seed=5, sensor=sensor)
    cam.exposure_us = 10.0
    n = 32
    stack = np.stack([f.data for f in cam.acquire(n)]).astype(float)
    temporal = 0.5 * np.var(stack[0] - stack[1])
    spatial = np.var(stack.mean(axis=0)) - temporal / n
    estimate = math.sqrt(spatial) / sensor.system_gain_dn_per_e
    # The DSNU map has 12 288 pixels: its sample σ is within ~1 % of the set value.
    assert estimate == pytest.approx(dsnu_e, rel=0.05)


@pytest.mark.parametrize("prnu", [0.01, 0.03])
def test_prnu_is_the_fixed_response_pattern_of_the_set_size(prnu):
    """EMVA 1288 R3.1 §4: the dark-subtracted, frame-averaged flat has a spatial relative σ
    of PRNU once the averaged temporal noise is removed."""
    world = flat_bench(radiance=2.0)
    sensor = replace(SMALL, prnu=prnu)
    cam = SimulatedCamera(world=world, seed=6, sensor=sensor,
                          pixel_format=PixelFormat.MONO16)
    rate_e = float(cam.photon_rate().mean()) * sensor.quantum_efficiency
    cam.exposure_us = 0.5 * sensor.full_well_e / rate_e * 1e6
    n = 16
    flats = np.stack([f.data for f in cam.acquire(n)]).astype(float)
    world.scene = GoniometerScene(target="none", ambient_radiance=0.0)
    dark = master_dark(np.stack([f.data for f in cam.acquire(n)]), method="mean")
    signal = flats.mean(axis=0) - dark
    temporal = 0.5 * np.var(flats[0] - flats[1])
    spatial = np.var(signal) - temporal / n
    assert math.sqrt(spatial) / signal.mean() == pytest.approx(prnu, rel=0.05)


def test_adc_bit_depth_scales_k_and_clips_at_the_top_code():
    """K = K₀ 10^(g/20) 2^(bits − native bits); the ADC clips at 2^bits − 1, below the full
    well when the gain is high."""
    world = flat_bench(radiance=2.0)
    cam = SimulatedCamera(world=world, seed=7, sensor=SMALL)
    p = SMALL
    rate_e = float(cam.photon_rate().mean()) * p.quantum_efficiency
    cam.exposure_us = 0.5 * p.full_well_e / rate_e * 1e6
    signal = {}
    for fmt in (PixelFormat.MONO8, PixelFormat.MONO12, PixelFormat.MONO16):
        cam.pixel_format = fmt
        frame = cam.acquire(1)[0]
        assert frame.data.dtype == fmt.dtype and frame.bit_depth == fmt.bit_depth
        signal[fmt.bit_depth] = frame.data.mean() - p.black_level(fmt.bit_depth)
    # Shot noise over 12 288 pixels and PRNU leave < 0.1 % on the mean; 8-bit codes of
    # ~110 DN leave their rounding (≤ 0.5 DN, averaged by the noise) well below 1 %.
    assert signal[16] / signal[12] == pytest.approx(16.0, rel=0.005)
    assert signal[8] / signal[12] == pytest.approx(1.0 / 16.0, rel=0.01)
    cam.pixel_format = PixelFormat.MONO12
    cam.exposure_us = 4.0 * p.full_well_e / rate_e * 1e6  # 4× the full well
    at_well = cam.acquire(1)[0]
    well_dn = p.black_level_dn + p.system_gain_dn_per_e * p.full_well_e
    assert at_well.data.max() <= well_dn + 4 * p.system_gain_dn_per_e * 2.5 + 1
    assert at_well.data.max() < 4095  # 0 dB: the full well limits, not the ADC
    cam.gain = 24.0  # K = 3.2 DN/e⁻: the full well would be 57 000 DN
    clipped = cam.acquire(1)[0]
    assert clipped.saturation_dn == 4095
    assert (clipped.data == 4095).all()


def test_signal_is_proportional_to_exposure_and_gain():
    cam = SimulatedCamera(world=lit_bench(), seed=2, sensor=SMALL)
    dark_world_level = SMALL.black_level_dn

    def signal():
        return cam.acquire(1)[0].data.astype(float).mean() - dark_world_level

    cam.exposure_us = 50.0
    s1 = signal()
    cam.exposure_us = 100.0
    s2 = signal()
    cam.gain = 6.0
    s3 = signal()
    assert s2 / s1 == pytest.approx(2.0, rel=0.01)
    assert s3 / s2 == pytest.approx(10 ** (6 / 20), rel=0.01)


def spot_moments(img: np.ndarray) -> tuple[float, float]:
    """Intensity-weighted standard deviations along columns (x) and rows (y), px."""
    img = np.clip(img, 0, None)
    h, w = img.shape
    ys, xs = np.mgrid[0:h, 0:w]
    total = img.sum()
    mx, my = (img * xs).sum() / total, (img * ys).sum() / total
    sx = math.sqrt((img * (xs - mx) ** 2).sum() / total)
    sy = math.sqrt((img * (ys - my) ** 2).sum() / total)
    return sx, sy


@pytest.mark.parametrize(
    "theta_s, theta_d, ratio",
    [(0.0, 0.0001, 1.0),  # normal view (the arm a hair off the beam)
     (60.0, 60.0, 1.0 / math.cos(math.radians(60))),  # footprint stretched by 1/cos θi
     (0.0, 60.0, math.cos(math.radians(60)))],  # foreshortened by cos θr
)
def test_spot_footprint_geometry(theta_s, theta_d, ratio):
    cam = SimulatedCamera(world=lit_bench(theta_s, theta_d), seed=0,
                          sensor=SensorParams(width=512, height=512))
    sx, sy = spot_moments(cam.photon_rate())
    assert sx / sy == pytest.approx(ratio, rel=0.02)
    # Beam 1/e² radius 2 mm → σ = w/2 = 1 mm on the sample; pinhole magnification f/R.
    px_mm = 5.5e-3 * 300.0 / 50.0
    assert sy * px_mm == pytest.approx(1.0, rel=0.03)


@pytest.mark.parametrize(("theta_s", "theta_d"), [(40.0, 80.0), (80.0, 160.0)],
                         ids=["specular-40", "specular-80"])
def test_pupil_sampling_is_converged(theta_s, theta_d):
    """The adaptive pupil integral (refined until two rules agree within 10⁻⁶) against the
    finest rule of the ladder on every pixel, on a sharp GGX lobe (α = 0.02) seen at its
    specular peak: equal to 10⁻⁶ of the brightest pixel per pixel and 10⁻⁶ in the sum,
    while the chief ray alone is off by more than 10 % (so the test can fail). At 80°
    incidence the lobe is 6× narrower across the plane of incidence than within it."""
    brdf = brdf_from_model("lambert+ggx", [0.3, 0.5, 0.02])
    world = lit_bench(theta_s, theta_d, scene=GoniometerScene(brdf=brdf))
    sensor = SensorParams(width=48, height=48, pixel_pitch_um=5.5 * 1024 / 48)
    rates = {}
    for name, optics in (("adaptive", OpticsParams()),
                         ("finest", OpticsParams(pupil_rtol=1e-15)),
                         ("chief", OpticsParams(pupil="chief"))):
        cam = SimulatedCamera(world=world, sensor=sensor, optics=optics)
        rates[name] = np.array(cam.photon_rate(), dtype=np.float64)
    fine, adaptive = rates["finest"], rates["adaptive"]
    assert np.max(np.abs(adaptive - fine)) <= 1e-6 * fine.max()
    assert adaptive.sum() == pytest.approx(fine.sum(), rel=1e-6)
    assert abs(rates["chief"].sum() / fine.sum() - 1.0) > 0.1


def test_uniform_field_gets_the_pupil_obliquity():
    """A uniform radiance L seen through a pupil of radius ρ focused at F: the centre
    pixel collects (p/f)² ∫cos⁴γ da = (p/f)² A (1 − ρ²/F² + …), the camera equation less
    the pupil's own obliquity (exact étendue π ρ²/(F² + ρ²) per unit object area)."""
    world = flat_bench(radiance=2.0)
    sensor = SensorParams(width=33, height=33)
    sampled = SimulatedCamera(world=world, sensor=sensor).photon_rate()
    chief = SimulatedCamera(world=world, sensor=sensor,
                            optics=OpticsParams(pupil="chief")).photon_rate()
    rho, focus = 6.25, 300.0
    assert sampled[16, 16] / chief[16, 16] == pytest.approx(1.0 / (1.0 + (rho / focus) ** 2),
                                                            rel=1e-7)


@pytest.mark.parametrize(
    "model, params, theta_s, theta_d",
    [("lambert", [0.5], 20.0, 50.0),
     ("lambert+ggx", [0.2, 0.5, 0.3], 20.0, 40.0),  # specular: θr = θi, φr = φi + π
     ("lambert+ggx", [0.2, 0.5, 0.3], 20.0, 75.0)],  # off-specular
)
def test_frame_to_radiance_matches_brdf_times_irradiance(model, params, theta_s, theta_d):
    """Calibrated units end to end: dark-subtracted DN → L = f·E at the spot centre, with
    the ground-truth BRDF evaluated in the analysis.brdf angle convention."""
    brdf = brdf_from_model(model, params)
    world = lit_bench(theta_s, theta_d, scene=GoniometerScene(brdf=brdf))
    cam = SimulatedCamera(world=world, seed=4, sensor=SensorParams(width=256, height=256))
    ti, tr = math.radians(theta_s), math.radians(theta_d - theta_s)
    f_true = float(brdf(ti, math.pi, tr, 0.0))
    peak_e = 2 * 1e-3 / (math.pi * (2e-3) ** 2)
    expected = f_true * peak_e * math.cos(ti)
    # Expose to about half the full well at the spot centre.
    cam.exposure_us = min(max(0.5 * 100.0 * 12.6 / expected, 10.0), 1e4)
    frames = np.stack([f.data for f in cam.acquire(8)])
    world.update_source(on=False)
    cam.invalidate()
    dark = master_dark(np.stack([f.data for f in cam.acquire(8)]), method="mean")
    radiance = to_radiance(frames.mean(axis=0), dark=dark, exposure_us=cam.exposure_us,
                           response=cam.radiometric_response())
    centre = radiance[126:130, 126:130].mean()
    assert centre == pytest.approx(expected, rel=0.02)


def test_out_of_plane_view_renders_the_brdf_at_the_kinematics_angles():
    """Sample tilted out of the plane of incidence and spun about its normal: the spot
    centre's radiance is f(θi, φi, θr, φr) · E with the angles of instrument.bench.kinematics."""
    from instrument.bench.kinematics import OutOfPlaneKinematics

    positions = {"sample_theta": 25.0, "detector_theta": 60.0, "sample_tilt": -15.0,
                 "sample_phi": 30.0}
    angles = OutOfPlaneKinematics(source_theta_deg=0.0).angles(positions)
    assert abs(math.sin(math.radians(angles.phi_r - angles.phi_i))) > 0.1  # out of plane
    brdf = brdf_from_model("lambert+ggx", [0.2, 0.5, 0.3])
    world = VirtualBench("oop", roles=positions, scene=GoniometerScene(brdf=brdf))
    world.update_source(on=True, power_w=1e-3)
    cam = SimulatedCamera(world=world, seed=4, sensor=SensorParams(width=256, height=256))
    ti, pi, tr, pr = (math.radians(a) for a in (angles.theta_i, angles.phi_i,
                                                angles.theta_r, angles.phi_r))
    expected = float(brdf(ti, pi, tr, pr)) * 2 * 1e-3 / (math.pi * (2e-3) ** 2) * math.cos(ti)
    cam.exposure_us = min(max(0.5 * 100.0 * 12.6 / expected, 10.0), 1e4)
    frames = np.stack([f.data for f in cam.acquire(8)])
    world.update_source(on=False)
    cam.invalidate()
    dark = master_dark(np.stack([f.data for f in cam.acquire(8)]), method="mean")
    radiance = to_radiance(frames.mean(axis=0), dark=dark, exposure_us=cam.exposure_us,
                           response=cam.radiometric_response())
    assert radiance[126:130, 126:130].mean() == pytest.approx(expected, rel=0.02)


def test_stale_frames_until_invalidated():
    world = lit_bench(0.0, 30.0)
    cam = SimulatedCamera(world=world, seed=1, sensor=SMALL, stale_buffers=2)
    cam.acquire(1)
    world.set_role("detector_theta", 45.0)  # a move the camera does not know about
    stale = cam.acquire(2)
    assert all(f.metadata["positions"]["detector_theta"] == 30.0 for f in stale)
    cam.invalidate()
    fresh = cam.acquire(1)[0]
    assert fresh.metadata["positions"]["detector_theta"] == 45.0


def test_saturation_level_and_binning():
    cam = SimulatedCamera(world=lit_bench(), seed=1, sensor=SMALL)
    cam.exposure_us = 1e5
    frame = cam.acquire(1)[0]
    sat = frame.saturation_dn
    assert frame.data.max() >= sat  # the spot centre is clipped at full well
    p = SMALL
    assert sat == pytest.approx(p.black_level_dn + p.system_gain_dn_per_e * p.full_well_e,
                                rel=0.01)
    cam.exposure_us = 50.0
    single = cam.acquire(1)[0].data.astype(float) - p.black_level_dn
    cam.binning = 2
    binned = cam.acquire(1)[0]
    assert binned.data.shape == (48, 64)
    assert (binned.data.astype(float) - p.black_level_dn).sum() == pytest.approx(
        single.sum(), rel=0.01)


def test_photon_transfer_recovers_simulator_gain_and_read_noise():
    """Validation: K and read noise within 5 % of the simulator's."""
    world = flat_bench(radiance=2.0)
    cam = SimulatedCamera(world=world, seed=9, sensor=SensorParams(width=256, height=256),
                          pixel_format=PixelFormat.MONO16)
    cam.roi = Roi(64, 64, 128, 128)
    rate = float(cam.photon_rate().mean()) * 0.6  # e⁻/s
    t_sat = 18000.0 / rate * 1e6
    exposures = np.linspace(0.02, 1.3, 22) * t_sat
    flats, darks = [], []
    for t in exposures:
        cam.exposure_us = float(t)
        world.scene = GoniometerScene(target="none", ambient_radiance=2.0)
        flats.append([f.data for f in cam.acquire(2)])
        world.scene = GoniometerScene(target="none", ambient_radiance=0.0)
        darks.append([f.data for f in cam.acquire(2)])
    res = photon_transfer(np.array(flats), np.array(darks), exposures)
    truth_k = cam.system_gain_dn_per_e
    assert truth_k == pytest.approx(3.2)
    assert res.system_gain_dn_per_e == pytest.approx(truth_k, rel=0.05)
    assert res.read_noise_e == pytest.approx(2.5, rel=0.05)
    # EMVA's saturation point (variance maximum) sits where the most responsive pixels
    # (PRNU 1 %) clip, within one sweep step (6 %) below the 18 000 e⁻ full well.
    assert 0.88 * 18000.0 < res.saturation_capacity_e <= 18000.0
    assert res.linearity_error_percent < 0.5


def test_hdr_merge_is_linear_over_1e6_on_the_simulated_bench():
    """Validation: an HDR merge of the beam spot, whose radiance spans more
    than 10⁶, agrees with the simulator's noise-free truth within 2 % wherever some bracket
    is unsaturated."""
    world = lit_bench(0.0, 20.0)
    cam = SimulatedCamera(world=world, seed=12, sensor=SensorParams(width=512, height=512))
    cam.roi = Roi(128, 128, 256, 256)
    exposures = np.array([10.0, 100.0, 1e3, 1e4, 1e5, 1e6, 1e7])  # µs, 10 µs to 10 s
    frames, darks, sats = [], [], []
    for t in exposures:
        cam.exposure_us = float(t)
        world.update_source(on=True)
        cam.invalidate()
        frame = cam.acquire(1)[0]
        frames.append(frame.data)
        sats.append(frame.saturation_dn)
        world.update_source(on=False)
        cam.invalidate()
        darks.append(master_dark(np.stack([f.data for f in cam.acquire(2)]), method="mean"))
    world.update_source(on=True)
    res = merge_hdr(np.stack(frames), exposures, darks=np.stack(darks), saturation_dn=sats,
                    weighting="inverse_variance", system_gain_dn_per_e=0.2,
                    read_noise_dn=0.2 * math.hypot(2.5, 1.0))
    # Truth in DN/µs: K η PRNU × photon rate (dark current is removed by the darks).
    sy, sx = slice(128, 384), slice(128, 384)
    truth = (0.2 * 0.6e-6 * cam.sensor.prnu_map[sy, sx] * cam.photon_rate()).astype(float)
    peak = truth.max()
    assert peak / truth.min() > 1e6
    edges = peak * np.logspace(-6, 0, 13)
    for lo, hi in itertools.pairwise(edges):
        sel = (truth >= lo) & (truth < hi) & ~res.saturated
        assert sel.sum() >= 20
        ratio = res.rate[sel].sum() / truth[sel].sum()
        assert ratio == pytest.approx(1.0, abs=0.02), (lo / peak, ratio, sel.sum())
    # And in calibrated units: the spot centre's radiance is ρ/π · E_peak (normal incidence).
    radiance = rate_to_radiance(res.rate, response=cam.radiometric_response())
    expected = 0.5 / math.pi * 2 * 1e-3 / (math.pi * (2e-3) ** 2)
    assert radiance[126:130, 126:130].mean() == pytest.approx(expected, rel=0.02)


def test_dark_and_flat_remove_the_fixed_pattern_to_shot_noise():
    """Validation: after dark + flat correction the spatial noise of a uniform
    scene equals the temporal (shot + read) noise; before, the fixed pattern dominates."""
    world = flat_bench(radiance=2.0)
    cam = SimulatedCamera(world=world, seed=21, sensor=SensorParams(width=1024, height=1024,
                                                                    prnu=0.02))
    cam.roi = Roi(256, 256, 512, 512)
    rate_e = float(cam.photon_rate().mean()) * 0.6
    cam.exposure_us = 0.5 * 18000.0 / rate_e * 1e6  # half the full well
    flats = np.stack([f.data for f in cam.acquire(48)])
    world.scene = GoniometerScene(target="none", ambient_radiance=0.0)
    dark = master_dark(np.stack([f.data for f in cam.acquire(16)]), method="mean")
    flat = flat_field(flats, dark)
    world.scene = GoniometerScene(target="none", ambient_radiance=2.0)
    a, b = (f.data.astype(float) for f in cam.acquire(2))
    temporal = np.std(a - b) / math.sqrt(2.0)  # EMVA pair difference: no fixed pattern
    corrected = apply_dark_flat(a, dark=dark, flat=flat)
    raw_spatial = np.std(a)
    # The flat's own noise (1/48 of a frame's variance) and the dark's add ~2 %.
    assert np.std(corrected) == pytest.approx(temporal, rel=0.05)
    assert raw_spatial > 1.5 * temporal


def test_camera_z_changes_the_magnification():
    world = lit_bench(0.0, 30.0)
    cam = SimulatedCamera(world=world, seed=0, sensor=SensorParams(width=256, height=256))
    _, sy_near = spot_moments(cam.photon_rate())
    world.set_role("camera_z", 100.0)  # the camera stage moves the camera back 100 mm
    _, sy_far = spot_moments(cam.photon_rate())
    assert sy_near / sy_far == pytest.approx(400.0 / 300.0, rel=0.01)


def test_realtime_acquisition_takes_the_exposure_time():
    import time

    cam = SimulatedCamera(world=lit_bench(), seed=0, sensor=SMALL, realtime=True)
    cam.exposure_us = 30000.0
    t0 = time.perf_counter()
    cam.acquire(2)
    assert time.perf_counter() - t0 >= 0.06


def test_mean_of_frames_is_the_noise_free_expectation():
    cam = SimulatedCamera(world=lit_bench(), seed=8, sensor=SMALL,
                          pixel_format=PixelFormat.MONO16)
    cam.exposure_us = 100.0
    mean = np.mean([f.data.astype(float) for f in cam.acquire(64)], axis=0)
    expected = cam.expected_dn()
    # Per pixel: σ/√64 of shot + read noise, in DN (K = 3.2 DN/e⁻).
    k = cam.system_gain_dn_per_e
    sigma = np.sqrt(k * (expected - 640.0) + (k * 2.5) ** 2 + 1 / 12) / 8.0
    z = (mean - expected) / sigma
    assert abs(z.mean()) < 0.05 and z.std() == pytest.approx(1.0, rel=0.05)


def test_ambient_and_instrument_signature_in_the_image():
    hv = 6.62607015e-34 * 299792458.0 / 633e-9
    etendue = math.pi * (6.25e-3) ** 2 * (5.5e-6 / 50e-3) ** 2
    world = VirtualBench("amb", roles={"detector_theta": 175.0},
                         scene=GoniometerScene(target="none", ambient_radiance=0.1,
                                               signature_sr=1e-3, signature_width_deg=5.0))
    cam = SimulatedCamera(world=world, seed=0, sensor=SMALL)
    centre = float(cam.photon_rate()[47:49, 63:65].mean())
    assert centre == pytest.approx(0.1 * etendue / hv, rel=1e-3)  # source off: ambient
    world.update_source(on=True, power_w=1e-3)
    veil = 1e-3 / 2.0 * 2 * 1e-3 / (math.pi * (2e-3) ** 2)  # f_sig(5°) · E_peak
    centre = float(cam.photon_rate()[47:49, 63:65].mean())
    assert centre == pytest.approx((0.1 + veil) * etendue / hv, rel=1e-3)
