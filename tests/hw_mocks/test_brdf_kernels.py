"""The fused BRDF kernels of the simulated sample (hw_mocks.sim.brdf_kernels) against the
registry models they stand for: the same values to rounding, at every incidence and over
the whole outgoing hemisphere (grazing included), in any frame turned about the normal;
models with a part that has no kernel get none."""

from __future__ import annotations

import math

import numpy as np
import pytest

from analysis.brdf import get_model
from analysis.brdf.geometry import geometry_from_vectors
from hw_mocks.sim.brdf_kernels import fixed_incidence, rounding_rtol
from hw_mocks.sim.goniometer_scene import brdf_from_model, lambertian_brdf


# Rounding alone separates the two forms: ~10 roundings each, amplified by 1/α² where D's
# denominator t = 1 − cos²θh (1 − α²) cancels near the peak (rounding_rtol: 64 ε/α²;
# 1.4e-11 at α = 0.02, 3.6e-13 at α = 0.2). The pupil rule's own tolerance is 1e-6.
def alphas(name: str, params: list[float]) -> list[float]:
    model = get_model(name)
    return [params[i + 1] for i, label in enumerate(model.param_names)
            if label.endswith("ks")]


def hemisphere(rng: np.random.Generator, n: int) -> np.ndarray:
    z = np.concatenate([rng.uniform(0.0, 1.0, n), [1.0, 0.0, 1e-9, 1e-3]])
    phi = rng.uniform(0.0, 2.0 * math.pi, z.size)
    s = np.sqrt(1.0 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=-1)


@pytest.mark.parametrize(("name", "params"), [
    ("lambert+ggx", [0.5, 0.2, 0.2]),  # the sim bench's sample
    ("lambert+ggx", [0.3, 0.5, 0.02]),  # a sharp lobe
    ("ggx", [1.0, 0.9]),  # a wide one
    ("lambert", [0.99]),
    ("ggx+lambert+ggx", [0.2, 0.05, 0.3, 0.4, 0.1]),
])
@pytest.mark.parametrize("theta_i_deg", [0.0, 20.0, 60.0, 85.0, 89.9])
def test_kernel_equals_the_model(name, params, theta_i_deg):
    rng = np.random.default_rng(7)
    rtol = rounding_rtol(alphas(name, params))
    model = get_model(name)
    at = fixed_incidence(model, np.array(params))
    assert at is not None
    t = math.radians(theta_i_deg)
    for phi_i in (0.0, 1.1, -2.5):
        wi = np.array([math.sin(t) * math.cos(phi_i), math.sin(t) * math.sin(phi_i),
                       math.cos(t)])
        wr = hemisphere(rng, 2000)
        want = model.evaluate_geometry(np.array(params), geometry_from_vectors(wi, wr))
        got = at(wi)(wr[:, 0].copy(), wr[:, 1].copy(), wr[:, 2].copy())
        np.testing.assert_allclose(got, want, rtol=rtol, atol=0.0)
        # isotropic: the same in a frame turned about the normal
        c, s = math.cos(0.7), math.sin(0.7)
        turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        wi_t, wr_t = turn @ wi, wr @ turn.T
        got_t = at(wi_t)(wr_t[:, 0].copy(), wr_t[:, 1].copy(), wr_t[:, 2].copy())
        np.testing.assert_allclose(got_t, want, rtol=rtol, atol=0.0)


def test_sharp_lobe_peak_and_tail():
    """α = 0.02 at and around the mirror direction: D spans many decades there."""
    model = get_model("lambert+ggx")
    params = np.array([0.3, 0.5, 0.02])
    t = math.radians(40.0)
    wi = np.array([-math.sin(t), 0.0, math.cos(t)])
    angles = math.radians(40.0) + np.linspace(-0.2, 0.2, 4001)
    wr = np.stack([np.sin(angles), np.zeros_like(angles), np.cos(angles)], axis=-1)
    want = model.evaluate_geometry(params, geometry_from_vectors(wi, wr))
    got = fixed_incidence(model, params)(wi)(wr[:, 0].copy(), wr[:, 1].copy(),
                                              wr[:, 2].copy())
    assert want.max() / want.min() > 300.0  # the lobe is resolved (the test can fail)
    np.testing.assert_allclose(got, want, rtol=rounding_rtol([0.02]), atol=0.0)


@pytest.mark.parametrize("name", ["oren_nayar", "lambert+beckmann", "lambert+phong",
                                  "ggx_vcavity"])
def test_models_without_kernels_get_none(name):
    model = get_model(name)
    assert fixed_incidence(model, model.start) is None
    assert brdf_from_model(name).fixed_incidence is None


def test_ground_truth_brdf_carries_the_kernel():
    brdf = brdf_from_model("lambert+ggx", [0.5, 0.2, 0.2])
    wi = np.array([-0.5, 0.0, math.sqrt(0.75)])
    wr = hemisphere(np.random.default_rng(3), 500)
    kernel = brdf.fixed_incidence(wi)
    np.testing.assert_allclose(
        kernel(wr[:, 0].copy(), wr[:, 1].copy(), wr[:, 2].copy()),
        brdf.from_vectors(wi, wr), rtol=rounding_rtol([0.2]), atol=0.0)


def test_reference_standard_has_a_constant_kernel():
    brdf = lambertian_brdf(0.99)
    wr = hemisphere(np.random.default_rng(4), 50)
    values = brdf.fixed_incidence(np.array([0.0, 0.3, 0.9]))(wr[:, 0], wr[:, 1], wr[:, 2])
    np.testing.assert_array_equal(values, np.full(wr.shape[0], 0.99 / math.pi))
