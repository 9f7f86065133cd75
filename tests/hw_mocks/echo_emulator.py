"""A toy line-protocol emulator used to test the link machinery on its own."""

from __future__ import annotations

from hw_mocks.emulator import FirmwareEmulator
from hw_mocks.link import EmulatedSerial


class EchoEmulator(FirmwareEmulator):
    """Replies ``OK <line>\\r\\n`` to every ``<line>\\n``; ``ERR`` after an error state."""

    scheme = "simecho"
    baudrate = 9600

    def __init__(self, name, **kw):
        super().__init__(name, **kw)
        self.error = None

    def _handle_input(self, buf):
        out = []
        while b"\n" in buf:
            line, _, rest = bytes(buf).partition(b"\n")
            buf[:] = rest
            out.append((b"ERR " if self.error else b"OK ") + line + b"\r\n")
        return out

    def unsolicited_frame(self):
        return b"!ALERT\r\n"

    def enter_error_state(self, code=None):
        self.error = code or "E"


class EchoSerial(EmulatedSerial):
    scheme = "simecho"
    factory = staticmethod(lambda name, opts: EchoEmulator(name, seed=int(opts.get("seed", 0))))
