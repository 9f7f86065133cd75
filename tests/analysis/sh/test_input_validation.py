"""Every public function of analysis.sh refuses NaN, inf and out-of-domain arguments with an
SHInputError that names the argument (analysis/sh/validation.py).

The property tests put a NaN or ±inf into any entry of any array argument of a valid call
(the table below), and feed out-of-domain scalars (negative, non-integer or NaN degrees;
negative, NaN or infinite σ, K, s, ...) to the scalar arguments. Sphere-image pixel values
are the documented exception (non-finite pixels mark unusable data and are left out) and
are therefore not in the table; their geometry and every other argument are.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from analysis.sh import consistency as cons
from analysis.sh import convention as conv
from analysis.sh import convolve as cv
from analysis.sh import filters as fl
from analysis.sh import identities as ident
from analysis.sh import inverse as inv
from analysis.sh import legendre as leg
from analysis.sh import sphere_image as si
from analysis.sh import transform as tr
from analysis.sh.validation import SHInputError

L = 3
N = (L + 1) ** 2


def _c(seed: int, n: int = N) -> np.ndarray:
    return np.random.default_rng(seed).standard_normal(n) + 2.0


def _dirs(n: int = 60) -> tuple[np.ndarray, np.ndarray]:
    v = np.random.default_rng(7).standard_normal((n, 3))
    return tr.directions_to_angles(v)


TH, PH = _dirs()
GRID = tr.gl_grid(L)
CAL = cons.calibrate(np.abs(np.random.default_rng(3).standard_normal((40, 4))) * 0.1,
                     false_alarm=0.1)
GEO = si.sphere_geometry((16, 16), center=(7.5, 7.5), radius=6.0, max_view_angle_deg=80.0)
OP = si.image_fit_operator(GEO, lmax=2)

#: (name, function, keyword arguments of a valid call, names of its array arguments)
ARRAY_CASES = [
    ("convert", conv.convert,
     dict(coeffs=_c(1), source=conv.PROJECT_CONVENTION,
          target=conv.SHConvention(kind="complex", condon_shortley=True)), ["coeffs"]),
    ("legendre_order", leg.legendre_order, dict(m=1, lmax=L, theta=TH[:5]), ["theta"]),
    ("legendre_table", leg.legendre_table, dict(lmax=L, theta=TH[:5]), ["theta"]),
    ("sectoral_seeds", leg.sectoral_seeds, dict(sin_theta=np.sin(TH[:5]), mmax=L),
     ["sin_theta"]),
    ("synthesis", tr.synthesis, dict(coeffs=_c(2), grid=GRID), ["coeffs"]),
    ("synthesis/reference", tr.synthesis, dict(coeffs=_c(2), grid=GRID, backend="reference"),
     ["coeffs"]),
    ("analysis", tr.analysis, dict(values=np.ones(GRID.shape), grid=GRID), ["values"]),
    ("directions_to_angles", tr.directions_to_angles,
     dict(directions=np.ones((4, 3))), ["directions"]),
    ("real_sh_matrix", tr.real_sh_matrix, dict(lmax=L, theta=TH, phi=PH), ["theta", "phi"]),
    ("evaluate", tr.evaluate, dict(coeffs=_c(3), theta=TH, phi=PH),
     ["coeffs", "theta", "phi"]),
    ("fit_scattered", tr.fit_scattered,
     dict(values=np.cos(TH), theta=TH, phi=PH, lmax=2, weights=np.ones(TH.size)),
     ["theta", "phi", "weights"]),
    ("scattered_fit_operator", tr.scattered_fit_operator,
     dict(theta=TH, phi=PH, lmax=2, weights=np.ones(TH.size)), ["theta", "phi", "weights"]),
    ("ScatteredFitOperator.apply", OP.apply, dict(values=np.ones(int(GEO.observed.sum()))),
     ["values"]),
    ("band_limit", fl.band_limit, dict(values=np.array([1.0, 0.5, 0.1])), ["values"]),
    ("kernel_energy_fraction", fl.kernel_energy_fraction,
     dict(values=np.array([1.0, 0.5]), total=2.0), ["values"]),
    ("irradiance_9", fl.irradiance_9, dict(lighting=_c(4, 9), normals=np.eye(3)),
     ["lighting", "normals"]),
    ("per_coefficient", cv.per_coefficient, dict(per_band=np.ones(L + 1), lmax=L),
     ["per_band"]),
    ("convolve", cv.convolve, dict(lighting=_c(5), filt=np.ones(L + 1)),
     ["lighting", "filt"]),
    ("band_power", cv.band_power, dict(coeffs=_c(6)), ["coeffs"]),
    ("estimate_coefficient_noise", cv.estimate_coefficient_noise,
     dict(coeffs=_c(7), filt=fl.lambertian_filter(L).values), ["coeffs", "filt"]),
    ("wiener_deconvolve", cv.wiener_deconvolve,
     dict(image_coeffs=_c(8), filt=fl.phong_filter(L, 10.0).values), ["image_coeffs", "filt"]),
    ("wiener_deconvolve/k", cv.wiener_deconvolve,
     dict(image_coeffs=_c(8), filt=np.ones(L + 1), k=np.full(L + 1, 0.1)), ["k"]),
    ("known_lighting", ident.known_lighting, dict(image=_c(9), lighting=_c(10)),
     ["image", "lighting"]),
    ("diffuse_plus_specular", ident.diffuse_plus_specular,
     dict(image=_c(9), lighting=_c(10), irradiance=_c(11)),
     ["image", "lighting", "irradiance"]),
    ("two_objects_one_lighting", ident.two_objects_one_lighting,
     dict(image1=_c(12), image2=_c(13)), ["image1", "image2"]),
    ("one_object_two_lightings", ident.one_object_two_lightings,
     dict(image1=_c(12), image2=_c(13), lighting1=_c(14), lighting2=_c(15)),
     ["image1", "image2", "lighting1", "lighting2"]),
    ("four_images", ident.four_images, dict(b11=_c(1), b12=_c(2), b21=_c(3), b22=_c(4)),
     ["b11", "b12", "b21", "b22"]),
    ("rank_one", ident.rank_one, dict(images=_c(5, 4 * N).reshape(2, 2, N)), ["images"]),
    ("brdf_transfer", ident.brdf_transfer, dict(image1=_c(1), image2=_c(2)),
     ["image1", "image2"]),
    ("lighting_transfer", ident.lighting_transfer, dict(image1=_c(1), image2=_c(2)),
     ["image1", "image2"]),
    ("render_missing_image", ident.render_missing_image,
     dict(b11=_c(1), b12=_c(2), b21=_c(3)), ["b11", "b12", "b21"]),
    ("irradiance_reflected", ident.irradiance_reflected,
     dict(lighting=_c(1, 9), lmax=2, view=np.array([0.0, 0.0, 1.0])), ["lighting", "view"]),
    ("separate_diffuse_specular", ident.separate_diffuse_specular,
     dict(image_normal=_c(1)), ["image_normal"]),
    ("statistic", cons.statistic, dict(z=np.ones(4)), ["z"]),
    ("calibrate", cons.calibrate, dict(consistent_errors=np.random.default_rng(1).random(
        (30, 3)), false_alarm=0.1), ["consistent_errors"]),
    ("threshold_factor", cons.threshold_factor,
     dict(normalised_statistics=np.linspace(0.1, 2.0, 30), false_alarm=0.1),
     ["normalised_statistics"]),
    ("bootstrap_consistent_errors", cons.bootstrap_consistent_errors,
     dict(consistent_model=np.ones(8), noise_sigma=np.full(8, 0.1),
          errors_of=lambda x: x[:2], n_cases=3, rng=np.random.default_rng(0)),
     ["consistent_model", "noise_sigma"]),
    ("check", cons.check, dict(errors=np.full(4, 0.1), calibration=CAL), ["errors"]),
    ("known_lighting_residual", cons.known_lighting_residual,
     dict(values=np.cos(TH), theta=TH, phi=PH, lighting=_c(1)),
     ["values", "theta", "phi", "lighting"]),
    ("sphere_geometry", si.sphere_geometry,
     dict(shape=(8, 8), center=np.array([3.5, 3.5]), radius=3.0,
          intrinsics=np.array([[100.0, 0, 3.5], [0, 100.0, 3.5], [0, 0, 1]])),
     ["center", "intrinsics"]),
    ("sh_to_image", si.sh_to_image, dict(coeffs=_c(1), geometry=GEO), ["coeffs"]),
    ("irradiance_image", si.irradiance_image, dict(lighting=_c(1), geometry=GEO),
     ["lighting"]),
    ("fit_diffuse_phong", inv.fit_diffuse_phong,
     dict(values=np.cos(TH), normal_dirs=(TH, PH), reflected_dirs=(TH, PH),
          lighting=_c(1, 9)), ["values", "lighting"]),
]


def _with_entry(value, index: int, bad: float):
    arr = np.array(value, dtype=float, copy=True)
    arr.reshape(-1)[index % arr.size] = bad
    return arr


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(case=st.sampled_from(ARRAY_CASES), which=st.integers(0, 10),
       index=st.integers(0, 10**6), bad=st.sampled_from([np.nan, np.inf, -np.inf]))
def test_any_non_finite_entry_is_refused_by_name(case, which, index, bad) -> None:
    _name, fn, kwargs, arrays = case
    arg = arrays[which % len(arrays)]
    call = dict(kwargs)
    call[arg] = _with_entry(call[arg], index, bad)
    with pytest.raises(SHInputError) as err:
        fn(**call)
    assert err.value.argument == arg
    assert arg in str(err.value)


@pytest.mark.parametrize("case", ARRAY_CASES, ids=[c[0] for c in ARRAY_CASES])
def test_the_valid_calls_of_the_table_pass(case) -> None:
    _name, fn, kwargs, _arrays = case
    fn(**kwargs)


def test_non_finite_directions_in_a_pair_are_named() -> None:
    bad = TH.copy()
    bad[3] = np.nan
    for arg in ("normal_dirs", "reflected_dirs"):
        call = dict(values=np.cos(TH), normal_dirs=(TH, PH), reflected_dirs=(TH, PH),
                    lighting=_c(1, 9))
        call[arg] = (bad, PH)
        with pytest.raises(SHInputError) as err:
            inv.fit_diffuse_phong(**call)
        assert err.value.argument == arg


# --- out-of-domain scalars ----------------------------------------------------------------

bad_degree = st.one_of(
    st.integers(max_value=-1),
    st.floats(allow_nan=True, allow_infinity=True),
    st.just(True),
)
#: (function, argument, valid keyword arguments) of the degree (L) arguments
DEGREE_CASES = [
    (conv.n_coeffs, "lmax", {}),
    (conv.degrees_orders, "lmax", {}),
    (conv.band_slice, "l", {}),
    (tr.gl_grid, "lmax", {}),
    (fl.lambertian_filter, "lmax", {}),
    (fl.phong_filter, "lmax", dict(s=10.0)),
    (fl.torrance_sparrow_filter, "lmax", dict(sigma=0.1)),
    (leg.gauss_legendre, "n", {}),
    (tr.real_sh_matrix, "lmax", dict(theta=TH, phi=PH)),
    (cv.per_coefficient, "lmax", dict(per_band=np.ones(5))),
    (ident.known_lighting, "lmin", dict(image=_c(1), lighting=_c(2))),
    (ident.separate_diffuse_specular, "lmax_diffuse", dict(image_normal=_c(1))),
    (si.image_fit_operator, "lmax", dict(geometry=GEO)),
]


@settings(max_examples=200, deadline=None)
@given(case=st.sampled_from(DEGREE_CASES), value=bad_degree)
def test_negative_or_non_integer_degrees_are_refused_by_name(case, value) -> None:
    fn, arg, kwargs = case
    with pytest.raises(SHInputError) as err:
        fn(**{arg: value}, **kwargs)
    assert err.value.argument == arg


bad_positive = st.one_of(st.floats(max_value=0.0), st.just(np.nan), st.just(np.inf),
                         st.just(-np.inf))
bad_nonnegative = st.one_of(st.floats(max_value=-1e-300), st.just(np.nan),
                            st.just(np.inf))
#: (function, argument, strategy of bad values, valid keyword arguments)
SCALAR_CASES = [
    (fl.phong_filter, "s", bad_positive, dict(lmax=4)),
    (fl.torrance_sparrow_filter, "sigma", bad_positive, dict(lmax=4)),
    (fl.lambertian_filter, "tol", bad_nonnegative, dict(lmax=4)),
    (cv.wiener_deconvolve, "noise_sigma", bad_nonnegative,
     dict(image_coeffs=_c(1), filt=fl.phong_filter(L, 10.0).values)),
    (cv.wiener_deconvolve, "k", bad_positive,
     dict(image_coeffs=_c(1), filt=fl.phong_filter(L, 10.0).values)),
    (ident.brdf_transfer, "k", bad_nonnegative, dict(image1=_c(1), image2=_c(2))),
    (tr.fit_scattered, "ridge", bad_nonnegative,
     dict(values=np.cos(TH), theta=TH, phi=PH, lmax=2)),
    (cons.calibrate, "false_alarm", st.one_of(st.floats(max_value=0.0),
                                              st.floats(min_value=1.0), st.just(np.nan)),
     dict(consistent_errors=np.random.default_rng(1).random((30, 3)))),
    (cons.scale_threshold, "factor", bad_positive, dict(calibration=CAL)),
    (si.sphere_geometry, "radius", bad_positive, dict(shape=(8, 8), center=(3.5, 3.5))),
    (si.mirror_sphere_lighting, "reflectance", bad_positive,
     dict(image=np.ones((16, 16)), geometry=GEO, lmax=2)),
    (inv.fit_diffuse_phong, "s0", bad_positive,
     dict(values=np.cos(TH), normal_dirs=(TH, PH), reflected_dirs=(TH, PH),
          lighting=_c(1, 9))),
]


@settings(max_examples=300, deadline=None)
@given(data=st.data(), case=st.sampled_from(SCALAR_CASES))
def test_out_of_domain_scalars_are_refused_by_name(data, case) -> None:
    fn, arg, bad, kwargs = case
    value = data.draw(bad)
    with pytest.raises(SHInputError) as err:
        fn(**{arg: value}, **kwargs)
    assert err.value.argument == arg


# --- the reported cases ------------------------------------------------------------------


@pytest.mark.parametrize("lmax", [0, 1, 4])
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_wiener_refuses_non_finite_coefficients_at_every_band_limit(lmax, bad) -> None:
    b = _c(1, (lmax + 1) ** 2)
    b[-1] = bad
    with pytest.raises(SHInputError, match="image_coeffs") as err:
        cv.wiener_deconvolve(b, fl.phong_filter(lmax, 20.0).values)
    assert err.value.argument == "image_coeffs"


@pytest.mark.parametrize(("kwargs", "name"), [
    (dict(k=np.nan), "k"), (dict(noise_sigma=np.nan), "noise_sigma"),
    (dict(noise_sigma=-1.0), "noise_sigma"), (dict(k=0.0), "k"),
])
def test_wiener_refuses_nan_or_negative_regularisation(kwargs, name) -> None:
    for lmax in (0, 1, 4):
        with pytest.raises(SHInputError) as err:
            cv.wiener_deconvolve(_c(2, (lmax + 1) ** 2), fl.phong_filter(lmax, 20.0).values,
                                 **kwargs)
        assert err.value.argument == name


def test_filters_refuse_infinite_exponents_and_negative_degrees() -> None:
    with pytest.raises(SHInputError) as err:
        fl.phong_filter(4, np.inf)
    assert err.value.argument == "s"
    with pytest.raises(SHInputError) as err:
        fl.lambertian_filter(-1)
    assert err.value.argument == "lmax"
    assert isinstance(err.value, ValueError)  # callers catching ValueError still do


@pytest.mark.parametrize("s", [5.0, 20.0])
@pytest.mark.parametrize("lmax", [1, 4])
def test_wiener_uses_the_given_noise_sigma(lmax: int, s: float) -> None:
    """Band-limited white lighting (P_L flat) through a Phong filter plus known noise σ:
    the estimate must be the lighting, within the noise σ/A_l per coefficient (5 σ) plus
    the Wiener shrinkage K_l/(A_l² + K_l) with K_l = σ²/P_L(l) ≈ σ² — not zero, as when a
    fitted noise floor replaced the given σ."""
    rng = np.random.default_rng(lmax)
    sigma = 1e-3
    truth = rng.standard_normal((lmax + 1) ** 2)
    a = fl.phong_filter(lmax, s).values
    b = cv.convolve(truth, a) + sigma * rng.standard_normal(truth.size)
    res = cv.wiener_deconvolve(b, a, noise_sigma=sigma)
    assert res.noise_sigma == sigma
    a_c = cv.per_coefficient(a, lmax)
    k_c = cv.per_coefficient(res.k, lmax)
    tol = 5 * sigma / np.abs(a_c) + np.abs(truth) * k_c / (a_c**2 + k_c)
    assert np.all(np.abs(res.coeffs - truth) <= tol), np.abs(res.coeffs - truth) / tol
    # K ≈ σ²/P_L with P_L ≈ 1 (white, unit variance): within a factor 10
    assert np.all((res.k > 0.1 * sigma**2) & (res.k < 10 * sigma**2)), res.k


# --- consistency: no test possible -----------------------------------------------------------


def _cal(errors: np.ndarray):
    return cons.calibrate(errors, false_alarm=0.05)


def test_check_with_no_informative_order_is_no_test() -> None:
    rng = np.random.default_rng(4)
    cal = _cal(rng.random((60, 3)) * 0.1)
    rep = cons.check(np.array([0.9, 0.9, 0.9]), cal, defined=np.zeros(3, dtype=bool))
    assert not rep.testable and not rep.inconsistent
    assert rep.verdict == cons.NO_TEST == "no test possible at this L"
    assert rep.statistic == 0.0 and "undefined" in rep.no_test_reason
    # an order that holds whatever the data (no spread over consistent cases)
    exact = _cal(np.zeros((60, 2)))
    assert cons.check(np.array([0.5, 0.5]), exact).verdict == cons.NO_TEST


def test_check_that_no_error_could_fail_is_no_test() -> None:
    """Consistent data whose errors reach the largest possible error 1 in more than α of
    the cases (noise as large as the signal): the threshold is what e_l = 1 gives, so no
    image could exceed it and 'consistent' would claim nothing."""
    rng = np.random.default_rng(5)
    errors = rng.uniform(0.5, 1.0, (60, 2))
    errors[:10] = 1.0
    cal = _cal(errors)
    rep = cons.check(np.array([0.7, 0.7]), cal, max_error=1.0)
    assert not rep.testable and rep.verdict == cons.NO_TEST
    assert "largest possible" in rep.no_test_reason
    # without the bound the same check is a test (and passes)
    assert cons.check(np.array([0.7, 0.7]), cal).verdict == "consistent"


def test_check_with_power_gives_a_verdict() -> None:
    rng = np.random.default_rng(6)
    cal = _cal(0.05 + 0.01 * rng.standard_normal((60, 3)))
    ok = cons.check(np.full(3, 0.05), cal, max_error=1.0)
    bad = cons.check(np.array([0.05, 0.5, 0.05]), cal, max_error=1.0)
    assert ok.testable and ok.verdict == "consistent"
    assert bad.testable and bad.verdict == "inconsistent" and bad.inconsistent
