"""The point-response model on the passed orders only gives the very arrays of the model on
every order (analysis/lightfield/ray_fit.py; the reference form and the timing are in
benchmarks/bench_ray_model.py)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from analysis.lightfield.ray_fit import ray_model
from analysis.lightfield.spectral import fourier_orders

BENCH = Path(__file__).parents[3] / "benchmarks" / "bench_ray_model.py"


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_ray_model", BENCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize(("n", "p_hat"), [(128, 45), (128, 9), (1024, 60), (64, 31)])
def test_passed_orders_only_give_identical_responses_and_derivatives(bench, n, p_hat):
    lf, use, phi, pos = bench.case(n, p_hat, k=5)
    for got, want in zip(ray_model(lf, use, phi, pos), bench.reference_ray_model(lf, use, phi, pos),
                         strict=True):
        assert got.shape == want.shape
        assert np.array_equal(got, want)


def test_a_filter_with_scattered_zeros_gives_identical_responses(bench):
    """A Wiener filter can pass orders out of sequence (its factors follow the gain)."""
    lf, use, _, pos = bench.case(256, 40, k=3)
    rng = np.random.default_rng(7)
    p = np.abs(fourier_orders(256))
    phi = np.where((p <= 70) & (rng.random(256) < 0.6), rng.random(256), 0.0)
    for got, want in zip(ray_model(lf, use, phi, pos), bench.reference_ray_model(lf, use, phi, pos),
                         strict=True):
        assert np.array_equal(got, want)
