"""Thorlabs PM100USB optical power meter (USBTMC, VID 0x1313 / PID 0x8072).

SCPI subset used (Thorlabs *PM100USB Operation Manual* (2020), ch. 7 "Computer Interface";
QMI ``pm100d.py``, pylablib ``GenericPM``): ``*IDN?`` →
``Thorlabs,PM100USB,<serial>,<firmware>``; ``SYST:SENS:IDN?`` → sensor name, serial,
calibration message, type, subtype, flags; ``SENS:CORR:WAV <nm>`` and ``SENS:CORR:WAV?
MIN|MAX`` (the photodiode responsivity correction: a wrong wavelength gives a wrong power);
``SENS:POW:RANG:AUTO 0|1``; ``SENS:AVER:COUN <n>``; ``MEAS:POW?`` (W); dark zero with
``SENS:CORR:COLL:ZERO:INIT`` and polling ``…:ZERO:STAT?`` (1 while running, 0 when done;
open-source drivers disagree, QMI against pylablib, so the poll also stops on any other value only
after the timeout); ``SYST:ERR?``.

Every *setting* command is followed by draining ``SYST:ERR?`` until ``0``; any error there
raises :class:`ControllerError` carrying the SCPI code (e.g. -222 data out of range).
Queries are not followed by ``SYST:ERR?`` (it would halve the reading rate); a query the
device rejects sends no response, so its timeout is turned into the queued
:class:`ControllerError` when there is one.
"""

from __future__ import annotations

import re
import threading
import time
from dataclasses import dataclass
from typing import Any

from drivers.base import DeviceIdentity, PowerMeter
from drivers.errors import (
    ConnectionFailed,
    ControllerError,
    DeviceError,
    DeviceTimeout,
    ProtocolError,
)
from drivers.usbtmc import UsbtmcDevice

__all__ = ["PM100USB", "SensorInfo", "parse_scpi_error", "parse_scpi_number"]

VENDOR_ID = 0x1313
PRODUCT_ID = 0x8072

# SCPI <NR1>|<NR2>|<NR3> response data (IEEE 488.2 §8.7): sign, digits, point, exponent.
# ASCII: SCPI replies are ASCII; Unicode \s would accept separators such as U+001F.
_NUMBER = re.compile(r"\s*([+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)\s*", re.ASCII)
_ERROR = re.compile(r'\s*([+-]?\d+)\s*,\s*"(.*)"\s*', re.DOTALL | re.ASCII)
# SCPI-99 §7.2.1: 9.9E37 is "not a number / overflow" in instrument replies.
_SCPI_NAN = 9.91e37


def parse_scpi_number(text: str, *, command: str | None = None,
                      device: str | None = None) -> float:
    """A SCPI numeric response (NR1/NR2/NR3) as float.

    Raises
    ------
    ProtocolError
        Anything else: empty text, words, ``nan``/``inf`` spellings, several numbers,
        or the SCPI overflow marker 9.9E37.
    """
    match = _NUMBER.fullmatch(text)
    if match is None:
        raise ProtocolError(f"expected a number, got {text[:40]!r}", device=device,
                            command=command)
    value = float(match.group(1))
    if abs(value) >= _SCPI_NAN * 0.99:
        raise ProtocolError(f"instrument reports over-range ({text.strip()})", device=device,
                            command=command)
    return value


def parse_scpi_error(text: str, *, device: str | None = None) -> tuple[int, str]:
    """``-222,"Data out of range"`` → ``(-222, "Data out of range")``."""
    match = _ERROR.fullmatch(text)
    if match is None:
        raise ProtocolError(f"malformed SYST:ERR? reply {text[:60]!r}", device=device,
                            command="SYST:ERR?")
    return int(match.group(1)), match.group(2)


@dataclass(frozen=True)
class SensorInfo:
    """The sensor head as ``SYST:SENS:IDN?`` describes it."""

    name: str
    serial: str
    calibration: str
    sensor_type: str
    subtype: str
    flags: str


class PM100USB(PowerMeter):
    """Thorlabs PM100USB console with its sensor head.

    Parameters
    ----------
    name
        Role name on the bench (``"power_meter"``).
    serial_number
        Open the console with this USB serial number (``None``: the first one found).
    backend
        pyusb backend for ``usb.core.find`` (``None``: libusb). Tests pass the emulated
        device from ``hw_mocks.usb``.
    timeout_s
        Per-transfer timeout.
    zero_poll_s
        Interval between ``ZERO:STAT?`` polls while zeroing.

    Raises
    ------
    ConnectionFailed
        No such console, or it cannot be claimed.
    ProtocolError
        It does not identify as a Thorlabs power meter.
    """

    def __init__(
        self,
        *,
        name: str,
        serial_number: str | None = None,
        backend: Any = None,
        timeout_s: float = 2.0,
        zero_poll_s: float = 0.05,
        vendor_id: int = VENDOR_ID,
        product_id: int = PRODUCT_ID,
    ) -> None:
        super().__init__(name)
        self.zero_poll_s = float(zero_poll_s)
        # A setting and its SYST:ERR? check must not interleave with another thread's.
        self._lock = threading.RLock()
        self._link = UsbtmcDevice(
            vendor_id=vendor_id, product_id=product_id, serial_number=serial_number,
            backend=backend, timeout_s=timeout_s, name=name,
        )
        try:
            self._identity = self._read_identity()
            # Errors queued before we arrived are not ours to report.
            self._link.write("*CLS")
            low = self._query_number("SENS:CORR:WAV? MIN")
            high = self._query_number("SENS:CORR:WAV? MAX")
            if not 0 < low < high:
                raise ProtocolError(f"implausible wavelength range {low}..{high} nm",
                                    device=name, command="SENS:CORR:WAV? MIN/MAX")
            self.wavelength_range_nm = (low, high)
        except BaseException:
            self._link.close()
            raise

    # -- identity -----------------------------------------------------------------------
    def _read_identity(self) -> DeviceIdentity:
        fields = [f.strip() for f in self._query("*IDN?").split(",")]
        if len(fields) != 4 or not fields[0].lower().startswith("thorlabs"):
            raise ProtocolError(f"not a Thorlabs power meter: *IDN? gave {fields!r}",
                                device=self.name, command="*IDN?")
        sensor = self._read_sensor()
        return DeviceIdentity(
            vendor=fields[0], model=fields[1], serial=fields[2], firmware=fields[3],
            extra={"sensor": sensor.name, "sensor_serial": sensor.serial,
                   "sensor_calibration": sensor.calibration,
                   "sensor_type": sensor.sensor_type},
        )

    def _read_sensor(self) -> SensorInfo:
        fields = [f.strip() for f in self._query("SYST:SENS:IDN?").split(",")]
        if len(fields) < 6:
            raise ProtocolError(f"SYST:SENS:IDN? gave {len(fields)} fields, expected 6",
                                device=self.name, command="SYST:SENS:IDN?")
        return SensorInfo(*fields[:6])

    @property
    def sensor(self) -> SensorInfo:
        """The sensor head plugged in now (read from the console)."""
        self._check_open("sensor")
        return self._read_sensor()

    def _do_identity(self) -> DeviceIdentity:
        return self._read_identity()

    # -- SCPI plumbing ------------------------------------------------------------------
    def query(self, command: str) -> str:
        """Send a SCPI query and return its response text."""
        self._check_open(command)
        return self._query(command)

    def command(self, command: str) -> None:
        """Send a SCPI setting command, then check the error queue.

        Raises
        ------
        ControllerError
            The console queued an error; ``code`` is the SCPI error number.
        """
        self._check_open(command)
        self._command(command)

    def _query(self, command: str) -> str:
        with self._lock:
            try:
                return self._link.query(command)
            except DeviceTimeout as timeout:
                # A rejected query sends no response: the error queue says why.
                errors = self._drain_errors()
                if errors:
                    raise self._controller_error(errors, command) from timeout
                raise

    def _query_number(self, command: str) -> float:
        return parse_scpi_number(self._query(command), command=command, device=self.name)

    def _command(self, command: str) -> None:
        with self._lock:
            self._link.write(command)
            errors = self._drain_errors()
        if errors:
            raise self._controller_error(errors, command)

    def _drain_errors(self) -> list[tuple[int, str]]:
        errors: list[tuple[int, str]] = []
        # SCPI queues hold a bounded number of entries; 32 reads empty any of them.
        for _ in range(32):
            code, message = parse_scpi_error(self._link.query("SYST:ERR?"), device=self.name)
            if code == 0:
                return errors
            errors.append((code, message))
        raise ProtocolError("SYST:ERR? never reported an empty queue", device=self.name,
                            command="SYST:ERR?")

    def _controller_error(self, errors: list[tuple[int, str]], command: str
                          ) -> ControllerError:
        code, message = errors[0]
        text = f"SCPI error {code}: {message}"
        if len(errors) > 1:
            text += " (then " + "; ".join(f"{c}: {m}" for c, m in errors[1:]) + ")"
        return ControllerError(text, code=code, device=self.name, command=command)

    # -- PowerMeter hooks ---------------------------------------------------------------
    def _do_get_wavelength_nm(self) -> float:
        return self._query_number("SENS:CORR:WAV?")

    def _do_set_wavelength_nm(self, value: float) -> None:
        self._command(f"SENS:CORR:WAV {value:.9g}")

    def _do_get_averaging(self) -> int:
        value = self._query_number("SENS:AVER:COUN?")
        if value != int(value):
            raise ProtocolError(f"averaging count {value} is not an integer",
                                device=self.name, command="SENS:AVER:COUN?")
        return int(value)

    def _do_set_averaging(self, count: int) -> None:
        self._command(f"SENS:AVER:COUN {count}")

    def _do_get_auto_range(self) -> bool:
        value = self._query_number("SENS:POW:RANG:AUTO?")
        if value not in (0.0, 1.0):
            raise ProtocolError(f"auto-range state {value} is not 0 or 1", device=self.name,
                                command="SENS:POW:RANG:AUTO?")
        return value == 1.0

    def _do_set_auto_range(self, on: bool) -> None:
        self._command(f"SENS:POW:RANG:AUTO {1 if on else 0}")

    def _do_read_power_w(self) -> float:
        return self._query_number("MEAS:POW?")

    def _do_zero(self, timeout: float) -> None:
        if not timeout > 0:
            raise ValueError(f"{self.name}: zero timeout must be > 0, got {timeout}")
        self._command("SENS:CORR:COLL:ZERO:INIT")
        deadline = time.monotonic() + timeout
        while True:
            state = self._query_number("SENS:CORR:COLL:ZERO:STAT?")
            if state == 0:
                return
            if time.monotonic() >= deadline:
                try:
                    self._command("SENS:CORR:COLL:ZERO:ABOR")
                except DeviceError as err:
                    if isinstance(err, ConnectionFailed):
                        raise
                raise DeviceTimeout(
                    f"dark zero did not finish within {timeout:g} s", device=self.name,
                    command="SENS:CORR:COLL:ZERO:INIT",
                    hint="the zero was aborted; block the light and try again")
            time.sleep(min(self.zero_poll_s, max(deadline - time.monotonic(), 0.0)))

    @property
    def zero_offset_w(self) -> float:
        """The dark offset the last zero subtracts (W, ``ZERO:MAGN?``)."""
        self._check_open("zero_offset_w")
        return self._query_number("SENS:CORR:COLL:ZERO:MAGN?")

    def _do_close(self) -> None:
        self._link.close()
