"""The EM-1's wire protocol, shared by the driver and the emulator.

9600 baud, 8N1. The host sends one command per line (ASCII, ending in ``\\n``); the meter
answers every command with one line ending in ``\\n``: the value asked for, ``OK`` for a
setting, or ``ERR <code>``.

=================  =====================================  ======================
command            reply                                  meaning
=================  =====================================  ======================
``*IDN?``          ``EXAMPLE,EM-1,<serial>,<firmware>``   identity
``WAVE?``          ``633.0``                              correction wavelength, nm
``WAVE <nm>``      ``OK``                                 300 to 1100 nm
``AVG?``           ``10``                                 readings averaged
``AVG <n>``        ``OK``                                 1 to 1000
``RANGE?``         ``AUTO`` or ``MANUAL``                 ranging
``RANGE AUTO``     ``OK``                                 (or ``RANGE MANUAL``)
``ZERO``           ``OK``                                 the present reading is the new zero
``POW?``           ``1.2345E-06``                         power, W
=================  =====================================  ======================
"""

from __future__ import annotations

__all__ = ["BAUDRATE", "ERROR_CODES", "MAX_AVERAGING", "TERMINATOR", "VENDOR",
           "WAVELENGTH_RANGE_NM"]

BAUDRATE = 9600
TERMINATOR = b"\n"
VENDOR = "EXAMPLE"
WAVELENGTH_RANGE_NM = (300.0, 1100.0)
MAX_AVERAGING = 1000
#: ``ERR <code>`` → what it means.
ERROR_CODES = {1: "unknown command", 2: "value out of range", 3: "malformed number",
               9: "internal fault"}
