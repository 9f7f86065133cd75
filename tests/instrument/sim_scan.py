"""In-plane BRDF scans rendered on the simulated bench without the motion emulators.

The points come from the real plan builder (``instrument.plans``) on the ``sim`` bench
profile; each point's axis targets are set as constant role positions of a private
:class:`hw_mocks.sim.world.VirtualBench`, and the frames are rendered by the same
:class:`hw_mocks.sim.camera.SimulatedCamera` / :class:`hw_mocks.sim.goniometer_scene.
GoniometerScene` / EMVA 1288 :class:`hw_mocks.sim.sensor.Sensor` code the emulated bench
uses — only the stage firmware (which would just put the axes at the same targets) is left
out, so 50-seed statistics take seconds instead of hours.

Acquisition per point mirrors the engine's ``mode = "auto"`` with ``dark = "per_point"``:
the exposure fills the brightest pixel to ``fill`` of the full well (noise-free prediction),
capped at ``max_exposure_us``; ``frames`` exposures are averaged, and a dark frame (light
off, same exposure, same averaging) follows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from analysis.brdf.reduction import (
    BRDFPoints,
    DetectorNoise,
    ReceiverGeometry,
    absolute_brdf,
    camera_power_w,
    camera_signal,
    camera_solid_angle_sr,
)
from analysis.radiometry import FlatField
from hw_mocks.sim.camera import OpticsParams, SimulatedCamera
from hw_mocks.sim.goniometer_scene import GoniometerScene, brdf_from_model
from hw_mocks.sim.sensor import Sensor, SensorParams
from hw_mocks.sim.speckle import (
    EXACT_PATTERNS,
    SpeckleOptics,
    decorrelation_angle_deg,
    speckle_image,
    speckle_seed,
)
from hw_mocks.sim.world import SourceState, VirtualBench
from instrument.bench.kinematics import kinematics_of
from instrument.bench.profile import load_profile
from instrument.plans.build import Plan, build_plan
from instrument.plans.planfile import parse_plan


@dataclass(frozen=True)
class Sample:
    """Ground truth: a registry model and its parameters."""

    name: str
    model: str
    params: tuple[float, ...]


#: The three closed-loop samples (BENCHMARKS.md brdf_closed_loop).
SAMPLES = (
    Sample("lambert", "lambert", (0.8,)),
    Sample("glossy", "lambert+ggx", (0.3, 0.5, 0.2)),
    Sample("rough", "oren_nayar", (0.8, 0.3)),
)
#: Candidate models the fits choose from.
CANDIDATES = ("lambert", "oren_nayar", "lambert+ggx")

#: The closed-loop validation matrix (bench_brdf_closed_loop.py --matrix): one sample per
#: family of the library,
#: from diffuse to a sharp specular lobe (GGX α = 0.02), scanned at θi = 20°, 50°, 80°.
MATRIX = (
    Sample("lambert", "lambert", (0.8,)),
    Sample("oren-nayar", "oren_nayar", (0.8, 0.3)),
    Sample("hapke", "hapke", (0.6,)),
    Sample("rough-beckmann", "lambert+beckmann", (0.4, 0.4, 0.3)),
    Sample("smooth-rayleigh-rice", "lambert+rayleigh_rice_gauss", (0.3, 5.0, 4.0)),
    Sample("glossy-ggx", "lambert+ggx", (0.3, 0.5, 0.2)),
    Sample("glossy-phong", "lambert+phong", (0.3, 0.5, 300.0)),
    Sample("sharp-ggx-0.05", "lambert+ggx", (0.3, 0.5, 0.05)),
    Sample("sharp-ggx-0.02", "lambert+ggx", (0.3, 0.5, 0.02)),
    Sample("metal-beckmann-kirchhoff", "beckmann_kirchhoff", (0.9, 0.2)),
)


@dataclass(frozen=True)
class ScanSetup:
    """Angles, acquisition and the simulated camera/source."""

    theta_i_deg: tuple[float, ...] = (20.0, 40.0, 60.0)
    theta_r_start: float = -70.0
    theta_r_stop: float = 80.0
    theta_r_step: float = 10.0
    specular_half_width_deg: float = 4.0
    specular_step_deg: float = 2.0
    fill: float = 0.02
    max_exposure_us: float = 200_000.0
    min_exposure_us: float = 10.0
    frames: int = 1
    power_w: float = 2e-6
    beam_radius_mm: float = 2.0
    sensor_px: int = 96
    focal_length_mm: float = 50.0
    aperture_mm: float = 12.5
    distance_mm: float = 300.0
    sample_radius_mm: float = 12.5
    sensor: SensorParams = field(default_factory=SensorParams)
    #: Rays per pixel side: a pixel integrates the irradiance over its area, the simulated
    #: camera samples its centre. Coarse pixels (2 mm on the sample at θr = 80° for 96 px)
    #: make that a midpoint rule off by −0.8 % there; None: enough for ≥ 384 px per side.
    supersample: int | None = None

    def rays_per_pixel_side(self) -> int:
        return self.supersample or max(1, 384 // self.sensor_px)

    def sensor_params(self) -> SensorParams:
        # same field of view as the 1024-px default camera, coarser pixels
        pitch = self.sensor.pixel_pitch_um * self.sensor.width / self.sensor_px

        return replace(self.sensor, width=self.sensor_px, height=self.sensor_px,
                       pixel_pitch_um=pitch)

    def plan_text(self) -> str:
        spec = ""
        if self.specular_half_width_deg > 0:
            spec = (f"specular = {{ half_width_deg = {self.specular_half_width_deg}, "
                    f"step_deg = {self.specular_step_deg} }}\n")
        return (
            '[plan]\nkind = "brdf_in_plane"\nname = "closed loop"\norder = "optimised"\n'
            '[sample]\nname = "sim"\n'
            f"[scan]\ntheta_i = {list(self.theta_i_deg)}\n"
            f"theta_r = {{ start = {self.theta_r_start}, stop = {self.theta_r_stop}, "
            f"step = {self.theta_r_step} }}\n{spec}skip_beam_points = true\n"
            '[acquisition]\nmode = "auto"\n'
            f"exposure_us = {min(2000.0, self.max_exposure_us)}\n"
            f"max_exposure_us = {self.max_exposure_us}\n"
            f'frames = {self.frames}\ndark = "per_point"\ndetectors = ["camera"]\n'
        )

    def plan(self) -> Plan:
        return build_plan(parse_plan(self.plan_text()), load_profile("sim"))


@dataclass(frozen=True)
class Rendered:
    """Noise-free photon rates of every point of a scan."""

    setup: ScanSetup
    sample: Sample
    angles_rad: np.ndarray          # (n, 4): θi, φi, θr, φr
    photon_rate: np.ndarray         # (n, H, W) photons/s per pixel
    plan: Plan


#: Noise-free renders of the default scene, kept per test process: the same (setup, sample)
#: scan is rendered by several test modules (the fit report's, the batch's, the reduction's,
#: the run browser's), a few seconds of CPU each time, and pytest-xdist may run one
#: module's tests on several workers, each building the module's fixtures again.
_RENDERED: dict[tuple[ScanSetup, Sample], Rendered] = {}


def render(setup: ScanSetup, sample: Sample, *, scene: GoniometerScene | None = None,
           plan: Plan | None = None, cache: dict | None = None) -> Rendered:
    """Render every plan point of ``setup`` (or of ``plan``) for ``sample`` (noise-free);
    ``scene`` replaces the default scene (the sample alone) e.g. to add an instrument
    signature. ``cache`` (a dict kept by the caller) reuses the frames of axis targets
    rendered before for the same sample and setup.

    A render of the default scene and plan is computed once per process and shared (its
    arrays are read-only, so no caller can change another's): the render is deterministic,
    the noise is added later, per seed."""
    if scene is None and plan is None and cache is None:
        key = (setup, sample)
        if key not in _RENDERED:
            _RENDERED[key] = _read_only(_render(setup, sample))
        return _RENDERED[key]
    return _render(setup, sample, scene=scene, plan=plan, cache=cache)


def _read_only(r: Rendered) -> Rendered:
    r.angles_rad.setflags(write=False)
    r.photon_rate.setflags(write=False)
    return r


def _render(setup: ScanSetup, sample: Sample, *, scene: GoniometerScene | None = None,
            plan: Plan | None = None, cache: dict | None = None) -> Rendered:
    plan = plan if plan is not None else setup.plan()
    if scene is None:
        scene = GoniometerScene(brdf=brdf_from_model(sample.model, sample.params),
                                sample_radius_mm=setup.sample_radius_mm)
    world = VirtualBench(
        f"closed-loop-{sample.name}", scene=scene, arm_length_mm=setup.distance_mm,
        source=SourceState(on=True, power_w=setup.power_w, max_power_w=1.0,
                           beam_radius_mm=setup.beam_radius_mm),
    )
    ss = setup.rays_per_pixel_side()
    coarse = setup.sensor_params()

    fine = replace(coarse, width=coarse.width * ss, height=coarse.height * ss,
                   pixel_pitch_um=coarse.pixel_pitch_um / ss)
    cam = SimulatedCamera(
        "camera", world=world, sensor=fine,
        optics=OpticsParams(setup.focal_length_mm, setup.aperture_mm),
    )
    offsets = getattr(kinematics_of(plan.profile.geometry), "offsets", {})
    rates, angles = [], []
    for p in plan.points:
        key = (sample, setup, tuple((r, round(v, 9)) for r, v in p.targets))
        if cache is not None and key in cache:
            rates.append(cache[key])
        else:
            for role, value in p.targets:
                # a type (i) arm's stage reads its angle plus the profile's offset
                world.set_role(role, value - offsets.get(role, 0.0))
            state = world.snapshot()
            rate = np.array(cam.photon_rate(state), dtype=np.float64)
            # each pixel sums its ss × ss sub-pixels (area integration)
            rates.append(rate.reshape(coarse.height, ss, coarse.width, ss).sum(axis=(1, 3)))
            if cache is not None:
                cache[key] = rates[-1]
        a = p.angles
        angles.append([math.radians(a.theta_i), math.radians(a.phi_i),
                       math.radians(a.theta_r), math.radians(a.phi_r)])
    return Rendered(setup, sample, np.array(angles), np.array(rates), plan)


def noise_free(r: Rendered) -> BRDFPoints:
    """The noise-free reduction of ``r``: the collected power of every point (its photon
    rates summed over the frame) by the absolute method, receiver factor divided out."""
    photon_j = 6.62607015e-34 * 299792458.0 / 633e-9
    power = r.photon_rate.reshape(len(r.photon_rate), -1).sum(axis=1) * photon_j
    rg = receiver(r.setup)
    a = r.angles_rad
    return absolute_brdf(power, power, a[:, 0], a[:, 1], a[:, 2], a[:, 3],
                         incident_power_w=r.setup.power_w, solid_angle=rg.solid_angle_sr,
                         receiver=rg)


def exposures_us(r: Rendered, attenuation: np.ndarray | float = 1.0) -> np.ndarray:
    """Per-point exposure: the brightest pixel at ``fill`` of the full well, capped (the
    light divided by ``attenuation``: 1/T behind a filter of transmission T)."""
    s = r.setup
    p = s.sensor_params()
    peak_e_per_s = r.photon_rate.reshape(len(r.photon_rate), -1).max(axis=1) * (
        p.quantum_efficiency * (1 + 3 * p.prnu))
    t = s.fill * p.full_well_e / np.maximum(peak_e_per_s, 1e-30) * 1e6
    return np.clip(t * attenuation, s.min_exposure_us, s.max_exposure_us)


def acquisition_seconds(r: Rendered, *, readout_s: float = 0.0) -> float:
    """Exposure time of the whole scan: frames × (light + dark) × exposure per point."""
    return float(np.sum(2 * r.setup.frames * (exposures_us(r) * 1e-6 + readout_s)))


def noise_model(setup: ScanSetup) -> DetectorNoise:
    p = setup.sensor_params()
    sensor = Sensor(p, seed=0)
    return DetectorNoise(p.system_gain(0.0, 12), p.read_noise_e,
                         sensor.saturation_dn(gain_db=0.0, bits=12), p.dark_current_e_per_s)


def receiver(setup: ScanSetup) -> ReceiverGeometry:
    """What the simulated camera integrates: the footprint seen through its whole entrance
    pupil, on the scene's sample disk, with Ω = A_pupil/R² (what
    ``instrument.pipelines.brdf.reduce`` builds for a run)."""
    omega, _ = camera_solid_angle_sr(setup.aperture_mm, setup.distance_mm)
    return ReceiverGeometry(setup.beam_radius_mm, setup.distance_mm, setup.aperture_mm, omega,
                            sample_aperture=True, sample_radius_mm=setup.sample_radius_mm)


@dataclass(frozen=True)
class NDFilters:
    """Neutral-density filters for a scan acquired without the engine, lightest first:
    ``true`` attenuates the light, ``value`` ± ``u`` is what the reduction divides by (a
    calibration's value and its error, shared by every point through that filter; the
    sim bench's wheel, ``instrument/bench/profiles/sim.toml``, by default), ``slots`` their
    wheel slots."""

    true: tuple[float, ...] = (0.1043, 0.00962, 0.001071)
    value: tuple[float, ...] = (0.1043, 0.00962, 0.001071)
    u: tuple[float, ...] = (1e-4, 1e-5, 1e-6)
    slots: tuple[int, ...] = (2, 3, 4)


def reduce_seed(r: Rendered, seed: int, *, sigma_theta_deg: float = 0.0,
                receiver_geometry: bool = True, nd: NDFilters | None = None) -> BRDFPoints:
    """Acquire every point with sensor seed ``seed`` and reduce by the absolute method
    (``receiver_geometry``: divide out the receiver factor and keep the geometry); ``nd``
    as for :func:`reduce_seed_nd`."""
    return reduce_seed_nd(r, seed, sigma_theta_deg=sigma_theta_deg,
                          receiver_geometry=receiver_geometry, nd=nd)[0]


def reduce_seed_nd(r: Rendered, seed: int, *, sigma_theta_deg: float = 0.0,
                   receiver_geometry: bool = True, nd: NDFilters | None = None
                   ) -> tuple[BRDFPoints, np.ndarray]:
    """:func:`reduce_seed`, and the wheel slot each point was read through (-1: open).

    With ``nd``, a point that clips at the shortest exposure is read again through the next
    denser filter (the engine's rule, ADR 0018); its reading is divided by the filter's
    ``value`` and the filter's error is a covariance between its points (as
    ``instrument.pipelines.brdf.attenuation.apply_nd`` carries it)."""
    s = r.setup
    p = s.sensor_params()
    sensor = Sensor(p, seed=seed)
    noise = noise_model(s)
    n = len(r.photon_rate)
    roi = (0, 0, p.width, p.height)
    # a perfect flat-field calibration: the sensor's own PRNU map (mean 1)
    flat = FlatField(sensor.prnu_map.astype(np.float64), np.ones(sensor.prnu_map.shape, bool),
                     1.0)
    rates = np.empty(n)
    variances = np.empty(n)
    clipped = np.zeros(n, dtype=bool)
    level = np.zeros(n, dtype=int)
    zero = np.zeros_like(r.photon_rate[0], dtype=np.float32)
    ladder = (1.0,) + (nd.true if nd is not None else ())
    for k in range(n):
        while True:
            lv = int(level[k])
            t = float(exposures_us(replace(r, photon_rate=r.photon_rate[k:k + 1]),
                                   1.0 / ladder[lv])[0])
            light, dark = [], []
            base = 4 * k * s.frames + lv * 4 * n * s.frames
            for j in range(s.frames):
                light.append(sensor.expose((r.photon_rate[k] * ladder[lv]).astype(np.float32),
                                           t, gain_db=0.0, bits=12, roi=roi,
                                           frame_index=base + j))
                dark.append(sensor.expose(zero, t, gain_db=0.0, bits=12, roi=roi,
                                          frame_index=base + 2 * s.frames + j))
            lf = np.mean(np.array(light, dtype=np.float64), axis=0)
            df = np.mean(np.array(dark, dtype=np.float64), axis=0)
            sig = camera_signal(lf[None], [t], df[None], noise=noise, n_averaged=s.frames,
                                flat=flat)
            if sig.clipped_pixels > 0 and t <= s.min_exposure_us and lv + 1 < len(ladder):
                level[k] += 1
                continue
            break
        rates[k], variances[k] = sig.rate_dn_per_us, sig.variance
        clipped[k] = sig.clipped_pixels > 0
    k_gain = noise.system_gain_dn_per_e
    wl = 633.0
    power = camera_power_w(rates, system_gain_dn_per_e=k_gain,
                           quantum_efficiency=p.quantum_efficiency, wavelength_nm=wl)
    u_power = camera_power_w(np.sqrt(variances), system_gain_dn_per_e=k_gain,
                             quantum_efficiency=p.quantum_efficiency, wavelength_nm=wl)
    cov_rel = None
    if nd is not None and (level > 0).any():
        value = np.array((1.0, *nd.value))[level]
        rel = np.array((0.0, *tuple(u / v for u, v in zip(nd.u, nd.value, strict=True))))[
            level]
        power, u_power = power / value, u_power / value
        same = (level[:, None] == level[None, :]) & (level[:, None] > 0)
        cov_rel = np.where(same, np.outer(rel, rel), 0.0)
    rg = receiver(s)
    a = r.angles_rad
    sig_t = math.radians(sigma_theta_deg)
    pts = absolute_brdf(power, u_power, a[:, 0], a[:, 1], a[:, 2], a[:, 3],
                        incident_power_w=s.power_w, solid_angle=rg.solid_angle_sr,
                        sigma_theta_i=sig_t, sigma_theta_r=sig_t,
                        receiver=rg if receiver_geometry else None, cov_power_rel=cov_rel)
    slots = np.array((-1,) + (nd.slots if nd is not None else ()))[level]
    # readings clipped even at the shortest exposure are lower bounds, as in a run
    return replace(pts, clipped=clipped), slots


def profile_text(setup: ScanSetup, sample: Sample) -> str:
    """The ``sim`` bench profile with this setup's camera, source and sample."""
    text = (Path(__file__).resolve().parents[2] / "instrument" / "bench" / "profiles" / "sim.toml"
            ).read_text(encoding="utf-8")
    p = setup.sensor_params()
    cam = (f"simcam://camera?world=sim&seed=1&width={p.width}&height={p.height}"
           f"&pixel_pitch_um={p.pixel_pitch_um!r}&aperture_mm={setup.aperture_mm!r}"
           f"&focal_length_mm={setup.focal_length_mm!r}")
    text = text.replace("simcam://camera?world=sim&seed=1", cam)
    head, _, _ = text.partition("[simulation.scene]")
    params = ", ".join(repr(v) for v in sample.params)
    return (head + f'[simulation.scene]\nbrdf = "{sample.model}"\nparams = [{params}]\n\n'
            f"[simulation.source]\npower_w = {setup.power_w!r}\nwavelength_nm = 633.0\n"
            f"beam_radius_mm = {setup.beam_radius_mm!r}\nmax_power_w = 1.0\n")


def write_run_file(r: Rendered, seed: int, path: Path, *, kind: str = "brdf_in_plane",
                   run_id: str = "closed-loop", plan_text: str | None = None,
                   coherence: str | None = None) -> Path:
    """Acquire every point of ``r`` with sensor ``seed`` and store it as a run file with
    :class:`instrument.run.storage.RunStore` (the engine's writer), frames per point: the light
    frame then its dark frame. ``plan_text`` is stored as the run's plan (default the
    setup's); ``coherence`` adds the profile's ``[source] coherence``."""
    import time as _time

    from instrument.run.storage import FrameData, PointRecord, RunHeader, RunStore

    s = r.setup
    p = s.sensor_params()
    sensor = Sensor(p, seed=seed)
    t = exposures_us(r)
    roi = (0, 0, p.width, p.height)
    plan = r.plan
    pol = plan.spec.acquisition
    header = RunHeader(
        run_id=run_id, plan_kind=kind, plan_name=plan.spec.name,
        plan_text=plan_text if plan_text is not None else s.plan_text(),
        profile_text=profile_text(s, r.sample) + (
            "" if coherence is None else f'\n[source]\ncoherence = "{coherence}"\n'),
        bench_name="sim", sample_name=r.sample.name,
        sample_description="closed-loop sample", axes=plan.axes,
        planned_targets=plan.targets_array().tolist(),
        planned_angles=[list(q.angles.as_tuple()) for q in plan.points],
        planned_label=[q.label for q in plan.points],
        planned_light=[q.light for q in plan.points],
        planned_exposure_us=[math.nan] * len(plan.points),
        acquisition_policy=pol.as_json(), retry_policies="{}", identities={},
        device_kinds={}, geometry={"detector_distance_mm": s.distance_mm,
                                   "detector_aperture_mm": 5.0, "kind": "in_plane"},
        calibration={}, software_version="test", created=_time.time())
    store = RunStore.create(path, header, fsync=False, min_free_bytes=0)
    zero = np.zeros_like(r.photon_rate[0], dtype=np.float32)
    for k, q in enumerate(plan.points):
        frames = []
        for light, rate in ((True, r.photon_rate[k].astype(np.float32)), (False, zero)):
            data = [sensor.expose(rate, t[k], gain_db=0.0, bits=12, roi=roi,
                                  frame_index=(4 * k + 2 * (not light)) * s.frames + j)
                    for j in range(s.frames)]
            avg = data[0] if s.frames == 1 else np.mean(data, axis=0).astype(np.float32)
            frames.append(FrameData(avg, float(t[k]), light, _time.time(), 0.0))
        store.append(PointRecord(q.index, q.label, _time.time(), _time.time(),
                                 tuple(v for _, v in q.targets), q.angles.as_tuple(),
                                 float(t[k]), math.nan, math.nan, frames=frames))
    store.close("finished")
    return path


def write_flat_run(setup: ScanSetup, seed: int, path: Path, *, n_frames: int = 8,
                   electrons: float = 9000.0) -> Path:
    """A ``flat_field`` run of the same sensor (``seed``: same PRNU): a uniform photon rate
    filling ``electrons`` per pixel, ``n_frames`` flat points each with its dark frame."""
    import time as _time

    from instrument.run.storage import FrameData, PointRecord, RunHeader, RunStore

    p = setup.sensor_params()
    sensor = Sensor(p, seed=seed)
    t_us = 10_000.0
    rate = np.full((p.height, p.width), electrons / (p.quantum_efficiency * t_us * 1e-6),
                   dtype=np.float32)
    roi = (0, 0, p.width, p.height)
    nan4 = [math.nan] * 4
    header = RunHeader(
        run_id=path.stem, plan_kind="flat_field", plan_name="flat", plan_text="",
        profile_text="", bench_name="sim", sample_name="", sample_description="",
        axes=("camera_z",), planned_targets=[[math.nan] for _ in range(n_frames)],
        planned_angles=[nan4] * n_frames, planned_label=["flat"] * n_frames,
        planned_light=[True] * n_frames, planned_exposure_us=[t_us] * n_frames,
        acquisition_policy="{}", retry_policies="{}", identities={}, device_kinds={},
        geometry={}, calibration={}, software_version="test", created=_time.time())
    store = RunStore.create(path, header, fsync=False, min_free_bytes=0)
    for k in range(n_frames):
        frames = [FrameData(sensor.expose(r, t_us, gain_db=0.0, bits=12, roi=roi,
                                          frame_index=10**6 + 2 * k + j), t_us, j == 0,
                            _time.time(), 0.0)
                  for j, r in enumerate((rate, np.zeros_like(rate)))]
        store.append(PointRecord(k, "flat", _time.time(), _time.time(), (math.nan,),
                                 frames=frames))
    store.close("finished")
    return path


#: The laser's wavelength on the simulated bench (nm).
LASER_NM = 633.0


def speckle_optics(setup: ScanSetup) -> SpeckleOptics:
    """The simulated camera's speckle grain for this setup (f/D: its pixels subtend p/f,
    :meth:`hw_mocks.sim.camera.SimulatedCamera.speckle_optics`)."""
    return SpeckleOptics(LASER_NM, setup.focal_length_mm / setup.aperture_mm,
                         setup.sensor_params().pixel_pitch_um)


def spun_patterns(r: Rendered, spin_deg_s: float) -> np.ndarray:
    """N per point: the independent speckle patterns each point's exposure
    (:func:`exposures_us`) averages while the sample spins at ``spin_deg_s``, by the
    simulated camera's model (:func:`hw_mocks.sim.speckle.decorrelation_angle_deg`)."""
    s = r.setup
    out = np.ones(len(r.angles_rad))
    for k, ((ti, pi_, tr, pr), t_us) in enumerate(zip(r.angles_rad, exposures_us(r),
                                                       strict=True)):
        q = math.hypot(math.sin(ti) * math.cos(pi_) + math.sin(tr) * math.cos(pr),
                       math.sin(ti) * math.sin(pi_) + math.sin(tr) * math.sin(pr))
        step = decorrelation_angle_deg(LASER_NM, s.beam_radius_mm, math.cos(ti), q,
                                       0.5 * s.aperture_mm / s.distance_mm)
        out[k] = max(1.0, spin_deg_s * t_us * 1e-6 / step)
    return out


def speckled(r: Rendered, seed: int, *, spin_deg_s: float = 0.0) -> Rendered:
    """Every point's image under a laser: one frozen pattern per geometry for this seed
    (a static sample), or the average of the N patterns a spinning sample sweeps in the
    point's exposure (:func:`spun_patterns`), as the simulated camera draws them."""
    optics = speckle_optics(r.setup)
    n = spun_patterns(r, spin_deg_s)
    rates = []
    for rate, angles, n_k in zip(r.photon_rate, r.angles_rad, n, strict=True):
        seeds = [speckle_seed(seed, angles, j)
                 for j in range(min(math.floor(n_k), EXACT_PATTERNS))]
        rates.append(speckle_image(rate, optics, seeds, patterns=n_k))
    return replace(r, photon_rate=np.array(rates))
