"""Driver of the EM-1 power meter: :class:`drivers.base.PowerMeter`'s ``_do_*`` hooks
over the ASCII protocol of :mod:`example_meter.protocol`.

The ABC validates every argument (a wavelength outside :attr:`wavelength_range_nm`, an
averaging count below 1) before a hook runs; the hooks only talk to the meter. Every
failure is a :mod:`drivers.errors` exception naming the device and the command.
"""

from __future__ import annotations

import math
import threading

import serial

from drivers.base import DeviceIdentity, PowerMeter
from drivers.errors import ConnectionFailed, ControllerError, ProtocolError
from drivers.transport import SerialChannel, open_serial
from example_meter import protocol

__all__ = ["Em1PowerMeter"]


class Em1PowerMeter(PowerMeter):
    """An EM-1 power meter on ``port``: a device path, a pyserial URL (``simem1://pm``)
    or an open ``serial.SerialBase`` (the caller keeps that one: it is not closed here).

    Raises :class:`~drivers.errors.ConnectionFailed` if the port does not open or the
    device on it is not an EM-1.
    """

    wavelength_range_nm = protocol.WAVELENGTH_RANGE_NM

    def __init__(self, port: str | serial.SerialBase, *, name: str,
                 baudrate: int = protocol.BAUDRATE, reply_timeout: float = 0.5) -> None:
        super().__init__(name)
        self._timeout = float(reply_timeout)
        self._owns_port = not isinstance(port, serial.SerialBase)
        self._port = open_serial(port, device=name, baudrate=baudrate, timeout=reply_timeout)
        # one command and its reply at a time (the GUI's poll and a run may share the meter)
        self._lock = threading.Lock()
        try:
            self._link = SerialChannel(self._port, device=name)
            self._link.discard_input()
            idn = self._query("*IDN?")
            fields = idn.split(",")
            if len(fields) != 4 or fields[0] != protocol.VENDOR:
                raise ConnectionFailed(f"the device answers *IDN? with {idn!r}, not an EM-1",
                                       device=name, command="*IDN?",
                                       hint="check that the port is the power meter's")
            self._idn = fields
        except BaseException:
            if self._owns_port:
                self._port.close()
            raise

    def _query(self, command: str) -> str:
        """Send one command line and return its reply line; ``ERR n`` raises."""
        with self._lock:
            self._link.write(command.encode("ascii") + protocol.TERMINATOR, command=command)
            line = self._link.read_line(protocol.TERMINATOR, timeout=self._timeout,
                                        command=command)
        reply = line.decode("ascii", "replace").strip()
        if reply.startswith("ERR"):
            code = reply[3:].strip()
            what = protocol.ERROR_CODES.get(int(code) if code.isdigit() else -1, "unknown")
            raise ControllerError(f"the meter refused {command!r}: {reply} ({what})",
                                  code=code, device=self.name, command=command)
        return reply

    def _set(self, command: str) -> None:
        reply = self._query(command)
        if reply != "OK":
            raise ProtocolError(f"expected OK, got {reply!r}", device=self.name,
                                command=command)

    def _number(self, command: str) -> float:
        reply = self._query(command)
        try:
            value = float(reply)
        except ValueError:
            value = math.nan
        if not math.isfinite(value):
            raise ProtocolError(f"expected a number, got {reply!r}", device=self.name,
                                command=command)
        return value

    # --- the PowerMeter hooks ---------------------------------------------------------
    def _do_identity(self) -> DeviceIdentity:
        vendor, model, serial_number, firmware = self._idn
        return DeviceIdentity(vendor, model, serial_number, firmware)

    def _do_get_wavelength_nm(self) -> float:
        return self._number("WAVE?")

    def _do_set_wavelength_nm(self, value: float) -> None:
        self._set(f"WAVE {value:.1f}")

    def _do_get_averaging(self) -> int:
        return int(self._number("AVG?"))

    def _do_set_averaging(self, count: int) -> None:
        if count > protocol.MAX_AVERAGING:  # the ABC checks >= 1; the EM-1's own ceiling
            raise ValueError(f"{self.name}: the EM-1 averages at most "
                             f"{protocol.MAX_AVERAGING} readings, got {count}")
        self._set(f"AVG {count}")

    def _do_get_auto_range(self) -> bool:
        reply = self._query("RANGE?")
        if reply not in ("AUTO", "MANUAL"):
            raise ProtocolError(f"expected AUTO or MANUAL, got {reply!r}", device=self.name,
                                command="RANGE?")
        return reply == "AUTO"

    def _do_set_auto_range(self, on: bool) -> None:
        self._set("RANGE AUTO" if on else "RANGE MANUAL")

    def _do_read_power_w(self) -> float:
        return self._number("POW?")

    def _do_zero(self, timeout: float) -> None:
        self._set("ZERO")  # the EM-1 zeroes at once and then answers

    def _do_close(self) -> None:
        if self._owns_port:
            self._link.close()
