"""The SMC100 emulator's command set: what the manual lists and the emulator leaves out is
answered as the controller answers an unknown command (nothing; ``TE`` reads ``A``)."""

from __future__ import annotations

import pytest

from hw_mocks.clock import ManualClock
from hw_mocks.firmware.smc100 import NOT_EMULATED, Smc100Emulator


def ask(emu: Smc100Emulator, request: str) -> list[bytes]:
    return emu.receive(request.encode("ascii") + b"\r\n")


@pytest.mark.parametrize("command", NOT_EMULATED)
@pytest.mark.parametrize("form", ["{}", "{}?", "{}1"])
def test_not_emulated_commands_answer_as_unknown(command, form):
    emu = Smc100Emulator("cs", clock=ManualClock())
    assert ask(emu, "1" + form.format(command)) == []
    assert ask(emu, "1TE") == [b"1TEA\r\n"]
    assert ask(emu, "1TE") == [b"1TE@\r\n"]  # read clears the latch
