"""Two-pass polarimetric lobe plans through ``scatterlab run`` and ``scatterlab fit`` on the
emulated benches (ADR 0106 amendment): the first pass is polarimetric over the coarse
geometries, the second pass is placed from its m00 with a σ model fitted to it and run
with the same polarimetry settings, and the fit of the second run takes both runs'
Mueller matrices and recovers the hidden glass.

PEM (``sim-polarimetric-pem``, no hidden misalignment: the nominal reduction is unbiased)
runs by default; DRR (``sim-polarimetric``, whose hidden optics need the calibration that
holds them, as in ``test_polarimetric_fit.py``) is slow: its default-run twin is the PEM
test below.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from instrument.cli import main
from instrument.pipelines.polarimetry.pipeline import fit_polarimetric_run
from instrument.run.runfile import read_run
from tests.instrument.pipelines.polarimetry.closed_loop import FRAME_DEG, fast_bench
from tests.instrument.pipelines.polarimetry.test_polarimetric_fit import _oracle
from tests.instrument.run.test_pem_run import fast_pem_bench

PLAN = """
[plan]
kind = "brdf_in_plane"
name = "glass lobe"
order = "raster"
[sample]
name = "glass"
[scan]
theta_i = [50.0]
theta_r = {{ start = 30.0, stop = 70.0, step = 20.0 }}
[scan.lobe]
points = 2
step_deg = 1.0
search_half_width_deg = 6.0
search_step_deg = 3.0
prior = "lambert+ggx"
[acquisition]
detectors = ["{detector}"]
{dark}
[polarimetry]
{polarimetry}
"""

#: The hidden glass (the profiles' [simulation.scene.pbrdf]): n, k, rms slope, albedo.
GLASS = (1.5, 0.0, 0.15, 0.3)


def _run_both(folder: Path, bench: Path, text: str, capsys: pytest.CaptureFixture[str]
              ) -> tuple[Path, Path, str]:
    plan = folder / "lobe.toml"
    plan.write_text(text, encoding="utf-8")
    out = folder / "runs"
    assert main(["run", str(plan), "--bench", str(bench), "--out", str(out), "--no-fsync",
                 "--quiet"]) == 0
    printed = capsys.readouterr().out
    runs = sorted(out.glob("*.h5"), key=lambda p: read_run(p).run_id)
    assert len(runs) == 2, printed
    second = next(p for p in runs if "first_pass" in tomllib.loads(
        read_run(p).plan_text)["scan"])
    first = next(p for p in runs if p != second)
    return first, second, printed


def _check(first: Path, second: Path, printed: str, per_geometry: int, frame_deg: float
           ) -> None:
    assert f"second pass: 2 geometries ({2 * per_geometry} points) placed by Fisher " \
        "information" in printed, printed
    plan2 = tomllib.loads(read_run(second).plan_text)
    assert plan2["scan"]["first_pass"] == first.name
    assert plan2["polarimetry"] == tomllib.loads(read_run(first).plan_text)["polarimetry"]
    # the second pass is polarimetric and lies on the lobe, near the mirror direction
    r2 = read_run(second)
    assert r2.n_points == 2 * per_geometry
    done = fit_polarimetric_run(second, report=False, write=False)
    # 30, 44, 47, 50, 53, 56, 70 of the first pass and two of the second
    assert len(done.points) == 9
    assert any("with the first pass" in n for n in done.summary["notes"])
    # on the lobe around the mirror direction (the glass's m00 peaks a few degrees past
    # it, Fresnel rising with the angle), not on the diffuse floor: each second-pass
    # geometry within 20° of specular and at over half the first pass's highest m00
    m00 = {round(p.group.theta_r, 1): float(p.brdf.m[0, 0]) for p in done.points}
    peak = max(m00[round(tr, 1)] for tr in (30.0, 44.0, 47.0, 50.0, 53.0, 56.0, 70.0))
    for _, tr in plan2["scan"]["points"]:
        assert abs(abs(tr) - 50.0) <= 20.0, plan2["scan"]["points"]
        assert m00[round(abs(tr), 1)] > 0.5 * peak, (tr, m00)
    fit = done.summary["pbrdf"]
    assert fit["adequate"], fit["verdict"]
    # one seed, a few free parameters: 3σ each (at 2σ one run in five fails by chance)
    truth = (*GLASS, frame_deg)
    for k, name in enumerate(fit["param_names"]):
        if name not in fit["fixed"]:
            assert abs(fit["params"][k] - truth[k]) < 3.0 * fit["stderr"][k], (
                name, fit["params"][k], fit["stderr"][k])


def test_a_pem_lobe_plan_runs_both_passes_and_fits_the_glass(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bench = fast_pem_bench(tmp_path)
    text = PLAN.format(detector="lockin", dark="", polarimetry='mode = "pem"\nreads = 4')
    first, second, printed = _run_both(tmp_path, bench, text, capsys)
    _check(first, second, printed, per_geometry=8, frame_deg=0.0)


@pytest.mark.slow  # 9 geometries × 23 retarder steps through the engine: a few minutes;
# its default-run twin is test_a_pem_lobe_plan_runs_both_passes_and_fits_the_glass
def test_a_drr_lobe_plan_runs_both_passes_and_fits_the_glass(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bench = fast_bench(tmp_path)
    # the hidden optics as the bench's calibration beside the runs (both passes use it)
    (tmp_path / "runs").mkdir()
    _oracle(tmp_path / "runs")
    text = PLAN.format(detector="power_meter", dark='dark = "per_point"',
                       polarimetry='mode = "drr"\nsteps = 23')
    first, second, printed = _run_both(tmp_path, bench, text, capsys)
    _check(first, second, printed, per_geometry=23, frame_deg=FRAME_DEG)
