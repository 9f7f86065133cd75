"""Registry names and composite models."""

import numpy as np
import pytest

from analysis.brdf import available_models, get_model, parse_model_list, sum_models
from analysis.brdf.geometry import make_geometry
from analysis.brdf.registry import register_model, unregister_model
from analysis.brdf.specular import cook_torrance


def test_parse_model_list() -> None:
    models = parse_model_list("lambert, lambert+ggx")
    assert [m.name for m in models] == ["lambert", "lambert+ggx"]
    assert models[1].param_names == ("lambert.rho", "ggx.ks", "ggx.alpha")
    assert models[1].has_analytic_jacobian


def test_unknown_model_names_the_known_ones() -> None:
    with pytest.raises(KeyError, match="lambert"):
        get_model("lambert+glossy")
    with pytest.raises(ValueError):
        parse_model_list(" , ")


def test_sum_is_sum_of_parts_and_repeated_parts_get_suffix() -> None:
    m = sum_models(get_model("ggx"), get_model("ggx"))
    assert m.param_names == ("ggx.ks", "ggx.alpha", "ggx2.ks", "ggx2.alpha")
    g = make_geometry(np.radians([10.0, 40.0]), 0.0, np.radians([12.0, 30.0]), np.pi)
    single = get_model("ggx")
    both = m.evaluate_geometry([0.2, 0.1, 0.3, 0.4], g)
    parts = single.evaluate_geometry([0.2, 0.1], g) + single.evaluate_geometry([0.3, 0.4], g)
    np.testing.assert_allclose(both, parts, rtol=1e-14)
    vals = m.component_values([0.2, 0.1, 0.3, 0.4], g)
    assert list(vals) == ["ggx", "ggx2"]


def test_aliases_and_registration() -> None:
    assert get_model("cook_torrance").name == "ggx"
    register_model("ggx_gold", lambda: cook_torrance(n=0.18 + 3.1j, name="ggx_gold"))
    try:
        m = get_model("lambert+ggx_gold")
        assert m.n_params == 3
    finally:
        unregister_model("ggx_gold")
    with pytest.raises(KeyError):
        get_model("ggx_gold")
    with pytest.raises(ValueError):
        register_model("a+b", lambda: get_model("lambert"))
    with pytest.raises(ValueError):
        register_model("ggx", lambda: get_model("lambert"))
    with pytest.raises(ValueError):
        unregister_model("lambert")


def test_wrong_parameter_count_raises() -> None:
    with pytest.raises(ValueError, match="takes 3 parameters"):
        get_model("lambert+ggx").evaluate([0.1, 0.2], 0.1, 0.0, 0.2, np.pi)


@pytest.mark.parametrize("name", available_models())
def test_every_model_documents_parameters_units_and_validity(name: str) -> None:
    m = get_model(name)
    assert m.description and m.validity and m.reference, name
    for p in m.params:
        assert p.unit and p.description, (name, p.name)
    if not m.energy_bounded:
        # the documented exception must be stated where users read it
        assert "energy" in m.validity or "DHR" in m.validity, (name, m.validity)
