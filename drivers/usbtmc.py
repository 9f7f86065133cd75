"""USBTMC (USB Test & Measurement Class 1.0) over pyusb endpoints.

A message-based link to an instrument such as the Thorlabs PM100USB, written against the
USB-IF *Universal Serial Bus Test and Measurement Class Specification (USBTMC)*, Revision 1.0, 2003
(cross-checked with
python-usbtmc and pyvisa-py behaviour):

* Every bulk-OUT transfer starts with a 12-byte header
  ``MsgID | bTag | ~bTag | 0x00 | TransferSize (u32 LE) | bmTransferAttributes | 0 0 0``.
  bTag runs 1..255 and never 0; each transfer takes the next one.
* ``write`` sends DEV_DEP_MSG_OUT transfers of at most :attr:`UsbtmcDevice.chunk_size`
  payload bytes (wMaxPacketSize by default, as pyvisa-py does), EOM only on the last,
  each padded with zeros to a multiple of 4 bytes.
* ``read`` sends REQUEST_DEV_DEP_MSG_IN (TransferSize = :attr:`max_transfer_size`) and
  reads bulk-IN until the DEV_DEP_MSG_IN header's TransferSize has arrived; it repeats
  the request until a transfer carries EOM. A reply may span any number of packets and
  of bulk reads.
* Opening detaches a kernel driver that holds the interface (Linux ``usbtmc``), sets the
  configuration if it is not already active, claims the interface and clears the device
  (INITIATE_CLEAR / CHECK_CLEAR_STATUS, then CLEAR_FEATURE(HALT) on bulk-OUT), so stale
  responses from an earlier session cannot be mistaken for replies.
* A timed-out transfer is aborted (INITIATE_ABORT_BULK_IN/OUT, CHECK_ABORT_…_STATUS) so
  that a late reply cannot answer the next query, then :class:`DeviceTimeout` is raised.

Errors (all chain the pyusb exception): timeout → :class:`DeviceTimeout`; ENODEV, EIO or
any other transport failure → :class:`ConnectionFailed`; a malformed or mismatched
header, a stalled endpoint or an overflow → :class:`ProtocolError`.

The pyusb backend is injected (``backend=``, passed to ``usb.core.find``), so the same
code runs on libusb and on the emulated device of ``hw_mocks.usb`` in tests.
"""

from __future__ import annotations

import contextlib
import errno
import struct
import threading
import time
from dataclasses import dataclass
from typing import Any, cast

import usb.core
import usb.util

from drivers.errors import ConnectionFailed, DeviceError, DeviceTimeout, ProtocolError

__all__ = [
    "BulkInHeader",
    "Capabilities",
    "UsbtmcDevice",
    "next_btag",
    "pack_dev_dep_msg_out",
    "pack_request_dev_dep_msg_in",
    "unpack_bulk_in_header",
]

HEADER_SIZE = 12

# USBTMC 1.0 Table 2 (MsgID), Table 15 (bRequest), Table 16 (USBTMC_status).
DEV_DEP_MSG_OUT = 1
REQUEST_DEV_DEP_MSG_IN = 2
DEV_DEP_MSG_IN = 2
INITIATE_ABORT_BULK_OUT = 1
CHECK_ABORT_BULK_OUT_STATUS = 2
INITIATE_ABORT_BULK_IN = 3
CHECK_ABORT_BULK_IN_STATUS = 4
INITIATE_CLEAR = 5
CHECK_CLEAR_STATUS = 6
GET_CAPABILITIES = 7
STATUS_SUCCESS = 0x01
STATUS_PENDING = 0x02

_USBTMC_CLASS, _USBTMC_SUBCLASS = 0xFE, 0x03
# Class requests to the interface (0xA1) and to an endpoint (0xA2), device-to-host.
_REQ_INTERFACE = usb.util.build_request_type(
    usb.util.CTRL_IN, usb.util.CTRL_TYPE_CLASS, usb.util.CTRL_RECIPIENT_INTERFACE)
_REQ_ENDPOINT = usb.util.build_request_type(
    usb.util.CTRL_IN, usb.util.CTRL_TYPE_CLASS, usb.util.CTRL_RECIPIENT_ENDPOINT)
# errno values (and libusb codes) meaning the device is gone, not merely busy.
_GONE_ERRNOS = {errno.ENODEV, errno.ENXIO, errno.ESHUTDOWN, errno.EIO}
_GONE_LIBUSB = {-4, -1}   # LIBUSB_ERROR_NO_DEVICE, LIBUSB_ERROR_IO
_POLL_S = 0.001


# --------------------------------------------------------------------------- framing

def next_btag(btag: int) -> int:
    """The bTag after ``btag``: 1, 2, …, 255, 1, … (0 is never used)."""
    return btag % 255 + 1


def _check_btag(btag: int) -> None:
    if not 1 <= btag <= 255:
        raise ValueError(f"bTag must be 1..255, got {btag}")


def pack_dev_dep_msg_out(btag: int, payload: bytes, *, eom: bool) -> bytes:
    """One DEV_DEP_MSG_OUT transfer: header, payload, zero padding to 4 bytes."""
    _check_btag(btag)
    header = struct.pack("<BBBxIBxxx", DEV_DEP_MSG_OUT, btag, ~btag & 0xFF, len(payload),
                         1 if eom else 0)
    return header + payload + b"\0" * (-len(payload) % 4)


def pack_request_dev_dep_msg_in(btag: int, max_size: int, *, term_char: int | None = None
                                ) -> bytes:
    """REQUEST_DEV_DEP_MSG_IN asking for up to ``max_size`` bytes (optionally up to and
    including ``term_char``)."""
    _check_btag(btag)
    if not 1 <= max_size <= 0xFFFFFFFF:
        raise ValueError(f"transfer size must be 1..2**32-1, got {max_size}")
    attributes = 0x02 if term_char is not None else 0x00
    return struct.pack("<BBBxIBBxx", REQUEST_DEV_DEP_MSG_IN, btag, ~btag & 0xFF, max_size,
                       attributes, term_char or 0)


@dataclass(frozen=True)
class BulkInHeader:
    """A decoded DEV_DEP_MSG_IN header."""

    btag: int
    transfer_size: int
    eom: bool
    term_char_ended: bool


def unpack_bulk_in_header(data: bytes) -> BulkInHeader:
    """Decode the 12-byte DEV_DEP_MSG_IN header at the start of ``data``.

    Raises
    ------
    ProtocolError
        Fewer than 12 bytes, a MsgID other than DEV_DEP_MSG_IN, bTag 0, a bTagInverse
        that does not invert bTag, or a non-zero reserved byte 3.
    """
    if len(data) < HEADER_SIZE:
        raise ProtocolError(f"bulk-IN transfer of {len(data)} bytes is shorter than a header")
    msg_id, btag, inverse, reserved, size, attributes = struct.unpack_from("<BBBBIB", data)
    if msg_id != DEV_DEP_MSG_IN:
        raise ProtocolError(f"bulk-IN MsgID {msg_id}, expected DEV_DEP_MSG_IN (2)")
    if btag == 0 or inverse != (~btag & 0xFF):
        raise ProtocolError(f"bulk-IN bTag {btag:#04x} with bTagInverse {inverse:#04x}")
    if reserved != 0:
        raise ProtocolError(f"bulk-IN header byte 3 is {reserved:#04x}, expected 0")
    return BulkInHeader(btag, size, bool(attributes & 0x01), bool(attributes & 0x02))


@dataclass(frozen=True)
class Capabilities:
    """GET_CAPABILITIES (USBTMC 1.0 Table 37, USB488 Table 8), as far as a host uses it."""

    bcd_usbtmc: int
    indicator_pulse: bool
    talk_only: bool
    listen_only: bool
    term_char: bool
    bcd_usb488: int

    @classmethod
    def from_bytes(cls, data: bytes) -> Capabilities:
        if len(data) < 0x18 or data[0] != STATUS_SUCCESS:
            raise ProtocolError("GET_CAPABILITIES failed or returned a short reply")
        return cls(
            bcd_usbtmc=struct.unpack_from("<H", data, 2)[0],
            indicator_pulse=bool(data[4] & 0x04),
            talk_only=bool(data[4] & 0x02),
            listen_only=bool(data[4] & 0x01),
            term_char=bool(data[5] & 0x01),
            bcd_usb488=struct.unpack_from("<H", data, 12)[0],
        )


# --------------------------------------------------------------------------- device

class UsbtmcDevice:
    """A USBTMC instrument on pyusb.

    Parameters
    ----------
    vendor_id, product_id
        USB IDs to look for.
    serial_number
        Pick the device with this iSerialNumber string (``None``: the first found).
    backend
        pyusb backend handed to ``usb.core.find`` (``None``: pyusb's default libusb).
    timeout_s
        Timeout of each USB transfer and of the clear/abort handshakes, in seconds.
    name
        Name used in every error.
    max_transfer_size
        TransferSize asked for in each REQUEST_DEV_DEP_MSG_IN.
    chunk_size
        Largest payload per DEV_DEP_MSG_OUT transfer (default: wMaxPacketSize).
    read_size
        Bytes asked for per bulk-IN read, rounded up to whole packets (default: enough
        for a whole transfer of ``max_transfer_size``).
    encoding
        Text encoding of messages (SCPI is ASCII).

    Raises
    ------
    ConnectionFailed
        No such device, no USBTMC interface, or the device cannot be claimed or cleared.
    """

    def __init__(
        self,
        *,
        vendor_id: int,
        product_id: int,
        serial_number: str | None = None,
        backend: Any = None,
        timeout_s: float = 2.0,
        name: str = "usbtmc",
        max_transfer_size: int = 4096,
        chunk_size: int | None = None,
        read_size: int | None = None,
        encoding: str = "ascii",
    ) -> None:
        if not timeout_s > 0:
            raise ValueError("timeout_s must be > 0")
        self.name = name
        self.timeout_s = float(timeout_s)
        self.encoding = encoding
        self.max_transfer_size = int(max_transfer_size)
        self._lock = threading.RLock()
        self._btag = 0
        self._closed = False
        self._interface: int | None = None
        self._detached: int | None = None   # interface taken from the kernel driver
        self.dev = self._find(vendor_id, product_id, serial_number, backend)
        try:
            self._open(chunk_size, read_size)
        except BaseException:
            self._release()
            raise

    # -- lifecycle ----------------------------------------------------------------------
    def _find(self, vid: int, pid: int, serial: str | None, backend: Any) -> usb.core.Device:
        def serial_matches(dev: usb.core.Device) -> bool:
            if serial is None:
                return True
            try:
                return cast(bool, dev.serial_number == serial)  # pyusb is untyped
            except (usb.core.USBError, ValueError):
                return False   # unreadable strings (permissions): not the one asked for

        what = f"USB device {vid:04x}:{pid:04x}" + (f" serial {serial}" if serial else "")
        try:
            dev = usb.core.find(backend=backend, idVendor=vid, idProduct=pid,
                                custom_match=serial_matches)
        except usb.core.NoBackendError as err:
            raise ConnectionFailed(
                "no pyusb backend (libusb) is available", device=self.name, command="find",
                hint="install libusb-1.0, or pass backend=",
            ) from err
        except usb.core.USBError as err:
            raise ConnectionFailed(f"enumerating {what} failed: {err}", device=self.name,
                                   command="find") from err
        if dev is None:
            raise ConnectionFailed(
                f"{what} not found", device=self.name, command="find",
                hint="check the cable and power; on Linux check the udev rule for access",
            )
        return dev

    def _open(self, chunk_size: int | None, read_size: int | None) -> None:
        intf = self._find_interface()
        number = intf.bInterfaceNumber
        try:
            if self._kernel_driver_active(number):
                self.dev.detach_kernel_driver(number)
                self._detached = number
            self._ensure_configuration(intf)
            usb.util.claim_interface(self.dev, number)
            self._interface = number
        except usb.core.USBError as err:
            raise ConnectionFailed(
                f"cannot claim USBTMC interface {number}: {err}", device=self.name,
                command="claim_interface",
                hint="another program may hold the instrument; close it and retry",
            ) from err
        self.ep_out, self.ep_in = self._bulk_endpoints(intf)
        self.max_packet = int(self.ep_in.wMaxPacketSize)
        self.chunk_size = int(chunk_size or self.ep_out.wMaxPacketSize)
        if self.chunk_size < 1:
            raise ValueError("chunk_size must be >= 1")
        wanted = read_size or HEADER_SIZE + self.max_transfer_size + 3 + 1
        self.read_size = -(-wanted // self.max_packet) * self.max_packet
        self.capabilities = self._get_capabilities()
        self.clear()

    def _find_interface(self) -> usb.core.Interface:
        try:
            for cfg in self.dev:
                for intf in cfg:
                    if (intf.bInterfaceClass, intf.bInterfaceSubClass) == (
                            _USBTMC_CLASS, _USBTMC_SUBCLASS):
                        self._config_value = cfg.bConfigurationValue
                        return intf
        except usb.core.USBError as err:
            raise self._map_error(err, "read descriptors") from err
        raise ConnectionFailed("device has no USBTMC interface (class 0xFE/0x03)",
                               device=self.name, command="open")

    def _kernel_driver_active(self, number: int) -> bool:
        try:
            return bool(self.dev.is_kernel_driver_active(number))
        except NotImplementedError:
            return False   # backends without kernel drivers (Windows, macOS)

    def _ensure_configuration(self, intf: usb.core.Interface) -> None:
        # Setting the configuration that is already active makes Linux reset the device's
        # state, so only set it when the device is unconfigured or in another one.
        try:
            active = self.dev.get_active_configuration().bConfigurationValue
        except usb.core.USBError:
            active = None
        if active != self._config_value:
            self.dev.set_configuration(self._config_value)

    def _bulk_endpoints(self, intf: usb.core.Interface) -> tuple[Any, Any]:
        def find(direction: int) -> Any:  # pyusb has no type information: endpoints are Any
            return usb.util.find_descriptor(
                intf, custom_match=lambda e: (
                    usb.util.endpoint_direction(e.bEndpointAddress) == direction
                    and usb.util.endpoint_type(e.bmAttributes) == usb.util.ENDPOINT_TYPE_BULK))
        ep_out, ep_in = find(usb.util.ENDPOINT_OUT), find(usb.util.ENDPOINT_IN)
        if ep_out is None or ep_in is None:
            raise ConnectionFailed("USBTMC interface lacks a bulk-IN or bulk-OUT endpoint",
                                   device=self.name, command="open")
        return ep_out, ep_in

    def close(self) -> None:
        """Release the interface and the device handle. Safe to call repeatedly."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._release()

    def _release(self) -> None:
        dev = getattr(self, "dev", None)
        if dev is None:
            return
        try:
            if self._interface is not None:
                usb.util.release_interface(dev, self._interface)
            if self._detached is not None:
                # Give the interface back to the kernel driver we took it from, also
                # when opening failed after the detach.
                dev.attach_kernel_driver(self._detached)
        except (usb.core.USBError, NotImplementedError):
            pass   # unplugged or unsupported: nothing left to give back
        finally:
            self._interface = None
            self._detached = None
            with contextlib.suppress(usb.core.USBError):
                usb.util.dispose_resources(dev)

    @property
    def closed(self) -> bool:
        return self._closed

    def __enter__(self) -> UsbtmcDevice:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- identity -------------------------------------------------------------------------
    @property
    def serial_number(self) -> str | None:
        return self._string("serial_number")

    @property
    def manufacturer(self) -> str | None:
        return self._string("manufacturer")

    @property
    def product(self) -> str | None:
        return self._string("product")

    def _string(self, attr: str) -> str | None:
        try:
            return cast(str | None, getattr(self.dev, attr))  # pyusb is untyped
        except (usb.core.USBError, ValueError) as err:
            raise self._map_error(err, f"read {attr}") from err

    # -- messages -----------------------------------------------------------------------
    def write(self, message: str) -> None:
        """Send ``message`` (a newline is appended if missing)."""
        if not message.endswith("\n"):
            message += "\n"
        self.write_raw(message.encode(self.encoding), command=message.strip())

    def write_raw(self, data: bytes, *, command: str | None = None) -> None:
        """Send ``data`` as one USBTMC message (one or more transfers, EOM on the last)."""
        with self._lock:
            self._check_open(command)
            chunks = [data[i:i + self.chunk_size]
                      for i in range(0, len(data), self.chunk_size)] or [b""]
            for i, chunk in enumerate(chunks):
                btag = self._take_btag()
                transfer = pack_dev_dep_msg_out(btag, chunk, eom=i == len(chunks) - 1)
                self._bulk_out(transfer, btag, command)

    def read_raw(self, *, command: str | None = None) -> bytes:
        """Read one whole response message (all transfers up to EOM)."""
        with self._lock:
            self._check_open(command)
            message = bytearray()
            while True:
                btag = self._take_btag()
                self._bulk_out(pack_request_dev_dep_msg_in(btag, self.max_transfer_size),
                               btag, command)
                payload, eom = self._read_transfer(btag, command)
                message += payload
                if eom:
                    return bytes(message)

    def read(self, *, command: str | None = None) -> str:
        """Read one response message as text, without its trailing newline."""
        raw = self.read_raw(command=command)
        try:
            return raw.decode(self.encoding).rstrip("\r\n")
        except UnicodeDecodeError as err:
            raise ProtocolError(f"response is not {self.encoding}: {raw[:40]!r}",
                                device=self.name, command=command) from err

    def query(self, message: str) -> str:
        """Send ``message`` and return the response text."""
        with self._lock:
            self.write(message)
            return self.read(command=message.strip())

    # -- transfers ----------------------------------------------------------------------
    def _check_open(self, command: str | None) -> None:
        if self._closed:
            raise ConnectionFailed("USBTMC link is closed", device=self.name, command=command)

    def _take_btag(self) -> int:
        self._btag = next_btag(self._btag)
        return self._btag

    @property
    def _timeout_ms(self) -> int:
        return max(1, round(self.timeout_s * 1000))

    def _bulk_out(self, transfer: bytes, btag: int, command: str | None) -> None:
        try:
            self.ep_out.write(transfer, self._timeout_ms)
        except usb.core.USBTimeoutError as err:
            self._abort_bulk_out(btag, command)
            raise DeviceTimeout(
                f"bulk-OUT transfer not accepted within {self.timeout_s:g} s",
                device=self.name, command=command, hint="the transfer was aborted",
            ) from err
        except usb.core.USBError as err:
            raise self._map_error(err, command, endpoint=self.ep_out) from err

    def _bulk_in(self, btag: int, command: str | None) -> bytes:
        try:
            return bytes(self.ep_in.read(self.read_size, self._timeout_ms))
        except usb.core.USBTimeoutError as err:
            self._abort_bulk_in(btag, command)
            raise DeviceTimeout(
                f"no response within {self.timeout_s:g} s", device=self.name,
                command=command, hint="the request was aborted; check the command is a query",
            ) from err
        except usb.core.USBError as err:
            raise self._map_error(err, command, endpoint=self.ep_in) from err

    def _read_transfer(self, btag: int, command: str | None) -> tuple[bytes, bool]:
        buf = bytearray()
        header: BulkInHeader | None = None
        deadline = time.monotonic() + self.timeout_s
        while header is None or len(buf) < HEADER_SIZE + header.transfer_size:
            chunk = self._bulk_in(btag, command)
            if not chunk and not buf:
                # A zero-length packet left over from an earlier transfer that ended on a
                # packet boundary: not part of this one.
                if time.monotonic() > deadline:
                    self._abort_bulk_in(btag, command)
                    raise DeviceTimeout("device sent only empty packets", device=self.name,
                                        command=command)
                continue
            buf += chunk
            if header is None and len(buf) >= HEADER_SIZE:
                header = self._checked_header(bytes(buf), btag, command)
            short = len(chunk) % self.max_packet != 0 or not chunk
            if short and (header is None or len(buf) < HEADER_SIZE + header.transfer_size):
                self._abort_bulk_in(btag, command)
                raise ProtocolError(
                    f"bulk-IN transfer ended after {len(buf)} bytes, header announced "
                    f"{HEADER_SIZE + (header.transfer_size if header else 0)}",
                    device=self.name, command=command)
        end = HEADER_SIZE + header.transfer_size
        if len(buf) - end > 3:
            raise ProtocolError(f"{len(buf) - end} bytes after the transfer's data",
                                device=self.name, command=command)
        return bytes(buf[HEADER_SIZE:end]), header.eom

    def _checked_header(self, data: bytes, btag: int, command: str | None) -> BulkInHeader:
        try:
            header = unpack_bulk_in_header(data)
        except ProtocolError as err:
            self._abort_bulk_in(btag, command)
            raise ProtocolError(err.message, device=self.name, command=command) from err
        if header.btag != btag:
            self._abort_bulk_in(btag, command)
            raise ProtocolError(f"response carries bTag {header.btag}, request had {btag}",
                                device=self.name, command=command,
                                hint="a stale response was discarded")
        if header.transfer_size > self.max_transfer_size:
            self._abort_bulk_in(btag, command)
            raise ProtocolError(
                f"device sent {header.transfer_size} bytes, {self.max_transfer_size} asked",
                device=self.name, command=command)
        return header

    # -- control requests ---------------------------------------------------------------
    def _control(self, request_type: int, request: int, value: int, index: int,
                 length: int, command: str | None) -> bytes:
        try:
            return bytes(self.dev.ctrl_transfer(request_type, request, value, index, length,
                                                self._timeout_ms))
        except usb.core.USBTimeoutError as err:
            raise DeviceTimeout(f"control request {request} timed out", device=self.name,
                                command=command) from err
        except usb.core.USBError as err:
            raise self._map_error(err, command) from err

    def _get_capabilities(self) -> Capabilities | None:
        try:
            data = self._control(_REQ_INTERFACE, GET_CAPABILITIES, 0, self._interface or 0,
                                 0x18, "GET_CAPABILITIES")
        except ProtocolError:
            return None   # optional for the host; some devices stall it
        return Capabilities.from_bytes(data)

    def clear(self) -> None:
        """Clear the device's input and output buffers (INITIATE_CLEAR handshake)."""
        with self._lock:
            command = "INITIATE_CLEAR"
            status = self._control(_REQ_INTERFACE, INITIATE_CLEAR, 0, self._interface or 0,
                                   1, command)
            if not status or status[0] != STATUS_SUCCESS:
                raise ConnectionFailed(f"device refused INITIATE_CLEAR (status {status!r})",
                                       device=self.name, command=command)
            deadline = time.monotonic() + self.timeout_s
            while True:
                reply = self._control(_REQ_INTERFACE, CHECK_CLEAR_STATUS, 0,
                                      self._interface or 0, 2, "CHECK_CLEAR_STATUS")
                if reply[:1] != bytes([STATUS_PENDING]):
                    break
                if len(reply) > 1 and reply[1] & 0x01:
                    self._drain_in()   # bmClear.D0: the device wants its bulk-IN read
                if time.monotonic() > deadline:
                    raise DeviceTimeout("device did not finish clearing", device=self.name,
                                        command="CHECK_CLEAR_STATUS")
                time.sleep(_POLL_S)
            if reply[:1] != bytes([STATUS_SUCCESS]):
                raise ConnectionFailed(f"clear failed (status {reply!r})", device=self.name,
                                       command="CHECK_CLEAR_STATUS")
            self._clear_halt(self.ep_out, "CLEAR_FEATURE")

    def _clear_halt(self, endpoint: usb.core.Endpoint, command: str | None) -> None:
        try:
            self.dev.clear_halt(endpoint)
        except usb.core.USBError as err:
            raise self._map_error(err, command) from err

    def _drain_in(self) -> None:
        """Read bulk-IN until a short packet (or nothing is left)."""
        for _ in range(1024):
            try:
                data = self.ep_in.read(self.max_packet, max(1, self._timeout_ms // 10))
            except usb.core.USBTimeoutError:
                return
            except usb.core.USBError as err:
                if self._gone(err):
                    raise self._map_error(err, "drain bulk-IN") from err
                return
            if len(data) < self.max_packet:
                return

    def _abort_bulk_in(self, btag: int, command: str | None) -> None:
        """USBTMC §4.2.1.4: abort the bulk-IN transfer ``btag`` and drain the endpoint."""
        address = self.ep_in.bEndpointAddress
        try:
            status = self._control(_REQ_ENDPOINT, INITIATE_ABORT_BULK_IN, btag, address, 2,
                                   command)
            if status[:1] != bytes([STATUS_SUCCESS]):
                return   # nothing in progress for that bTag: nothing to abort
            self._drain_in()
            deadline = time.monotonic() + self.timeout_s
            while time.monotonic() < deadline:
                reply = self._control(_REQ_ENDPOINT, CHECK_ABORT_BULK_IN_STATUS, 0, address,
                                      8, command)
                if reply[:1] != bytes([STATUS_PENDING]):
                    return
                if len(reply) > 1 and reply[1] & 0x01:
                    self._drain_in()
                time.sleep(_POLL_S)
        except ConnectionFailed:
            raise
        except DeviceError:
            pass   # the abort itself failed; the caller reports the original problem

    def _abort_bulk_out(self, btag: int, command: str | None) -> None:
        """USBTMC §4.2.1.2: abort the bulk-OUT transfer ``btag`` and clear the halt."""
        address = self.ep_out.bEndpointAddress
        try:
            status = self._control(_REQ_ENDPOINT, INITIATE_ABORT_BULK_OUT, btag, address, 2,
                                   command)
            if status[:1] == bytes([STATUS_SUCCESS]):
                deadline = time.monotonic() + self.timeout_s
                while time.monotonic() < deadline:
                    reply = self._control(_REQ_ENDPOINT, CHECK_ABORT_BULK_OUT_STATUS, 0,
                                          address, 8, command)
                    if reply[:1] != bytes([STATUS_PENDING]):
                        break
                    time.sleep(_POLL_S)
            self._clear_halt(self.ep_out, command)
        except ConnectionFailed:
            raise
        except DeviceError:
            pass   # the abort itself failed; the caller reports the original problem

    # -- errors -------------------------------------------------------------------------
    @staticmethod
    def _gone(err: usb.core.USBError) -> bool:
        return err.errno in _GONE_ERRNOS or getattr(err, "backend_error_code", None) in (
            _GONE_LIBUSB)

    def _map_error(self, err: usb.core.USBError | ValueError, command: str | None,
                   endpoint: usb.core.Endpoint | None = None) -> DeviceError:
        if isinstance(err, usb.core.USBError) and self._gone(err):
            return ConnectionFailed(
                f"USB device vanished ({err})", device=self.name, command=command,
                hint="reconnect the cable and open the device again")
        code = getattr(err, "errno", None)
        if code == errno.EPIPE:
            if endpoint is None:
                return ProtocolError("device stalled the control request", device=self.name,
                                     command=command)
            # The device halted the endpoint (it rejected the transfer); clear it so
            # the next command has a chance.
            with contextlib.suppress(usb.core.USBError):
                self.dev.clear_halt(endpoint)
            return ProtocolError("device stalled the endpoint (transfer rejected)",
                                 device=self.name, command=command,
                                 hint="the halt was cleared; retry the command")
        if code == errno.EOVERFLOW:
            return ProtocolError("device sent more data than requested", device=self.name,
                                 command=command)
        return ConnectionFailed(f"USB transfer failed: {err}", device=self.name,
                                command=command)

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return f"<UsbtmcDevice {self.name!r} {state}>"
