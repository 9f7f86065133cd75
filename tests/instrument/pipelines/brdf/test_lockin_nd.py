"""The lock-in path divides out the neutral-density filter a point was read through
(ADR 0018), as the camera path does: through the engine on the emulated bench (sim.toml
with the sharp sample, its FW102C wheel of ND filters and an SR830 reading a chopped
photodiode on the detector arm). The camera clips on the peak at its shortest exposure,
the engine reads the point again behind ND1 with every detector, and the reduction
divides the lock-in's readings by ND1's transmission.

The bench hides ND1's true transmission, 0.1043 (4.3 % above the nominal 10^−1): a
nominal T leaves exactly that ratio in the reduced values, inside the 10 % it is given;
a certified T = 0.1043 ± 0.0005 leaves none, and its error is a covariance shared by the
points behind the filter.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from analysis.brdf.reduction import receiver_model
from analysis.brdf.registry import get_model
from instrument.cli import main
from instrument.pipelines.brdf.spectral import (
    SpectralOptions,
    reduce_group,
    single_wavelength_group,
)
from instrument.run.runfile import RunData, read_run
from tests.instrument.pipelines.brdf.test_nd_filters import run_plan, sharp_bench
from tests.shared_files import made_once

pytestmark = pytest.mark.slow  # one run through the engine, about 45 s

LOCKIN = """[devices.lockin]
driver = "sr830"
url = "simsr830://lockin?chopper=137&world=sim&responsivity=0.4&gain=1000000&seed=3"
settings = { reference_source = "external", time_constant_s = 0.03 }

[photodiode]
responsivity_a_per_w = 0.4
u_responsivity_rel = 0.02
transimpedance_v_per_a = 1e6

[geometry]"""

PLAN = """
[plan]
kind = "brdf_in_plane"
name = "the sharp peak on the lock-in"
order = "raster"
[sample]
name = "sharp"
[scan]
skip_beam_points = true
points = [[20, 10], [20, 18], [20, 20], [20, 22]]
[acquisition]
mode = "auto"
exposure_us = 2000
min_exposure_us = 10
max_exposure_us = 200000
dark = "per_point"
detectors = ["camera", "lockin"]
"""

TRUTH = (0.3, 0.5, 0.05)  # lambert.rho, ggx.ks, ggx.alpha of the sharp sample
TRUE_T = 0.1043  # ND1 on the bench (sim.toml [simulation.filter_wheel])


@pytest.fixture(scope="module")
def peak_run(tmp_path_factory) -> Path:
    def scan(tmp: Path) -> Path:
        bench = sharp_bench(tmp)
        bench.write_text(bench.read_text(encoding="utf-8").replace("[geometry]", LOCKIN, 1),
                         encoding="utf-8")
        return run_plan(tmp, PLAN, bench, "peak")
    return made_once(tmp_path_factory, "lockin_nd", scan)  # once per session, not per worker


def _reduced(run: RunData):
    opts = SpectralOptions(detector="lockin", models=("lambert+ggx",))
    red = reduce_group(run, single_wavelength_group(run, opts), opts, detector="lockin")
    pts = red.points
    seen = receiver_model(get_model("lambert+ggx"), pts.receiver, level=3)
    truth = seen.evaluate(TRUTH, pts.theta_i, pts.phi_i, pts.theta_r, pts.phi_r)
    return red, pts.brdf / truth


def test_the_lock_in_reads_the_peak_through_nd1_and_a_nominal_t_is_divided_out(peak_run):
    run = read_run(peak_run)
    rows = run.brdf_rows()
    slots = run.nd_position[rows]
    assert slots[0] == -1 and list(slots[1:]) == [2, 2, 2]  # the peak behind ND1
    red, ratio = _reduced(run)
    # open beam: the instrument-aware truth within the lock-in's noise and quadrature
    assert abs(ratio[0] - 1.0) < 2e-3, ratio
    # behind ND1, divided by the nominal 0.1: too high by exactly 0.1043/0.1, which is
    # inside the 10 % σ the nominal value carries (undivided they would be 10× low)
    np.testing.assert_allclose(ratio[1:], TRUE_T / 0.1, rtol=2e-3)
    u_rel = red.points.u_point[1:] / red.points.brdf[1:]
    assert np.all(u_rel >= 0.1) and np.all(np.abs(ratio[1:] - 1.0) < u_rel)
    assert any("slot 2 (ND1) not calibrated" in w for w in red.warnings)
    assert red.provenance["nd_filters"] == ["slot 2 (ND1): T = 0.1 ± 0.01 (nominal od 1): "
                                            "3 point(s)"]


def test_a_certified_transmission_is_divided_out_with_its_error_shared(peak_run):
    run = read_run(peak_run)
    text = run.profile_text.replace('2 = { od = 1.0, label = "ND1" }',
                                    '2 = { od = 1.0, label = "ND1", transmission = 0.1043, '
                                    'u_transmission = 0.0005 }')
    assert "u_transmission = 0.0005" in text
    red, ratio = _reduced(dataclasses.replace(run, profile_text=text))
    np.testing.assert_allclose(ratio, 1.0, atol=2e-3)
    assert not any("not calibrated" in w for w in red.warnings)
    pts = red.points
    # the filter's error is shared by its three points (on top of the lock-in's
    # range-gain covariance), not put into their independent σ
    behind = np.arange(1, 4)
    f = pts.brdf[behind]
    shared = (0.0005 / 0.1043) ** 2 * np.outer(f, f)
    cov = pts.cov_corr[np.ix_(behind, behind)]
    assert np.all(cov >= shared * 0.999)
    assert np.all(pts.u_stat[behind] / f < 1e-3)


def test_the_cli_fits_a_one_wavelength_lock_in_run(peak_run, capsys):
    capsys.readouterr()
    # four points: a one-parameter model (three parameters on four points leave one degree
    # of freedom, and the lock-in's noise draw depends on when it was read)
    assert main(["fit", str(peak_run), "--detector", "lockin", "--models", "lambert",
                 "--no-write", "--no-cv"]) == 0
    out = capsys.readouterr().out
    assert "1 wavelengths (lockin)" in out and "633 nm" in out, out
