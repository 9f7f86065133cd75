"""A photoelastic modulator in the hidden train: the generator's steady, 1f and 2f parts.

The world's own algebra (Jones matrices, the PEM controller's live drive) against a
numerical time average over one modulation period, and against the analysis's
instrument rows (written independently, ADR 0102)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import special

from analysis.polarimetry.drr import pem_instrument_rows
from hw_mocks import registry
from hw_mocks.clock import ManualClock
from hw_mocks.firmware.pem200 import Pem200Emulator
from hw_mocks.sim.polarisation import HiddenTrain, polariser_mueller, retarder_mueller
from hw_mocks.sim.world import VirtualBench

NM_PER_DRIVE = 1230.0
WAVELENGTH = 633.0
AMPLITUDE = 2.405  # rad: J0 = 0


def train(polariser_deg: float = 0.0, pem_deg: float = 45.0) -> HiddenTrain:
    return HiddenTrain.from_config({
        "source": [
            {"kind": "polariser", "mount": "psg_polariser", "orientation_deg": polariser_deg},
            {"kind": "pem", "orientation_deg": pem_deg, "modulator": "simpem://pem",
             "nm_per_drive": NM_PER_DRIVE}],
        "detector": [{"kind": "polariser", "mount": "psa_polariser"}]})


def drive_for(amplitude_rad: float) -> float:
    return amplitude_rad * WAVELENGTH / (2 * math.pi * NM_PER_DRIVE)


@pytest.mark.parametrize(("polariser_deg", "pem_deg"), [(0.0, 45.0), (45.0, 45.0),
                                                         (20.0, 37.0)])
def test_the_parts_are_the_time_average_and_fourier_terms(polariser_deg, pem_deg):
    state = train(polariser_deg, pem_deg).state(
        lambda role: 0.0, WAVELENGTH, lambda url: (drive_for(AMPLITUDE), 50_000.0))
    assert state.modulation_hz == 50_000.0
    t = np.linspace(0.0, 2 * math.pi, 2048, endpoint=False)
    g_in = polariser_mueller(math.radians(polariser_deg)) @ np.array([1.0, 0, 0, 0])
    g_t = np.array([retarder_mueller(math.radians(pem_deg), AMPLITUDE * math.sin(x)) @ g_in
                    for x in t])
    np.testing.assert_allclose(state.generator, g_t.mean(axis=0), atol=1e-12)
    harmonics = dict(state.harmonics)
    # RMS of a b·sin t term is b/√2, b = 2·mean(g sin t); likewise for cos 2t
    np.testing.assert_allclose(harmonics[1], math.sqrt(2) * (g_t * np.sin(t)[:, None]).mean(0),
                               atol=1e-12)
    np.testing.assert_allclose(harmonics[2],
                               math.sqrt(2) * (g_t * np.cos(2 * t)[:, None]).mean(0),
                               atol=1e-12)


def test_the_parts_agree_with_the_analysis_rows():
    rng = np.random.default_rng(3)
    m = rng.normal(size=(4, 4))
    state = train(0.0, 45.0).state(lambda role: 30.0, WAVELENGTH,
                                   lambda url: (drive_for(AMPLITUDE), 50_000.0))
    harmonics = dict(state.harmonics)
    channels = [state.generator, harmonics[1], harmonics[2]]
    world = [state.analyser @ m @ g for g in channels]
    rows = pem_instrument_rows(state.analyser[None, :], amplitude_rad=AMPLITUDE,
                               polariser_deg=30.0)
    np.testing.assert_allclose(rows @ m.ravel(), world, atol=1e-12)


def test_the_world_reads_the_controller_and_keys_its_drive():
    clock = ManualClock()
    pem = registry.get_or_create(
        "simpem", "pem", lambda name, _o: Pem200Emulator(name, clock=clock))
    world = VirtualBench("pem-world", optics=train())
    dark = world.snapshot()
    assert dict(dark.optics.harmonics)[1] == pytest.approx(np.zeros(4))  # drive 0
    # the drive that makes A = 2.405 rad at the world's own wavelength
    pem.drive = AMPLITUDE * world.source.wavelength_nm / (2 * math.pi * NM_PER_DRIVE)
    lit = world.snapshot()
    assert lit.key != dark.key
    assert lit.optics.modulation_hz == pytest.approx(50_000.0, abs=5.0)
    assert dict(lit.optics.harmonics)[1][3] == pytest.approx(
        math.sqrt(2) * 0.5 * special.jv(1, AMPLITUDE), rel=1e-9)  # √2 J1(A), ½ the source


@pytest.mark.parametrize(("source", "detector", "match"), [
    ([{"kind": "pem", "nm_per_drive": 1.0}], [], "modulator must be"),
    ([{"kind": "pem", "modulator": "simpem://p"}], [], "nm_per_drive > 0"),
    ([], [{"kind": "pem", "modulator": "simpem://p", "nm_per_drive": 1.0}], "source arm"),
    ([{"kind": "pem", "modulator": "simpem://p", "nm_per_drive": 1.0}] * 2, [], "one pem"),
])
def test_a_bad_pem_is_refused_naming_it(source, detector, match):
    with pytest.raises(ValueError, match=match):
        HiddenTrain.from_config({"source": source, "detector": detector})
