"""The PM100USB model's command set: the manual's headers it leaves out are answered as
the console answers an unknown header (-113 queued, no response)."""

from __future__ import annotations

import pytest

from hw_mocks.firmware.pm100usb import NOT_EMULATED_HEADERS, Pm100usbFirmware


@pytest.mark.parametrize("header", NOT_EMULATED_HEADERS)
def test_not_emulated_headers_are_undefined(header):
    fw = Pm100usbFirmware("cs")
    assert fw.receive(header.encode("ascii") + b"\n") == []
    assert [code for code, _ in fw.error_queue] == [-113]
    assert fw.receive(b"*IDN?\n")[0].startswith(b"Thorlabs")  # still answering
