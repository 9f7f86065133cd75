"""A pyusb backend whose one device is an emulated USBTMC instrument.

``usb.core.find(backend=EmulatedUsbtmcBackend(firmware), idVendor=…, idProduct=…)`` returns
a real :class:`usb.core.Device`; every descriptor read, control request and bulk transfer
the host makes through pyusb lands here. pyusb documents this extension point
(``usb.backend.IBackend`` in pyusb's ``usb/backend/__init__.py``), so nothing in
``usb.core`` is patched and the driver's whole pyusb code path runs.

The device side implements USBTMC 1.0 (and the USB488 interface descriptor) as far as a
power meter needs it, written from the specification (USB-IF *Universal Serial Bus Test and
Measurement Class Specification (USBTMC)*, Revision 1.0, 2003) and independent of
``drivers/usbtmc.py``:

* descriptors: device (VID/PID, bus/address/port/speed), one configuration, one USBTMC
  interface (class 0xFE, subclass 0x03, protocol 0x01), bulk-OUT 0x02, bulk-IN 0x81,
  interrupt-IN 0x83; string descriptors (LANGID 0x0409, manufacturer, product, serial)
  through GET_DESCRIPTOR;
* bulk-OUT: 12-byte headers checked (MsgID, bTag ≠ 0, bTagInverse, reserved bytes zero,
  4-byte alignment); transfers may span several writes; a message is complete at EOM.
  A malformed header halts the endpoint (EPIPE until CLEAR_FEATURE(ENDPOINT_HALT));
* REQUEST_DEV_DEP_MSG_IN: the response is framed as DEV_DEP_MSG_IN with the request's
  bTag, at most TransferSize bytes, EOM on the last transfer, TermChar honoured, padded to
  4 bytes, and sent as wMaxPacketSize packets ending in a short packet (a zero-length
  packet when the transfer fills its last packet). A read into a buffer smaller than the
  next packet fails with EOVERFLOW, as libusb does. With nothing to send the device NAKs
  and the host times out (and the firmware logs -420 Query UNTERMINATED);
* class requests: INITIATE_CLEAR / CHECK_CLEAR_STATUS (PENDING for ``clear_pending_polls``
  polls), INITIATE_ABORT_BULK_OUT/IN and their CHECK_…_STATUS, GET_CAPABILITIES,
  INDICATOR_PULSE;
* Linux-like ownership: the kernel ``usbtmc`` driver is bound at plug-in, so claiming the
  interface or setting the configuration fails with EBUSY until it is detached.

Faults: the firmware's :class:`~hw_mocks.faults.FaultInjector` acts on every bulk-IN
transfer (DROP/DELAY → host timeout, CORRUPT/GARBAGE/UNSOLICITED → bad header or bad
data, SPLIT, ERROR_STATE → SCPI error queue, DISCONNECT → every call raises
``USBError`` errno 19 ENODEV until the device is re-plugged); :attr:`usb_faults`
adds bulk-OUT timeouts and stalls.
"""

from __future__ import annotations

import array
import errno
import struct
import threading
import time
from collections import deque
from types import SimpleNamespace
from typing import Protocol

import usb.backend
import usb.core
import usb.util

from hw_mocks.faults import FaultInjector
from hw_mocks.usb.faults import UsbFaultKind, UsbFaults

__all__ = ["EmulatedUsbtmcBackend", "UsbtmcFirmware"]

# USBTMC 1.0 message IDs (Table 2) and class requests (Table 15), status values (Table 16).
_DEV_DEP_MSG_OUT = 1
_REQUEST_DEV_DEP_MSG_IN = 2
_DEV_DEP_MSG_IN = 2
_INITIATE_ABORT_BULK_OUT = 1
_CHECK_ABORT_BULK_OUT_STATUS = 2
_INITIATE_ABORT_BULK_IN = 3
_CHECK_ABORT_BULK_IN_STATUS = 4
_INITIATE_CLEAR = 5
_CHECK_CLEAR_STATUS = 6
_GET_CAPABILITIES = 7
_INDICATOR_PULSE = 64
_SUCCESS = 0x01
_PENDING = 0x02
_FAILED = 0x80
_NOT_IN_PROGRESS = 0x81

_EP_OUT = 0x02
_EP_IN = 0x81
_EP_INT = 0x83
_LANGID_EN_US = 0x0409

# libusb error codes that pyusb's libusb1 backend puts in ``backend_error_code``.
_LIBUSB_IO, _LIBUSB_INVALID, _LIBUSB_NO_DEVICE, _LIBUSB_NOT_FOUND = -1, -2, -4, -5
_LIBUSB_BUSY, _LIBUSB_TIMEOUT, _LIBUSB_OVERFLOW, _LIBUSB_PIPE = -6, -7, -8, -9


class UsbtmcFirmware(Protocol):
    """What the backend needs from the instrument behind the USBTMC interface."""

    faults: FaultInjector
    lock: threading.RLock

    def receive(self, data: bytes) -> list[bytes]:
        """Take one complete message; return the response message(s)."""
        ...

    def unsolicited_frame(self) -> bytes: ...

    def enter_error_state(self, code: str | None = None) -> None: ...

    def query_interrupted(self) -> None: ...

    def query_unterminated(self) -> None: ...


def _usb_error(text: str, code: int, err: int) -> usb.core.USBError:
    return usb.core.USBError(text, error_code=code, errno=err)


def _stall() -> usb.core.USBError:
    return _usb_error("Pipe error", _LIBUSB_PIPE, errno.EPIPE)


class _Handle:
    """An open device handle; stale once the device is unplugged."""


class EmulatedUsbtmcBackend(usb.backend.IBackend):
    """pyusb backend with one emulated USBTMC device.

    Parameters
    ----------
    firmware
        The instrument model (:class:`hw_mocks.firmware.pm100usb.Pm100usbFirmware`).
    vendor_id, product_id, manufacturer, product, serial
        Identity in the descriptors; ``serial`` defaults to ``firmware.serial``.
    max_packet
        wMaxPacketSize of the bulk endpoints (64 for a full-speed device).
    kernel_driver
        Whether the kernel's usbtmc driver binds the interface at plug-in.
    configured
        Whether the device is configured at plug-in (Linux configures it).
    clear_pending_polls
        CHECK_CLEAR_STATUS answers PENDING this many times before SUCCESS.
    seed
        Seed of :attr:`usb_faults`.
    """

    def __init__(
        self,
        firmware: UsbtmcFirmware,
        *,
        vendor_id: int = 0x1313,
        product_id: int = 0x8072,
        manufacturer: str = "Thorlabs",
        product: str = "PM100USB",
        serial: str | None = None,
        max_packet: int = 64,
        kernel_driver: bool = True,
        configured: bool = True,
        clear_pending_polls: int = 1,
        bus: int = 1,
        address: int = 7,
        port_numbers: tuple[int, ...] = (1, 4),
        seed: int = 0,
    ) -> None:
        if max_packet not in (8, 16, 32, 64, 512):
            raise ValueError(f"invalid bulk wMaxPacketSize {max_packet}")
        self.firmware = firmware
        self.vendor_id = vendor_id
        self.product_id = product_id
        self.max_packet = max_packet
        self.strings = {
            1: manufacturer,
            2: product,
            3: serial if serial is not None else str(getattr(firmware, "serial", "0")),
        }
        self.kernel_driver_at_plug = kernel_driver
        self.configured_at_plug = configured
        self.clear_pending_polls = clear_pending_polls
        self.usb_faults = UsbFaults(seed)
        self._lock = threading.RLock()
        self._speed = usb.util.SPEED_HIGH if max_packet == 512 else usb.util.SPEED_FULL
        self._ident = SimpleNamespace(bus=bus, address=address, port_numbers=port_numbers)
        self._handles: set[_Handle] = set()
        self._unplugged = False
        #: Every bulk-OUT write as the device received it (for byte-exact tests).
        self.bulk_out_log: list[bytes] = []
        #: Every control request: (bmRequestType, bRequest, wValue, wIndex, wLength).
        self.control_log: list[tuple[int, int, int, int, int]] = []
        #: Every IN transfer the device framed (before faults touched it).
        self.bulk_in_log: list[bytes] = []
        #: Header problems the device saw (each one halted bulk-OUT).
        self.framing_errors: list[str] = []
        self._plug_in()

    # ------------------------------------------------------------------ plug state
    def _plug_in(self) -> None:
        """State right after the device is plugged in (or re-plugged)."""
        self.kernel_driver_active = self.kernel_driver_at_plug
        self.configuration = 1 if self.configured_at_plug else 0
        #: Claimed interfaces and the handle that holds each.
        self.claimed: dict[int, _Handle] = {}
        self.out_halted = False
        self.in_halted = False
        self._reset_io()

    def _reset_io(self) -> None:
        self._rx = bytearray()           # bulk-OUT bytes not yet forming a whole transfer
        self._message = bytearray()      # DEV_DEP_MSG_OUT payloads until EOM
        self._response = bytearray()     # response bytes not yet framed for bulk-IN
        self._packets: deque[tuple[float, bytes]] = deque()
        self._in_btag: int | None = None
        self._pending: tuple[int, int, int | None] | None = None
        self._clear_polls_left = 0
        self._out_rxd = 0
        self._in_txd = 0
        self._abort_out_status = _FAILED
        self._out_partial_btag: int | None = None

    def unplug(self) -> None:
        """Backdoor: pull the cable (same as a DISCONNECT fault)."""
        self.firmware.faults.disconnected = True

    def replug(self) -> None:
        """Backdoor: plug the cable back in (the kernel driver binds again)."""
        with self._lock:
            self.firmware.faults.reconnect()
            self._alive()

    def _alive(self) -> None:
        """Raise ENODEV while unplugged; reset USB state after a re-plug."""
        if self.firmware.faults.disconnected:
            if not self._unplugged:
                self._unplugged = True
                self._handles.clear()    # every open handle is dead for good
            raise _usb_error("No such device (it may have been disconnected)",
                             _LIBUSB_NO_DEVICE, errno.ENODEV)
        if self._unplugged:
            self._unplugged = False
            self._plug_in()

    def _check(self, handle: _Handle) -> None:
        self._alive()
        if handle not in self._handles:
            raise _usb_error("No such device (it may have been disconnected)",
                             _LIBUSB_NO_DEVICE, errno.ENODEV)

    # ------------------------------------------------------------------ descriptors
    def enumerate_devices(self):
        with self._lock:
            try:
                self._alive()
            except usb.core.USBError:
                return iter(())
            return iter((self._ident,))

    def get_parent(self, dev):
        return None

    def get_device_descriptor(self, dev):
        return SimpleNamespace(
            bLength=18, bDescriptorType=usb.util.DESC_TYPE_DEVICE, bcdUSB=0x0200,
            bDeviceClass=0, bDeviceSubClass=0, bDeviceProtocol=0, bMaxPacketSize0=64,
            idVendor=self.vendor_id, idProduct=self.product_id, bcdDevice=0x0107,
            iManufacturer=1, iProduct=2, iSerialNumber=3, bNumConfigurations=1,
            bus=self._ident.bus, address=self._ident.address,
            port_number=self._ident.port_numbers[-1],
            port_numbers=self._ident.port_numbers, speed=self._speed,
        )

    def _endpoints(self) -> list[SimpleNamespace]:
        def ep(address: int, attributes: int, size: int, interval: int) -> SimpleNamespace:
            return SimpleNamespace(
                bLength=7, bDescriptorType=usb.util.DESC_TYPE_ENDPOINT,
                bEndpointAddress=address, bmAttributes=attributes, wMaxPacketSize=size,
                bInterval=interval, bRefresh=0, bSynchAddress=0, extra_descriptors=[],
            )
        return [
            ep(_EP_OUT, usb.util.ENDPOINT_TYPE_BULK, self.max_packet, 0),
            ep(_EP_IN, usb.util.ENDPOINT_TYPE_BULK, self.max_packet, 0),
            ep(_EP_INT, usb.util.ENDPOINT_TYPE_INTR, 2, 10),
        ]

    def get_configuration_descriptor(self, dev, config):
        if config != 0:
            raise IndexError(config)
        return SimpleNamespace(
            bLength=9, bDescriptorType=usb.util.DESC_TYPE_CONFIG,
            wTotalLength=9 + 9 + 7 * 3, bNumInterfaces=1, bConfigurationValue=1,
            iConfiguration=0, bmAttributes=0x80, bMaxPower=50, extra_descriptors=[],
        )

    def get_interface_descriptor(self, dev, intf, alt, config):
        if config != 0 or intf != 0 or alt != 0:
            raise IndexError((intf, alt, config))
        return SimpleNamespace(
            bLength=9, bDescriptorType=usb.util.DESC_TYPE_INTERFACE, bInterfaceNumber=0,
            bAlternateSetting=0, bNumEndpoints=3, bInterfaceClass=0xFE,
            bInterfaceSubClass=0x03, bInterfaceProtocol=0x01, iInterface=0,
            extra_descriptors=[],
        )

    def get_endpoint_descriptor(self, dev, ep, intf, alt, config):
        if config != 0 or intf != 0 or alt != 0:
            raise IndexError((ep, intf, alt, config))
        return self._endpoints()[ep]

    def _descriptor_bytes(self, dtype: int, index: int, langid: int) -> bytes:
        if dtype == usb.util.DESC_TYPE_STRING:
            if index == 0:
                return struct.pack("<BBH", 4, usb.util.DESC_TYPE_STRING, _LANGID_EN_US)
            if index not in self.strings or langid != _LANGID_EN_US:
                raise _stall()
            text = self.strings[index].encode("utf-16-le")
            return bytes([2 + len(text), usb.util.DESC_TYPE_STRING]) + text
        if dtype == usb.util.DESC_TYPE_DEVICE:
            d = self.get_device_descriptor(None)
            return struct.pack(
                "<BBHBBBBHHHBBBB", 18, 1, d.bcdUSB, 0, 0, 0, 64, d.idVendor, d.idProduct,
                d.bcdDevice, 1, 2, 3, 1)
        if dtype == usb.util.DESC_TYPE_CONFIG:
            out = struct.pack("<BBHBBBBB", 9, 2, 39, 1, 1, 0, 0x80, 50)
            out += struct.pack("<BBBBBBBBB", 9, 4, 0, 0, 3, 0xFE, 0x03, 0x01, 0)
            for e in self._endpoints():
                out += struct.pack("<BBBBHB", 7, 5, e.bEndpointAddress, e.bmAttributes,
                                   e.wMaxPacketSize, e.bInterval)
            return out
        raise _stall()

    # ------------------------------------------------------------------ ownership
    def open_device(self, dev):
        with self._lock:
            self._alive()
            handle = _Handle()
            self._handles.add(handle)
            return handle

    def close_device(self, dev_handle):
        with self._lock:
            self._handles.discard(dev_handle)
            # Closing a handle releases what it claimed (as libusb_close does).
            for intf in [i for i, h in self.claimed.items() if h is dev_handle]:
                del self.claimed[intf]

    def set_configuration(self, dev_handle, config_value):
        with self._lock:
            self._check(dev_handle)
            if config_value not in (0, 1):
                raise _usb_error("Entity not found", _LIBUSB_NOT_FOUND, errno.ENOENT)
            if self.kernel_driver_active or self.claimed:
                raise _usb_error("Resource busy", _LIBUSB_BUSY, errno.EBUSY)
            self.configuration = config_value
            self._reset_io()

    def get_configuration(self, dev_handle):
        with self._lock:
            self._check(dev_handle)
            return self.configuration

    def set_interface_altsetting(self, dev_handle, intf, altsetting):
        with self._lock:
            self._check(dev_handle)
            if intf != 0 or altsetting != 0:
                raise _usb_error("Entity not found", _LIBUSB_NOT_FOUND, errno.ENOENT)

    def claim_interface(self, dev_handle, intf):
        with self._lock:
            self._check(dev_handle)
            if self.configuration != 1 or intf != 0:
                raise _usb_error("Entity not found", _LIBUSB_NOT_FOUND, errno.ENOENT)
            holder = self.claimed.get(intf)
            if self.kernel_driver_active or (holder is not None and holder is not dev_handle):
                raise _usb_error("Resource busy", _LIBUSB_BUSY, errno.EBUSY)
            self.claimed[intf] = dev_handle

    def release_interface(self, dev_handle, intf):
        with self._lock:
            self._check(dev_handle)
            if self.claimed.get(intf) is dev_handle:
                del self.claimed[intf]

    def is_kernel_driver_active(self, dev_handle, intf):
        with self._lock:
            self._check(dev_handle)
            return self.kernel_driver_active and intf == 0

    def detach_kernel_driver(self, dev_handle, intf):
        with self._lock:
            self._check(dev_handle)
            if not self.kernel_driver_active or intf != 0:
                raise _usb_error("Entity not found", _LIBUSB_NOT_FOUND, errno.ENOENT)
            self.kernel_driver_active = False

    def attach_kernel_driver(self, dev_handle, intf):
        with self._lock:
            self._check(dev_handle)
            if intf in self.claimed:
                raise _usb_error("Resource busy", _LIBUSB_BUSY, errno.EBUSY)
            self.kernel_driver_active = True

    def clear_halt(self, dev_handle, ep):
        with self._lock:
            self._check(dev_handle)
            # On the wire this is CLEAR_FEATURE(ENDPOINT_HALT); log it as such.
            self.control_log.append((0x02, 0x01, 0, ep, 0))
            self._clear_halt(ep)

    def _clear_halt(self, ep: int) -> None:
        if ep == _EP_OUT:
            self.out_halted = False
        elif ep == _EP_IN:
            self.in_halted = False
        elif ep != _EP_INT:
            raise _usb_error("Invalid parameter", _LIBUSB_INVALID, errno.EINVAL)

    def reset_device(self, dev_handle):
        with self._lock:
            self._check(dev_handle)
            self._plug_in()
            self.kernel_driver_active = False   # the host that reset it keeps it

    # ------------------------------------------------------------------ bulk-OUT
    def bulk_write(self, dev_handle, ep, intf, data, timeout):
        with self._lock:
            self._check(dev_handle)
            if ep != _EP_OUT or self.configuration != 1:
                raise _usb_error("Invalid parameter", _LIBUSB_INVALID, errno.EINVAL)
            if self.out_halted:
                raise _stall()
            raw = bytes(data)
            self.bulk_out_log.append(raw)
            fault = self.usb_faults.next_write()
            if fault is UsbFaultKind.STALL_OUT:
                self.out_halted = True
                raise _stall()
            if fault is UsbFaultKind.WRITE_TIMEOUT and len(raw) > self.max_packet:
                # A multi-packet transfer gets its first packet through, then the device
                # NAKs until the host gives up; a one-packet transfer is NAKed outright.
                self._rx += raw[: self.max_packet]
                self._out_rxd += self.max_packet
                self._parse_out()
        if fault is UsbFaultKind.WRITE_TIMEOUT:
            time.sleep(timeout / 1000.0 if timeout else 1.0)
            raise usb.core.USBTimeoutError("Operation timed out", _LIBUSB_TIMEOUT,
                                           errno.ETIMEDOUT)
        with self._lock:
            self._check(dev_handle)
            self._rx += raw
            self._out_rxd += len(raw)
            self._parse_out()
            return len(raw)

    def _framing_error(self, why: str) -> None:
        # USBTMC 1.0 §3.2.2.3: a device that cannot decode a Bulk-OUT header halts
        # the endpoint; whatever was buffered is lost.
        self.framing_errors.append(why)
        self.out_halted = True
        self._rx.clear()
        self._message.clear()
        self._out_partial_btag = None

    def _parse_out(self) -> None:
        while len(self._rx) >= 12:
            msg_id, btag, inverse, zero = self._rx[0], self._rx[1], self._rx[2], self._rx[3]
            if btag == 0 or inverse != (~btag & 0xFF) or zero != 0:
                self._framing_error(f"bad bTag/bTagInverse {btag:#04x}/{inverse:#04x}")
                return
            size = struct.unpack_from("<I", self._rx, 4)[0]
            attributes = self._rx[8]
            if msg_id == _DEV_DEP_MSG_OUT:
                if bytes(self._rx[9:12]) != b"\0\0\0" or attributes & 0xFE:
                    self._framing_error("reserved bytes not zero")
                    return
                total = 12 + size + (-size % 4)
                if len(self._rx) < total:
                    self._out_partial_btag = btag
                    return
                payload = bytes(self._rx[12:12 + size])
                del self._rx[:total]
                self._out_partial_btag = None
                self._message += payload
                if attributes & 0x01:
                    message = bytes(self._message)
                    self._message.clear()
                    self._deliver(message)
            elif msg_id == _REQUEST_DEV_DEP_MSG_IN:
                if bytes(self._rx[10:12]) != b"\0\0" or attributes & 0xFD:
                    self._framing_error("reserved bytes not zero")
                    return
                term = self._rx[9] if attributes & 0x02 else None
                del self._rx[:12]
                if size == 0:
                    self._framing_error("REQUEST_DEV_DEP_MSG_IN for 0 bytes")
                    return
                self._pending = (btag, size, term)
                if self._response:
                    self._send_response()
                else:
                    self.firmware.query_unterminated()
            else:
                # Vendor-specific and USB488 TRIGGER messages are not supported.
                self._framing_error(f"unsupported MsgID {msg_id}")
                return

    def _deliver(self, message: bytes) -> None:
        if self._response or self._packets:
            # A new command while the previous response is unread (IEEE 488.2 §6.3.2.3).
            self._response.clear()
            self._packets.clear()
            self.firmware.query_interrupted()
        self._response += b"".join(self.firmware.receive(message))
        if self._pending is not None and self._response:
            self._send_response()

    # ------------------------------------------------------------------ bulk-IN
    def _send_response(self) -> None:
        assert self._pending is not None
        btag, max_size, term = self._pending
        self._pending = None
        n = min(len(self._response), max_size)
        attributes = 0
        if term is not None:
            at = self._response.find(bytes([term]), 0, n)
            if at >= 0:
                n = at + 1
                attributes |= 0x02
        data = bytes(self._response[:n])
        del self._response[:n]
        if not self._response:
            attributes |= 0x01   # EOM
        header = bytes([_DEV_DEP_MSG_IN, btag, ~btag & 0xFF, 0])
        header += struct.pack("<IBxxx", n, attributes)
        transfer = header + data + b"\0" * (-n % 4)
        self.bulk_in_log.append(transfer)
        firmware = self.firmware
        with firmware.lock:
            deliveries = firmware.faults.process(transfer, firmware)
        if not deliveries:
            self._in_btag = btag    # lost on the wire: the device thinks it was sent
            return
        if any(d.hold is not None for d in deliveries):
            raise ValueError("a held DELAY fault is for serial links; on USB a bulk-IN read "
                             "never takes a transfer that arrives after its deadline, so "
                             "delay_s alone makes a reply late")
        # A delayed or split transfer is complete only when its last piece arrives.
        at = time.monotonic() + max(d.delay_s for d in deliveries)
        wire = b"".join(d.data for d in deliveries)
        self._queue_packets(wire, at)
        self._in_btag = btag

    def _queue_packets(self, wire: bytes, at: float) -> None:
        mp = self.max_packet
        for start in range(0, len(wire), mp):
            self._packets.append((at, wire[start:start + mp]))
        if len(wire) % mp == 0:
            self._packets.append((at, b""))   # zero-length packet ends a full transfer

    def bulk_read(self, dev_handle, ep, intf, buff, timeout):
        deadline = time.monotonic() + (timeout / 1000.0 if timeout else 3600.0)
        while True:
            with self._lock:
                self._check(dev_handle)
                if ep != _EP_IN or self.configuration != 1:
                    raise _usb_error("Invalid parameter", _LIBUSB_INVALID, errno.EINVAL)
                if self.in_halted:
                    raise _stall()
                # A transfer that arrives after this read's deadline is not part of it,
                # even when the reading thread was descheduled past the deadline and only
                # looks now: a late reply stays late however loaded the host.
                now = min(time.monotonic(), deadline)
                if self._packets and self._packets[0][0] <= now:
                    return self._take_packets(buff, now)
                wait = deadline - now
                if self._packets:
                    wait = min(wait, self._packets[0][0] - now)
            if time.monotonic() >= deadline:
                raise usb.core.USBTimeoutError("Operation timed out", _LIBUSB_TIMEOUT,
                                               errno.ETIMEDOUT)
            time.sleep(min(max(wait, 0.0), 0.002))

    def _take_packets(self, buff: array.array, now: float) -> int:
        room = len(buff) * buff.itemsize
        n = 0
        while self._packets and self._packets[0][0] <= now:
            packet = self._packets[0][1]
            if len(packet) > room - n:
                if n == 0:
                    # The host asked for less than a packet: libusb reports an overflow
                    # and the packet is lost.
                    self._packets.popleft()
                    raise _usb_error("Overflow", _LIBUSB_OVERFLOW, errno.EOVERFLOW)
                break
            self._packets.popleft()
            buff[n:n + len(packet)] = array.array("B", packet)
            n += len(packet)
            self._in_txd += len(packet)
            if len(packet) < self.max_packet:
                break   # a short packet ends the transfer
        return n

    def intr_read(self, dev_handle, ep, intf, buff, timeout):
        # The interrupt endpoint never has anything to say in this model.
        with self._lock:
            self._check(dev_handle)
        time.sleep(timeout / 1000.0 if timeout else 0.0)
        raise usb.core.USBTimeoutError("Operation timed out", _LIBUSB_TIMEOUT,
                                       errno.ETIMEDOUT)

    # ------------------------------------------------------------------ control
    def ctrl_transfer(self, dev_handle, bmRequestType, bRequest, wValue, wIndex, data,
                      timeout):
        with self._lock:
            self._check(dev_handle)
            length = len(data) * data.itemsize
            self.control_log.append((bmRequestType, bRequest, wValue, wIndex, length))
            kind = bmRequestType & (3 << 5)
            recipient = bmRequestType & 3
            if kind == usb.util.CTRL_TYPE_STANDARD:
                reply = self._standard_request(bmRequestType, bRequest, wValue, wIndex)
            elif kind == usb.util.CTRL_TYPE_CLASS and recipient == 1 and wIndex == 0:
                reply = self._interface_request(bRequest, wValue)
            elif kind == usb.util.CTRL_TYPE_CLASS and recipient == 2:
                reply = self._endpoint_request(bRequest, wValue, wIndex)
            else:
                raise _stall()
            if bmRequestType & usb.util.CTRL_IN:
                n = min(len(reply), length)
                data[:n] = array.array("B", reply[:n])
                return n
            return length

    def _standard_request(self, rtype: int, request: int, value: int, index: int) -> bytes:
        if rtype == 0x80 and request == 0x06:           # GET_DESCRIPTOR
            return self._descriptor_bytes(value >> 8, value & 0xFF, index)
        if rtype in (0x80, 0x81, 0x82) and request == 0x00:   # GET_STATUS
            return b"\0\0"
        if rtype == 0x02 and request == 0x01 and value == 0:  # CLEAR_FEATURE(HALT)
            self._clear_halt(index)
            return b""
        if rtype == 0x80 and request == 0x08:           # GET_CONFIGURATION
            return bytes([self.configuration])
        raise _stall()

    def _interface_request(self, request: int, value: int) -> bytes:
        if self.configuration != 1:
            raise _stall()
        if request == _INITIATE_CLEAR:
            # USBTMC §4.2.1.6: discard every buffered input and output.
            self._reset_io()
            self._clear_polls_left = self.clear_pending_polls
            return bytes([_SUCCESS])
        if request == _CHECK_CLEAR_STATUS:
            if self._clear_polls_left > 0:
                self._clear_polls_left -= 1
                return bytes([_PENDING, 0])
            return bytes([_SUCCESS, 0])
        if request == _GET_CAPABILITIES:
            caps = bytearray(0x18)
            caps[0] = _SUCCESS
            caps[2:4] = struct.pack("<H", 0x0100)   # bcdUSBTMC 1.00
            caps[4] = 0x04                           # accepts INDICATOR_PULSE
            caps[5] = 0x01                           # supports TermChar
            caps[12:14] = struct.pack("<H", 0x0100)  # bcdUSB488 1.00
            caps[14] = 0x04                          # USB488.2 interface
            caps[15] = 0x08                          # understands SCPI
            return bytes(caps)
        if request == _INDICATOR_PULSE:
            return bytes([_SUCCESS])
        raise _stall()

    def _endpoint_request(self, request: int, value: int, index: int) -> bytes:
        btag = value & 0xFF
        if request == _INITIATE_ABORT_BULK_OUT and index == _EP_OUT:
            if self._out_partial_btag is None:
                return bytes([_FAILED, btag])
            if btag != self._out_partial_btag:
                return bytes([_NOT_IN_PROGRESS, self._out_partial_btag])
            self._rx.clear()
            self._message.clear()
            self._out_partial_btag = None
            self._abort_out_status = _SUCCESS
            return bytes([_SUCCESS, btag])
        if request == _CHECK_ABORT_BULK_OUT_STATUS and index == _EP_OUT:
            status, self._abort_out_status = self._abort_out_status, _FAILED
            return struct.pack("<BxxxI", status, self._out_rxd)
        if request == _INITIATE_ABORT_BULK_IN and index == _EP_IN:
            current = self._pending[0] if self._pending is not None else self._in_btag
            in_progress = self._pending is not None or bool(self._packets)
            if not in_progress and self._in_btag is None:
                return bytes([_FAILED, btag])
            if btag != current:
                return bytes([_NOT_IN_PROGRESS, current or 0])
            # Drop what is queued and finish the transfer with a short packet.
            self._pending = None
            self._packets.clear()
            self._response.clear()
            self._in_btag = None
            self._packets.append((time.monotonic(), b""))
            return bytes([_SUCCESS, btag])
        if request == _CHECK_ABORT_BULK_IN_STATUS and index == _EP_IN:
            if self._packets:
                return struct.pack("<BBxxI", _PENDING, 0x01, self._in_txd)
            return struct.pack("<BBxxI", _SUCCESS, 0x00, self._in_txd)
        raise _stall()
