"""SerialChannel: deadlines, typed errors, buffered lines, tolerant RTS."""

from __future__ import annotations

import pytest

from drivers.errors import ConnectionFailed, DeviceTimeout, ProtocolError
from drivers.transport import SerialChannel, open_serial
from hw_mocks.pty_server import PtyServer
from hw_mocks.transcript import TranscriptSerial
from tests.hw_mocks.echo_emulator import EchoEmulator


def channel(steps):
    port = TranscriptSerial(steps, baudrate=9600)
    return SerialChannel(port, device="dev"), port


def test_read_line_keeps_what_follows_the_terminator():
    # Bytes the transcript has already delivered are read at once; the 10 s bounds only a
    # hang, so a descheduled reader cannot miss them. The 0.05 s read expects silence.
    chan, port = channel([(b"q\n", b"first\r\nsecond\r\npart")])
    chan.write(b"q\n", command="q")
    assert chan.read_line(b"\r\n", timeout=10.0, command="q") == b"first\r\n"
    assert chan.read_line(b"\r\n", timeout=10.0, command="q") == b"second\r\n"
    with pytest.raises(DeviceTimeout) as info:
        chan.read_line(b"\r\n", timeout=0.05, command="q")
    assert b"part" in str(info.value).encode() and info.value.device == "dev"
    assert chan.read_exact(4, timeout=10.0, command="q") == b"part"
    port.assert_complete()


def test_discard_input_drops_buffered_leftovers():
    chan, _ = channel([(b"q\n", b"a\r\nstale\r\n")])
    chan.write(b"q\n", command="q")
    assert chan.read_line(b"\r\n", timeout=10.0, command="q") == b"a\r\n"
    assert chan.discard_input() == len(b"stale\r\n")
    assert chan.read_available() == b""


def test_line_noise_without_terminator_is_a_protocol_error():
    chan, _ = channel([(b"q\n", b"x" * 100)])
    chan.write(b"q\n", command="q")
    with pytest.raises(ProtocolError):
        chan.read_line(b"\r\n", timeout=10.0, command="q", max_bytes=50)


def test_read_exact_times_out_with_partial_data_shown():
    chan, _ = channel([(b"q\n", b"ab")])
    chan.write(b"q\n", command="q")
    with pytest.raises(DeviceTimeout, match="2 of 4"):
        chan.read_exact(4, timeout=0.1, command="q")


def test_open_failure_names_device_and_url():
    with pytest.raises(ConnectionFailed) as info:
        open_serial("/dev/does-not-exist", device="arm", baudrate=9600)
    assert info.value.device == "arm" and "/dev/does-not-exist" in str(info.value)


def test_rts_is_tolerated_on_a_pty():
    with PtyServer(EchoEmulator("pty-echo")) as server:
        port = open_serial(server.path, device="echo", baudrate=9600)
        chan = SerialChannel(port, device="echo")
        assert chan.set_rts(True) is False  # a pty refuses modem-control ioctls
        chan.write(b"hi\n", command="hi")
        assert chan.read_line(b"\r\n", timeout=2.0, command="hi") == b"OK hi\r\n"
        chan.close()
        chan.close()
