"""The Analysis tab's fit options: the same plain options as ``scatterlab fit``'s."""

from __future__ import annotations

import argparse

import pytest

from gui.model.analyses import FitSettings
from instrument.cli.fit import add_fit_options, fit_options


def test_the_gui_options_equal_the_cli_options():
    p = argparse.ArgumentParser()
    add_fit_options(p)
    cli = fit_options(p.parse_args(["--distance-mm", "305", "--distance-u-mm", "0.5",
                                    "--incident-power-u", "0.02", "--models",
                                    "lambertian,lambertian+ggx", "--detector",
                                    "power_meter"]))
    gui = FitSettings(305.0, 0.5, 0.02, ("lambertian", "lambertian+ggx"),
                      "power_meter").options()
    assert gui == cli
    # nothing set: the command line's defaults
    assert FitSettings().options() == fit_options(p.parse_args([]))


@pytest.mark.parametrize(("settings", "control"), [
    (FitSettings(distance_mm=-1.0), "Distance (mm)"),
    (FitSettings(distance_u_mm=float("nan")), "Distance uncertainty (mm)"),
    (FitSettings(incident_power_u=0.0), "Incident power uncertainty"),
    (FitSettings(detector="lockin"), "Detector"),
])
def test_a_bad_value_is_named_by_its_control(settings, control):
    with pytest.raises(ValueError, match=r"^" + control.replace("(", r"\(").replace(")", r"\)")):
        settings.options()
