"""Zaber ASCII codec: exact encoding, decoding of every message type, and fuzzing.

Arbitrary bytes must raise only ProtocolError (never IndexError, UnicodeDecodeError ...),
encoded messages must decode to themselves, and a valid message is still found after
line noise.
"""

from __future__ import annotations

import contextlib

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.errors import ProtocolError
from drivers.zaber_protocol import (
    REJECTION_REASONS,
    WARNING_FLAGS,
    Alert,
    FlagLevel,
    Info,
    Reply,
    checksum,
    encode_command,
    flag_level,
    parse_int,
    parse_message,
    parse_warnings,
    scan_message,
)

# --------------------------------------------------------------------------- encoding


@pytest.mark.parametrize("args, kw, wire", [
    ((1, 1, "move abs 10000"), {}, b"/1 1 move abs 10000\n"),
    ((1, 1, "move rel -500"), {}, b"/1 1 move rel -500\n"),
    ((1, 1), {}, b"/1 1\n"),                                  # status poll
    ((0, 0, "get pos"), {}, b"/0 0 get pos\n"),
    ((12, 3, "home"), {"message_id": 0}, b"/12 3 0 home\n"),
    ((1, 0, "warnings clear"), {"message_id": 99}, b"/1 0 99 warnings clear\n"),
    # checksum: two's complement of the byte sum after '/' (hardware reference §1d example)
    ((1, 1, "move abs 10000"), {"with_checksum": True}, b"/1 1 move abs 10000:40\n"),
    ((2, 0, "get pos"), {"message_id": 7, "with_checksum": True}, b"/2 0 7 get pos:55\n"),
])
def test_encode_command_exact_bytes(args, kw, wire):
    assert encode_command(*args, **kw) == wire


@pytest.mark.parametrize("args, kw, error", [
    ((100, 1, "home"), {}, ValueError),
    ((-1, 1, "home"), {}, ValueError),
    ((1, 10, "home"), {}, ValueError),
    ((True, 1, "home"), {}, TypeError),
    ((1, 1.0, "home"), {}, TypeError),
    ((1, 1, "home"), {"message_id": 100}, ValueError),
    ((1, 1, "home\n/1 1 stop"), {}, ValueError),   # a line end would inject a command
    ((1, 1, "set x:12"), {}, ValueError),          # ':' starts a checksum
    ((1, 1, "a/b"), {}, ValueError),               # '/' starts a command
    ((1, 1, " home"), {}, ValueError),
    ((1, 1, "move  abs 1"), {}, ValueError),
    ((1, 1, "hömé"), {}, ValueError),
])
def test_encode_command_rejects_bad_arguments(args, kw, error):
    with pytest.raises(error):
        encode_command(*args, **kw)


def test_checksum_makes_the_byte_sum_vanish():
    body = b"01 1 OK IDLE -- 0"
    assert (sum(body) + int(checksum(body), 16)) % 256 == 0
    assert checksum(b"") == "00"


# --------------------------------------------------------------------------- decoding


def test_reply_examples_from_the_reference():
    reply = parse_message(b"@01 0 OK IDLE FS 10000\r\n")
    assert reply == Reply(1, 0, None, "OK", "IDLE", "FS", "10000")
    assert not reply.rejected and not reply.busy and reply.reason is None
    reply = parse_message(b"@01 0 OK BUSY FS 0\r\n")
    assert reply.busy
    reply = parse_message(b"@01 1 12 RJ IDLE -- BADCOMMAND\r\n")
    assert reply.rejected and reply.reason == "BADCOMMAND" and reply.message_id == 12
    assert parse_message(b"@01 1 OK IDLE -- 02 FO WR\r\n").data == "02 FO WR"


def test_alert_and_info_examples():
    assert parse_message(b"!01 1 IDLE --\r\n") == Alert(1, 1, "IDLE", "--")
    assert parse_message(b"!02 3 BUSY FS extra\r\n") == Alert(2, 3, "BUSY", "FS", "extra")
    info = parse_message(b"#01 0 Visit www.zaber.com for instruction manuals.\r\n")
    assert info == Info(1, 0, None, "Visit www.zaber.com for instruction manuals.")
    assert parse_message(b"#01 0 05 text\r\n").message_id == 5


def test_checksum_is_verified_and_can_be_required():
    good = b"@01 1 OK IDLE -- 0:8C\r\n"
    assert parse_message(good).checksummed
    with pytest.raises(ProtocolError, match="bad checksum 8D"):
        parse_message(b"@01 1 OK IDLE -- 0:8D\r\n")
    with pytest.raises(ProtocolError, match="missing checksum"):
        parse_message(b"@01 1 OK IDLE -- 0\r\n", require_checksum=True)
    assert parse_message(good, require_checksum=True).data == "0"
    alert = Alert(1, 1, "IDLE", "--").encode(with_checksum=True)
    assert parse_message(alert, require_checksum=True).checksummed


@pytest.mark.parametrize("line, words", [
    (b"@01 1 OK IDLE -- 0", "no CR LF"),
    (b"\r\n", "empty"),
    (b"/1 1 home\r\n", "not '@'"),
    (b"@01 1 OK IDLE -- \x800\r\n", "non-printable"),
    (b"@1 1 OK IDLE -- 0\r\n", "device address"),
    (b"@01 x OK IDLE -- 0\r\n", "axis"),
    (b"@01 1 OX IDLE -- 0\r\n", "reply flag"),
    (b"@01 1 OK IDLY -- 0\r\n", "status"),
    (b"@01 1 OK IDLE X 0\r\n", "warning flag"),
    (b"@01 1 OK IDLE --\r\n", "data missing"),
    (b"@01 1 OK IDLE XY 0\r\n", "is neither"),
    (b"@01 1 123 OK IDLE -- 0\r\n", "message id 123"),
    (b"@01 1 RJ IDLE -- nope\r\n", "reason"),
    (b"!01 1 IDLE\r\n", "malformed alert"),
    (b"#0x 1 hi\r\n", "malformed info"),
])
def test_malformed_messages_name_what_is_wrong(line, words):
    with pytest.raises(ProtocolError, match=words):
        parse_message(line)


def test_scan_skips_garbage_before_the_message():
    assert scan_message(b"\xff\x00@0x !9 @01 1 OK IDLE -- 7\r\n").data == "7"
    assert scan_message(b"junk@01 1 OK IDLE -- 7:85\r\n", require_checksum=True).data == "7"
    with pytest.raises(ProtocolError, match="no message"):
        scan_message(b"\x15\x80~\r\n")
    with pytest.raises(ProtocolError, match="bad checksum"):
        scan_message(b"xx@01 1 OK IDLE -- 7:00\r\n")


def test_data_field_decoders():
    assert parse_int(" -42 ") == -42
    assert parse_warnings("00") == ()
    assert parse_warnings("02 FO WR") == ("FO", "WR")
    for bad in ("", "1.5", "abc", "1e3", "--1", "9" * 19):
        with pytest.raises(ProtocolError):
            parse_int(bad)
    for bad in ("", "x", "01", "01 FO WR", "02 FO", "01 XY", "01 fs"):
        with pytest.raises(ProtocolError):
            parse_warnings(bad)


def test_flag_tables():
    assert flag_level("FS") is FlagLevel.FAULT and flag_level("WR") is FlagLevel.WARNING
    assert flag_level("NI") is FlagLevel.NOTICE and flag_level("--") is FlagLevel.NONE
    with pytest.raises(ProtocolError):
        flag_level("XY")
    assert all(len(f) == 2 and f[0] in "FWN" for f in WARNING_FLAGS)
    assert {"FS", "FO", "FD", "WR", "WH", "WL", "NI"} <= set(WARNING_FLAGS)
    assert {"BADCOMMAND", "BADDATA", "BADAXIS", "DEVICEONLY", "STATUSBUSY",
            "DRIVERDISABLED"} <= set(REJECTION_REASONS)


# --------------------------------------------------------------------------- fuzzing

printable = st.text(st.characters(min_codepoint=0x21, max_codepoint=0x7E), min_size=1,
                    max_size=12).filter(lambda s: ":" not in s)
data_text = st.lists(printable, min_size=1, max_size=4).map(" ".join)
flags = st.sampled_from(["--", *sorted(WARNING_FLAGS)])
ids = st.one_of(st.none(), st.integers(0, 99))

replies = st.builds(
    Reply, st.integers(0, 99), st.integers(0, 9), ids, st.just("OK"),
    st.sampled_from(["BUSY", "IDLE"]), flags, data_text)
rejections = st.builds(
    Reply, st.integers(0, 99), st.integers(0, 9), ids, st.just("RJ"),
    st.sampled_from(["BUSY", "IDLE"]), flags, st.sampled_from(sorted(REJECTION_REASONS)))
alerts = st.builds(Alert, st.integers(0, 99), st.integers(0, 9),
                   st.sampled_from(["BUSY", "IDLE"]), flags,
                   st.one_of(st.just(""), data_text))
infos = st.builds(Info, st.integers(0, 99), st.integers(0, 9), st.none(),
                  data_text.filter(lambda s: not s.split(" ")[0].isdigit()))
messages = st.one_of(replies, rejections, alerts, infos)


@given(messages, st.booleans())
def test_encoded_messages_decode_to_themselves(message, with_checksum):
    wire = message.encode(with_checksum=with_checksum)
    back = parse_message(wire, require_checksum=with_checksum)
    assert back == type(message)(**{**message.__dict__, "checksummed": with_checksum})


@given(st.integers(0, 99), st.integers(0, 9), ids,
       st.one_of(st.just(""), data_text.filter(lambda s: "/" not in s)), st.booleans())
def test_command_round_trips_through_its_own_framing(device, axis, message_id, text, summed):
    wire = encode_command(device, axis, text, message_id=message_id, with_checksum=summed)
    assert wire.startswith(b"/") and wire.endswith(b"\n") and wire.count(b"\n") == 1
    body = wire[1:-1]
    if summed:
        body, given_sum = body[:-3], body[-2:].decode()
        assert given_sum == checksum(body)
    words = body.decode().split(" ")
    assert int(words[0]) == device and int(words[1]) == axis
    if message_id is not None:
        assert int(words[2]) == message_id


@given(st.binary(max_size=80), st.booleans())
def test_arbitrary_bytes_raise_only_protocol_error(data, require):
    for line in (data, data + b"\r\n"):
        for decoder in (parse_message, scan_message):
            with contextlib.suppress(ProtocolError):
                message = decoder(line, require_checksum=require)
                assert isinstance(message, Reply | Alert | Info)


@given(st.text(max_size=30))
def test_arbitrary_data_fields_raise_only_protocol_error(text):
    for decoder in (parse_int, parse_warnings):
        with contextlib.suppress(ProtocolError):
            decoder(text)


def _no_message_start(data: bytes) -> bool:
    return not any(c in data for c in b"@!#")


@settings(max_examples=200)
@given(st.binary(max_size=40).filter(lambda d: b"\r\n" not in d and _no_message_start(d)),
       messages, st.booleans())
def test_valid_message_after_noise_is_found(noise, message, with_checksum):
    wire = message.encode(with_checksum=with_checksum)
    found = scan_message(noise + wire, require_checksum=with_checksum)
    assert found == parse_message(wire)


@given(replies, st.integers(0, 200), st.integers(0, 7))
def test_a_flipped_bit_in_a_checksummed_reply_is_always_caught(reply, where, bit):
    """An 8-bit sum changes with every single-bit flip of the summed bytes; a flip of the
    type character, the ':' or a checksum digit breaks the framing instead."""
    wire = bytearray(reply.encode(with_checksum=True))
    where %= len(wire) - 2  # not the CR LF: that is a framing fault, not a corruption
    wire[where] ^= 1 << bit
    with pytest.raises(ProtocolError):
        parse_message(bytes(wire), require_checksum=True)
