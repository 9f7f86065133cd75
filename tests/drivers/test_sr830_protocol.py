"""SR830 message layer: exact formatting, table values, and fuzzing of every decoder.

Arbitrary text must raise only ProtocolError (never IndexError, ValueError...), and
everything the instrument can say must decode to what it means.
"""

from __future__ import annotations

import contextlib
import itertools
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.errors import ProtocolError
from drivers.sr830_protocol import (
    FILTER_SLOPES_DB,
    SENSITIVITIES_V,
    TIME_CONSTANTS_S,
    EventStatus,
    LiaStatus,
    decode_error_status,
    format_command,
    index_of,
    parse_float,
    parse_floats,
    parse_identity,
    parse_int,
    parse_status_byte,
    reply_text,
)

# --------------------------------------------------------------------------- tables


def test_tables_match_the_manual():
    # p. 5-6: SENS 0 = 2 nV ... 26 = 1 V in 1-2-5 steps; OFLT 0 = 10 us ... 19 = 30 ks.
    assert len(SENSITIVITIES_V) == 27
    assert SENSITIVITIES_V[:3] == (2e-9, 5e-9, 10e-9)
    assert (SENSITIVITIES_V[17], SENSITIVITIES_V[21], SENSITIVITIES_V[26]) == (1e-3, 20e-3, 1.0)
    assert len(TIME_CONSTANTS_S) == 20
    assert (TIME_CONSTANTS_S[0], TIME_CONSTANTS_S[8], TIME_CONSTANTS_S[19]) == (10e-6, 0.1, 30e3)
    assert FILTER_SLOPES_DB == (6, 12, 18, 24)
    ratios = [b / a for a, b in itertools.pairwise(SENSITIVITIES_V)]
    assert all(any(math.isclose(r, q) for q in (2.0, 2.5)) for r in ratios)


# --------------------------------------------------------------------------- formatting


@pytest.mark.parametrize("args, wire", [
    (("*IDN?",), b"*IDN?\n"),
    (("OUTX", 0), b"OUTX 0\n"),
    (("OFLT", 8), b"OFLT 8\n"),
    (("SNAP?", 1, 2, 3, 4), b"SNAP? 1,2,3,4\n"),
    (("*STB?", 1), b"*STB? 1\n"),
    (("FREQ", 137.5), b"FREQ 137.5\n"),
    (("FREQ", 1e-3), b"FREQ 0.001\n"),
    (("PHAS", -12.345678), b"PHAS -12.3457\n"),
])
def test_format_command_exact_bytes(args, wire):
    assert format_command(*args) == wire


@pytest.mark.parametrize("args, error", [
    (("oflt", 1), ValueError),
    (("OFL", 1), ValueError),
    (("OFLTX", 1), ValueError),
    (("OFLT\n;*RST",), ValueError),
    (("OFLT", math.nan), ValueError),
    (("OFLT", True), TypeError),
    (("OFLT", "8"), TypeError),
    (("SNAP?", 1, 2, 3, 4, 5, 6, 7), ValueError),
])
def test_format_command_rejects_bad_arguments(args, error):
    with pytest.raises(error):
        format_command(*args)


@given(st.floats(-1e6, 1e6, allow_nan=False))
def test_float_arguments_round_trip_through_the_reply_parser(x):
    wire = format_command("FREQ", x)
    text = wire.decode("ascii").strip().split(" ", 1)[1]
    assert parse_float(text) == pytest.approx(x, rel=1e-5, abs=1e-300)


# --------------------------------------------------------------------------- decoding


def test_reply_examples_from_the_manual():
    assert reply_text(b"-1.01026\r") == "-1.01026"
    assert parse_float(reply_text(b"-1.01026\r")) == -1.01026
    assert parse_floats("0.951359,0.0253297,1000.00,1.234", 4) == (
        0.951359, 0.0253297, 1000.0, 1.234)
    assert parse_float("-1.234567e-009") == -1.234567e-9
    ident = parse_identity("Stanford_Research_Systems,SR830,s/n00111,ver1.000")
    assert (ident.vendor, ident.model, ident.serial, ident.firmware) == (
        "Stanford_Research_Systems", "SR830", "00111", "1.000")


def test_status_bytes_decode_to_the_manuals_bits():
    lia = LiaStatus(0b1111)
    assert lia.input_overload and lia.filter_overload and lia.output_overload and lia.unlocked
    assert lia.texts == ("input or amplifier overload", "time-constant filter overload",
                         "output overload", "reference unlock")
    assert not LiaStatus(0x70).input_overload and len(LiaStatus(0x70).texts) == 3
    events = EventStatus(0x10 | 0x80)
    assert events.execution_error and events.power_on and not events.command_error
    assert EventStatus(0x20).command_error and EventStatus(0x04).queue_overflow
    assert decode_error_status(0x44) == ("RAM memory test error", "DSP test error")
    assert decode_error_status(0x01) == ("undocumented bit 0",)


@pytest.mark.parametrize("line", [b"1.0", b"1.0\n", b"1\xff\r", b"\x00\r"])
def test_malformed_lines_raise_protocol_error(line):
    with pytest.raises(ProtocolError):
        reply_text(line)


@pytest.mark.parametrize("call", [
    lambda: parse_float("nan"), lambda: parse_float("1e999"), lambda: parse_float("1,2"),
    lambda: parse_float(""), lambda: parse_floats("1,2,3", 4), lambda: parse_floats("", 1),
    lambda: parse_int("27", 0, 26), lambda: parse_int("2.0", 0, 26),
    lambda: parse_status_byte("256"), lambda: parse_identity("SR830"),
    lambda: parse_identity("a,,c,d"),
])
def test_bad_replies_raise_protocol_error(call):
    with pytest.raises(ProtocolError):
        call()


def test_index_of_is_exact_up_to_a_ppm():
    assert index_of(SENSITIVITIES_V, 0.02, "sensitivity") == 21
    assert index_of(TIME_CONSTANTS_S, 0.1 * (1 + 1e-9), "time constant") == 8
    with pytest.raises(ValueError):
        index_of(SENSITIVITIES_V, 0.03, "sensitivity")


# --------------------------------------------------------------------------- fuzzing

_printable = st.text(alphabet=st.characters(min_codepoint=0x20, max_codepoint=0x7E), max_size=40)


@given(st.binary(max_size=60))
def test_reply_text_raises_only_protocol_error(data):
    try:
        text = reply_text(data)
    except ProtocolError:
        return
    assert data.endswith(b"\r") and text == text.strip()


@given(_printable, st.integers(1, 6))
def test_decoders_raise_only_protocol_error(text, count):
    for decode in (parse_float, lambda t: parse_floats(t, count), parse_status_byte,
                   lambda t: parse_int(t, 0, 26), parse_identity):
        with contextlib.suppress(ProtocolError):
            decode(text)


@given(st.lists(st.floats(allow_nan=False, allow_infinity=False, width=32), min_size=4,
                max_size=4))
def test_snapshot_replies_in_any_number_format_decode(values):
    for form in ("{:.6g}", "{:.6e}", "{:+.9f}"):
        text = ",".join(form.format(v) for v in values)
        decoded = parse_floats(text, 4)
        assert decoded == pytest.approx([float(form.format(v)) for v in values])
