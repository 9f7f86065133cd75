"""pyserial URL handler ``simpem://<name>?frequency=50000&speed=1&seed=0``.

Options (applied when the named emulator is first created): ``frequency``, the head's
resonance in Hz (default 50 kHz, a fused-silica head); ``speed=<factor>`` or
``step=<seconds>``, the emulator clock; ``seed``, the fault-injector seed.
"""

from __future__ import annotations

from hw_mocks.emulator import clock_from_options
from hw_mocks.firmware.pem200 import Pem200Emulator
from hw_mocks.link import EmulatedSerial

__all__ = ["Serial", "make_emulator"]


def make_emulator(name: str, options: dict[str, str]) -> Pem200Emulator:
    """Build the emulator a ``simpem://`` URL describes."""
    return Pem200Emulator(name, frequency_hz=float(options.get("frequency", 50_000.0)),
                          clock=clock_from_options(options), seed=int(options.get("seed", 0)))


class Serial(EmulatedSerial):
    scheme = "simpem"
    factory = staticmethod(make_emulator)
