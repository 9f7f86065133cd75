"""PEM polarimetry with a ``[spectral]`` axis on ``sim-polarimetric-pem-spectral``: the plan
expands every geometry over the filter wheel's wavelengths, the engine turns the wheel and
leaves the modulator's drive alone, and the fit reduces each wavelength with the amplitude
the drive gives there.

Physics checked: a PEM controller drives the crystal to a peak retardation in nanometres
(its wavelength setting λ₀ times the amplitude in waves); at the light's wavelength λ the
amplitude is A(λ) = 2π · waves · λ₀ / λ radians, so at a fixed drive it scales as 1/λ. The
world modulates the generator with the head's true nm per drive over the filtered light's
centre wavelength (``hw_mocks.sim.polarisation``), independently of the reduction's
``A(λ₀) · λ₀ / λ`` (``instrument.pipelines.polarimetry.pem_readings``).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from analysis.polarimetry.drr import reduce
from analysis.polarimetry.pem import pem_design
from instrument.bench.profile import load_profile
from instrument.cli import main
from instrument.pipelines.polarimetry.pipeline import fit_polarimetric_run
from instrument.plans import build_plan
from instrument.plans.planfile import PlanError, parse_plan
from tests.instrument.pipelines.polarimetry.closed_loop import pulls, run_with_truth
from tests.instrument.run.test_pem_bench import with_reference

BENCH = "sim-polarimetric-pem-spectral"
#: The modulator's wavelength setting and the plan's amplitude (waves at it).
PEM_NM, WAVES = 633.0, 0.3828

PLAN = """
[plan]
kind = "brdf_in_plane"
name = "polariser, two wavelengths"
order = "raster"
[sample]
name = "polariser"
[scan]
theta_i = [10.0]
theta_r = [10.0]
[acquisition]
detectors = ["lockin"]
[spectral]
filters = [1, 2]
[polarimetry]
mode = "pem"
amplitude_waves = 0.3828
"""


def amplitude_at(wavelength_nm: float) -> float:
    """The modulator's peak retardation (rad) at ``wavelength_nm`` for the plan's drive."""
    return 2.0 * math.pi * WAVES * PEM_NM / wavelength_nm


def spectral_reference_bench(folder: Path) -> Path:
    """The spectral PEM bench with a linear polariser at 30° straight through (the world's
    detector arm at 180°), mounts 10× faster, the lock-in's waits on its emulated clock,
    and 1 µW through each filter (the 1f and 2f within the lock-in's 1 V range)."""
    text = load_profile(BENCH).source_text.replace("speed=20", "speed=200")
    text = text.replace("power_w = 3e-2", "power_w = 3e-5")
    text = text.replace("clock=host&seed=5", "clock=host&sleep=0&seed=5")
    text = text.replace("[simulation.source]", "[simulation.roles]\ndetector_theta = 180.0"
                        "\n\n[simulation.source]")
    path = folder / "bench-spectral-polariser.toml"
    path.write_text(with_reference(text, "polariser"), encoding="utf-8")
    return path


def test_a_spectral_pem_plan_takes_every_setting_at_every_filter():
    plan = build_plan(parse_plan(PLAN), load_profile(BENCH))
    lit = [p for p in plan.points if p.light]
    metas = [dict(p.meta) for p in lit]
    assert [m["filter"] for m in metas] == [1] * 8 + [2] * 8
    assert [m["pem_setting"] for m in metas] == [0, 1, 2, 3, 7, 6, 5, 4] * 2
    # one drive for both filters: the engine sets the modulator once
    assert {m["pem_waves"] for m in metas} == {WAVES}


def test_the_planner_judges_each_wavelength_at_its_own_amplitude(capsys, tmp_path):
    path = tmp_path / "plan.toml"
    path.write_text(PLAN, encoding="utf-8")
    assert main(["plan", str(path), "--bench", BENCH, "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    # 2π · 0.3828 · 633/550 and 633/650; the zero-order quarter wave's 90° · 633/λ
    assert f"κ = 7.32 at 550 nm (PEM amplitude {amplitude_at(550.0):.3f} rad, analyser " \
           "retardance 103.58°)" in out
    assert f"κ = 10.1 at 650 nm (PEM amplitude {amplitude_at(650.0):.3f} rad, analyser " \
           "retardance 87.65°)" in out
    assert f"{amplitude_at(550.0):.3f}" == "2.768" and f"{amplitude_at(650.0):.3f}" == "2.342"


@pytest.fixture(scope="module")
def spectral_run(tmp_path_factory):  # type: ignore[no-untyped-def]
    """A polariser at 30° straight through, eight settings at 550 and 650 nm."""
    folder = tmp_path_factory.mktemp("pem-spectral")
    path, truths = run_with_truth(folder, spectral_reference_bench(folder), PLAN, steps=8,
                                  world_name=BENCH, frame_deg=0.0, straight_through=True)
    (truth,) = truths.values()  # an ideal polariser: the same matrix at every wavelength
    return path, truth, fit_polarimetric_run(path, report=False, write=False)


def test_each_wavelength_is_reduced_at_the_modulators_amplitude_there(spectral_run):
    _, _, fit = spectral_run
    groups = sorted((p.group for p in fit.points), key=lambda g: g.wavelength_nm)
    assert [g.wavelength_nm for g in groups] == [550.0, 650.0]
    for g in groups:
        assert g.pem is not None
        # 1/λ at a fixed drive: 2.768 rad at 550 nm, 2.342 rad at 650 nm (that the world
        # modulates with these is what the closed loop below shows: the elements agree
        # with its truth within σ, and with the 633 nm amplitude they would not)
        assert g.pem.amplitude_rad == pytest.approx(amplitude_at(g.wavelength_nm), rel=1e-4)


def test_both_wavelengths_recover_the_polariser_within_their_sigma(spectral_run):
    """15 normalised elements per wavelength of one seed, each within 3σ (all fifteen at
    2σ would hold about half the time with σ right; at 3σ 96 %), and every group's 15 pulls
    together consistent with σ: χ² below its 0.999 quantile for 15 dof (37.7)."""
    _, truth, fit = spectral_run
    for point in fit.points:
        assert point.brdf.normalised_valid
        pull = pulls(point, truth)
        assert np.all(np.abs(pull) < 3.0), (point.group.label(), np.round(pull, 2))
        assert float(np.sum(pull**2)) < 37.7, (point.group.label(), np.round(pull, 2))


def test_the_amplitude_at_the_pem_setting_would_bias_the_other_wavelengths(spectral_run):
    """The 1/λ scaling is what makes the reduction right: the 550 nm group reduced with the
    amplitude of 633 nm (2.405 rad, the drive's nominal) is many σ off the truth."""
    _, truth, fit = spectral_run
    point = next(p for p in fit.points if p.group.wavelength_nm == 550.0)
    g = point.group
    assert g.pem is not None
    w = pem_design(g.pem.settings, amplitude_rad=amplitude_at(PEM_NM),
                   analyser_retardance_rad=math.radians(103.58))
    wrong = reduce(g.pem.readings.ravel(), g.pem.sigmas.ravel(), w)
    m = np.asarray(wrong.m)
    s = np.asarray(point.brdf.sigma_normalised)
    off = ((m / m[0, 0] - truth) / np.where(s > 0, s, 1.0)).ravel()[1:]
    assert np.max(np.abs(off)) > 10.0, np.round(off, 1)


@pytest.mark.parametrize(("bench", "change", "field"), [
    # the monochromatic PEM bench has no filter wheel
    ("sim-polarimetric-pem", ("", ""), "spectral"),
    # a slot the wheel does not hold
    (BENCH, ("filters = [1, 2]", "filters = [1, 4]"), "spectral.filters"),
    # PEM mode reads the lock-in only, whatever the wavelength axis
    (BENCH, ('detectors = ["lockin"]', 'detectors = ["power_meter"]'),
     "acquisition.detectors"),
    (BENCH, ('detectors = ["lockin"]', 'detectors = ["lockin"]\ndark = "per_point"'),
     "acquisition.dark"),
])
def test_a_spectral_pem_plan_the_bench_cannot_run_is_refused_by_field(bench, change, field):
    with pytest.raises(PlanError) as err:
        build_plan(parse_plan(PLAN.replace(*change)), load_profile(bench))
    assert field in {e.path for e in err.value.errors}, str(err.value)


@pytest.mark.slow  # the glass's pBRDF per world state at two wavelengths: about a minute;
# its twin in the default run is test_both_wavelengths_recover_the_polariser_within_their_sigma
def test_the_glass_at_two_wavelengths_through_run_and_fit(tmp_path):
    """Reflection off the bench's glass at θi = θr = 50°, at 550 and 650 nm (1 mW through
    each filter). The simulated glass has one index at every wavelength, so the world's
    truth is the same matrix at both; the instrument matrix is not (A and the analyser's
    retardance follow λ). Per wavelength: no element beyond 4σ, and the 15 pulls' χ² below
    its 0.999 quantile (37.7): one seed at one in a thousand per wavelength (ADR 0108)."""
    text = load_profile(BENCH).source_text.replace("speed=20", "speed=200")
    text = text.replace("clock=host&seed=5", "clock=host&sleep=0&seed=5")
    bench = tmp_path / "bench-spectral-glass.toml"
    bench.write_text(text, encoding="utf-8")
    glass = PLAN.replace("theta_i = [10.0]\ntheta_r = [10.0]", "theta_i = [50.0]\n"
                         "theta_r = [50.0]").replace('name = "polariser"', 'name = "glass"')
    path, truths = run_with_truth(tmp_path, bench, glass, steps=8, world_name=BENCH,
                                  frame_deg=0.0, straight_through=False)
    (truth,) = truths.values()
    done = fit_polarimetric_run(path, report=False, write=False)
    assert sorted(p.group.wavelength_nm for p in done.points) == [550.0, 650.0]
    for p in done.points:
        pull = pulls(p, truth)
        assert np.all(np.abs(pull) < 4.0), (p.group.label(), np.round(pull, 2))
        assert float(np.sum(pull**2)) < 37.7, (p.group.label(), np.round(pull, 2))
