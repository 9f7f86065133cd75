"""The emulator link carries frames faithfully, and each injected fault does what it says."""

from __future__ import annotations

import threading
import time

import pytest
import serial
from serial.serialutil import SerialException

from hw_mocks import registry
from hw_mocks.faults import FaultKind
from hw_mocks.pty_server import PtyServer
from tests.hw_mocks.echo_emulator import EchoEmulator, EchoSerial
from tests.waiting import wait_for


def open_echo(name="e1", **kw):
    port = EchoSerial(None, baudrate=9600, timeout=0.05, **kw)
    port.port = f"simecho://{name}"
    port.open()
    return port


def test_round_trip_and_shared_instance():
    port = open_echo()
    port.write(b"hello\n")
    assert port.read_until(b"\r\n") == b"OK hello\r\n"
    again = open_echo()
    assert again.emulator is port.emulator is registry.get("simecho", "e1")


def test_wrong_baud_rate_gets_no_answer():
    port = EchoSerial(None, baudrate=115200, timeout=0.02)
    port.port = "simecho://e2"
    port.open()
    port.write(b"x\n")
    assert port.read(10) == b""


def test_drop_then_normal():
    port = open_echo()
    port.emulator.faults.schedule(FaultKind.DROP, nth=1)
    port.write(b"a\n")
    assert port.read(10) == b""
    port.write(b"b\n")
    assert port.read_until(b"\r\n") == b"OK b\r\n"


def test_a_fault_aimed_at_a_reply_counts_only_the_replies_that_contain_its_bytes():
    """``on=``: the second reply that says "b" is lost, however many other replies came."""
    port = open_echo()
    faults = port.emulator.faults
    faults.schedule(FaultKind.DROP, nth=2, on=b"b")
    for line in (b"a", b"b", b"a", b"a", b"xb", b"b"):
        port.write(line + b"\n")
    expected = b"OK a\r\nOK b\r\nOK a\r\nOK a\r\nOK b\r\n"  # "xb" is the one dropped
    assert port.read_until(b"OK b\r\nOK a\r\nOK a\r\nOK b\r\n") == expected
    assert faults.log == [(5, FaultKind.DROP)]


def test_delay_keeps_order_and_arrives_late():
    """A delayed reply arrives no earlier than its delay, and the reply after it waits
    behind it. (Only the lower bound is a fact; how much later a loaded host reads it is
    the machine's business.)"""
    port = open_echo()
    port.emulator.faults.schedule(FaultKind.DELAY, nth=1, delay_s=0.1)
    t0 = time.monotonic()
    port.write(b"a\n")
    port.write(b"b\n")
    port.timeout = 60.0
    assert port.read(len(b"OK a\r\nOK b\r\n")) == b"OK a\r\nOK b\r\n"
    assert time.monotonic() - t0 >= 0.1


def test_a_held_reply_and_those_behind_it_arrive_only_when_released():
    """``hold``: late by construction, however long the host waits or however late it
    looks; released, it arrives first and the wire's order is kept."""
    port = open_echo()
    faults = port.emulator.faults
    release = threading.Event()
    faults.schedule(FaultKind.DELAY, nth=1, hold=release)
    port.write(b"a\n")
    port.write(b"b\n")
    assert port.read(10) == b"" and port.in_waiting == 0
    port.reset_input_buffer()  # drops only what has arrived: nothing
    release.set()
    assert port.in_waiting == len(b"OK a\r\nOK b\r\n")
    port.timeout = 60.0
    assert port.read(len(b"OK a\r\nOK b\r\n")) == b"OK a\r\nOK b\r\n"
    port.write(b"c\n")  # the hold was for one frame
    assert port.read_until(b"\r\n") == b"OK c\r\n"
    assert faults.log == [(1, FaultKind.DELAY)]


def test_a_reply_held_until_the_host_writes_arrives_ahead_of_the_next_reply():
    """``until_host_writes``: a retried query's first reply comes only when the host has
    given up on it and asked again, just ahead of the retry's reply."""
    port = open_echo()
    port.emulator.faults.schedule(FaultKind.DELAY, nth=1, until_host_writes=True)
    port.write(b"a\n")
    assert port.read(10) == b""  # however long the host waits
    port.write(b"a again\n")
    port.timeout = 60.0
    assert port.read_until(b"again\r\n") == b"OK a\r\nOK a again\r\n"


def test_only_a_delay_can_hold_its_frame():
    with pytest.raises(ValueError, match="DELAY"):
        open_echo().emulator.faults.schedule(FaultKind.DROP, nth=1, hold=threading.Event())


def test_a_held_reply_on_a_pty_reaches_the_host_only_when_released():
    """The pty server's thread keeps a held frame back as the in-process link does."""
    emulator = EchoEmulator("pty-held")
    with PtyServer(emulator) as server, serial.Serial(server.path, timeout=0.05) as port:
        release = threading.Event()
        emulator.faults.schedule(FaultKind.DELAY, nth=1, hold=release)
        port.write(b"a\n")
        port.write(b"b\n")
        # both replies made and through the injector (held): none reaches the host
        wait_for(lambda: emulator.faults.frames_seen >= 2, what="the two replies")
        assert port.in_waiting == 0
        release.set()
        port.timeout = 60.0
        assert port.read(len(b"OK a\r\nOK b\r\n")) == b"OK a\r\nOK b\r\n"


def test_split_garbage_corrupt_unsolicited():
    port = open_echo()
    faults = port.emulator.faults
    faults.schedule(FaultKind.SPLIT, nth=1, chunks=3, gap_s=0.005)
    port.timeout = 0.5
    port.write(b"abcdef\n")
    assert port.read(11) == b"OK abcdef\r\n"
    faults.schedule(FaultKind.GARBAGE, nth=1, nbytes=4)
    port.write(b"g\n")
    data = port.read(4 + 6)
    assert data.endswith(b"OK g\r\n") and len(data) == 10
    faults.schedule(FaultKind.CORRUPT, nth=1, nbytes=1)
    port.write(b"hhhh\n")
    corrupted = port.read(9)
    assert corrupted != b"OK hhhh\r\n" and len(corrupted) == 9
    faults.schedule(FaultKind.UNSOLICITED, nth=1)
    port.write(b"u\n")
    assert port.read(8 + 6) == b"!ALERT\r\nOK u\r\n"
    assert [k for _, k in faults.log] == [FaultKind.SPLIT, FaultKind.GARBAGE,
                                          FaultKind.CORRUPT, FaultKind.UNSOLICITED]


def test_disconnect_and_reconnect():
    port = open_echo()
    port.emulator.faults.schedule(FaultKind.DISCONNECT, nth=2)
    port.write(b"1\n")
    assert port.read_until(b"\r\n") == b"OK 1\r\n"
    port.write(b"2\n")
    with pytest.raises(SerialException):
        port.read(1)
    port.close()
    port = open_echo()
    port.write(b"3\n")
    assert port.read_until(b"\r\n") == b"OK 3\r\n"


def test_error_state_and_probabilistic_faults_are_reproducible():
    def run(seed, name):
        port = open_echo(name=f"{name}?seed={seed}")
        port.emulator.faults.randomly(FaultKind.DROP, probability=0.3)
        # An in-process reply has arrived when the write returns (no delay fault), so
        # in_waiting says whether it was dropped without any timeout. A read_until with a
        # short timeout did not: descheduled mid-line on a loaded box, it returned half a
        # reply and the next read took the rest, shifting every later answer.
        port.timeout = 5.0
        got = []
        for i in range(40):
            port.write(b"%d\n" % i)
            arrived = port.in_waiting > 0
            if arrived:
                assert port.read_until(b"\r\n") == b"OK %d\r\n" % i
            got.append(arrived)
        return got

    first = run(7, "a")
    assert first == run(7, "b")
    assert first != run(8, "c")
    assert 0 < sum(not g for g in first) < 40
    port = open_echo(name="err")
    port.emulator.faults.schedule(FaultKind.ERROR_STATE, nth=1, code="X")
    port.write(b"a\n")
    port.read_until(b"\r\n")
    port.write(b"b\n")
    assert port.read_until(b"\r\n") == b"ERR b\r\n"
