"""The registration scatterlab finds under the entry point ``example_meter`` (this
package's ``pyproject.toml``): the kind, the class, the profile keys and the emulator."""

from __future__ import annotations

from instrument.bench.driver_registry import DriverEntry, Emulator, Option

__all__ = ["DRIVER"]

DRIVER = DriverEntry(
    kind="power_meter",
    # imported when a device is opened: validating a profile needs only this module
    driver="example_meter.driver:Em1PowerMeter",
    summary="EM-1 power meter, ASCII over RS-232 (the example plugin)",
    # the keyword arguments of Em1PowerMeter that a profile's `options` may give
    options={"reply_timeout": Option(float, 0.01, 10.0, doc="seconds to wait for a reply"),
             "baudrate": Option(int, 1200, 115200, doc="the meter's configured rate")},
    # the public PowerMeter properties a profile's `settings` may set after opening
    settings={"wavelength_nm": Option(float, 300.0, 1100.0, doc="correction wavelength"),
              "averaging": Option(int, 1, 1000), "auto_range": Option(bool)},
    # profiles' `simem1://NAME` URLs open the emulator: pyserial imports
    # example_meter.urlhandler.protocol_simem1
    emulator=Emulator("simem1", "example_meter.urlhandler"),
)
