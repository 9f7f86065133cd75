"""A two-pass polarimetric lobe plan over two filters: the lobe fitted at one reference
filter against each wavelength's own lobe (the union of their placements).

    PYTHONPATH=. OPENBLAS_NUM_THREADS=1 .venv/bin/python \\
        benchmarks/bench_polarimetric_spectral_lobe.py --points 3

The bench and plan are the slow test's
(``tests/instrument/pipelines/polarimetry/test_polarimetric_spectral_lobe.py``):
``sim-polarimetric`` behind a wheel of 550 and 650 nm filters, θi 50°, a first pass at θr
30, 44, 50, 56 and 70° (23 retarder steps at each filter), ``--points`` geometries placed
on the lobe. Both passes run as ``scatterlab run`` runs them (the lobe fitted at the
reference filter, 550 nm); then, from the first pass, the lobe and the σ model of m00 are
fitted at each wavelength and the second pass placed from each (:func:`lobe_placement`).
For every wavelength it prints the predicted σ of the target parameter (the lobe width)
after the first pass, with the reference filter's placement, with the wavelength's own,
and with the union of both placements, and the second pass's time for each choice (every
geometry is read at every filter).
"""

from __future__ import annotations

import argparse
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np

from analysis.brdf.geometry import make_geometry
from benchmarks.bench_polarimetric_lobe import run_both_passes
from instrument.bench.profile import load_profile
from instrument.pipelines.polarimetry.lobe import (
    LobePlacement,
    M00Rows,
    geometry_seconds,
    lobe_placement,
    m00_rows,
)
from instrument.pipelines.polarimetry.pipeline import fit_polarimetric_run
from instrument.plans.lobe import _angles_rad, lobe_of, reference_filter
from instrument.plans.lobe_budget import predicted_covariance
from instrument.plans.planfile import parse_plan
from instrument.run.runfile import read_run
from tests.instrument.pipelines.polarimetry.test_polarimetric_spectral_lobe import (
    spectral_drr_lobe_setup,
)


def _sigma_target(lp: LobePlacement, first: M00Rows, pairs: list[tuple[float, float]],
                  target: str) -> float:
    """σ of ``target`` predicted at one wavelength (its lobe and σ model ``lp``, its first
    pass ``first``) with the second pass at ``pairs``."""
    extra = _angles_rad(pairs) if pairs else np.zeros((0, 4))
    sigma = lp.noise.sigma(lp.forward.evaluate_geometry(lp.params, make_geometry(*extra.T)))
    cov = predicted_covariance(lp.forward, lp.params,
                               np.concatenate([first.angles_rad, extra]),
                               np.concatenate([first.sigma, sigma]))
    k = lp.forward.param_names.index(target)
    return float(np.sqrt(max(cov[k, k], 0.0)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=3, help="geometries of the second pass")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        bench, text = spectral_drr_lobe_setup(folder, points=args.points)
        runs = run_both_passes(folder, bench, text)
        files = sorted(runs.glob("*.h5"))
        second = next(p for p in files
                      if "first_pass" in tomllib.loads(read_run(p).plan_text)["scan"])
        first = next(p for p in files if p != second)
        spec = parse_plan(text)
        profile = load_profile(bench)
        lobe = lobe_of(spec)
        ref = reference_filter(spec, profile)
        assert lobe is not None and ref is not None
        placed = {}
        rows = {}
        for wl in (550.0, 650.0):
            t = time.perf_counter()
            placed[wl] = lobe_placement(first, spec, profile, wl)
            rows[wl] = m00_rows(first, wavelength_nm=wl)
            lp = placed[wl]
            print(f"{wl:.0f} nm: {lp.model} "
                  + ", ".join(f"{n} {v:.4g}" for n, v in zip(lp.forward.param_names,
                                                              lp.params, strict=True))
                  + f"; {lp.noise.describe()}; placed θr "
                  + ", ".join(f"{tr:.2f}" for _, tr in lp.placement.pairs)
                  + f" ({time.perf_counter() - t:.1f} s)")
        target = str(lobe.target or placed[ref.center_nm].forward.param_names[-1])
        per_geometry = geometry_seconds(spec, profile, placed[550.0].placement.pairs[0],
                                        lobe.step_deg)
        other = 650.0 if ref.center_nm == 550.0 else 550.0
        choices = {f"reference ({ref.center_nm:.0f} nm) placement":
                   placed[ref.center_nm].placement.pairs,
                   f"{other:.0f} nm's own placement": placed[other].placement.pairs,
                   "union of both": list(dict.fromkeys(placed[550.0].placement.pairs
                                                       + placed[650.0].placement.pairs))}
        alone = ", ".join(f"{wl:.0f} nm {_sigma_target(placed[wl], rows[wl], [], target):.4g}"
                          for wl in (550.0, 650.0))
        print(f"σ({target}) predicted (first pass alone: {alone}); one geometry at both "
              f"filters costs {per_geometry:.1f} s on the plan's estimate")
        for name, pairs in choices.items():
            got = ", ".join(f"{wl:.0f} nm {_sigma_target(placed[wl], rows[wl], pairs, target):.4g}"
                            for wl in (550.0, 650.0))
            print(f"  {name:28s} {len(pairs)} geometries, {len(pairs) * per_geometry:.1f} s: "
                  f"{got}")
        done = fit_polarimetric_run(second, report=False, write=False)
        fit = done.summary["pbrdf"]
        print(f"joint fit of {len(done.points)} matrices (both passes, both wavelengths): "
              f"{fit['variant']}, {fit['verdict']}")
        for name, v, s in zip(fit["param_names"], fit["params"], fit["stderr"], strict=True):
            print(f"  {name:10s} {v:.4f} ± {s:.4f}")


if __name__ == "__main__":
    main()
