"""The profile's ``[source]`` table: the light's coherence, validated field by field, and
passed to the simulated source."""

from __future__ import annotations

from pathlib import Path

import pytest

from instrument.bench.devices import simulation_config
from instrument.bench.profile import ProfileError, parse_profile

SIM = (Path(__file__).resolve().parents[3] / "instrument" / "bench" / "profiles" / "sim.toml"
       ).read_text(encoding="utf-8")


def test_default_is_incoherent() -> None:
    profile = parse_profile(SIM)
    assert profile.coherence == "incoherent"
    assert simulation_config(profile)[1]["source"]["coherence"] == "incoherent"


def test_laser_reaches_the_simulated_source() -> None:
    profile = parse_profile(SIM + '\n[source]\ncoherence = "laser"\nwavelength_nm = 633.0\n')
    assert profile.coherence == "laser"
    assert profile.source["wavelength_nm"] == 633.0
    config = simulation_config(profile)[1]
    assert config["source"]["coherence"] == "laser"
    # the rest of [simulation.source] is kept
    assert config["source"]["beam_radius_mm"] == 2.0


@pytest.mark.parametrize(("extra", "field", "says"), [
    ('[source]\ncoherence = "partial"\n', "source.coherence", "laser"),
    ("[source]\nwavelength_nm = -1\n", "source.wavelength_nm", "> 0"),
    ("[source]\ncolour = 1\n", "source.colour", "unknown field"),
    ("source = 3\n", "source", "must be a table"),
])
def test_bad_source_names_the_field(extra: str, field: str, says: str) -> None:
    # a top-level key must come before the first table: prepend the one-line case
    text = extra + SIM if not extra.startswith("[") else SIM + "\n" + extra
    with pytest.raises(ProfileError) as err:
        parse_profile(text)
    fields = {e.path: e.message for e in err.value.errors}
    assert field in fields and says in fields[field]


def test_simulated_source_cannot_disagree() -> None:
    text = SIM.replace("[simulation.source]\n", '[simulation.source]\ncoherence = "laser"\n')
    with pytest.raises(ProfileError) as err:
        parse_profile(text)
    assert any(e.path == "simulation.source.coherence" for e in err.value.errors)
