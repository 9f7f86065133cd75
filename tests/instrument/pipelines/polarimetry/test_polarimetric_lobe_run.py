"""Two-pass polarimetric lobe plans through ``scatterlab run`` and ``scatterlab fit`` on the
emulated benches (ADR 0106 amendment): the first pass is polarimetric over the coarse
geometries, the second pass is placed from its m00 with a σ model fitted to it and run
with the same polarimetry settings, and the fit of the second run takes both runs'
Mueller matrices.

DRR (``sim-polarimetric``, its hidden optics held by the calibration beside the runs, as
``test_polarimetric_fit.py`` writes it) recovers the hidden glass's pBRDF within the
goodness-of-fit gate; it is slow (two passes of 23 retarder steps per geometry), and its
default-run twin is the PEM test: the smallest PEM lobe plan (five geometries, then one)
through both passes and the joint fit. The PEM runs are not put through the pBRDF gate:
the emulated lock-in's harmonics carry σ of ~10⁻⁵ of m00 on two columns of the matrix,
where the point-receiver pBRDF and the world's aperture average differ by more.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import pytest

from instrument.cli import main
from instrument.pipelines.polarimetry.pipeline import fit_polarimetric_run
from instrument.pipelines.polarimetry.reduce import MuellerPoint
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
theta_r = {theta_r}
[scan.lobe]
points = {points}
step_deg = 1.0
search_half_width_deg = 6.0
search_step_deg = {search}
prior = "{prior}"
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


def _check_passes(first: Path, second: Path, printed: str, *, placed: int,
                  per_geometry: int) -> list[MuellerPoint]:
    """Two runs, the second naming the first with the same polarimetry, its geometries on
    the lobe; the fit of the second run reduces both. Returns the joint fit's points."""
    assert f"second pass: {placed} geometries ({placed * per_geometry} points) placed by " \
        "Fisher information" in printed, printed
    plan1 = tomllib.loads(read_run(first).plan_text)
    plan2 = tomllib.loads(read_run(second).plan_text)
    assert plan2["scan"]["first_pass"] == first.name
    assert plan2["polarimetry"] == plan1["polarimetry"]
    assert read_run(second).n_points == placed * per_geometry
    done = fit_polarimetric_run(second, report=False, write=False)
    n_first = len(fit_polarimetric_run(first, report=False, write=False).points)
    assert len(done.points) == n_first + placed
    assert any("with the first pass" in n for n in done.summary["notes"])
    # on the lobe around the mirror direction (the glass's m00 peaks a few degrees past
    # it, Fresnel rising with the angle), not on the diffuse floor: each second-pass
    # geometry within 20° of specular and at over half the first pass's highest m00
    m00 = [(p.group.theta_r, float(p.brdf.m[0, 0])) for p in done.points]
    peak = max(m for _, m in m00[:n_first])
    for _, tr in plan2["scan"]["points"]:
        assert abs(abs(tr) - 50.0) <= 20.0, plan2["scan"]["points"]
        (m,) = [m for t, m in m00[n_first:] if abs(t - abs(tr)) < 0.05]
        assert m > 0.5 * peak, (tr, m00)
    return list(done.points)


def test_a_pem_lobe_plan_runs_both_passes_and_fits_them_together(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # 30, 44, 50, 56 and 70° (the search of ±6° every 6°), then one geometry
    bench = fast_pem_bench(tmp_path)
    text = PLAN.format(theta_r="[30.0, 70.0]", points=1, search=6.0, prior="ggx",
                       detector="lockin", dark="", polarimetry='mode = "pem"\nreads = 4')
    first, second, printed = _run_both(tmp_path, bench, text, capsys)
    points = _check_passes(first, second, printed, placed=1, per_geometry=8)
    assert len(points) == 6
    # the joint fit's normalised matrices: the glass's diattenuation near Brewster's angle
    assert all(p.brdf.m_normalised[0, 1] < -0.5 for p in points[1:4])


def drr_lobe_setup(folder: Path) -> tuple[Path, str]:
    """The DRR test's bench (``folder/runs`` holding the hidden optics as the bench's newest
    calibration, with which both passes are reduced, for the placement and for the fit)
    and plan text: 30, 44, 47, 50, 53, 56 and 70° (the search of ±6° every 3°), then two
    geometries. Shared with ``benchmarks/bench_polarimetric_lobe.py``."""
    runs = folder / "runs"
    runs.mkdir()
    cal = _oracle(runs).path
    assert cal is not None
    cal.rename(cal.with_name("polarimeter-hidden-optics.json"))
    text = PLAN.format(theta_r="{ start = 30.0, stop = 70.0, step = 20.0 }", points=2,
                       search=3.0, prior="lambert+ggx", detector="power_meter",
                       dark='dark = "per_point"', polarimetry='mode = "drr"\nsteps = 23')
    return fast_bench(folder), text


@pytest.mark.slow  # 9 geometries × 23 retarder steps through the engine: ~23 s CPU, 30-90 s;
# its default-run twin is test_a_pem_lobe_plan_runs_both_passes_and_fits_them_together
def test_a_drr_lobe_plan_runs_both_passes_and_recovers_the_glass(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bench, text = drr_lobe_setup(tmp_path)
    first, second, printed = _run_both(tmp_path, bench, text, capsys)
    _check_passes(first, second, printed, placed=2, per_geometry=23)
    done = fit_polarimetric_run(second, report=False, write=False)
    assert done.summary["calibrated"] and len(done.points) == 9
    assert_recovers_the_glass(done.summary["pbrdf"])


def assert_recovers_the_glass(fit: dict[str, Any]) -> None:
    """The joint pBRDF fit passes its gate and holds the hidden glass and frame: one seed,
    four free parameters, 3σ each (at 2σ one run in five fails by chance)."""
    assert fit["adequate"], fit["verdict"]
    truth = (*GLASS, FRAME_DEG)
    for k, name in enumerate(fit["param_names"]):
        if name not in fit["fixed"]:
            assert abs(fit["params"][k] - truth[k]) < 3.0 * fit["stderr"][k], (
                name, fit["params"][k], fit["stderr"][k])
