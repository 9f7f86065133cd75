"""The planner's κ (and the trade's σ) take the polarisers' ``extinction`` and the source's
``source_dop`` from the profile's ``[optics]``, as the run's W does (ADR 0108's
amendment, ADR 0113): with ε = 0 κ is the ideal polarisers' value, with 1e-2 it is the
κ of the partial polarisers' W (``generator_extinction`` for the source arm)."""

from __future__ import annotations

import math
import re

import pytest

from analysis.polarimetry.drr import (
    condition_number,
    drr_angles,
    generator_extinction,
    instrument_matrix,
)
from analysis.polarimetry.pem import pem_condition_number
from instrument.bench.profile import load_profile, parse_profile
from instrument.plans.polarimetry import conditioning
from instrument.plans.polarimetry_pem import (
    pem_conditioning,
    pem_train,
    plan_settings,
    plan_waves,
)

DRR = {"mode": "drr", "steps": 25, "ratio": 5.0}


def _with_extinction(name: str, eps: float):  # type: ignore[no-untyped-def]
    text = load_profile(name).source_text
    head, sim = text.split("[simulation]", 1)  # the nominal [optics] only
    head = re.sub(r"^extinction = [\deE.+-]+", f"extinction = {eps!r}", head, flags=re.M)
    if "extinction" not in head:  # a polariser without the field: add it
        head = re.sub(r'(kind = "polariser"\nmount = "(psg|psa)_polariser"\n'
                      r"orientation_deg = [-\d.]+\n)", rf"\1extinction = {eps!r}\n", head)
    return parse_profile(head + "[simulation]" + sim, source=f"{name}, ε {eps}")


def _ideal_drr_kappa(dg: float, da: float, **extinction: float) -> float:
    g, a = drr_angles(25, 5.0)
    return condition_number(instrument_matrix(g, a, psg_retardance=math.radians(dg),
                                              psa_retardance=math.radians(da),
                                              **extinction))


def test_drr_kappa_with_zero_extinction_is_the_ideal_polarisers():
    (c,) = conditioning(DRR, _with_extinction("sim-polarimetric", 0.0), [633.0])
    assert c.kappa == _ideal_drr_kappa(c.psg_retardance_deg, c.psa_retardance_deg)


def test_drr_kappa_with_a_leaky_polariser_moves_as_the_partial_polariser_says():
    profile = _with_extinction("sim-polarimetric", 1e-2)
    (c,) = conditioning(DRR, profile, [633.0])
    ideal = _ideal_drr_kappa(c.psg_retardance_deg, c.psa_retardance_deg)
    # the generator's leak lowered by the laser's own polarisation (source_dop 0.98)
    expected = _ideal_drr_kappa(c.psg_retardance_deg, c.psa_retardance_deg,
                                psg_extinction=generator_extinction(1e-2, 0.98),
                                psa_extinction=1e-2)
    assert c.kappa == pytest.approx(expected, rel=1e-12)
    # a partial polariser's modulation depth is (1 − ε)/(1 + ε): κ grows, by about 2ε
    assert 1.005 < c.kappa / ideal < 1.03


@pytest.mark.parametrize("eps", [0.0, 1e-2])
def test_pem_kappa_takes_the_extinction(eps):
    profile = _with_extinction("sim-polarimetric-pem", eps)
    pol = {"mode": "pem", "amplitude_waves": None, "generator_deg": [0.0, 45.0],
           "analyser_deg": [-75.0, -37.5, 37.5, 75.0]}
    (c,) = pem_conditioning(pol, profile, [633.0])
    train = pem_train(profile)
    settings = plan_settings(pol, train)
    amp = 2.0 * math.pi * plan_waves(pol, profile, train)
    ideal = pem_condition_number(settings, amplitude_rad=amp)
    if eps == 0.0:
        assert c.kappa == ideal
    else:  # an unpolarised source: the generator leaks the datasheet's ε
        assert c.kappa == pytest.approx(pem_condition_number(
            settings, amplitude_rad=amp, psg_extinction=eps, psa_extinction=eps),
            rel=1e-12)
        assert c.kappa > ideal
