"""The lock-in's σ match its scatter, through the engine on the emulated spectral bench
(SR830 firmware with a chopped photodiode, SC10, FW102C; real drivers): a Lambertian
ρ = 0.5 sample at the 550 nm filter, per-point darks, two lock-in noise seeds, reduced and
fitted as ``scatterlab fit`` does. The reduced version of benchmarks/bench_pulls.py
``--lockin`` (BENCHMARKS.md, honest_sigma), which measures the RMS pull over ten seeds.

With the instrument function and the pooled noise model each fit passes the χ² test and
its ρ lies within 3σ of the truth (σ before the common scale and the range-gain
covariance, which the emulator's exact gain and responsivity give nothing to scatter
against); each check fails with probability ≈ 0.3 % and 0.1 % when the σ are right.
Before them the same scans gave χ²/dof ≈ 3.

The emulated lock-in runs on a host-paced clock (``clock=host`` in sim-spectral), so each
seed's data, and these checks' outcome, are the same on a quiet and a loaded machine
(tests/instrument/run/test_lockin_determinism.py): seed 0 gives χ² 5.23 for 9 degrees of
freedom (p 0.81) and z −0.23, seed 1 χ² 8.10 (p 0.52) and z −0.74. (On the wall clock
seed 1 had given p 0.77 on a quiet box and 9e-4 under load.)
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from instrument.cli import main
from instrument.pipelines.brdf.spectral import SpectralOptions, analyse_spectral
from instrument.run.runfile import read_run

ROOT = Path(__file__).resolve().parents[4]

PLAN = """
[plan]
kind = "brdf_in_plane"
name = "lock-in pulls"
[sample]
name = "lambert"
[scan]
skip_beam_points = true
theta_i = [30]
theta_r = [-60, -40, -10, 0, 10, 20, 40, 50, 60, 70]
[acquisition]
detectors = ["lockin"]
dark = "per_point"
frames = 4
[spectral]
filters = [2]
"""


def lockin_profile(brdf: str, params: str, seed: int, aperture_samples: int | None = None
                   ) -> str:
    """The sim-spectral bench with a plain sample (no spectral table) and the lock-in's
    noise seed ``seed``; ``aperture_samples`` sets the resolution of the emulator's rule
    over the photodiode's aperture (default 9: 36 nodes, GoniometerScene). Shared with
    benchmarks/bench_pulls.py."""
    text = (ROOT / "instrument" / "bench" / "profiles" / "sim-spectral.toml").read_text(
        encoding="utf-8")
    head, _, tail = text.partition('[simulation.scene]\nbrdf = "spectral"')
    tail = tail.split("[simulation.source]", 1)[1]
    grid = "" if aperture_samples is None else f"aperture_samples = {aperture_samples}\n"
    text = (f'{head}[simulation.scene]\nbrdf = "{brdf}"\nparams = {params}\n{grid}\n'
            f"[simulation.source]{tail}")
    out = re.sub(r"(simsr830://lockin\?[^\"]*)seed=\d+", rf"\g<1>seed={seed}", text)
    assert f"seed={seed}&" in out or out.count(f"seed={seed}\"") == 1
    return out


def _bench(tmp_path: Path, seed: int) -> Path:
    path = tmp_path / f"lambert-{seed}.toml"
    path.write_text(lockin_profile("lambert", "{ rho = 0.5 }", 400 + seed), encoding="utf-8")
    return path


@pytest.mark.slow
@pytest.mark.timeout(1200)  # one scan of 10 points, each settled and read 4 + 4 times
@pytest.mark.parametrize("seed", [0, 1])
def test_the_lock_in_fit_passes_chi2_and_its_rho_pull_is_within_3_sigma(tmp_path, seed):
    plan = tmp_path / "plan.toml"
    plan.write_text(PLAN, encoding="utf-8")
    out = tmp_path / "runs"
    assert main(["run", str(plan), "--bench", str(_bench(tmp_path, seed)), "--out",
                 str(out), "--no-fsync", "--quiet"]) == 0
    (path,) = out.glob("*.h5")
    done = analyse_spectral(read_run(path), SpectralOptions(models=("lambert",)))
    (wf,) = done.fits
    assert "noise model of the run's" in wf.reduced.provenance["lockin_noise"]
    fit = wf.result.selection.fits["lambert"]
    gof = wf.result.goodness["lambert"]
    assert gof.dof == wf.reduced.points.n - 1
    # χ² test: fails 0.1 % of the time with the right σ (two-sided)
    assert 5e-4 < gof.p_value < 1 - 5e-4, (gof.chi2, gof.dof)
    assert wf.result.inflation["lambert"] == 1.0  # nothing inflated
    z = (fit.params[0] - 0.5) / fit.stderr[0]
    assert abs(z) < stats.norm.ppf(1 - 0.0015), (fit.params, fit.stderr)
    assert np.isfinite(z)
