"""USBTMC on pyusb, driven through the emulated device of ``hw_mocks.usb``.

The real pyusb code path runs: ``usb.core.find(backend=…)`` builds ``usb.core.Device``
objects from the emulated descriptors and every transfer goes through pyusb's endpoint
and control-transfer code. Nothing patches ``usb.core``. Byte-exact expectations come
from the USBTMC 1.0 specification's layout (USB-IF, 2003), not from the driver.
"""

from __future__ import annotations

import itertools
import struct
import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.errors import ConnectionFailed, DeviceTimeout, ProtocolError
from drivers.usbtmc import (
    BulkInHeader,
    UsbtmcDevice,
    next_btag,
    pack_dev_dep_msg_out,
    pack_request_dev_dep_msg_in,
    unpack_bulk_in_header,
)
from hw_mocks.faults import FaultKind
from hw_mocks.usb import backend_from_url, get_firmware
from hw_mocks.usb.faults import UsbFaultKind

VID, PID = 0x1313, 0x8072
IDN = "Thorlabs,PM100USB,P2000000,1.7.0"
TIMEOUT_S = 0.15

# Class requests as (bmRequestType, bRequest) pairs (USBTMC 1.0 Table 15).
INITIATE_CLEAR = (0xA1, 5)
CHECK_CLEAR_STATUS = (0xA1, 6)
INITIATE_ABORT_BULK_OUT = (0xA2, 1)
CHECK_ABORT_BULK_OUT_STATUS = (0xA2, 2)
INITIATE_ABORT_BULK_IN = (0xA2, 3)
CHECK_ABORT_BULK_IN_STATUS = (0xA2, 4)
CLEAR_FEATURE_HALT = (0x02, 1)


def open_tmc(url: str = "simusb://tmc?serial=P2000000", **kw) -> UsbtmcDevice:
    kw.setdefault("timeout_s", TIMEOUT_S)
    return UsbtmcDevice(vendor_id=VID, product_id=PID, backend=backend_from_url(url), **kw)


def requests(backend, kind: tuple[int, int]) -> list[tuple[int, int, int, int, int]]:
    return [r for r in backend.control_log if r[:2] == kind]


def headers(backend) -> list[bytes]:
    """The 12-byte header of every bulk-OUT write the device received."""
    return [w[:12] for w in backend.bulk_out_log]


# --------------------------------------------------------------------------- opening

def test_open_detaches_kernel_driver_claims_and_clears():
    backend = backend_from_url("simusb://tmc?serial=P2000000&clear_polls=2")
    assert backend.kernel_driver_active    # Linux bound usbtmc at plug-in
    tmc = UsbtmcDevice(vendor_id=VID, product_id=PID, backend=backend, timeout_s=TIMEOUT_S)
    assert not backend.kernel_driver_active
    assert set(backend.claimed) == {0}
    # INITIATE_CLEAR, CHECK_CLEAR_STATUS until SUCCESS (PENDING twice), then the
    # bulk-OUT halt is cleared: USBTMC 1.0 §4.2.1.6-7.
    tail = [r[:2] for r in backend.control_log[-5:]]
    assert tail == [INITIATE_CLEAR, CHECK_CLEAR_STATUS, CHECK_CLEAR_STATUS,
                    CHECK_CLEAR_STATUS, CLEAR_FEATURE_HALT]
    assert backend.control_log[-1] == (0x02, 1, 0, 0x02, 0)
    assert backend.bulk_out_log == []     # clearing needs no bulk traffic
    assert tmc.serial_number == "P2000000"
    assert (tmc.manufacturer, tmc.product) == ("Thorlabs", "PM100USB")
    assert tmc.capabilities is not None and tmc.capabilities.term_char
    assert tmc.query("*IDN?") == IDN
    tmc.close()
    tmc.close()   # idempotent
    assert backend.claimed == {}
    assert backend.kernel_driver_active   # given back to the kernel driver
    with pytest.raises(ConnectionFailed):
        tmc.query("*IDN?")


def test_clear_on_open_discards_a_stale_response():
    backend = backend_from_url("simusb://tmc?serial=P2000000")
    first = UsbtmcDevice(vendor_id=VID, product_id=PID, backend=backend, timeout_s=TIMEOUT_S)
    first.write("SYST:SENS:IDN?")   # response left unread, as after a crashed session
    first.close()
    second = UsbtmcDevice(vendor_id=VID, product_id=PID, backend=backend, timeout_s=TIMEOUT_S)
    assert second.query("*IDN?") == IDN
    second.close()


def test_open_sets_configuration_of_an_unconfigured_device_without_kernel_driver():
    backend = backend_from_url("simusb://tmc?serial=P2000000&configured=0&kernel=0")
    assert backend.configuration == 0
    with UsbtmcDevice(vendor_id=VID, product_id=PID, backend=backend,
                      timeout_s=TIMEOUT_S) as tmc:
        assert backend.configuration == 1
        assert tmc.query("*IDN?") == IDN
    assert not backend.kernel_driver_active   # nothing was detached, nothing given back


@pytest.mark.parametrize("kw", [{"serial_number": "P9999999"}, {"product_id": 0x8078}])
def test_absent_device_is_connection_failed(kw):
    backend = backend_from_url("simusb://tmc?serial=P2000000")
    args = {"vendor_id": VID, "product_id": PID, **kw}
    with pytest.raises(ConnectionFailed, match="not found"):
        UsbtmcDevice(backend=backend, timeout_s=TIMEOUT_S, **args)


def test_second_host_cannot_claim_and_leaves_nothing_claimed():
    first = open_tmc()
    with pytest.raises(ConnectionFailed, match="claim"):
        open_tmc()
    assert first.query("*IDN?") == IDN
    first.close()


# --------------------------------------------------------------------------- framing

def test_write_and_read_request_bytes_are_exact():
    tmc = open_tmc(max_transfer_size=1024)
    backend = backend_from_url("simusb://tmc")
    assert tmc.query("*IDN?") == IDN
    # Computed by hand from the USBTMC 1.0 bulk header layout.
    assert backend.bulk_out_log[-2] == bytes.fromhex(
        "01 01 FE 00 06 00 00 00 01 00 00 00 2A 49 44 4E 3F 0A 00 00")
    assert backend.bulk_out_log[-1] == bytes.fromhex("02 02 FD 00 00 04 00 00 00 00 00 00")
    assert backend.bulk_in_log[-1][:12] == bytes.fromhex(
        "02 02 FD 00 21 00 00 00 01 00 00 00")
    tmc.close()


@pytest.mark.parametrize("n", range(0, 9))
def test_padding_to_four_bytes_with_zeros(n):
    payload = bytes(range(65, 65 + n))
    transfer = pack_dev_dep_msg_out(7, payload, eom=True)
    assert len(transfer) == 12 + n + (-n % 4)
    assert len(transfer) % 4 == 0
    assert transfer[12:12 + n] == payload
    assert transfer[12 + n:] == b"\0" * (-n % 4)
    assert struct.unpack_from("<I", transfer, 4)[0] == n   # size excludes the padding


def test_long_message_is_chunked_at_wmaxpacketsize_with_eom_last():
    tmc = open_tmc()
    backend = backend_from_url("simusb://tmc")
    firmware = get_firmware("tmc")
    command = "SYST:ERR?" + " " * 141            # 150 characters + newline
    before = len(backend.bulk_out_log)
    tmc.write(command)
    writes = backend.bulk_out_log[before:]
    sizes = [struct.unpack_from("<I", w, 4)[0] for w in writes]
    assert sizes == [64, 64, 23]
    assert [w[8] for w in writes] == [0, 0, 1]   # EOM only on the last transfer
    assert [w[1] for w in writes] == [1, 2, 3]
    assert firmware.commands[-1] == command.strip()
    assert tmc.read() == '+0,"No error"'
    tmc.close()


def test_btags_run_1_to_255_never_zero_and_wrap():
    tmc = open_tmc()
    backend = backend_from_url("simusb://tmc")
    for _ in range(140):                            # 280 transfers: wraps once
        tmc.query("*OPC?")
    tags = [h[1] for h in headers(backend)]
    assert all(1 <= t <= 255 for t in tags)
    assert all(h[2] == (~h[1] & 0xFF) for h in headers(backend))
    assert tags[:3] == [1, 2, 3] and 255 in tags
    assert all(b == next_btag(a) for a, b in itertools.pairwise(tags))
    tmc.close()


@pytest.mark.parametrize("read_size", [None, 16])
def test_multi_packet_multi_transfer_read(read_size):
    # 16-byte packets and 4-byte transfers: every transfer fills its packet exactly,
    # so each ends with a zero-length packet, and the 33-byte reply needs 9 transfers.
    url = "simusb://tmc?serial=P2000000&packet=16"
    tmc = open_tmc(url, max_transfer_size=4, read_size=read_size)
    backend = backend_from_url(url)
    assert tmc.query("*IDN?") == IDN
    transfers = backend.bulk_in_log
    assert len(transfers) == 9
    assert [t[8] & 1 for t in transfers] == [0] * 8 + [1]
    assert tmc.query("SYST:SENS:IDN?") == "S120C,200611301,21-Jun-2024,1,2,289"
    tmc.close()


def test_reply_spanning_many_packets_in_one_transfer():
    url = "simusb://tmc?serial=P2000000&packet=8"
    tmc = open_tmc(url, read_size=8)      # one packet per bulk read
    assert tmc.query("SYST:SENS:IDN?") == "S120C,200611301,21-Jun-2024,1,2,289"
    assert len(backend_from_url(url).bulk_in_log[-1]) == 12 + 36
    tmc.close()


# --------------------------------------------------------------------------- faults

@pytest.mark.parametrize("kind", [FaultKind.DROP, FaultKind.DELAY])
def test_lost_or_late_reply_times_out_aborts_bulk_in_and_resynchronises(kind):
    tmc = open_tmc()
    backend = backend_from_url("simusb://tmc")
    firmware = get_firmware("tmc")
    firmware.faults.schedule(kind, nth=1, delay_s=3 * TIMEOUT_S)
    with pytest.raises(DeviceTimeout):
        tmc.query("SYST:SENS:IDN?")
    aborts = requests(backend, INITIATE_ABORT_BULK_IN)
    assert aborts and aborts[-1][2:] == (headers(backend)[-1][1], 0x81, 2)
    assert requests(backend, CHECK_ABORT_BULK_IN_STATUS)
    time.sleep(4 * TIMEOUT_S)           # the late reply would have arrived by now
    assert tmc.query("*IDN?") == IDN    # and yet the fresh answer comes back
    tmc.close()


def test_read_without_query_times_out_and_device_logs_query_unterminated():
    tmc = open_tmc()
    tmc.write("*CLS")
    with pytest.raises(DeviceTimeout):
        tmc.read()
    assert tmc.query("SYST:ERR?") == '-420,"Query UNTERMINATED"'
    tmc.close()


def test_write_timeout_aborts_bulk_out_and_the_link_recovers():
    tmc = open_tmc()
    backend = backend_from_url("simusb://tmc")
    backend.usb_faults.schedule(UsbFaultKind.WRITE_TIMEOUT, nth=1)
    long_command = "SENS:CORR:WAV 850" + " " * 60   # 78 bytes: a two-packet transfer
    with pytest.raises(DeviceTimeout, match="bulk-OUT"):
        tmc.write(long_command)
    btag = headers(backend)[-1][1]
    kinds = [r[:2] for r in backend.control_log[-3:]]
    assert kinds == [INITIATE_ABORT_BULK_OUT, CHECK_ABORT_BULK_OUT_STATUS, CLEAR_FEATURE_HALT]
    assert backend.control_log[-3][2:] == (btag, 0x02, 2)
    # The half-sent transfer was discarded, so the next message is framed correctly.
    assert tmc.query("*IDN?") == IDN
    assert backend.framing_errors == []
    tmc.close()


def test_stalled_bulk_out_is_protocol_error_and_cleared():
    tmc = open_tmc()
    backend = backend_from_url("simusb://tmc")
    backend.usb_faults.schedule(UsbFaultKind.STALL_OUT, nth=1)
    with pytest.raises(ProtocolError, match="stalled"):
        tmc.write("*CLS")
    assert not backend.out_halted
    assert tmc.query("*IDN?") == IDN
    tmc.close()


def test_device_rejects_a_bad_btag_inverse_by_halting_bulk_out():
    tmc = open_tmc()
    backend = backend_from_url("simusb://tmc")
    bad = bytearray(pack_dev_dep_msg_out(9, b"*CLS\n", eom=True))
    bad[2] ^= 0x01
    tmc.ep_out.write(bytes(bad))
    assert backend.framing_errors and backend.out_halted
    with pytest.raises(ProtocolError):
        tmc.write("*CLS")
    assert tmc.query("*IDN?") == IDN
    tmc.close()


@pytest.mark.parametrize("kind", [FaultKind.GARBAGE, FaultKind.UNSOLICITED])
def test_bytes_before_the_header_are_a_protocol_error(kind):
    tmc = open_tmc()
    get_firmware("tmc").faults.schedule(kind, nth=1, nbytes=3)
    with pytest.raises(ProtocolError):
        tmc.query("*IDN?")
    assert tmc.query("*IDN?") == IDN
    tmc.close()


def test_disconnect_is_connection_failed_and_replug_reconnects():
    tmc = open_tmc()
    get_firmware("tmc").faults.schedule(FaultKind.DISCONNECT, nth=1)
    with pytest.raises(ConnectionFailed, match="vanished") as info:
        tmc.query("*IDN?")
    assert info.value.__cause__.errno == 19           # ENODEV from the backend
    with pytest.raises(ConnectionFailed):
        tmc.write("*CLS")
    tmc.close()                                        # no error on a dead device
    backend = backend_from_url("simusb://tmc")        # plugged back in
    assert backend.kernel_driver_active                # the kernel grabbed it again
    again = UsbtmcDevice(vendor_id=VID, product_id=PID, backend=backend, timeout_s=TIMEOUT_S)
    assert again.query("*IDN?") == IDN
    again.close()


def test_unplugged_device_is_not_found():
    backend = backend_from_url("simusb://tmc?serial=P2000000")
    backend.unplug()
    with pytest.raises(ConnectionFailed, match="not found"):
        UsbtmcDevice(vendor_id=VID, product_id=PID, backend=backend, timeout_s=TIMEOUT_S)


# --------------------------------------------------------------------------- parsers

@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=40))
def test_header_parser_accepts_or_raises_protocol_error_only(data):
    try:
        header = unpack_bulk_in_header(data)
    except ProtocolError:
        return
    assert data[0] == 2 and data[1] != 0 and data[2] == (~data[1] & 0xFF) and data[3] == 0
    assert header.transfer_size == struct.unpack_from("<I", data, 4)[0]


@settings(max_examples=200, deadline=None)
@given(btag=st.integers(1, 255), size=st.integers(0, 2**32 - 1),
       eom=st.booleans(), term=st.booleans())
def test_header_parser_round_trips_a_device_header(btag, size, eom, term):
    attributes = (1 if eom else 0) | (2 if term else 0)
    data = bytes([2, btag, ~btag & 0xFF, 0]) + struct.pack("<IBxxx", size, attributes)
    assert unpack_bulk_in_header(data) == BulkInHeader(btag, size, eom, term)


@settings(max_examples=200, deadline=None)
@given(btag=st.integers(1, 255), payload=st.binary(max_size=70), eom=st.booleans())
def test_out_header_fields(btag, payload, eom):
    transfer = pack_dev_dep_msg_out(btag, payload, eom=eom)
    assert transfer[:4] == bytes([1, btag, ~btag & 0xFF, 0])
    assert transfer[8] == (1 if eom else 0) and transfer[9:12] == b"\0\0\0"
    assert len(transfer) % 4 == 0


@given(st.integers(1, 255), st.integers(1, 2**32 - 1))
def test_request_header_fields(btag, size):
    request = pack_request_dev_dep_msg_in(btag, size)
    assert request == bytes([2, btag, ~btag & 0xFF, 0]) + struct.pack("<I", size) + bytes(4)


@pytest.mark.parametrize("btag", [0, 256, -1])
def test_invalid_btag_is_rejected(btag):
    with pytest.raises(ValueError):
        pack_dev_dep_msg_out(btag, b"", eom=True)


def test_btag_sequence_cycles_through_255_values():
    seen, tag = [], 255
    for _ in range(255):
        tag = next_btag(tag)
        seen.append(tag)
    assert sorted(seen) == list(range(1, 256))
