"""The EM-1's firmware emulator: the device side of :mod:`example_meter.protocol`.

It is a :class:`hw_mocks.emulator.FirmwareEmulator` (scatterlab's base of every emulator:
bytes in, reply frames out, a clock, a seeded fault injector), so the links, the
pseudo-terminal server and the fault injection of ``hw_mocks`` serve it as they serve the
built-in controllers.

The light it reads: with ``world`` set, the optical power the virtual bench of that name
sends onto its power-meter head (:meth:`hw_mocks.sim.world.VirtualBench.optical_power_w`,
looked up at every reading, so the meter may be opened before the world is configured:
it reads darkness until then); otherwise :attr:`incident_w`, which a test sets.

Each reading is the incident power plus a dark offset, less the zero, plus Gaussian noise
of σ = √((1e-4·P)² + (1e-10 W)²)/√n over n averaged readings (a photodiode's relative
noise and its amplifier's floor; seeded).
"""

from __future__ import annotations

import math

import numpy as np

from example_meter import protocol
from hw_mocks import registry
from hw_mocks.emulator import FirmwareEmulator

__all__ = ["DARK_OFFSET_W", "Em1Emulator"]

#: What the meter reads in the dark before it is zeroed (W).
DARK_OFFSET_W = 5e-9
RELATIVE_NOISE = 1e-4
NOISE_FLOOR_W = 1e-10


class Em1Emulator(FirmwareEmulator):
    """An emulated EM-1. ``world`` names the virtual bench it reads; ``serial`` is what
    ``*IDN?`` reports."""

    scheme = "simem1"
    baudrate = protocol.BAUDRATE

    def __init__(self, name: str, *, serial: str = "EM0001", world: str | None = None,
                 seed: int = 0, **kw) -> None:
        super().__init__(name, seed=seed, **kw)
        self.serial = serial
        self.world = world
        #: Power on the sensor (W) when no world is named.
        self.incident_w = 0.0
        self.wavelength_nm = 633.0
        self.averaging = 1
        self.auto_range = True
        self.zero_w = 0.0
        self.error_code: int | None = None
        self._rng = np.random.default_rng(seed)

    def optical_power_w(self) -> float:
        """The power arriving on the sensor now (W)."""
        if self.world is None:
            return self.incident_w
        world = registry.find_world(self.world)
        return 0.0 if world is None else float(world.optical_power_w(self.wavelength_nm))

    def _reading_w(self) -> float:
        power = self.optical_power_w()
        sigma = math.hypot(RELATIVE_NOISE * power, NOISE_FLOOR_W) / math.sqrt(self.averaging)
        return power + DARK_OFFSET_W - self.zero_w + float(self._rng.normal(0.0, sigma))

    # --- bytes in, frames out ---------------------------------------------------------
    def _handle_input(self, buf: bytearray) -> list[bytes]:
        replies = []
        while protocol.TERMINATOR in buf:
            end = buf.index(protocol.TERMINATOR)
            line = bytes(buf[:end]).decode("ascii", "replace").strip()
            del buf[:end + 1]
            if line:
                replies.append(self._reply(line).encode("ascii") + protocol.TERMINATOR)
        return replies

    def _reply(self, line: str) -> str:
        if self.error_code is not None:
            code, self.error_code = self.error_code, None
            return f"ERR {code}"
        command, _, arg = line.partition(" ")
        if command == "*IDN?":
            return f"{protocol.VENDOR},EM-1,{self.serial},1.0"
        if command == "WAVE?":
            return f"{self.wavelength_nm:.1f}"
        if command == "AVG?":
            return str(self.averaging)
        if command == "RANGE?":
            return "AUTO" if self.auto_range else "MANUAL"
        if command == "POW?":
            return f"{self._reading_w():.6E}"
        if command == "ZERO":
            self.zero_w += self._reading_w()
            return "OK"
        if command == "RANGE" and arg in ("AUTO", "MANUAL"):
            self.auto_range = arg == "AUTO"
            return "OK"
        if command in ("WAVE", "AVG"):
            return self._set_number(command, arg)
        return "ERR 1"

    def _set_number(self, command: str, arg: str) -> str:
        try:
            value = float(arg)
        except ValueError:
            return "ERR 3"
        if command == "WAVE":
            low, high = protocol.WAVELENGTH_RANGE_NM
            if not low <= value <= high:
                return "ERR 2"
            self.wavelength_nm = value
        else:
            if value != int(value) or not 1 <= value <= protocol.MAX_AVERAGING:
                return "ERR 2"
            self.averaging = int(value)
        return "OK"

    # --- what the fault injector asks of every emulator ---------------------------------
    def unsolicited_frame(self) -> bytes:
        return b"ERR 9" + protocol.TERMINATOR

    def enter_error_state(self, code: str | None = None) -> None:
        self.error_code = int(code) if code and code.isdigit() else 9
