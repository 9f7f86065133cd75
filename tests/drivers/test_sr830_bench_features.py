"""Sr830LockIn's bench features beyond the LockIn contract: harmonic detection, the
reference trigger, the input configuration and the data buffer for fast scans.

Settings run on both transports (in-process URL and a real pty). The buffer tests hold the
emulator's clock (:class:`~hw_mocks.clock.ManualClock`) so that the number of points
stored depends on emulated time only, never on how fast the machine is.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.stanford_sr830 import CommandRejected, Sr830Input, Sr830LockIn
from hw_mocks.clock import ManualClock
from hw_mocks.firmware.sr830 import InputSignal, Sr830Emulator
from hw_mocks.pty_server import PtyServer
from tests.drivers.test_stanford_sr830 import emulator_of, open_lockin


@pytest.fixture
def lockin(transport, servers):
    lockin = open_lockin(transport, f"bench-{transport}", cleanup=servers)
    yield lockin
    lockin.close()


@pytest.fixture
def held():
    """A lock-in on a pty whose emulator's time moves only when the test says so."""
    clock = ManualClock()
    emulator = Sr830Emulator("held", clock=clock, output_interface=0,
                             input_noise_v_per_rthz=0.0)
    server = PtyServer(emulator)
    lockin = Sr830LockIn(server.path, name="held", reply_timeout=2.0)
    yield lockin, emulator, clock
    lockin.close()
    server.close()


def test_harmonic_round_trip_and_limits(lockin):
    assert lockin.harmonic == 1
    lockin.harmonic = 2
    assert lockin.harmonic == 2
    lockin.reference_frequency_hz  # noqa: B018 - the frequency is unchanged by HARM
    for bad in (0, 20000, 1.5, True, "2"):
        with pytest.raises(ValueError):
            lockin.harmonic = bad
    # 1 kHz × 200 = 200 kHz > 102 kHz: the SR830 refuses it and keeps the old value.
    with pytest.raises(CommandRejected) as info:
        lockin.harmonic = 200
    assert info.value.device == lockin.name and info.value.command == "HARM 200"
    assert lockin.harmonic == 2


def test_second_harmonic_reads_the_2f_component(lockin):
    emulator = emulator_of(lockin)
    emulator.input_signal = lambda: InputSignal(
        ac_rms_v=4e-3, phase_deg=10.0, harmonics=((2, 1.5e-3, -30.0),))
    lockin.sensitivity_v = 0.01
    lockin.time_constant_s = 1e-3
    lockin.harmonic = 2
    lockin.settle()
    reading = lockin.snapshot()
    # 2f only: 1.5 mV rms at −30°; the 1f part averages away. Noise: 10 nV/√Hz × √ENBW
    # (125 Hz at 1 ms, 12 dB/oct) ≈ 0.1 µV, far inside 1 %.
    assert reading.r_v == pytest.approx(1.5e-3, rel=0.01)
    assert reading.theta_deg == pytest.approx(-30.0, abs=0.5)
    lockin.harmonic = 1
    lockin.settle()
    assert lockin.snapshot().r_v == pytest.approx(4e-3, rel=0.01)


def test_reference_slope_round_trip(lockin):
    assert lockin.reference_slope == "sine"
    for slope in ("rising", "falling", "sine"):
        lockin.reference_slope = slope
        assert lockin.reference_slope == slope
    with pytest.raises(ValueError):
        lockin.reference_slope = "up"


def test_input_configuration_round_trip(lockin):
    assert lockin.input_configuration == Sr830Input("A", False, False, "none")
    got = lockin.configure_input(source="A-B", grounded=True, dc_coupled=True,
                                 line_filters="both")
    assert got == Sr830Input("A-B", True, True, "both")
    assert lockin.configure_input(line_filters="line").line_filters == "line"
    assert lockin.input_configuration.source == "A-B"  # untouched settings stay
    with pytest.raises(ValueError):
        lockin.configure_input(source="B")
    with pytest.raises(TypeError):
        lockin.configure_input(grounded=1)
    assert lockin.input_configuration == Sr830Input("A-B", True, True, "line")


def test_buffer_stores_at_the_sample_rate_on_the_emulated_clock(held):
    lockin, emulator, clock = held
    emulator.set_input(3e-3, phase_deg=60.0)
    lockin.time_constant_s = 1e-3
    clock.advance(1.0)  # settled: 1000 τ
    lockin.start_buffer(64.0)
    clock.advance(2.0)
    lockin.pause_buffer()
    assert lockin.buffer_points() == 129  # t = 0, 1/64, … 2 s
    x = lockin.read_buffer(1)
    y = lockin.read_buffer(2, start=100, count=29)
    assert x.shape == (129,) and y.shape == (29,)
    # Noise-free input, float32 on the wire: X = 3 mV cos 60°, Y = 3 mV sin 60°.
    np.testing.assert_allclose(x, 3e-3 * math.cos(math.radians(60.0)), rtol=1e-6)
    np.testing.assert_allclose(y, 3e-3 * math.sin(math.radians(60.0)), rtol=1e-6)
    clock.advance(5.0)
    assert lockin.buffer_points() == 129  # paused
    with pytest.raises(ValueError):
        lockin.read_buffer(1, start=100, count=30)
    with pytest.raises(ValueError):
        lockin.read_buffer(3)
    with pytest.raises(ValueError):
        lockin.start_buffer(100.0)


def test_buffer_per_trigger_and_long_reads_in_chunks(held):
    lockin, emulator, clock = held
    emulator.set_input(1e-3)
    lockin.time_constant_s = 1e-3
    clock.advance(1.0)
    lockin.start_buffer(None)
    for _ in range(3):
        lockin.trigger()
        clock.advance(0.5)
    assert lockin.buffer_points() == 3
    lockin.start_buffer(512.0, loop=True)  # starts afresh
    clock.advance(4.0)
    lockin.pause_buffer()
    assert lockin.buffer_points() == 2049  # more than one chunk of 1024 points
    x = lockin.read_buffer(1)
    assert x.shape == (2049,)
    np.testing.assert_allclose(x, 1e-3, rtol=1e-6)


def test_read_harmonics_at_1f_and_2f_of_a_pem_on_ref_in(lockin):
    """A photoelastic modulator's frequency on REF IN: one settled reading per harmonic,
    the harmonic restored; the 3f of a 50 kHz head is beyond the SR830's 102 kHz."""
    from drivers.hinds_pem import Pem200
    from hw_mocks import registry

    registry.remove("simpem", f"ref-{lockin.name}")
    pem = Pem200(f"simpem://ref-{lockin.name}", name="pem", nm_per_drive=1000.0)
    try:
        pem.retardation_waves = 0.383  # 2.405 rad, the J0 zero
        emulator = emulator_of(lockin)
        emulator.reference_input_hz = pem.frequency_hz  # the PEM's reference output
        lockin.reference_source = "external"
        assert lockin.reference_frequency_hz == pytest.approx(pem.frequency_hz, rel=1e-4)
        emulator.input_signal = lambda: InputSignal(
            ac_rms_v=3e-3, phase_deg=0.0, harmonics=((2, 1.2e-3, 90.0), (3, 5e-3, 0.0)))
        lockin.sensitivity_v = 0.01
        lockin.time_constant_s = 1e-3
        readings = lockin.read_harmonics((1, 2))
        # noise: 10 nV/√Hz × √(125 Hz) ≈ 0.1 µV, far inside 1 %
        assert readings[1].r_v == pytest.approx(3e-3, rel=0.01)
        assert readings[2].r_v == pytest.approx(1.2e-3, rel=0.01)
        assert readings[2].theta_deg == pytest.approx(90.0, abs=0.5)
        assert lockin.harmonic == 1
        with pytest.raises(CommandRejected) as info:
            lockin.read_harmonics((2, 3))
        assert info.value.command == "HARM 3" and lockin.harmonic == 1
        with pytest.raises(ValueError):
            lockin.read_harmonics(())
    finally:
        pem.close()
