"""pymeasure's ``SR830`` class, through pyvisa-py's serial backend, against the SR830
emulator on a real pty: an independent client's reading of the same manual.

Every property of the class is read and (where it can be) set and read back; the methods
that talk to the instrument are called and their effect checked. The emulator's clock is
held (:class:`~hw_mocks.clock.ManualClock`), so readings and buffer counts depend on
emulated time only; before time is moved, a query makes sure the emulator has executed the
commands written before it (pymeasure's writes return before the far end reads them).

Quirks of the client (where it differs from the manual, the emulator follows the manual):

- ``channel1``/``channel2`` read ``DDEF? i``, which answers ``j,k`` (display and ratio,
  manual p. 5-9); pymeasure gets the list ``[j, k]`` back instead of the display's name.
- ``get_buffer`` reads the binary ``TRCB?`` reply (no terminator) until the VISA read
  times out, so every call takes one timeout.
- ``buffer_measure`` and a ``fill_buffer``/``wait_for_buffer`` that must wait loop on
  real time until the buffer fills; on a held clock it never does, so they are called
  here only once the points are stored.
- ``harmonic`` accepts 1…19998 (``range(1, 19999)``); the manual allows 19999.
- ``set_scaling(channel, percent, expand)`` sends the expand factor (1, 10, 100) where
  ``OEXP`` takes its index (0, 1, 2): ``expand=1`` gives ×10, ``expand=10`` is refused
  (EXE). ``get_scaling`` maps the index back correctly.
- pymeasure does not send ``OUTX 0``: a unit set to GPIB (the emulator's default) answers
  nothing on RS-232 until the program sends it (the manual asks every program to).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from hw_mocks.clock import ManualClock
from hw_mocks.firmware.sr830 import AUX_IN_STEP_V, Sr830Emulator
from hw_mocks.pty_server import PtyServer
from tests.waiting import wait_for

#: VISA timeout, ms: generous (a loaded machine), and the cost of each get_buffer call.
TIMEOUT_MS = 3000


@pytest.fixture
def pymeasure_srs():
    """pymeasure's SRS classes, imported by the tests that use them: at collection every
    test process would pay the import (0.5 s of CPU), and only one of them runs these."""
    srs = pytest.importorskip("pymeasure.instruments.srs", reason="pymeasure not installed")
    pytest.importorskip("pyvisa_py", reason="pyvisa-py not installed")
    return srs


@pytest.fixture
def bench(pymeasure_srs):
    from pymeasure.adapters import VISAAdapter

    clock = ManualClock()
    emulator = Sr830Emulator("pm", clock=clock, input_noise_v_per_rthz=0.0)
    server = PtyServer(emulator)
    adapter = VISAAdapter(f"ASRL{server.path}::INSTR", visa_library="@py",
                          read_termination="\r", write_termination="\n",
                          timeout=TIMEOUT_MS)
    lockin = pymeasure_srs.SR830(adapter)
    lockin.write("OUTX 0")
    assert lockin.ask("*ESR?") == "128"  # power-on, cleared by the read
    yield lockin, emulator, clock
    adapter.close()
    server.close()


def settle(lockin, clock) -> None:
    clock.advance(100 * lockin.time_constant)  # the query has synchronised the writes




def test_identity_and_status(bench, pymeasure_srs):
    lockin, emulator, _ = bench
    assert lockin.id == "Stanford_Research_Systems,SR830,s/n00111,ver1.07"
    assert int(lockin.lia_status) == 0 and int(lockin.err_status) == 0
    emulator.enter_error_state("6")
    assert lockin.err_status == pymeasure_srs.sr830.ERRStatus.DSP_ERR
    lockin.clear()
    assert lockin.status == "3"  # IFC and SCN: idle, no scan


def test_every_setting_round_trips(bench):
    lockin, _, _ = bench
    cases = {
        "sine_voltage": [0.004, 1.5, 5.0], "frequency": [0.001, 137.5, 102000.0],
        "phase": [-45.5, 0.0, 179.99], "sensitivity": [2e-9, 1e-3, 1.0],
        "time_constant": [10e-6, 0.1, 30.0], "filter_slope": [6, 12, 18, 24],
        "filter_synchronous": [True, False], "harmonic": [2, 19998, 1],
        "input_config": ["A", "A - B", "I (1 MOhm)", "I (100 MOhm)"],
        "input_grounding": ["Ground", "Float"], "input_coupling": ["DC", "AC"],
        "input_notch_config": ["Line", "2 x Line", "Both", "None"],
        "reference_source": ["External", "Internal"],
        "reference_source_trigger": ["POS EDGE", "NEG EDGE", "SINE"],
        "aux_out_1": [-10.5, 0.0], "aux_out_2": [1.234], "aux_out_3": [10.5],
        "aux_out_4": [-0.001], "sample_frequency": [0.0625, 64, 512, None],
        "reserve": ["High Reserve", "Low Noise", "Normal"],
    }
    for name, values in cases.items():
        for value in values:
            if name == "harmonic":
                lockin.frequency = 5.0  # i·f ≤ 102 kHz up to i = 19999
            setattr(lockin, name, value)
            got = getattr(lockin, name)
            if isinstance(value, float):
                assert got == pytest.approx(value, rel=1e-4, abs=1e-9), name
            else:
                assert got == value, name
    assert lockin.ask("*ESR?") == "0"  # nothing was refused


def test_display_channels_follow_the_manuals_ddef_reply(bench):
    lockin, _, _ = bench
    lockin.channel1 = "R"
    lockin.channel2 = "Theta"
    assert lockin.channel1 == [1.0, 0.0]  # pymeasure quirk: the raw "j,k" reply
    assert lockin.channel2 == [1.0, 0.0]
    lockin.channel1 = "Aux In 2"
    assert lockin.ask("DDEF? 1") == "4,0"


def test_readings_snap_aux_and_scaling(bench):
    lockin, emulator, clock = bench
    emulator.set_input(0.2, phase_deg=30.0)
    emulator.aux_inputs_v = [1.0, -2.5, 0.25, 7.0]
    lockin.time_constant = 1e-3
    settle(lockin, clock)
    x, y = 0.2 * math.cos(math.radians(30.0)), 0.2 * math.sin(math.radians(30.0))
    assert lockin.x == pytest.approx(x, rel=1e-5) and lockin.y == pytest.approx(y, rel=1e-5)
    assert lockin.xy == pytest.approx((x, y), rel=1e-5)
    assert lockin.magnitude == pytest.approx(0.2, rel=1e-5)
    assert lockin.theta == pytest.approx(30.0, abs=1e-3)
    assert lockin.snap("X", "Y", "R", "Theta", "Frequency", "CH1") == pytest.approx(
        [x, y, 0.2, 30.0, 1000.0, x], rel=1e-5)
    # the inputs as the 16-bit A/D reads them: within half a step (21 V / 2¹⁶)
    assert [lockin.aux_in_1, lockin.aux_in_2, lockin.aux_in_3, lockin.aux_in_4] == \
        pytest.approx([1.0, -2.5, 0.25, 7.0], abs=AUX_IN_STEP_V / 2)
    lockin.set_scaling("X", 10.0, 1)  # pymeasure quirk: 1 is index 1, ×10
    assert lockin.get_scaling("X") == (10.0, 10)
    lockin.set_scaling("Y", 5.0, 10)  # index 10 does not exist: refused
    assert lockin.ask("*ESR?") == "16" and lockin.get_scaling("Y") == (0.0, 1)
    assert lockin.output_conversion("X")(lockin.x) == pytest.approx(x, rel=1e-5)
    lockin.auto_offset("Y")
    assert lockin.y == pytest.approx(0.0, abs=1e-5)
    lockin.auto_phase()
    assert lockin.phase == pytest.approx(30.0, abs=0.01)


def test_auto_functions_and_range(bench):
    lockin, emulator, clock = bench
    emulator.set_input(3e-3)
    lockin.time_constant = 1e-3
    lockin.sensitivity = 1e-3
    settle(lockin, clock)
    assert lockin.is_out_of_range()  # OUTPT overload latched
    lockin.auto_gain()
    wait_for(emulator.is_busy)
    clock.advance(1.0)  # AGAN keeps the interpreter busy for 10 τ (at least 50 ms)
    assert lockin.sensitivity == pytest.approx(5e-3)  # smallest with R ≤ 80 % of it
    lockin.auto_reserve()
    assert lockin.reserve == "Normal"  # the reserve is not modelled: unchanged
    # quick_range steps the sensitivity up while LIAS bit 2 (output overload) latches,
    # then sets 1.15 × R, truncated up the table: 3.45 mV → 5 mV. The held clock keeps
    # the output constant, so the loop's real sleeps (5 τ) do not matter.
    lockin.sensitivity = 1e-3
    lockin.write("*CLS")
    lockin.magnitude  # noqa: B018 - a query: the overload latches
    lockin.quick_range()
    assert lockin.sensitivity == pytest.approx(5e-3)


def test_setups_reset_and_errors(bench):
    lockin, _, _ = bench
    lockin.harmonic = 3
    lockin.save_setup(2)
    lockin.reset()
    assert lockin.harmonic == 1
    lockin.load_setup(2)
    assert lockin.harmonic == 3
    lockin.write("HARM 99999")  # out of range: refused, EXE latched
    assert lockin.ask("*ESR?") == "16" and lockin.harmonic == 3
    lockin.write("WXYZ")  # unknown: CMD latched, nothing answered
    assert lockin.ask("*ESR?") == "32"


def test_buffer_scan_and_trigger(bench, pymeasure_srs):
    lockin, emulator, clock = bench
    emulator.set_input(0.5)
    lockin.time_constant = 1e-3
    settle(lockin, clock)
    lockin.reset_buffer()
    lockin.sample_frequency = 32
    lockin.start_scan()
    assert lockin.buffer_count == 1  # the first point at the start
    clock.advance(1.0)
    lockin.pause_scan()
    assert lockin.buffer_count == 33  # t = 0, 1/32, … 1 s
    lockin.wait_for_buffer(33)  # already there: returns at once
    ch1, ch2 = lockin.fill_buffer(33)  # get_buffer (binary TRCB?) on both displays
    assert ch1.dtype == np.float32 and ch1.shape == ch2.shape == (33,)
    np.testing.assert_allclose(ch1, 0.5, rtol=1e-6)  # CH1 = X
    np.testing.assert_allclose(ch2, 0.0, atol=1e-9)  # CH2 = Y
    lockin.reset_buffer()
    lockin.sample_frequency = None  # one point per trigger
    lockin.aquireOnTrigger(True)
    for _ in range(4):
        lockin.trigger()
    assert lockin.buffer_count == 4
    assert lockin.lia_status & pymeasure_srs.sr830.LIAStatus.TRIGGER


def test_fast_transfer_start_is_accepted(bench):
    lockin, _, clock = bench
    lockin.sample_frequency = 1
    lockin.start_buffer(fast=True)  # FAST2;STRD: the scan starts 0.5 s later
    assert lockin.buffer_count == 0
    clock.advance(2.6)
    assert lockin.buffer_count == 3
    lockin.pause_buffer()
    lockin.start_buffer(fast=False)
    assert lockin.ask("FAST?") == "0"
