"""A two-pass polarimetric lobe plan over two filters through ``scatterlab run`` and
``scatterlab fit`` (ADR 0106, amendment "a polarimetric lobe over several filters").

The bench is ``sim-polarimetric`` (the dual rotating retarder, its hidden optics held by
the calibration beside the runs) behind an FW102C wheel of 550 and 650 nm band-pass
filters with a broadband source (:func:`spectral_drr_bench`): the shipped DRR bench has no
wheel. The retarders of its hidden train are achromatic (94.5° and 85.5° at every
wavelength), so the one calibration holds at both filters, and the glass has one index
at every wavelength, so one pBRDF describes both.

The first pass runs over both filters; the lobe is fitted at the reference filter (by
default the filter nearest the band's centre: of 550 and 650 nm, the shorter) and the
second pass's geometries, placed from it, are read at both filters with the same
[polarimetry] and [spectral]; the fit of the second run takes both runs' matrices at
both wavelengths and passes the pBRDF's goodness-of-fit gate.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from instrument.pipelines.polarimetry.pipeline import fit_polarimetric_run
from instrument.run.runfile import read_run
from tests.instrument.pipelines.polarimetry.closed_loop import fast_bench
from tests.instrument.pipelines.polarimetry.test_polarimetric_fit import _oracle
from tests.instrument.pipelines.polarimetry.test_polarimetric_lobe_run import (
    PLAN,
    _run_both,
    assert_recovers_the_glass,
)

#: The filters of sim-polarimetric-pem-spectral's wheel.
BANDS = ("{ 1 = { center_nm = 550.0, bandwidth_nm = 10.0 }, "
         "2 = { center_nm = 650.0, bandwidth_nm = 10.0 } }")
#: That wheel, on the DRR bench's world.
WHEEL = f"""
[devices.filter_wheel]
driver = "fw102c"
url = "simfw102c://drr_filter_wheel?world=sim-polarimetric"
options = {{ filters = {BANDS} }}

[geometry]"""

#: A flat source 300 nm wide: 30 mW in all puts 1 mW (the laser's power) through each
#: 10 nm filter, so the calibration's source scale holds at both.
SOURCE = f"""[simulation.filter_wheel]
url = "simfw102c://drr_filter_wheel?world=sim-polarimetric"
filters = {BANDS}

[simulation.source]
power_w = 3e-2
max_power_w = 5e-2
wavelength_nm = 600.0
bandwidth_nm = 300.0"""


def spectral_drr_bench(folder: Path) -> Path:
    """``sim-polarimetric`` (mounts 100× faster) behind a wheel of 550 and 650 nm
    band-pass filters and a broadband source (module docstring)."""
    text = fast_bench(folder).read_text(encoding="utf-8")
    assert "\n[geometry]" in text and "[simulation.source]\npower_w = 1e-3\nwavelength_nm = " \
        "633.0" in text
    text = text.replace("\n[geometry]", WHEEL, 1).replace(
        "[simulation.source]\npower_w = 1e-3\nwavelength_nm = 633.0", SOURCE, 1)
    path = folder / "bench-spectral-drr.toml"
    path.write_text(text, encoding="utf-8")
    return path


def spectral_drr_lobe_setup(folder: Path, points: int = 1) -> tuple[Path, str]:
    """The bench (``folder/runs`` holding the hidden optics as its newest calibration) and
    the plan: θi 50°, θr 30, 44, 50, 56 and 70° (the search of ±6° every 6°) at both
    filters, then ``points`` geometries at both filters. Shared with
    ``benchmarks/bench_polarimetric_spectral_lobe.py``."""
    runs = folder / "runs"
    runs.mkdir()
    cal = _oracle(runs).path
    assert cal is not None
    cal.rename(cal.with_name("polarimeter-hidden-optics.json"))
    text = PLAN.format(theta_r="[30.0, 70.0]", points=points, search=6.0,
                       prior="lambert+ggx",
                       detector="power_meter", dark='dark = "per_point"',
                       polarimetry='mode = "drr"\nsteps = 23')
    return spectral_drr_bench(folder), text + "\n[spectral]\nfilters = [1, 2]\n"


@pytest.mark.slow  # 6 geometries × 2 filters × 23 retarder steps through the engine: 1-3 min
def test_a_drr_lobe_plan_over_two_filters_runs_both_passes_and_fits_each_wavelength(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bench, text = spectral_drr_lobe_setup(tmp_path)
    first, second, printed = _run_both(tmp_path, bench, text, capsys)
    assert "second pass: 1 geometries (46 points) placed by Fisher information" in printed
    assert "the lobe fitted at filter 1 (550 nm; the filter nearest the band's centre, " \
        "600 nm; lobe.reference_filter names another); the second pass reads every " \
        "filter" in printed, printed
    plan1 = tomllib.loads(read_run(first).plan_text)
    plan2 = tomllib.loads(read_run(second).plan_text)
    assert plan2["scan"]["first_pass"] == first.name
    assert plan2["polarimetry"] == plan1["polarimetry"]
    assert plan2["spectral"] == plan1["spectral"] == {"filters": [1, 2]}
    assert read_run(first).n_points == 5 * 2 * 23 and read_run(second).n_points == 2 * 23
    # the joint fit: both runs' geometries at both wavelengths
    done = fit_polarimetric_run(second, report=False, write=False)
    assert done.summary["calibrated"]
    assert any("with the first pass" in n for n in done.summary["notes"])
    by_wl: dict[float, list[float]] = {}
    for p in done.points:
        by_wl.setdefault(round(p.group.wavelength_nm), []).append(p.group.theta_r)
    assert sorted(by_wl) == [550, 650]
    (placed,) = {round(abs(tr), 3) for _, tr in plan2["scan"]["points"]}
    for wl, trs in by_wl.items():
        assert len(trs) == 6, (wl, trs)  # 5 of the first pass and the placed one
        assert any(abs(t - placed) < 0.05 for t in trs), (wl, trs, placed)
    assert_recovers_the_glass(done.summary["pbrdf"])
