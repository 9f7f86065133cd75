"""SMC100 codec: exact formatting, table decoding, and fuzzing of every decoder.

Arbitrary bytes must raise only ProtocolError (never IndexError, UnicodeDecodeError...),
and a valid reply is still decoded after line noise.
"""

from __future__ import annotations

import contextlib
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.errors import DeviceTimeout, ProtocolError
from drivers.newport_smc100 import Smc100Axis
from drivers.smc100_protocol import (
    COMMAND_ERRORS,
    POSITIONER_ERRORS,
    STATE_TABLE,
    Phase,
    format_command,
    format_number,
    match_reply,
    parse_error_code,
    parse_number,
    parse_status,
)
from hw_mocks.transcript import TranscriptSerial

COMMANDS = ["TP", "TS", "TE", "TH", "VA", "AC", "ID", "VE", "SL", "SR"]
addresses = st.integers(1, 31)
commands = st.sampled_from(COMMANDS)


# --------------------------------------------------------------------------- formatting


@pytest.mark.parametrize("args, wire", [
    ((1, "TS"), b"1TS\r\n"),
    ((12, "TS"), b"12TS\r\n"),
    ((1, "PA", 45.0), b"1PA45\r\n"),
    ((1, "PA", 45.5), b"1PA45.5\r\n"),
    ((1, "PR", -1.5), b"1PR-1.5\r\n"),
    ((3, "VA", "?"), b"3VA?\r\n"),
    ((1, "MM", "0"), b"1MM0\r\n"),
    ((31, "PA", 1e-7), b"31PA0\r\n"),
    ((1, "PA", -0.0), b"1PA0\r\n"),
    ((1, "PA", 123456.1234567), b"1PA123456.123457\r\n"),
])
def test_format_command_exact_bytes(args, wire):
    assert format_command(*args) == wire


@pytest.mark.parametrize("args, error", [
    ((0, "TS"), ValueError),
    ((32, "TS"), ValueError),
    ((True, "TS"), TypeError),
    ((1, "ts"), ValueError),
    ((1, "TSX"), ValueError),
    ((1, "PA", math.nan), ValueError),
    ((1, "PA", math.inf), ValueError),
    ((1, "PA", "1 2"), ValueError),
    ((1, "PA", "1\r\n2PA3"), ValueError),
])
def test_format_command_rejects_bad_arguments(args, error):
    with pytest.raises(error):
        format_command(*args)


@given(st.floats(-1e6, 1e6, allow_nan=False))
def test_format_number_round_trips_to_a_micro_unit_without_exponent(x):
    text = format_number(x)
    assert "e" not in text.lower()
    assert abs(float(text) - x) <= 5e-7 + 1e-12 * abs(x)
    assert parse_number(text) == float(text)


# --------------------------------------------------------------------------- decoding


def test_reply_examples_from_the_reference():
    assert match_reply(b"1TS000033\r\n", 1, "TS") == "000033"
    assert match_reply(b"1TE@\r\n", 1, "TE") == "@"
    assert match_reply(b"1TP10.500000\r\n", 1, "TP") == "10.500000"
    assert match_reply(b"12TS00000A\r\n", 12, "TS") == "00000A"
    assert match_reply(b"1VE CONEX-CC 2.0.1\r\n", 1, "VE") == "CONEX-CC 2.0.1"


def test_other_command_other_address_and_noise_are_not_ours():
    assert match_reply(b"1TP10.5\r\n", 1, "TS") is None     # stale reply
    assert match_reply(b"2TS000033\r\n", 1, "TS") is None   # neighbour
    assert match_reply(b"12TS000033\r\n", 2, "TS") is None  # "12" is not "2"
    assert match_reply(b"11TS000033\r\n", 1, "TS") is None
    assert match_reply(b"\x00\xff\r\n", 1, "TS") is None


def test_malformed_lines_raise_protocol_error():
    with pytest.raises(ProtocolError):
        match_reply(b"1TS000033", 1, "TS")  # no terminator
    with pytest.raises(ProtocolError):
        match_reply(b"1TS00\xff033\r\n", 1, "TS")  # our echo, corrupted value


def test_status_decoding_and_tables():
    status = parse_status("000032")
    assert status.phase is Phase.READY and status.is_referenced and status.is_enabled
    assert not status.is_moving and status.errors == ()
    status = parse_status("02013D")
    assert status.phase is Phase.DISABLE and not status.is_enabled
    assert status.at_negative_limit and not status.at_positive_limit
    assert status.errors == ("negative end of run", "80 W output power exceeded")
    assert status.fault_errors == ("80 W output power exceeded",)
    assert parse_status("04001E").fault_errors == ("undocumented error bit 0x0400",)
    assert parse_status("00001e").is_homing and parse_status("000028").is_moving
    assert not parse_status("00000A").is_referenced
    assert parse_status("000014").phase is Phase.CONFIGURATION
    # every documented state decodes; every bit has a meaning
    for code in STATE_TABLE:
        assert parse_status(f"0000{code:02X}").state == code
    assert sorted(POSITIONER_ERRORS) == [1 << b for b in range(10)]


def test_error_letters():
    assert parse_error_code("@") is None
    code = parse_error_code("H")
    assert code.letter == "H" and "NOT REFERENCED" in code.meaning
    assert set("ABCDEFGHIJKLMNSUVWX") == set(COMMAND_ERRORS)
    for bad in ("", "@@", "Z", "h", "1"):
        with pytest.raises(ProtocolError):
            parse_error_code(bad)


@pytest.mark.parametrize("bad", ["", "0000", "0000333", "00003G", "0000FF", "-00033"])
def test_bad_status_values(bad):
    with pytest.raises(ProtocolError):
        parse_status(bad)


@pytest.mark.parametrize("bad", ["", "abc", "1.2.3", "nan", "inf", "1e999", "--1", "0x10"])
def test_bad_numbers(bad):
    with pytest.raises(ProtocolError):
        parse_number(bad)


# --------------------------------------------------------------------------- fuzzing


@given(st.binary(max_size=80), addresses, commands)
def test_arbitrary_lines_raise_only_protocol_error(data, address, command):
    for line in (data, data + b"\r\n"):
        try:
            value = match_reply(line, address, command)
        except ProtocolError:
            continue
        if value is None:
            continue
        assert isinstance(value, str)
        for decoder in (parse_number, parse_status, parse_error_code):
            with contextlib.suppress(ProtocolError):
                decoder(value)


@given(st.text(max_size=20))
def test_arbitrary_values_raise_only_protocol_error(text):
    for decoder in (parse_number, parse_status, parse_error_code):
        with contextlib.suppress(ProtocolError):
            decoder(text)


def _noise(data: bytes) -> bool:
    return not (data[-1:].isdigit())


@given(
    st.binary(max_size=40).filter(_noise),
    addresses,
    st.floats(-1e5, 1e5, allow_nan=False),
)
def test_valid_position_after_noise_is_decoded(noise, address, x):
    line = noise + f"{address}TP{x:.6f}\r\n".encode()
    assert parse_number(match_reply(line, address, "TP")) == pytest.approx(x, abs=1e-6)


@given(st.binary(max_size=40).filter(_noise), st.integers(0, 0x3FF),
       st.sampled_from(sorted(STATE_TABLE)))
def test_valid_status_after_noise_is_decoded(noise, bits, state):
    status = parse_status(match_reply(noise + f"7TS{bits:04X}{state:02X}\r\n".encode(), 7,
                                      "TS"))
    assert (status.error_bits, status.state) == (bits, state)


# --------------------------------------------------------------------------- stream level

CONNECT = [
    (b"1TS\r\n", b"1TS000033\r\n"),
    (b"1TE\r\n", b"1TE@\r\n"),
]


@settings(max_examples=60, deadline=None)
@given(st.binary(max_size=60).filter(lambda d: b"1TP" not in d and _noise(d)),
       st.floats(-1e4, 1e4, allow_nan=False))
def test_driver_decodes_reply_after_arbitrary_stream_noise(noise, x):
    """Noise (line ends included) before the reply on the wire is skipped by the driver."""
    reply = noise + f"1TP{x:.6f}\r\n".encode()
    port = TranscriptSerial([*CONNECT, (b"1TP\r\n", reply)], baudrate=57600)
    # The reply is always complete, so the timeout is never reached on a healthy run; it is
    # generous so that a loaded host cannot expire it between two reads of the line.
    axis = Smc100Axis(port, name="fuzz", soft_limits=(-1, 1), reply_timeout=10.0, retries=0)
    assert axis.position == pytest.approx(x, abs=1e-6)
    port.assert_complete()


@settings(max_examples=60, deadline=None)
@given(st.binary(max_size=60))
def test_driver_arbitrary_reply_is_value_or_typed_error(reply):
    port = TranscriptSerial([*CONNECT, (b"1TP\r\n", reply)], baudrate=57600)
    axis = Smc100Axis(port, name="fuzz", soft_limits=(-1, 1), reply_timeout=0.01, retries=0)
    try:
        value = axis.position
    except (ProtocolError, DeviceTimeout) as err:
        assert err.device == "fuzz" and err.command == "1TP"
    else:
        assert math.isfinite(value)
