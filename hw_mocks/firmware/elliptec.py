"""Firmware emulator of a bus of Thorlabs Elliptec rotation mounts (ELL14).

Written from the protocol facts (Thorlabs *ELLx modules protocol manual*, Issue 5),
independently of ``drivers/``: it imports nothing from there, so a misreading shared by
the driver and the emulator cannot pass unnoticed.

The device side of the protocol:

- Host → module: ``<address><mnemonic><data>``, a fixed-length packet without terminator:
  the address ``0``-``F``, a two-letter lower-case mnemonic, then the command's fixed data
  (``ma``/``mr``/``sj``: 8 hex digits, two's complement pulses; ``sv``: 2 hex; ``ho``: one
  direction character). CR and LF between packets are ignored. A packet to an address no
  module has is ignored (nobody answers). An unknown mnemonic is answered ``GS03``
  (command error) and its data, if any, is taken for the next packet's start.
- Module → host: ``<address><MNEMONIC><data>`` CR LF.

Default behaviour, declared once:

- Each module is an ELL14: 143360 pulses per revolution, continuous rotation, maximum
  speed 430°/s at 100 % velocity (power-up 100 %), a resonant-motor acceleration of
  5000°/s² **[assumed]**, power-up counter 0 wherever the optic is (physical
  ``start_positions``), so that a home (``ho``) is needed to reference it.
- Motion commands (``ma``, ``mr``, ``ho``, ``fw``, ``bw``) are answered when the motion
  ends: ``PO`` with the final position, or ``GS`` with the reason it failed. While a
  module moves, ``gs`` answers ``GS09`` (busy), ``gp`` the present position, and a new
  motion command or ``sv``/``sj`` is refused ``GS09``. ``st`` stops at once and answers
  ``GS00``; the stopped motion then answers ``PO`` **[assumed for moves]**.
- ``ma``/``mr`` targets beyond the 32-bit counter answer ``GS04`` (value out of range);
  ``sv`` outside 1..100 % answers ``GS04``.
- A status other than ok/busy is latched and reported by the next ``gs``, which clears it
  **[assumed]**. :meth:`ElliptecEmulator.enter_error_state` (fault injection) stops the
  module at once with a code (default ``02``, mechanical time out; ``"A:0C"`` for address
  A, code 0x0C): a motion in progress answers that ``GS`` code.
- The "unsolicited" frame used for fault injection is a ``PO`` of the first module (what a
  motion that ended unobserved sends). A host reconnecting finds the tail of an old reply
  and a whole old reply in the pipe.
"""

from __future__ import annotations

from dataclasses import dataclass

from hw_mocks.clock import Clock
from hw_mocks.emulator import FirmwareEmulator
from hw_mocks.motion import StageMechanics

__all__ = ["ELL14", "ElliptecEmulator", "ElliptecModel"]

_INT32 = (-(2**31), 2**31 - 1)
_DATA_LENGTH = {"in": 0, "gs": 0, "gp": 0, "gv": 0, "gj": 0, "st": 0, "fw": 0, "bw": 0,
                "ho": 1, "ma": 8, "mr": 8, "sj": 8, "sv": 2}
_ADDRESSES = "0123456789ABCDEF"
_HEX = frozenset("0123456789ABCDEF")
_FAULT_CODES = frozenset({2, 5, 7, 8, 10, 11, 12, 13})


@dataclass(frozen=True)
class ElliptecModel:
    """What a module reports and how it moves."""

    module_type: int = 14              # ELL14
    pulses_per_revolution: int = 143360
    max_velocity: float = 430.0        # deg/s at 100 %
    acceleration: float = 5000.0       # deg/s² [assumed]
    firmware: str = "17"
    hardware: str = "01"
    year: str = "2023"


ELL14 = ElliptecModel()


class _Module:
    """One addressed module: mechanics in degrees, counter in pulses."""

    def __init__(self, address: str, model: ElliptecModel, clock: Clock, start: float,
                 serial_number: int) -> None:
        self.address = address
        self.model = model
        self.degrees_per_pulse = 360.0 / model.pulses_per_revolution
        self.velocity_percent = 100
        self.jog_pulses = model.pulses_per_revolution // 8  # 45°
        self.serial_number = serial_number
        self.stage = StageMechanics(clock, velocity=model.max_velocity,
                                    acceleration=model.acceleration,
                                    home_velocity=model.max_velocity, start_position=start)
        self.motion: str | None = None   # the motion whose reply is owed
        self.latched: int | None = None  # status reported (and cleared) by the next gs

    def position(self) -> int:
        return round(self.stage.position() / self.degrees_per_pulse)

    def apply_velocity(self) -> None:
        speed = self.velocity_percent / 100.0 * self.model.max_velocity
        self.stage.velocity = speed
        self.stage.home_velocity = speed

    def info(self) -> str:
        m = self.model
        return (f"{m.module_type:02X}{self.serial_number:08d}{m.year}{m.firmware}"
                f"{m.hardware}{360:04X}{m.pulses_per_revolution:08X}")


def _pulses_hex(value: int) -> str:
    return f"{value & 0xFFFFFFFF:08X}"


def _signed(data: str) -> int:
    value = int(data, 16)
    return value - 2**32 if value >= 2**31 else value


class ElliptecEmulator(FirmwareEmulator):
    """A bus of Elliptec rotation mounts, one per address in ``addresses``.

    Parameters
    ----------
    name
        Instance name (URL host part).
    addresses
        The modules' addresses (``"0"``, ``"0123"`` ...), one character each.
    start_positions
        Physical power-up angles in degrees, one per module; default 0.
    """

    scheme = "simell"
    baudrate = 9600

    def __init__(self, name: str, *, addresses: str = "0",
                 start_positions: tuple[float, ...] | list[float] | None = None,
                 model: ElliptecModel = ELL14, clock: Clock | None = None,
                 seed: int = 0) -> None:
        super().__init__(name, clock=clock, seed=seed)
        addresses = addresses.upper()
        if not addresses or len(set(addresses)) != len(addresses) or \
                any(a not in _ADDRESSES for a in addresses):
            raise ValueError(f"addresses must be distinct characters 0-9/A-F, got {addresses!r}")
        if start_positions is not None and len(start_positions) != len(addresses):
            raise ValueError("give one start position per module")
        starts = list(start_positions) if start_positions is not None else [0.0] * len(addresses)
        self.modules: dict[str, _Module] = {
            a: _Module(a, model, self.clock, float(s), 11400000 + 10 * seed + i)
            for i, (a, s) in enumerate(zip(addresses, starts, strict=True))}
        self._pending: list[bytes] = []  # motion replies waiting to go out

    @property
    def stage(self) -> StageMechanics:
        """The first module's mechanics (what a virtual-bench role without an address
        reads)."""
        return next(iter(self.modules.values())).stage

    def stage_at(self, address: str) -> StageMechanics:
        """The mechanics of the module at ``address``: a virtual-bench role bound by
        address (``{url, address}``) reads each mount of the bus as its own axis."""
        module = self.modules.get(str(address).upper())
        if module is None:
            raise KeyError(f"{self.scheme}://{self.name} has no module at address "
                           f"{address!r}; its addresses are {''.join(self.modules)}")
        return module.stage

    # backdoor -----------------------------------------------------------------
    def position_pulses(self, address: str = "0") -> int:
        with self.lock:
            self._update()
            return self.modules[address].position()

    # FirmwareEmulator ---------------------------------------------------------
    def _handle_input(self, buf: bytearray) -> list[bytes]:
        out: list[bytes] = []
        while buf:
            head = chr(buf[0])
            if head not in _ADDRESSES:
                del buf[0]  # CR, LF, line noise: not a packet start
                continue
            if len(buf) < 3:
                break  # wait for the mnemonic
            command = bytes(buf[1:3]).decode("ascii", "replace")
            length = _DATA_LENGTH.get(command)
            if length is None:
                del buf[:3]
                out += self._answer(head, "GS", "03")
                continue
            if len(buf) < 3 + length:
                break  # wait for the data
            data = bytes(buf[3:3 + length]).decode("ascii", "replace")
            del buf[:3 + length]
            out += self._execute(head, command, data)
        return out

    def poll(self) -> list[bytes]:
        with self.lock:
            self._update()
            out, self._pending = self._pending, []
            return out

    def on_connect(self) -> list[bytes]:
        super().on_connect()
        with self.lock:
            if self.connections <= 1:
                return []
            first = next(iter(self.modules.values()))
            old = self._frame(first.address, "PO", _pulses_hex(first.position()))
            return [old[-5:], old]

    def unsolicited_frame(self) -> bytes:
        """A ``PO`` of the first module, as a motion that ended unobserved sends."""
        with self.lock:
            self._update()
            first = next(iter(self.modules.values()))
            return self._frame(first.address, "PO", _pulses_hex(first.position()))

    def enter_error_state(self, code: str | None = None) -> None:
        """Stop a module at once with a status code: ``"02"`` (default, first module) or
        ``"A:0C"`` (address A, code 0x0C)."""
        with self.lock:
            text = (code or "02").strip().upper()
            address = next(iter(self.modules))
            if ":" in text:
                address, text = text.split(":", 1)
            value = int(text, 16)
            if value not in _FAULT_CODES:
                raise ValueError(f"an Elliptec error state is one of "
                                 f"{sorted(_FAULT_CODES)}, got {code!r}")
            if address not in self.modules:
                raise ValueError(f"no module at address {address!r}")
            self._update()
            module = self.modules[address]
            module.stage.stop(immediate=True)
            module.latched = value
            if module.motion is not None:
                module.motion = None
                self._pending.append(self._frame(address, "GS", f"{value:02X}"))

    # state ------------------------------------------------------------------------
    def _update(self) -> None:
        """Bring every module to ``clock.now()``; a motion that ended sends its reply."""
        for module in self.modules.values():
            if module.motion is None or module.stage.is_moving():
                continue
            module.motion = None
            self._pending.append(self._frame(module.address, "PO",
                                             _pulses_hex(module.position())))

    @staticmethod
    def _frame(address: str, code: str, data: str) -> bytes:
        return f"{address}{code}{data}".encode("ascii") + b"\r\n"

    def _answer(self, address: str, code: str, data: str) -> list[bytes]:
        if address not in self.modules:
            return []  # nobody at that address
        replies = [*self._pending, self._frame(address, code, data)]
        self._pending = []
        return replies

    # command interpreter ------------------------------------------------------------
    def _execute(self, address: str, command: str, data: str) -> list[bytes]:
        module = self.modules.get(address)
        if module is None:
            return []
        self._update()
        if command in ("ma", "mr", "sj", "sv") and not set(data) <= _HEX:
            return self._answer(address, "GS", "04")
        if command == "ho" and data not in ("0", "1"):
            return self._answer(address, "GS", "04")
        handler = getattr(self, f"_cmd_{command}")
        result: tuple[str, str] | None = handler(module, data)
        out = list(self._pending)
        self._pending = []
        if result is not None:
            out.append(self._frame(address, *result))
        return out

    def _status(self, code: int) -> tuple[str, str]:
        return "GS", f"{code:02X}"

    def _cmd_in(self, module: _Module, data: str) -> tuple[str, str]:
        return "IN", module.info()

    def _cmd_gs(self, module: _Module, data: str) -> tuple[str, str]:
        if module.latched is not None:
            code, module.latched = module.latched, None
            return self._status(code)
        return self._status(9 if module.stage.is_moving() else 0)

    def _cmd_gp(self, module: _Module, data: str) -> tuple[str, str]:
        return "PO", _pulses_hex(module.position())

    def _cmd_gv(self, module: _Module, data: str) -> tuple[str, str]:
        return "GV", f"{module.velocity_percent:02X}"

    def _cmd_gj(self, module: _Module, data: str) -> tuple[str, str]:
        return "GJ", _pulses_hex(module.jog_pulses)

    def _cmd_sv(self, module: _Module, data: str) -> tuple[str, str]:
        if module.stage.is_moving():
            return self._status(9)
        value = int(data, 16)
        if not 1 <= value <= 100:
            return self._status(4)
        module.velocity_percent = value
        return self._status(0)

    def _cmd_sj(self, module: _Module, data: str) -> tuple[str, str]:
        if module.stage.is_moving():
            return self._status(9)
        module.jog_pulses = _signed(data)
        return self._status(0)

    def _cmd_st(self, module: _Module, data: str) -> tuple[str, str]:
        module.stage.stop(immediate=True)
        self._update()  # the stopped motion answers now
        return self._status(0)

    def _start(self, module: _Module, target: int) -> tuple[str, str] | None:
        if module.stage.is_moving():
            return self._status(9)
        if not _INT32[0] <= target <= _INT32[1]:
            return self._status(4)
        module.apply_velocity()
        module.stage.move_to(target * module.degrees_per_pulse)
        module.motion = "move"
        self._update()  # a zero-length move answers at once
        return None

    def _cmd_ma(self, module: _Module, data: str) -> tuple[str, str] | None:
        return self._start(module, _signed(data))

    def _cmd_mr(self, module: _Module, data: str) -> tuple[str, str] | None:
        return self._start(module, module.position() + _signed(data))

    def _cmd_fw(self, module: _Module, data: str) -> tuple[str, str] | None:
        return self._start(module, module.position() + module.jog_pulses)

    def _cmd_bw(self, module: _Module, data: str) -> tuple[str, str] | None:
        return self._start(module, module.position() - module.jog_pulses)

    def _cmd_ho(self, module: _Module, data: str) -> tuple[str, str] | None:
        if module.stage.is_moving():
            return self._status(9)
        module.apply_velocity()
        module.stage.start_homing()
        module.motion = "home"
        self._update()
        return None
