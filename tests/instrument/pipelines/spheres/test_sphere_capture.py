"""Sphere captures end to end: the sphere scene on the virtual bench, the
``sphere_capture`` plan, the engine's HDR acquisition and the SH analysis of the run file.

* Scene physics, checked independently of the renderer's quadrature: a Lambertian sphere
  under one small source follows Lambert's law E = L·Ω·(n·s)⁺ at every pixel, and turning
  the ``source_theta`` arm turns the lighting about lab ŷ in the stated sense.
* Plans: objects × lightings expand to one point per pair, invalid plans are refused field
  by field.
* End to end: ``scatterlab run examples/sphere_capture.toml --bench sim-spheres`` (APT and
  SMC100 firmware emulators under the real drivers, simulated camera with its EMVA 1288
  sensor, auto-exposure HDR brackets, a dark per bracket), then ``scatterlab spheres``:
  the fourth image rendered from the other three is within 6.5 % (L1) of the measured one
  (Mahajan et al. 2006 report 9.5 % and 6.5 % on real data), the untampered capture
  passes the calibrated consistency check and a spliced one does not.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hw_mocks.sim.sphere_bench import (
    SphereBenchScene,
    SphereObject,
    environment_from_config,
    intersect_sphere,
)
from hw_mocks.sim.sphere_scene import (
    EnvironmentMap,
    Lambertian,
    Phong,
    SharpSource,
    random_environment,
    render_spheres,
    shade,
)
from hw_mocks.sim.world import VirtualBench
from instrument.bench.profile import load_profile
from instrument.cli import main
from instrument.pipelines.spheres.analyse import (
    CONSISTENCY_LIMIT,
    SIM_SPHERES_THRESHOLD_SCALE,
    analyse_capture,
)
from instrument.pipelines.spheres.capture import read_capture
from instrument.pipelines.spheres.pipeline import analyse_run
from instrument.pipelines.spheres.results import read_sphere_results, summary
from instrument.plans import PlanError, build_plan, parse_plan
from instrument.run.paths import results_path
from instrument.run.runfile import read_run
from tests.shared_files import made_once

ROOT = Path(__file__).resolve().parents[4]
EXAMPLE = ROOT / "examples" / "sphere_capture.toml"
PROFILE = ROOT / "instrument" / "bench" / "profiles" / "sim-spheres.toml"


# ------------------------------------------------------------------ scene physics
def _lambert_scene(source_dir: tuple[float, float, float], radius_rad: float,
                   radiance: float) -> SphereBenchScene:
    env = EnvironmentMap(zenith=0.0, horizon=0.0, ground=0.0,
                         sharp_sources=(SharpSource(source_dir, radius_rad, radiance),))
    return SphereBenchScene((SphereObject("white", 0.0, Lambertian(0.8)),), env,
                            sphere_radius_mm=10.0, n_theta=32)


def _view(scene: SphereBenchScene, source_theta: float, *, on: bool = True,
          sample_phi: float = 0.0, n: int = 41):
    """Radiance seen from 1 m on +z through an n × n grid of rays, and their normals."""
    bench = VirtualBench("t", roles={"source_theta": source_theta, "sample_phi": sample_phi},
                         scene=scene, arm_length_mm=1000.0)
    bench.update_source(on=on)
    state = bench.snapshot()
    origin = np.array([0.0, 0.0, 1000.0])
    s = np.linspace(-0.0105, 0.0105, n)
    dirs = np.stack(np.broadcast_arrays(s[None, :], -s[:, None], -1.0), axis=-1)
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    hit, normals = intersect_sphere(origin, dirs, scene.sphere_radius_mm)
    return scene.radiance(origin, dirs, state), hit, normals


@pytest.mark.parametrize("source_theta", [0.0, -90.0, 35.0])
def test_lambertian_sphere_follows_lamberts_law_under_the_turned_lighting(source_theta):
    """Lambertian sphere, one 1° source along +x of the environment: B = ρ/π · L Ω (n·s)⁺,
    s = R_y(source_theta) x̂ = (cos θ, 0, −sin θ) in the lab (right-handed about ŷ)."""
    a, lum = math.radians(1.0), 100.0
    scene = _lambert_scene((1.0, 0.0, 0.0), a, lum)
    rad, hit, normals = _view(scene, source_theta)
    t = math.radians(source_theta)
    s_lab = np.array([math.cos(t), 0.0, -math.sin(t)])
    omega = 2 * math.pi * (1 - math.cos(a))
    expected = 0.8 / math.pi * lum * omega * np.clip(normals @ s_lab, 0.0, None)
    assert hit.sum() > 900
    # away from the terminator (where the disc is partly below the horizon) to 0.5 %
    core = hit & (np.abs(normals @ s_lab) > 0.05)
    np.testing.assert_allclose(rad[core], expected[core], rtol=5e-3,
                               atol=1e-3 * expected.max())
    assert np.all(rad[~hit] == 0.0)


def test_the_turret_selects_the_sphere_and_the_source_switches_the_lighting():
    env = environment_from_config({"seed": 4})
    scene = SphereBenchScene((SphereObject("a", 0.0, Phong(ks=1.0, s=80.0)),
                              SphereObject("b", 60.0, Lambertian(0.5))), env,
                             sphere_radius_mm=10.0, n_theta=48)
    a, hit, _ = _view(scene, 0.0, sample_phi=0.0, n=15)
    b, _, _ = _view(scene, 0.0, sample_phi=60.2, n=15)
    between, _, _ = _view(scene, 0.0, sample_phi=30.0, n=15)
    dark, _, _ = _view(scene, 0.0, on=False, n=15)
    assert np.all(a[hit] > 0) and np.all(b[hit] > 0)
    assert np.max(np.abs(a[hit] - b[hit]) / b[hit]) > 0.5  # different objects
    assert not between.any() and not dark.any()


def test_shade_reproduces_the_orthographic_renderer():
    """shade() (per-point normals and views) against render_spheres (distant viewer)."""
    env = random_environment(np.random.default_rng(2))
    brdf = Phong(kd=0.3, ks=0.6, s=40.0)
    rend = render_spheres([env], brdf, size=24, n_theta=64)
    yy, xx = np.mgrid[0:24, 0:24].astype(float)
    u = (xx - rend.center[0]) / rend.radius
    t = -(yy - rend.center[1]) / rend.radius
    on = u * u + t * t < 1
    n = np.stack([u[on], t[on], np.sqrt(1 - u[on] ** 2 - t[on] ** 2)], axis=-1)
    v = np.broadcast_to([0.0, 0.0, 1.0], n.shape)
    np.testing.assert_allclose(shade(env, brdf, n, v, n_theta=64), rend.radiance[0][on],
                               rtol=1e-12)


@pytest.mark.filterwarnings("error::RuntimeWarning")  # e.g. overflow at normal incidence
@pytest.mark.parametrize("brdf", [
    {"model": "lambertian", "albedo": 0.5},
    {"model": "phong", "kd": 0.2, "ks": 0.5, "s": 20.0},
    {"model": "microfacet", "kd": 0.5, "ks": 0.5, "alpha": 0.2},
    {"model": "mirror", "reflectance": 0.9},
])
def test_every_brdf_model_renders_a_lit_sphere(brdf):
    """Lambertian, Phong, Lambertian + microfacet and mirror spheres: every hit pixel is lit
    by the sky (positive), bounded by the brightest the environment can give."""
    scene = SphereBenchScene.from_config({
        "kind": "spheres", "environment": {"seed": 3}, "n_theta": 32,
        "sphere_radius_mm": 10.0, "spheres": [{"station_deg": 0.0, "brdf": brdf}]})
    rad, hit, _ = _view(scene, 0.0, n=11)
    assert np.all(rad[hit] > 0) and np.all(rad[~hit] == 0)
    env = scene.environment
    peak = max([env.zenith, env.horizon] + [s.radiance for s in env.sharp_sources]
               + [a.radiance + env.zenith for a in env.area_lights])
    assert rad.max() < peak


@pytest.mark.parametrize("bad, msg", [
    ({"selector": "source_theta"}, "different axes"),
    ({"spheres": [{"station_deg": 0.0, "brdf": {"model": "phong", "s": 10}},
                  {"station_deg": 0.5, "brdf": {"model": "lambertian"}}]}, "further apart"),
    ({"spheres": [{"station_deg": 0.0, "brdf": {"model": "velvet"}}]}, "unknown brdf"),
    ({"colour": "red"}, "unknown sphere scene keys"),
    ({"selector": "camera_z"}, "not a rotary role"),
])
def test_scene_configuration_is_validated(bad, msg):
    cfg = {"kind": "spheres", "environment": {"seed": 1},
           "spheres": [{"station_deg": 0.0, "brdf": {"model": "phong", "s": 50}}]}
    cfg.update(bad)
    with pytest.raises(ValueError, match=msg):
        SphereBenchScene.from_config(cfg)


# ------------------------------------------------------------------ plans
def test_sphere_capture_plan_expands_objects_times_lightings():
    profile = load_profile(PROFILE)
    plan = build_plan(parse_plan(EXAMPLE.read_text()), profile)
    assert plan.axes == ("source_theta", "sample_phi")
    got = [(p.target_dict()["source_theta"], p.target_dict()["sample_phi"], p.label)
           for p in plan.points]
    assert got == [(0.0, 0.0, "sphere"), (0.0, 60.0, "sphere"), (90.0, 0.0, "sphere"),
                   (90.0, 60.0, "sphere")]


@pytest.mark.parametrize("scan, field", [
    ('objects = [{ name = "a", station_deg = 0.0 }]\nlighting_deg = [0.0, 0.0]',
     "scan.lighting_deg"),
    ('objects = [{ name = "a", station_deg = 0.0 }, { name = "a", station_deg = 5.0 }]\n'
     'lighting_deg = [0.0]', "scan.objects"),
    ('objects = [{ name = "a", station_deg = 0.0, known_brdf = { model = "velvet" } }]\n'
     'lighting_deg = [0.0]', "scan.objects[0].known_brdf.model"),
    ('objects = [{ name = "a", station_deg = 0.0 }]\nlighting_deg = [0.0]\n'
     'selector = "source_theta"', "scan.selector"),
    ('lighting_deg = [0.0]', "scan.objects"),
    ('objects = [{ name = "a" }]\nlighting_deg = [0.0]', "scan.objects[0].station_deg"),
])
def test_invalid_sphere_capture_plans_name_the_field(scan, field):
    text = f'[plan]\nkind = "sphere_capture"\n[sample]\nname = "s"\n[scan]\n{scan}\n'
    with pytest.raises(PlanError) as info:
        parse_plan(text)
    assert field in [e.path for e in info.value.errors], info.value.errors


_values = st.one_of(st.floats(-400, 400), st.just(math.nan), st.integers(-400, 400),
                    st.text(max_size=3), st.booleans())


@settings(max_examples=80, deadline=None)
@given(
    stations=st.lists(_values, min_size=0, max_size=4),
    names=st.lists(st.text(min_size=0, max_size=4), min_size=0, max_size=4),
    lights=st.lists(_values, min_size=0, max_size=3),
    selector=st.sampled_from(["sample_phi", "source_theta", "camera_z", "sample_tilt"]),
)
def test_fuzzed_sphere_capture_plans_parse_or_fail_with_field_errors(stations, names, lights,
                                                                     selector):
    """Any [scan] either validates and expands to objects × lightings points, or is refused
    with a PlanError naming fields: never another exception."""
    objs = [{"name": n, "station_deg": s} for n, s in zip(names, stations, strict=False)]

    def toml(x):
        if isinstance(x, str):
            return '"' + x.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(x, bool):
            return "true" if x else "false"
        if isinstance(x, float) and math.isnan(x):
            return "nan"
        return repr(x)

    obj_txt = ", ".join(f"{{ name = {toml(o['name'])}, station_deg = "
                        f"{toml(o['station_deg'])} }}" for o in objs)
    text = (f'[plan]\nkind = "sphere_capture"\n[sample]\nname = "s"\n[scan]\n'
            f'selector = "{selector}"\nobjects = [{obj_txt}]\n'
            f'lighting_deg = [{", ".join(toml(x) for x in lights)}]\n')
    try:
        spec = parse_plan(text)
    except PlanError as err:
        assert err.errors and all(e.path for e in err.errors)
        return
    assert len(spec.scan["objects"]) == len(objs) >= 1
    assert selector in ("sample_phi", "sample_tilt")
    profile = load_profile(PROFILE)
    try:
        plan = build_plan(spec, profile)
    except (PlanError, ValueError):  # e.g. a station outside the turret's soft limits
        return
    assert len(plan.points) == len(objs) * len(lights)


# ------------------------------------------------------------------ end to end
@pytest.fixture(scope="module")
def capture_run(tmp_path_factory) -> Path:
    def capture(out: Path) -> Path:
        rc = main(["run", str(EXAMPLE), "--bench", str(PROFILE), "--out", str(out),
                   "--no-fsync", "--quiet"])
        assert rc == 0
        (path,) = out.glob("*.h5")
        return path
    # the seeded capture (~10 s of CPU) once per session, not once per xdist worker
    return made_once(tmp_path_factory, "spheres", capture)


def test_capture_holds_hdr_brackets_with_darks(capture_run):
    with h5py.File(capture_run, "r") as f:
        light = f["entry/data/frame_light"][()].astype(bool)
        exposures = f["entry/data/frame_exposure_us"][()]
        n_frames = f["entry/points/n_frames"][()]
    assert n_frames.size == 4
    assert light.sum() == (~light).sum()  # one dark per bracket
    assert np.unique(exposures[light]).size >= 2  # HDR: several exposures per point


def test_merged_hdr_radiance_is_the_scene_radiance(capture_run):
    """Camera equation, sensor, HDR merge and calibration chain: the merged image of the
    glossy sphere at source_theta = 0 against the scene's radiance along each pixel's ray
    (pinhole 1 m on +z, f = 100 mm, 42 µm pixels, image right = +x, down = −y)."""
    capture = read_capture(capture_run)
    scene = SphereBenchScene.from_config(tomllib.loads(PROFILE.read_text())
                                         ["simulation"]["scene"])
    bench = VirtualBench("truth", roles={"source_theta": 0.0, "sample_phi": 0.0},
                         scene=scene, arm_length_mm=1000.0)
    bench.update_source(on=True, power_w=1e-3)
    i, j = np.mgrid[0:72, 0:72].astype(float)
    u, v = (j - 35.5) * 0.042 / 100.0, (i - 35.5) * 0.042 / 100.0
    d = np.stack([u, -v, -np.ones_like(u)], axis=-1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    truth = scene.radiance(np.array([0.0, 0.0, 1000.0]), d, bench.snapshot())
    lit = truth > 0.05 * truth.max()
    ratio = capture.radiance[0, 0][lit] / truth[lit]
    assert lit.sum() > 2000
    # PRNU (1 %) and shot noise scatter single pixels; the scale must be exact
    assert abs(np.median(ratio) - 1.0) < 0.005, np.median(ratio)
    assert np.percentile(np.abs(ratio - 1.0), 90) < 0.04
    # Where the scene sends nothing, the merged radiance is noise: a dark-subtracted
    # bracket (σ = √2 × the model's per-frame σ, which `variance` holds at zero signal)
    # that passed the merge's 5 σ_read threshold, or none. 6 σ of that over the ~2300
    # background pixels is exceeded with probability ~10⁻⁵. (A bound at 10⁻³ of the peak
    # is not one: a 3 DN fluctuation in the 39 µs bracket alone reaches 3.6·10⁻³.)
    background = truth == 0
    sigma = np.sqrt(2.0 * capture.variance[0, 0][background])
    assert np.all(np.abs(capture.radiance[0, 0][background]) <= 6.0 * sigma)


@pytest.fixture(scope="module")
def analysed(capture_run, tmp_path_factory):
    """The capture analysed once (results file written next to the run, figure drawn) for
    the tests that read its results."""
    fig = tmp_path_factory.mktemp("spheres-figure") / "relight.png"
    raw = capture_run.read_bytes()
    capture, res = analyse_run(capture_run, figure=fig)
    assert capture_run.read_bytes() == raw  # the raw run file stays as acquired
    return capture, res, fig


def test_relighting_the_fourth_image_and_consistency(capture_run, analysed):
    capture, res, fig = analysed
    assert capture.objects == ("glossy", "satin")
    assert capture.lighting_deg == (0.0, 90.0)
    assert capture.units == "W m-2 sr-1"
    # geometry found from the image: 12.7 mm at 1 m through 100 mm / 42 µm → 30.2 px
    assert res.radius == pytest.approx(1e5 * math.tan(math.asin(12.7 / 1000)) / 42.0, abs=0.3)
    assert res.center == pytest.approx((35.5, 35.5), abs=0.2)
    assert res.relight_l1 <= 0.065, res.relight_l1
    assert not res.consistency.inconsistent
    assert res.consistency.threshold > 0 and np.all(res.consistency.noise_error > 0)
    # the glossy sphere's BRDF is declared known: lighting estimated, M10/M19 on the other
    assert res.lighting_object == "glossy" and res.lighting.shape == (2, 21 * 21)
    assert {"M21", "M25", "M10 0,1", "M19 satin"} <= set(res.identities)
    assert fig.stat().st_size > 10_000
    assert read_sphere_results(capture_run) is None  # nothing written into the run file
    results = results_path(capture_run, "spheres")
    stored = read_sphere_results(results)
    assert stored["relight"]["l1_error"] == pytest.approx(res.relight_l1)
    assert stored["consistency"]["inconsistent"] is False
    assert stored["consistency"]["limit"] == CONSISTENCY_LIMIT
    with h5py.File(results, "r") as f:
        assert f["entry"].attrs["run_id"] == read_run(capture_run).run_id
        assert f["entry/analysis/images/radiance"].shape == (2, 2, 72, 72)
        assert f["entry/analysis/sh/coeffs"].shape == (2, 2, 441)


def _turned(env: EnvironmentMap, theta_deg: float) -> EnvironmentMap:
    """The environment turned by θ about lab ŷ (right-handed): every direction d → R_y d."""
    c, s = math.cos(math.radians(theta_deg)), math.sin(math.radians(theta_deg))

    def rot(d):
        x, y, z = d
        return (c * x + s * z, y, -s * x + c * z)

    return dataclasses.replace(
        env, up=rot(env.up),
        area_lights=tuple(dataclasses.replace(a, direction=rot(a.direction))
                          for a in env.area_lights),
        sharp_sources=tuple(dataclasses.replace(x, direction=rot(x.direction))
                            for x in env.sharp_sources))


def test_lighting_estimates_match_the_scene_turned_by_the_source_arm(analysed):
    """The Wiener lighting from the glossy sphere against the true environment coefficients
    (bands l ≤ 8, which the s = 80 lobe passes well), for each source_theta: the second
    lighting is the environment turned by +90° about lab ŷ, not the first one again."""
    from hw_mocks.sim.sphere_scene import environment_coefficients

    _capture, res, _fig = analysed
    prof = tomllib.loads(PROFILE.read_text())
    env = environment_from_config(prof["simulation"]["scene"]["environment"])
    # radiance_scale = 1 W m⁻² sr⁻¹ per environment unit at the reference power
    truths = environment_coefficients([env, _turned(env, 90.0)], 8, n_theta=128)
    for k, truth in enumerate(truths):
        est = res.lighting[k, :81]
        rel = np.linalg.norm(est - truth) / np.linalg.norm(truth)
        assert rel < 0.05, (k, rel)
    wrong = np.linalg.norm(res.lighting[1, :81] - truths[0]) / np.linalg.norm(truths[0])
    assert wrong > 0.3


def test_a_spliced_capture_is_flagged_at_the_benchs_calibrated_threshold(capture_run,
                                                                         analysed):
    capture = read_capture(capture_run)
    rad = capture.radiance.copy()
    rad[1, 1, :36] = rad[0, 1, :36]  # top half of the last image from the other lighting
    q = SIM_SPHERES_THRESHOLD_SCALE
    assert q > 1  # the noise-only bootstrap threshold is too low for this bench
    res = analyse_capture(dataclasses.replace(capture, radiance=rad),
                                    threshold_scale=q)
    assert res.consistency.inconsistent and res.threshold_scale == q
    assert res.relight_l1 > 0.1
    stored = summary(capture, res)["consistency"]
    assert stored["threshold_scale"] == q and stored["limit"] is None
    # the untampered capture stays consistent at the calibrated threshold
    _cap, clean, _fig = analysed
    assert clean.consistency.statistic <= q * clean.consistency.threshold


def test_cli_spheres_reports(capture_run, tmp_path, capsys):
    rc = main(["spheres", str(capture_run), "--out", str(tmp_path), "--no-write"])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "L1 error" in out and "consistent" in out
    # the decision's known limit (false alarms above α on the bench) is stated with it
    assert CONSISTENCY_LIMIT in out and "2 of 16" in out
    # the identities are named in words with the paper's equation, not by private tags
    assert "two objects × two lightings" in out and "[eq. 21]" in out
    assert "Mahajan, Ramamoorthi & Curless 2006" in out
    assert not any(tag in out for tag in ("M10", "M16", "M19", "M21", "M25", "α"))
    assert (tmp_path / "relighting.png").stat().st_size > 10_000
    assert not (tmp_path / "results.h5").exists()
    assert main(["spheres", str(tmp_path / "missing.h5")]) == 2


@pytest.mark.parametrize(("args", "flag"), [
    (["--lmax", "0"], "--lmax must"),
    (["--lmax-check", "40"], "--lmax-check"),
    (["--max-view-angle", "95"], "--max-view-angle"),
    (["--check-view-angle", "88"], "--check-view-angle"),
    (["--false-alarm", "2"], "--false-alarm"),
    (["--threshold-scale", "0"], "--threshold-scale"),
])
def test_cli_spheres_names_a_bad_option(tmp_path, capsys, args, flag):
    assert main(["spheres", str(tmp_path / "never-read.h5"), *args]) == 2
    out = capsys.readouterr().out
    assert out.startswith("error: ") and flag in out, out


def test_cli_spheres_names_an_unreadable_file(tmp_path, capsys):
    bad = tmp_path / "not-a-run.h5"
    bad.write_text("not hdf5")
    assert main(["spheres", str(bad), "--no-write"]) == 2
    out = capsys.readouterr().out
    assert out == f"error: {bad} is not a scatterlab run file (not an HDF5 file)\n", out


def test_the_check_at_l_1_is_a_test_and_says_so(capture_run, capsys):
    """At --lmax 1 --lmax-check 1 the check still has power on this bench (a top-half
    splice is flagged, T ≈ 45 against ≈ 14), so the untampered capture's statistic of 0
    (both orders below their consistent median) is a real 'consistent' and is printed as
    one; where no test is possible the verdict says that instead (next test)."""
    rc = main(["spheres", str(capture_run), "--lmax", "1", "--lmax-check", "1",
               "--no-write", "--no-figures"])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "SH orders 0..1" in out and "consistent within the noise" in out
    capture = read_capture(capture_run)
    rad = capture.radiance.copy()
    rad[1, 1, :36] = rad[0, 1, :36]
    res = analyse_capture(dataclasses.replace(capture, radiance=rad), lmax=1, lmax_check=1)
    assert res.consistency.testable and res.consistency.inconsistent


def test_a_check_without_power_is_reported_as_no_test():
    from analysis.sh.consistency import NO_TEST, calibrate, check
    from instrument.cli.spheres import verdict_words

    errors = np.random.default_rng(5).uniform(0.5, 1.0, (60, 2))
    errors[:10] = 1.0  # noise as large as the identity's largest error
    rep = check(np.array([0.7, 0.7]), calibrate(errors, false_alarm=0.05), max_error=1.0)
    words = verdict_words(rep)
    assert words.startswith(NO_TEST.upper()) and "largest possible" in words
    assert "consistent" not in words.lower()
