"""The polarimetric validation matrix: hidden-truth closed loops of every reference and
sample through the engine, the emulated drivers, ``scatterlab calibrate polarimeter`` and
the polarimetric fit, on ``sim-polarimetric`` (retarders 2° off, retardances 5 % off a
quarter wave, polarisers 0.3° off).

Shared by the slow tests (one seed, 3σ) and ``benchmarks/bench_polarimetric_validation.py``
(ten seeds, the fraction within 2σ and the pull spread). With ``pem=True`` the same
samples go through ``sim-polarimetric-pem`` (modulator amplitude 3 % high and its axis
0.4° off, polarisers ±0.3°, analyser retarder −0.4°) and its PEM calibration (ADR 0113;
``benchmarks/bench_pem_calibration.py``). The samples:

* straight through (the detector arm at 180°, as the calibration's reference scans): air,
  a linear polariser at 0°, 30° and 45°, a quarter-wave plate at 0°; truth: the ideal
  element turned into the calibration's frame (the generator polariser's hidden 0.3°);
* reflected (the profile's scene replaced): the Fresnel dielectric (n = 1.5) in the
  specular direction at θi 20°, 50° and 70°, the rough metal (n = 1.4, k = 7.6) at 50°,
  the depolarising diffuser at θi 30°, θr 10°; truth: the world's aperture-averaged matrix
  (``mueller_on_aperture``) at the read-back pose.
"""

from __future__ import annotations

import argparse
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from analysis.polarimetry.elements import linear_polariser, linear_retarder, rotated
from instrument.bench.profile import load_profile
from instrument.cli import main
from instrument.pipelines.polarimetry.calibration import calibration_folder
from instrument.pipelines.polarimetry.pipeline import fit_polarimetric_run
from tests.instrument.pipelines.polarimetry.closed_loop import (
    FRAME_DEG,
    fast_bench,
    plan_text,
    pulls,
    run_with_truth,
)

STEPS = 25

GLASS = "[simulation.scene.pbrdf]\nn = 1.5\nslope_rms = 0.15\nalbedo = 0.05\n\n"
METAL = "[simulation.scene.pbrdf]\nn = 1.4\nk = 7.6\nslope_rms = 0.1\n\n"
DIFFUSER = "[simulation.scene.pbrdf]\nn = 1.5\nalbedo = 0.8\nspecular = 0.0\n\n"

#: Brewster's angle of the dielectric, arctan 1.5 (deg).
BREWSTER_DEG = math.degrees(math.atan(1.5))


@dataclass(frozen=True)
class Sample:
    """One row of the matrix: a straight-through reference (``reference`` = the
    calibration's kind, ``angle_deg`` its azimuth) or a reflecting scene at (θi, θr)."""

    name: str
    reference: str | None = None
    angle_deg: float = 0.0
    scene: str | None = None
    theta_i: float = 0.0
    theta_r: float = 0.0


SAMPLES: tuple[Sample, ...] = (
    Sample("air", reference="air"),
    Sample("polariser 0°", reference="polariser", angle_deg=0.0),
    Sample("polariser 30°", reference="polariser", angle_deg=30.0),
    Sample("polariser 45°", reference="polariser", angle_deg=45.0),
    Sample("quarter-wave plate", reference="retarder", angle_deg=0.0),
    Sample("dielectric 20°", scene=GLASS, theta_i=20.0, theta_r=20.0),
    Sample("dielectric 50°", scene=GLASS, theta_i=50.0, theta_r=50.0),
    Sample("dielectric 70°", scene=GLASS, theta_i=70.0, theta_r=70.0),
    Sample("rough metal", scene=METAL, theta_i=50.0, theta_r=50.0),
    Sample("diffuser", scene=DIFFUSER, theta_i=30.0, theta_r=10.0),
)


def sample(name: str) -> Sample:
    """The matrix's row called ``name``."""
    return next(s for s in SAMPLES if s.name == name)


@dataclass(frozen=True)
class Outcome:
    """One sample, one seed: the pulls of the 15 normalised elements with the measured
    calibration and with the nominal optics, and the calibrated normalised matrix."""

    sample: Sample
    seed: int | None
    calibrated: np.ndarray
    nominal: np.ndarray
    m_normalised: np.ndarray
    truth: np.ndarray


def _bench(folder: Path, scene: str | None, seed: int | None, pem: bool) -> Path:
    """The fast DRR bench, or the fast, misaligned PEM bench (its lock-in's ``seed``)."""
    if not pem:
        return fast_bench(folder, scene, seed=seed)
    from tests.instrument.run.test_pem_run import fast_pem_bench

    path = fast_pem_bench(folder, seed=5 if seed is None else seed, ideal=False)
    if scene is not None:
        text = re.sub(r"\[simulation\.scene\.pbrdf\][^\[]*", scene,
                      path.read_text(encoding="utf-8"), flags=re.DOTALL)
        path = path.with_name(f"scene-{abs(hash(scene)) % 10**8}-{path.name}")
        path.write_text(text, encoding="utf-8")
    return path


def calibrate(folder: Path, seed: int | None, pem: bool = False) -> tuple[Path, Path]:
    """``scatterlab calibrate polarimeter`` on the fast bench of ``seed`` (None: the
    profile's own) with 25 steps (a PEM bench: its 2 × 4 settings): (the bench profile,
    the calibration file)."""
    folder.mkdir(parents=True, exist_ok=True)
    bench = _bench(folder, None, seed, pem)
    assert main(["calibrate", "polarimeter", "--bench", str(bench), "--out", str(folder),
                 "--steps", str(STEPS), "--no-fsync"]) == 0
    (file,) = calibration_folder(folder).glob("polarimeter-*.json")
    return bench, file


def _ideal(s: Sample) -> np.ndarray:
    """The reference's normalised matrix in the calibration's frame."""
    m = {"air": np.eye(4), "polariser": linear_polariser(0.0),
         "retarder": linear_retarder(0.0, math.pi / 2)}[s.reference or "air"]
    return np.asarray(rotated(m / m[0, 0], math.radians(s.angle_deg - FRAME_DEG)))


def measure(s: Sample, seed: int | None, folder: Path, calibration: Path,
            pem: bool = False) -> Outcome:
    """Run ``s`` on the fast bench of ``seed`` (``pem``: the PEM bench) and fit it with
    the calibration and with the nominal optics."""
    from instrument.cli._calibrate_polarimeter import _reference_run

    folder.mkdir(parents=True, exist_ok=True)
    if s.reference is not None:
        bench = _bench(folder, None, seed, pem)
        args = argparse.Namespace(out=str(folder), steps=STEPS, no_fsync=True)
        path = _reference_run(load_profile(bench), s.reference, s.angle_deg, args)
        truth = _ideal(s)
    elif pem:
        from tests.instrument.run.test_pem_run import plan_text as pem_plan

        bench = _bench(folder, s.scene, seed, pem)
        path, truths = run_with_truth(folder, bench, pem_plan(
            s.name, str(s.theta_i), str(s.theta_r)), steps=8,
            world_name="sim-polarimetric-pem")
        truth = truths[(round(s.theta_i), round(s.theta_r))]
    else:
        bench = fast_bench(folder, s.scene, seed=seed)
        path, truths = run_with_truth(folder, bench, plan_text(
            s.name, str(s.theta_i), str(s.theta_r)), steps=STEPS)
        truth = truths[(round(s.theta_i), round(s.theta_r))]
    (point,) = fit_polarimetric_run(path, calibration=calibration, report=False,
                                    write=False).points
    (nominal,) = fit_polarimetric_run(path, calibration="none", report=False,
                                      write=False).points
    return Outcome(s, seed, pulls(point, truth), pulls(nominal, truth),
                   np.asarray(point.brdf.m_normalised), truth)


#: One seed's 15 calibrated elements count as recovered with every |pull| < 3 and at
#: least 85 % within 2σ (at 95 % per element, 15 elements fall below 85 % about one time
#: in 6; the tests check 3σ for that reason, the ten-seed statistics the 2σ standard).
RECOVERED_MAX = 3.0
RECOVERED_WITHIN_2 = 0.85
#: Over several seeds (≥ 60 elements): at least 90 % within 2σ and a pull spread below
#: 1.3 (the spread of 150 unit normal pulls is 1 ± 0.06; 1.3 is five of those off).
POOLED_WITHIN_2 = 0.9
POOLED_SPREAD = 1.3
#: The nominal reduction counts as visibly off when some element is > 5σ from the truth,
#: as marginally off from 3σ (a dim sample's larger σ hides part of the polarimeter's bias:
#: the dielectric at 20° reflects about 4 % of the light).
VISIBLY_OFF = 5.0
MARGINALLY_OFF = 3.0


def verdict(calibrated: np.ndarray, nominal: np.ndarray) -> tuple[str, str]:
    """(the calibrated elements' verdict, the nominal ones') as report text."""
    c = np.abs(np.ravel(calibrated))
    n = np.abs(np.ravel(nominal))
    if c.size <= 15:
        ok = bool(np.max(c) < RECOVERED_MAX and np.mean(c < 2.0) >= RECOVERED_WITHIN_2)
    else:  # pooled seeds: a rare 3σ element is expected, the fraction and spread judge
        ok = bool(np.mean(c < 2.0) >= POOLED_WITHIN_2
                  and np.std(np.ravel(calibrated)) < POOLED_SPREAD)
    first = (f"calibrated: {np.mean(c < 2.0):.0%} within 2σ, pull spread "
             f"{np.std(np.ravel(calibrated)):.2f}, max |pull| {np.max(c):.1f} — "
             + ("recovered" if ok else "NOT recovered"))
    worst = float(np.max(n))
    second = (f"uncalibrated: {np.mean(n < 2.0):.0%} within 2σ, max |pull| {worst:.1f} — "
              + ("visibly off" if worst > VISIBLY_OFF else
                 "marginally off" if worst > MARGINALLY_OFF else
                 "not visibly off (the polarimeter's errors do not show in this sample)"))
    return first, second


def report(outcomes: list[Outcome]) -> str:
    """One block per sample, over the seeds given: the calibrated and nominal verdicts."""
    lines = []
    for s in SAMPLES:
        mine = [o for o in outcomes if o.sample == s]
        if not mine:
            continue
        cal = np.concatenate([o.calibrated for o in mine])
        nom = np.concatenate([o.nominal for o in mine])
        first, second = verdict(cal, nom)
        lines.append(f"{s.name} ({len(mine)} seed{'s' if len(mine) > 1 else ''}):")
        lines.append(f"  {first}")
        lines.append(f"  {second}")
    return "\n".join(lines)
