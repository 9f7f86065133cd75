"""Pem200 (photoelastic modulator): transcripts, the modulator contract on both transports,
typed errors, faults, and the answer parser fuzzed."""

from __future__ import annotations

import contextlib
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.base import DeviceIdentity, Modulator
from drivers.errors import ConnectionFailed, DeviceTimeout, ProtocolError, StateError
from drivers.hinds_pem import (
    NOTICES_KEPT,
    Pem200,
    PemAnswer,
    PemCommandError,
    PemFault,
    PemOutOfRange,
    parse_answer,
)
from hw_mocks import registry
from hw_mocks.faults import FaultKind
from hw_mocks.firmware.pem200 import Pem200Emulator
from hw_mocks.pty_server import PtyServer
from hw_mocks.transcript import TranscriptSerial
from tests.drivers.fault_checks import unplug_and_replug
from tests.drivers.serial_faults import QUERY_FAULTS, query_survives

NM = 1000.0  # the test head: 1000 nm peak retardation at drive 1
IDN = (b"*IDN?\n", b"[*IDN?](Hinds Instruments,PEM200,1234,2.1.0)\n")


def transcript_pem(steps, **kw) -> tuple[Pem200, TranscriptSerial]:
    port = TranscriptSerial(steps, baudrate=250000)
    kw.setdefault("reply_timeout", 0.05)
    return Pem200(port, name="pem", nm_per_drive=NM, **kw), port


# --------------------------------------------------------------------------- transcripts


def test_identity_retardation_and_frequency_transcript():
    steps = [IDN, (b":MOD:DRV 0.316400\n", b"[:MOD:DRV](0.316400)\n"),
             (b":MOD:DRV?\n", b"[:MOD:DRV?](0.316400)\n"),
             (b":MOD:FREQ?\n", b"[:MOD:FREQ?](50012.500)\n")]
    pem, port = transcript_pem(steps)
    ident = pem.identity
    assert (ident.vendor, ident.model, ident.serial, ident.firmware) == (
        "Hinds Instruments", "PEM200", "1234", "2.1.0")
    pem.retardation_waves = 0.5  # a half-wave at 632.8 nm: 316.4 nm of 1000
    assert pem.retardation_waves == pytest.approx(0.5)
    assert pem.frequency_hz == pytest.approx(50012.5)
    port.assert_complete()


def test_errors_are_typed_and_unsolicited_ones_kept():
    steps = [IDN, (b":MOD:DRV 0.900000\n", b"<RANGE>(:MOD:DRV 0.900000)\n"),
             (b":MOD:FREQ?\n", b"<TEMP>(head temperature high)\n"
                               b"<HWERR>(:MOD:FREQ?: modulator not resonating)\n"),
             (b":MOD:DRV?\n", b"<SCPINOP>(:MOD:DRV?)\n")]
    pem, port = transcript_pem(steps)
    with pytest.raises(PemOutOfRange) as info:
        pem.retardation_waves = 0.9 * NM / 632.8
    assert info.value.code == "RANGE" and info.value.device == "pem"
    with pytest.raises(PemFault) as fault:
        pem.frequency_hz  # noqa: B018
    assert isinstance(fault.value, StateError) and fault.value.command == ":MOD:FREQ?"
    assert list(pem.notices) == [PemAnswer("TEMP", "head temperature high", True)]
    with pytest.raises(PemCommandError) as unknown:
        pem.drive  # noqa: B018
    assert unknown.value.code == "SCPINOP"
    port.assert_complete()


@pytest.mark.parametrize("command, text", [
    (":MOD:DRV?", "nan"), (":MOD:DRV?", "-0.2"), (":MOD:DRV?", "1.5"), (":MOD:DRV?", "inf"),
    (":MOD:FREQ?", "nan"), (":MOD:FREQ?", "0"), (":MOD:FREQ?", "-50000")])
def test_an_answer_outside_its_range_is_a_protocol_error(command, text):
    steps = [IDN, (command.encode() + b"\n", f"[{command}]({text})\n".encode())]
    pem, port = transcript_pem(steps)
    read = {":MOD:DRV?": lambda: pem.drive, ":MOD:FREQ?": lambda: pem.frequency_hz}[command]
    with pytest.raises(ProtocolError) as info:
        read()
    assert info.value.device == "pem" and info.value.command == command
    assert text in str(info.value)
    port.assert_complete()


def test_only_the_latest_unsolicited_errors_are_kept():
    notices = b"".join(f"<TEMP>(warning {i})\n".encode() for i in range(NOTICES_KEPT + 50))
    steps = [IDN, (b":MOD:FREQ?\n", notices + b"[:MOD:FREQ?](50012.500)\n")]
    pem, port = transcript_pem(steps, reply_timeout=5.0)
    assert pem.frequency_hz == pytest.approx(50012.5)
    assert len(pem.notices) == NOTICES_KEPT
    assert pem.notices[-1].text == f"warning {NOTICES_KEPT + 49}"  # newest last
    assert pem.notices[0].text == "warning 50"
    port.assert_complete()


def test_values_outside_the_drive_are_refused_before_sending():
    pem, port = transcript_pem([IDN])
    with pytest.raises(ValueError, match=r"above the controller's 1\.0"):
        pem.retardation_waves = 2.0  # 1265.6 nm > 1000 nm
    for bad in (-0.1, math.nan, math.inf):
        with pytest.raises(ValueError):
            pem.retardation_waves = bad
    with pytest.raises(ValueError):
        pem.wavelength_nm = 0.0
    port.assert_complete()


def test_no_answer_is_connection_failed_and_lost_answers_are_retried():
    port = TranscriptSerial([(b"*IDN?\n", b"")] * 3, baudrate=250000)
    with pytest.raises(ConnectionFailed) as info:
        Pem200(port, name="pem", nm_per_drive=NM, reply_timeout=0.05)
    assert isinstance(info.value.__cause__, DeviceTimeout)
    steps = [IDN, (b":MOD:FREQ?\n", b""), (b":MOD:FREQ?\n", b"\x15garbage\n"),
             (b":MOD:FREQ?\n", b"[:MOD:FREQ?](50000.000)\n")]
    pem, port = transcript_pem(steps)
    assert pem.frequency_hz == 50000.0
    port.assert_complete()


@given(st.binary(max_size=60))
def test_answer_parser_raises_only_protocol_errors(data):
    with contextlib.suppress(ProtocolError):
        answer = parse_answer(data)
        assert isinstance(answer, PemAnswer)


@given(st.text("ABCDEFGHIJKLMNOPQRSTUVWXYZ:*?", min_size=1, max_size=12),
       st.text("0123456789.,e- abcxyz:", max_size=30), st.booleans())
def test_answers_round_trip(identifier, text, error):
    left, right = ("<", ">") if error else ("[", "]")
    line = f"{left}{identifier}{right}({text})\r\n".encode()
    assert parse_answer(line) == PemAnswer(identifier, text, error)


# --------------------------------------------------------------------------- emulator


def open_pem(transport: str, name: str, cleanup: list, **kw) -> Pem200:
    if transport == "url":
        pem = Pem200(f"simpem://{name}", name=name, nm_per_drive=NM, **kw)
    else:
        emulator = registry.get_or_create("simpem", name, lambda n, o: Pem200Emulator(n))
        server = PtyServer(emulator)
        cleanup.append(server)
        pem = Pem200(server.path, name=name, nm_per_drive=NM, **kw)
    cleanup.append(pem)
    return pem


def emulator_of(pem: Pem200) -> Pem200Emulator:
    emulator = registry.get("simpem", pem.name)
    assert isinstance(emulator, Pem200Emulator)
    return emulator


class TestModulatorContract:
    """What every Modulator owes its user, against the emulator on both transports."""

    @pytest.fixture
    def pem(self, transport, cleanup, request):
        name = "".join(c for c in request.node.name if c.isalnum())[-40:]
        registry.remove("simpem", name)  # a fresh controller for every test
        return open_pem(transport, name, cleanup)

    def test_is_a_modulator_with_identity(self, pem):
        assert isinstance(pem, Modulator) and isinstance(pem.identity, DeviceIdentity)
        assert pem.identity.model and pem.identity.serial

    @pytest.mark.parametrize("waves", [0.0, 0.25, 0.383, 0.5])
    def test_retardation_round_trips(self, pem, waves):
        pem.retardation_waves = waves
        assert pem.retardation_waves == pytest.approx(waves, abs=1e-5)
        assert pem.retardation_rad == pytest.approx(2 * math.pi * waves, abs=1e-4)

    def test_same_drive_is_fewer_waves_at_a_longer_wavelength(self, pem):
        pem.wavelength_nm = 500.0
        pem.retardation_waves = 0.5
        pem.wavelength_nm = 1000.0
        assert pem.retardation_waves == pytest.approx(0.25, abs=1e-5)

    def test_frequency_is_the_heads_resonance(self, pem):
        assert pem.frequency_hz == pytest.approx(50_000.0, abs=5.0)

    def test_closed_modulator_refuses_and_close_is_idempotent(self, pem):
        pem.close()
        pem.close()
        with pytest.raises(StateError):
            pem.retardation_waves = 0.1
        with pytest.raises(StateError):
            pem.frequency_hz  # noqa: B018


@pytest.fixture
def faulty(transport, cleanup):
    pem = open_pem(transport, f"fpem{transport}", cleanup, reply_timeout=0.1)
    return pem, emulator_of(pem).faults


@pytest.mark.parametrize("kind, params", QUERY_FAULTS)
def test_query_faults_recover(faulty, kind, params):
    pem, faults = faulty
    pem.retardation_waves = 0.25
    query_survives(faults, kind, params, lambda: round(pem.drive, 6), 0.1582)


def test_error_state_is_a_fault_until_reset(faulty):
    pem, faults = faulty
    pem.retardation_waves = 0.5
    faults.schedule(FaultKind.ERROR_STATE, nth=1)
    pem.frequency_hz  # noqa: B018  (the answer that brought the fault)
    with pytest.raises(PemFault) as info:
        pem.frequency_hz  # noqa: B018
    assert info.value.device == pem.name and "not resonating" in str(info.value)
    pem.reset()
    assert pem.drive == 0.0  # *RST leaves the head undriven: nothing modulates unasked
    pem.retardation_waves = 0.5
    assert pem.retardation_waves == pytest.approx(0.5, abs=1e-5)


def test_disconnect_is_typed_and_reopen_finds_same_drive(transport, cleanup):
    pem = open_pem(transport, f"dpem{transport}", cleanup)
    pem.retardation_waves = 0.3
    again = unplug_and_replug(pem, emulator_of(pem).faults, transport, lambda: pem.drive,
                              lambda: open_pem(transport, pem.name, cleanup),
                              command=":MOD:DRV?")
    assert again.retardation_waves == pytest.approx(0.3, abs=1e-5)


# --------------------------------------------------------------------------- profile


def test_profile_opens_a_pem200_and_the_gui_reads_it_as_a_modulator():
    """``driver = "pem200"``: options, settings in order (wavelength, then amplitude) and the
    device kind the bench panel shows it through."""
    from instrument.bench.device_state import kind_of, read_state
    from instrument.bench.devices import open_device
    from instrument.bench.profile import parse_profile

    registry.remove("simpem", "pem")
    text = ('[bench]\nname = "b"\n[devices.pem]\ndriver = "pem200"\n'
            'url = "simpem://pem?frequency=47000"\n'
            'options = { nm_per_drive = 1200.0 }\n'
            'settings = { wavelength_nm = 600.0, retardation_waves = 0.383 }\n')
    spec = parse_profile(text).device("pem")
    with open_device(spec) as pem:
        assert isinstance(pem, Pem200)
        assert pem.drive == pytest.approx(0.383 * 600.0 / 1200.0, abs=1e-6)
        assert kind_of(pem).name == "modulator"
        state = read_state("pem", pem, with_info=True)
        assert state.kind == "modulator" and state.connected
        assert state.info["wavelength_nm"] == 600.0
        assert state.values["frequency_hz"] == pytest.approx(47000.0, abs=5.0)
        assert state.values["retardation_waves"] == pytest.approx(0.383, abs=1e-5)
    with pytest.raises(ConnectionFailed, match="nm_per_drive"):
        open_device(parse_profile(text.replace("nm_per_drive = 1200.0", "baudrate = 9600"))
                    .device("pem"))


@pytest.mark.hardware
def test_real_controller_identity_and_frequency():
    """Opt-in: ``SCATTERLAB_HW_PEM200=/dev/ttyACM0``. Reads only (the drive is unchanged):
    confirms the answer format and the assumed ``:MOD:FREQ?``."""
    import os

    port = os.environ.get("SCATTERLAB_HW_PEM200")
    if not port:
        pytest.skip("set SCATTERLAB_HW_PEM200 to the controller's serial port")
    with Pem200(port, name="hw_pem", nm_per_drive=1000.0) as pem:
        assert pem.identity.model
        assert 0.0 <= pem.drive <= 1.0
        assert 1e3 < pem.frequency_hz < 1e6
