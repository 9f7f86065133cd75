"""Closed-loop check of fitting + selection on synthetic scans (without the simulated
bench): for three ground truths, over 50 seeds, the true parameters lie within
the reported 2σ in ≥ 90 % of fits and the right model is chosen in ≥ 90 %."""

import numpy as np
import pytest

from analysis.brdf import get_model, parse_model_list, select_model

from .synth import noisy, scan_angles

CANDIDATES = "lambert,oren_nayar,lambert+ggx,oren_nayar+ggx"
CASES = [
    ("lambert", [0.8]),
    ("lambert+ggx", [0.3, 0.5, 0.2]),
    ("oren_nayar", [0.7, 0.3]),
]


@pytest.mark.slow
@pytest.mark.parametrize(("truth", "params"), CASES)
def test_fifty_seed_coverage_and_selection(truth: str, params: list[float]) -> None:
    model = get_model(truth)
    candidates = parse_model_list(CANDIDATES)
    angles = scan_angles(15, out_of_plane=False)
    n_seeds = 50
    covered = np.zeros(len(params))
    chosen_right = 0
    for seed in range(n_seeds):
        y, sig, _ = noisy(model, params, angles, seed=1000 + seed, rel=0.03, floor=0.001)
        res = select_model(candidates, y, *angles, sigma=sig, run_cv=False, n_starts=2,
                           seed=seed)
        chosen_right += res.chosen == truth
        fit = res.fits[truth]
        covered += np.abs(fit.params - np.asarray(params)) <= 2.0 * fit.stderr
    assert chosen_right >= 0.9 * n_seeds, chosen_right
    assert np.all(covered >= 0.9 * n_seeds), covered
