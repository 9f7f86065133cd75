"""HDR merge of bracketed linear frames: linearity over 10⁶, saturation and noise handling."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from analysis.hdr import merge_hdr

K = 1.0  # DN/e⁻
READ_E = 3.0
FULL_WELL = 60000.0
OFFSET = 100.0
BITS = 16
EXPOSURES = np.array([10.0, 100.0, 1e3, 1e4, 1e5, 1e6])  # µs


def wedge(n_patches=13, side=24, low=4e-3, high=4e3):
    """A step wedge: patches of constant rate (e⁻/µs) log-spaced from low to high."""
    rates = np.geomspace(low, high, n_patches)
    img = np.repeat(rates, side)[None, :].repeat(side, axis=0)
    return rates, img


def expose(rate_e_per_us, t_us, rng):
    lam = rate_e_per_us * t_us
    e = np.minimum(rng.poisson(lam).astype(float), FULL_WELL)
    dn = np.rint(K * (e + READ_E * rng.standard_normal(lam.shape)) + OFFSET)
    return np.clip(dn, 0, 2**BITS - 1).astype(np.uint16)


def bracket(img, rng):
    frames = np.stack([expose(img, t, rng) for t in EXPOSURES])
    return frames


SAT = OFFSET + K * FULL_WELL - 4 * READ_E


@pytest.mark.parametrize("weighting", ["hat", "inverse_variance"])
def test_merge_is_linear_within_2_percent_over_1e6(weighting):
    rng = np.random.default_rng(11)
    rates, img = wedge()
    assert rates[-1] / rates[0] == pytest.approx(1e6)
    frames = bracket(img, rng)
    before = frames.copy()
    res = merge_hdr(frames, EXPOSURES, darks=OFFSET, saturation_dn=SAT, weighting=weighting,
                    system_gain_dn_per_e=K, read_noise_dn=READ_E * K)
    np.testing.assert_array_equal(frames, before)  # input untouched
    side = img.shape[0]
    merged = res.rate.reshape(side, -1, side).mean(axis=(0, 2))  # per patch, DN/µs
    np.testing.assert_allclose(merged / (K * rates), 1.0, rtol=0.02)
    assert not res.saturated.any()
    assert (res.n_used >= 1).all()


def test_saturated_everywhere_is_flagged_and_a_lower_bound():
    rng = np.random.default_rng(2)
    img = np.full((16, 16), 1e4)  # 10 µs already gives 1e5 e⁻ > full well
    res = merge_hdr(bracket(img, rng), EXPOSURES, darks=OFFSET, saturation_dn=SAT)
    assert res.saturated.all()
    assert (res.rate < 1e4 * K).all()
    assert (res.rate > 0.5 * FULL_WELL * K / EXPOSURES[0]).all()


def test_dark_everywhere_uses_longest_exposure_and_flags():
    rng = np.random.default_rng(3)
    img = np.full((32, 32), 1e-6)  # < 1 e⁻ in the longest exposure
    res = merge_hdr(bracket(img, rng), EXPOSURES, darks=OFFSET, saturation_dn=SAT,
                    system_gain_dn_per_e=K, read_noise_dn=READ_E)
    assert res.underexposed.all()
    # Unbiased estimate from the 1 s bracket: mean ≈ 1 e⁻, noise √(1 + 9) e⁻ per pixel.
    assert res.rate.mean() * EXPOSURES[-1] == pytest.approx(1.0, abs=4 * np.sqrt(10 / 1024))


def test_inverse_variance_beats_hat_and_its_variance_is_right():
    rng = np.random.default_rng(5)
    img = np.full((64, 64), 2.0)  # usable in the 1e3 and 1e4 µs brackets
    frames = bracket(img, rng)
    kw = dict(darks=OFFSET, saturation_dn=SAT, system_gain_dn_per_e=K, read_noise_dn=READ_E)
    hat = merge_hdr(frames, EXPOSURES, weighting="hat", **kw)
    ivw = merge_hdr(frames, EXPOSURES, weighting="inverse_variance", **kw)
    assert ivw.rate.std() < hat.rate.std()
    # Predicted variance matches the empirical scatter of a uniform patch within 10 %.
    assert ivw.variance.mean() == pytest.approx(ivw.rate.var(), rel=0.1)
    assert hat.variance.mean() == pytest.approx(hat.rate.var(), rel=0.1)


def test_per_bracket_darks_and_gains():
    rng = np.random.default_rng(8)
    img = np.full((32, 32), 5.0)
    gains = np.array([1.0, 2.0, 1.0])
    t = np.array([100.0, 200.0, 400.0])
    darks = np.stack([np.full((32, 32), OFFSET + 7.0 * i) for i in range(3)])
    frames = np.stack([
        np.rint(K * g * rng.poisson(img * ti) + d).astype(np.uint16)
        for ti, g, d in zip(t, gains, darks, strict=True)
    ])
    res = merge_hdr(frames, t, darks=darks, gains=gains, saturation_dn=SAT)
    assert res.rate.mean() == pytest.approx(5.0 * K, rel=0.01)


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(exposures_us=[1.0, 2.0]),
        dict(exposures_us=[1.0, -2.0, 3.0]),
        dict(exposures_us=[1.0, 2.0, 3.0], weighting="robertson"),
        dict(exposures_us=[1.0, 2.0, 3.0], weighting="inverse_variance"),
        dict(exposures_us=[1.0, 2.0, 3.0], darks=np.zeros((2, 4, 4))),
    ],
)
def test_bad_arguments_raise(kwargs):
    frames = np.zeros((3, 4, 4), dtype=np.uint16)
    with pytest.raises(ValueError):
        merge_hdr(frames, saturation_dn=4000, **kwargs)


@settings(max_examples=60, deadline=None)
@given(
    log_rates=st.lists(st.floats(-3.0, 3.0), min_size=1, max_size=16),
    exposures=st.lists(st.floats(1.0, 1e5), min_size=1, max_size=5, unique=True),
    gains=st.floats(0.5, 4.0),
    weighting=st.sampled_from(["hat", "inverse_variance"]),
)
def test_noise_free_linear_frames_are_merged_exactly(log_rates, exposures, gains, weighting):
    """Every bracket of a noise-free linear camera estimates the rate exactly, so any
    weighted mean of them must return it wherever some bracket is usable."""
    rate = 10.0 ** np.array(log_rates)[None, :]  # DN/µs at unit gain
    t = np.array(exposures)
    g = np.full(t.size, gains)
    frames = np.stack([np.minimum(rate * ti * gi + 50.0, 4095.0) for ti, gi in zip(t, g,
                                                                                strict=True)])
    res = merge_hdr(frames, t, darks=50.0, gains=g, saturation_dn=4095.0, weighting=weighting,
                    min_signal_dn=1.0, system_gain_dn_per_e=0.5, read_noise_dn=1.0)
    usable = res.n_used > 0
    np.testing.assert_allclose(res.rate[usable], rate[usable], rtol=1e-9)
    assert np.all(np.isfinite(res.rate)) and np.all(np.isfinite(res.variance))
    # Where no bracket is usable, the flags say why.
    assert np.all(res.saturated | res.underexposed | usable)
