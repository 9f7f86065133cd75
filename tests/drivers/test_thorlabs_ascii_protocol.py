"""Thorlabs keyword protocol: exact request bytes, answer decoding, fuzzing, and the link.

Arbitrary bytes must decode to "not ours" or raise only ProtocolError; a valid answer
after line noise is still found. The link's retry rules are pinned with transcripts:
queries are retried, commands (``ens`` toggles!) never.
"""

from __future__ import annotations

import contextlib

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.errors import ConnectionFailed, DeviceTimeout, ProtocolError, StateError
from drivers.thorlabs_ascii_link import CommandRejected, PromptLink
from drivers.thorlabs_ascii_protocol import (
    COMMAND_ERRORS,
    PROMPT,
    Reply,
    format_request,
    looks_like_reply,
    parse_flag,
    parse_int,
    split_reply,
)
from hw_mocks.transcript import TranscriptSerial

KEYWORDS = ["pos", "pcount", "speed", "ens", "closed", "interlock", "mode", "*idn", "id"]
keywords = st.sampled_from(KEYWORDS)

# --------------------------------------------------------------------------- requests


@pytest.mark.parametrize("args, kwargs, wire", [
    (("pos", 3), {}, b"pos=3\r"),
    (("pos",), {"query": True}, b"pos?\r"),
    (("ens",), {}, b"ens\r"),
    (("*idn",), {"query": True}, b"*idn?\r"),
    (("open", 999999), {}, b"open=999999\r"),
    (("mode", 1), {}, b"mode=1\r"),
])
def test_format_request_exact_bytes(args, kwargs, wire):
    assert format_request(*args, **kwargs) == wire


@pytest.mark.parametrize("args, kwargs, error", [
    (("POS",), {}, ValueError),
    (("pos 3",), {}, ValueError),
    (("pos\r",), {}, ValueError),
    (("",), {}, ValueError),
    (("pos", 3), {"query": True}, ValueError),
    (("pos", 2.5), {}, TypeError),
    (("pos", True), {}, TypeError),
    (("pos", "3"), {}, TypeError),
])
def test_format_request_rejects_bad_arguments(args, kwargs, error):
    with pytest.raises(error):
        format_request(*args, **kwargs)


# --------------------------------------------------------------------------- answers


def test_query_answer_command_answer_and_error_answer():
    reply = split_reply(b"pos?\r3\r> ", b"pos?\r")
    assert reply == Reply(("3",)) and reply.value == "3" and reply.error is None
    reply = split_reply(b"pos=3\r> ", b"pos=3\r")
    assert reply is not None and reply.lines == () and reply.error is None
    reply = split_reply(b"pos=9\rCommand error CMD_ARG_INVALID\n\r> ", b"pos=9\r")
    assert reply is not None and reply.error is not None
    assert reply.error.code == "CMD_ARG_INVALID"
    assert reply.error.meaning == COMMAND_ERRORS["CMD_ARG_INVALID"]
    unknown = split_reply(b"x?\rCommand error CMD_WHATEVER\r> ", b"x?\r")
    assert unknown is not None and unknown.error.meaning == "undocumented error"


def test_noise_before_the_echo_is_skipped_and_foreign_answers_are_not_ours():
    reply = split_reply(b"\x00\x00\xffpos?\r5\r> ", b"pos?\r")
    assert reply is not None and reply.value == "5" and reply.skipped == b"\x00\x00\xff"
    assert split_reply(b"speed?\r1\r> ", b"pos?\r") is None  # a late answer to another query
    assert split_reply(b"> ", b"pos?\r") is None  # a stray prompt
    assert looks_like_reply(b"speed?\r1\r> ") and not looks_like_reply(b"\x07\x80> ")


@pytest.mark.parametrize("chunk", [b"pos?\r3\r", b"pos?\r3\r>", b""])
def test_answer_without_prompt_is_a_protocol_error(chunk):
    with pytest.raises(ProtocolError):
        split_reply(chunk, b"pos?\r")


def test_corrupted_answer_to_our_request_is_a_protocol_error():
    with pytest.raises(ProtocolError):
        split_reply(b"pos?\r3\x85\r> ", b"pos?\r")


def test_value_needs_exactly_one_line():
    with pytest.raises(ProtocolError):
        Reply(()).value  # noqa: B018
    with pytest.raises(ProtocolError):
        Reply(("1", "2")).value  # noqa: B018


@pytest.mark.parametrize("text, low, high, value", [
    ("3", 1, 6, 3), (" 12 ", 1, 12, 12), ("-1", None, None, -1), ("+7", 0, 9, 7),
])
def test_parse_int(text, low, high, value):
    assert parse_int(text, low, high) == value


@pytest.mark.parametrize("text", ["", "3.0", "x", "1e3", "7", "0x1", "1 2", "１"])
def test_parse_int_rejects(text):
    with pytest.raises(ProtocolError):
        parse_int(text, 1, 6)


def test_parse_flag():
    assert parse_flag("1") is True and parse_flag("0") is False
    with pytest.raises(ProtocolError):
        parse_flag("2")


# --------------------------------------------------------------------------- fuzzing


@given(st.binary(max_size=60), keywords, st.booleans())
def test_arbitrary_bytes_decode_or_raise_only_protocol_error(junk, keyword, query):
    request = format_request(keyword, query=query)
    for chunk in (junk, junk + PROMPT, junk + request + junk + PROMPT):
        try:
            reply = split_reply(chunk, request)
        except ProtocolError:
            continue
        if reply is not None:
            assert all(line == line.strip() and line for line in reply.lines)
            with contextlib.suppress(ProtocolError):
                reply.value  # noqa: B018


_printable = st.text(st.characters(min_codepoint=0x21, max_codepoint=0x7E), min_size=1,
                     max_size=20).filter(lambda t: ">" not in t)


@given(st.binary(max_size=30).filter(lambda b: b"> " not in b), keywords, _printable)
def test_a_valid_answer_after_noise_is_still_decoded(noise, keyword, value):
    request = format_request(keyword, query=True)
    reply = split_reply(noise + request + value.encode() + b"\r" + PROMPT, request)
    assert reply is not None and reply.value == value


@given(st.text(max_size=12), st.integers(-5, 20), st.integers(-5, 20))
def test_parse_int_never_raises_anything_but_protocol_error(text, low, high):
    try:
        value = parse_int(text, low, high)
    except ProtocolError:
        return
    assert low <= value <= high and str(value) == str(int(text.strip()))


# --------------------------------------------------------------------------- link


def link_over(steps, **kw) -> tuple[PromptLink, TranscriptSerial]:
    port = TranscriptSerial(steps, baudrate=115200)
    kw.setdefault("reply_timeout", 0.05)
    kw.setdefault("retries", 2)
    return PromptLink(port, device="wheel", **kw), port


def test_query_is_retried_after_silence_and_garbling():
    link, port = link_over([(b"pos?\r", b""), (b"pos?\r", b"pos?\rx\r> "),
                            (b"pos?\r", b"pos?\r4\r> ")])
    assert link.query("pos", lambda t: parse_int(t, 1, 6)) == 4
    port.assert_complete()


def test_query_gives_up_with_typed_error_naming_device_and_command():
    link, port = link_over([(b"pos?\r", b"")] * 3)
    with pytest.raises(DeviceTimeout) as info:
        link.query("pos")
    assert info.value.device == "wheel" and info.value.command == "pos?"
    assert "3 attempts" in str(info.value)
    port.assert_complete()


def test_rejection_is_not_retried_and_carries_the_code():
    link, port = link_over([(b"pcount?\r", b"pcount?\rCommand error CMD_NOT_DEFINED\n\r> ")])
    with pytest.raises(CommandRejected) as info:
        link.query("pcount")
    assert info.value.code == "CMD_NOT_DEFINED" and info.value.command == "pcount?"
    port.assert_complete()


def test_command_is_sent_once_even_when_its_answer_is_lost():
    link, port = link_over([(b"ens\r", b"")])
    with pytest.raises(DeviceTimeout) as info:
        link.command("ens")
    assert info.value.command == "ens"
    port.assert_complete()  # exactly one ens on the wire


def test_command_with_an_unexpected_answer_line_is_a_protocol_error():
    link, port = link_over([(b"mode=1\r", b"mode=1\r7\r> ")])
    with pytest.raises(ProtocolError):
        link.command("mode", 1)
    port.assert_complete()


def test_stale_answers_are_skipped_and_noise_then_silence_names_the_noise():
    link, port = link_over([
        (b"pos?\r", b"speed?\r1\r> > pos?\r2\r> "),       # stale answer, stray prompt, ours
        (b"ens?\r", b"\x07\x13> "),                       # noise, then silence
    ], retries=2)
    assert link.query("pos") == "2"
    assert link.skipped == 2
    with pytest.raises(ProtocolError) as info:
        link.query("ens", attempts=1)
    assert "noise" in str(info.value) and info.value.command == "ens?"
    port.assert_complete()


def test_resync_ends_a_half_line_and_tolerates_silence():
    link, port = link_over([(b"\r", b"\rCommand error CMD_NOT_DEFINED\n\r> "), (b"\r", b"")])
    assert link.resync().endswith(PROMPT)
    assert link.resync() == b""
    port.assert_complete()


def test_closed_link_refuses_with_state_error():
    link, _ = link_over([])
    link.close()
    link.close()
    with pytest.raises(StateError):
        link.query("pos")


def test_link_arguments_are_validated():
    port = TranscriptSerial([], baudrate=115200)
    with pytest.raises(ValueError):
        PromptLink(port, device="w", reply_timeout=0.0, retries=1)
    with pytest.raises(ValueError):
        PromptLink(port, device="w", reply_timeout=0.1, retries=-1)


def test_abandon_closes_only_a_port_the_link_opened():
    handed = TranscriptSerial([], baudrate=9600)
    link = PromptLink.open(handed, device="s", baudrate=9600, reply_timeout=0.05, retries=0)
    link.abandon()
    assert handed.is_open  # the caller's port stays the caller's
    link = PromptLink.open("simsc10://abandon", device="s", baudrate=9600,
                           reply_timeout=0.05, retries=0)
    port = link._chan("test").port
    link.abandon()
    assert not port.is_open


def test_identify_names_what_answered():
    link, port = link_over([(b"\r", b"\r> "), q_step("*idn", "ACME WHEEL 1.0")])
    with pytest.raises(ConnectionFailed) as info:
        link.identify("*idn", "FW102C/FW212C", r"FW(102|212)C", baudrate=115200)
    assert "ACME WHEEL" in str(info.value) and info.value.command == "*idn?"
    port.assert_complete()


def q_step(keyword: str, value: str) -> tuple[bytes, bytes]:
    request = f"{keyword}?\r".encode()
    return request, request + value.encode() + b"\r> "
