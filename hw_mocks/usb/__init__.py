"""Emulated USB instruments reached by ``simusb://`` URLs.

``backend_from_url("simusb://power_meter?serial=P2000000&seed=0")`` returns a pyusb
backend (:class:`~hw_mocks.usb.backend.EmulatedUsbtmcBackend`) to pass to a USB driver
as ``backend=``; ``usb.core.find(backend=…)`` then finds the emulated PM100USB.

The firmware model lives in :mod:`hw_mocks.registry` under ``("simusb", name)``, like the
serial emulators, so reopening the URL reaches the same device and ``registry.reset()``
(done around every test) powers it off. Tests and the virtual bench reach the backdoor
with :func:`get_firmware` (set ``optical_power_w``, inject faults) and :func:`get_backend`
(USB-level logs and faults).

URL options (applied when the device is first created):

``serial``      console serial number (default ``P2000000``)
``seed``        seeds the fault injector, USB faults and sensor noise (default 0)
``speed``/``step``  emulator clock (:func:`hw_mocks.emulator.clock_from_options`)
``packet``      bulk wMaxPacketSize (8, 16, 32, 64 (default) or 512)
``kernel``      1 (default): the kernel usbtmc driver is bound at plug-in; 0: it is not
``configured``  1 (default): configured at plug-in; 0: unconfigured
``clear_polls`` CHECK_CLEAR_STATUS answers PENDING this many times first (default 1)
"""

from __future__ import annotations

import threading

from hw_mocks import registry
from hw_mocks.emulator import clock_from_options
from hw_mocks.firmware.pm100usb import Pm100usbFirmware
from hw_mocks.usb.backend import EmulatedUsbtmcBackend

__all__ = ["SCHEME", "EmulatedUsbtmcBackend", "backend_from_url", "get_backend", "get_firmware"]

SCHEME = "simusb"

_lock = threading.Lock()
#: One backend (the USB side of the device) per firmware instance, by device name.
_backends: dict[str, EmulatedUsbtmcBackend] = {}


def _make_firmware(name: str, options: dict[str, str]) -> Pm100usbFirmware:
    return Pm100usbFirmware(
        name,
        serial=options.get("serial", "P2000000"),
        clock=clock_from_options(options),
        seed=int(options.get("seed", 0)),
    )


def backend_from_url(url: str) -> EmulatedUsbtmcBackend:
    """The pyusb backend of the emulated device named by ``simusb://<name>?…``.

    Opening a URL plugs the device in (a DISCONNECT fault is undone), as
    :class:`hw_mocks.link.EmulatedSerial` reconnects a serial link.
    """
    scheme, name, options = registry.parse_url(url)
    if scheme != SCHEME:
        raise ValueError(f"expected a {SCHEME}:// URL, got {url!r}")
    firmware = registry.get_or_create(SCHEME, name, _make_firmware, options)
    with _lock:
        backend = _backends.get(name)
        if backend is None or backend.firmware is not firmware:
            backend = EmulatedUsbtmcBackend(
                firmware,
                max_packet=int(options.get("packet", 64)),
                kernel_driver=options.get("kernel", "1") != "0",
                configured=options.get("configured", "1") != "0",
                clear_pending_polls=int(options.get("clear_polls", 1)),
                seed=int(options.get("seed", 0)),
            )
            _backends[name] = backend
    backend.replug()
    _bind_to_world(firmware, options.get("world"))
    return backend


def _bind_to_world(firmware: Pm100usbFirmware, world_name: str | None) -> None:
    """Let a meter whose URL names a world (``world=sim``) read its light from that world.

    Needed when the device is (re)created after the world was configured, e.g. after an
    emulated power cycle; a world that does not exist yet binds the meter when it is made.
    """
    if world_name is None or getattr(firmware, "bound_world", None) is not None:
        return
    world = registry.find_world(world_name)
    if world is not None:
        world.bind_power_meter(firmware)


def get_firmware(name: str) -> Pm100usbFirmware:
    """The firmware model of ``simusb://<name>`` (KeyError if not created)."""
    firmware = registry.get(SCHEME, name)
    assert isinstance(firmware, Pm100usbFirmware)
    return firmware


def get_backend(name: str) -> EmulatedUsbtmcBackend:
    """The backend of ``simusb://<name>`` (KeyError if not created or powered off)."""
    firmware = registry.get(SCHEME, name)
    with _lock:
        backend = _backends.get(name)
    if backend is None or backend.firmware is not firmware:
        raise KeyError(f"no USB device {SCHEME}://{name} has been opened")
    return backend
