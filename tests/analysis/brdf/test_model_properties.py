"""Property tests: any parameters within bounds, any directions in the closed hemisphere →
finite, non-negative values without floating-point overflow or invalid operations."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from analysis.brdf import available_models, get_model

_MODELS = {n: get_model(n) for n in available_models()}


@st.composite
def model_and_params(draw: st.DrawFn) -> tuple[str, np.ndarray]:
    name = draw(st.sampled_from(sorted(_MODELS)))
    m = _MODELS[name]
    p = []
    for spec in m.params:
        hi = spec.upper if np.isfinite(spec.upper) else spec.lower + 1e3
        if spec.log:
            p.append(float(np.exp(draw(st.floats(np.log(spec.lower), np.log(hi))))))
        else:
            p.append(draw(st.floats(spec.lower, hi)))
    return name, np.array(p)


angle = st.floats(0.0, np.pi / 2)
azimuth = st.floats(-np.pi, np.pi)


@settings(max_examples=300, deadline=None)
@given(model_and_params(), angle, azimuth, angle, azimuth)
def test_finite_nonnegative_anywhere(
    mp: tuple[str, np.ndarray], ti: float, pi_: float, tr: float, pr: float
) -> None:
    name, p = mp
    with np.errstate(over="raise", invalid="raise", divide="raise", under="ignore"):
        f = _MODELS[name].evaluate(p, ti, pi_, tr, pr)
    assert np.isfinite(f) and f >= 0.0, (name, p, f)


@settings(max_examples=100, deadline=None)
@given(model_and_params(), angle, azimuth, angle, azimuth)
def test_jacobian_finite_anywhere(
    mp: tuple[str, np.ndarray], ti: float, pi_: float, tr: float, pr: float
) -> None:
    name, p = mp
    from analysis.brdf.geometry import make_geometry

    j = _MODELS[name].jacobian_geometry(p, make_geometry(ti, pi_, tr, pr))
    assert np.all(np.isfinite(j)), (name, p, j)
