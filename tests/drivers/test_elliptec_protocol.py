"""The Elliptec message layer: encoding, the reply parser (fuzzed) and the IN decoding."""

from __future__ import annotations

import contextlib

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.elliptec_protocol import (
    ADDRESSES,
    STATUS_CODES,
    Reply,
    encode_command,
    parse_info,
    parse_position,
    parse_reply,
    parse_status,
    parse_velocity,
    pulses_to_hex,
    scan_reply,
    status_text,
)
from drivers.errors import ProtocolError

ELL14_INFO = "0E11400517202317010168" + "00023000"


def test_encode_commands():
    assert encode_command("0", "ma", "00004600") == b"0ma00004600"
    assert encode_command("F", "ho", "1") == b"Fho1"
    assert encode_command("A", "gs") == b"Ags"
    for bad in [("G", "gs", ""), ("0", "zz", ""), ("0", "ma", "4600"), ("0", "ma", "0000460g"),
                ("00", "gs", ""), ("0", "gs", "1")]:
        with pytest.raises(ValueError):
            encode_command(*bad)


@given(st.integers(-(2**31), 2**31 - 1))
def test_pulses_round_trip_through_twos_complement(pulses):
    assert parse_position(pulses_to_hex(pulses)) == pulses


def test_pulses_outside_32_bits_are_refused():
    with pytest.raises(ValueError):
        pulses_to_hex(2**31)
    with pytest.raises(TypeError):
        pulses_to_hex(1.0)  # type: ignore[arg-type]


def test_ell14_info_is_decoded():
    info = parse_info(ELL14_INFO)
    assert (info.module_type, info.serial, info.year, info.firmware, info.hardware) == (
        14, "11400517", "2023", "17", "01")
    assert info.travel == 360 and info.pulses_per_unit == 143360 and info.is_rotary
    assert info.degrees_per_pulse == pytest.approx(360 / 143360)
    for bad in [ELL14_INFO[:-1], "XX" + ELL14_INFO[2:], ELL14_INFO[:2] + "1140051A"
                + ELL14_INFO[10:], ELL14_INFO[:22] + "00000000"]:
        with pytest.raises(ProtocolError):
            parse_info(bad)


def test_status_codes_and_their_meanings():
    assert parse_status("0D") == 13 and status_text(13) == "over current error"
    assert status_text(2) == "mechanical time out" and status_text(0x42) == \
        "undocumented status"
    assert sorted(STATUS_CODES) == list(range(14))
    assert parse_velocity("64") == 100
    with pytest.raises(ProtocolError):
        parse_velocity("65")
    assert parse_velocity("01") == 1
    with pytest.raises(ProtocolError, match=r"1\.\.100"):
        parse_velocity("00")  # a module takes 1..100 % (sv 0 is refused): 0 is no reading


def test_reply_parsing_and_resynchronisation():
    assert parse_reply(b"2PO0000FFFF\r\n") == Reply("2", "PO", "0000FFFF")
    assert scan_reply(b"\xfe\x001x2GS09\r\n") == Reply("2", "GS", "09")
    for bad in [b"2PO0000FFFF", b"2po0000\r\n", b"G PO00\r\n", b"\r\n"]:
        with pytest.raises(ProtocolError):
            parse_reply(bad)


replies = st.builds(Reply, st.sampled_from(ADDRESSES),
                    st.sampled_from(["IN", "GS", "PO", "GV", "GJ", "HO"]),
                    st.text("0123456789ABCDEF", max_size=30))


@given(replies)
def test_every_encoded_reply_parses_back(reply):
    assert parse_reply(reply.encode()) == reply


@given(st.binary(max_size=12), replies)
def test_garbage_before_a_reply_is_skipped_or_refused_typed(junk, reply):
    """Junk in front either resynchronises onto a well-formed reply or fails with
    ProtocolError, never another exception."""
    line = junk.replace(b"\r\n", b"") + reply.encode()
    try:
        got = scan_reply(line)
    except ProtocolError:
        return
    assert got.encode().endswith(b"\r\n") and got.code.isupper()


@settings(max_examples=300)
@given(st.binary(max_size=40))
def test_arbitrary_bytes_raise_only_protocol_errors(data):
    for parse in (parse_reply, scan_reply):
        try:
            reply = parse(data)
        except ProtocolError:
            continue
        assert reply.address in ADDRESSES
    for decode in (parse_position, parse_status, parse_velocity, parse_info):
        with contextlib.suppress(ProtocolError):
            decode(data.decode("latin-1"))
