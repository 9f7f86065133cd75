"""One exception hierarchy for every device.

Every error raised by a driver is a :class:`DeviceError`. It names the device, the
command that failed and, where we know it, what the user can do about it. Drivers
chain the underlying cause (``raise ... from err``) so the pyserial/pyusb error is
never lost.

``ValueError`` and ``TypeError`` stay for bad *arguments* (a negative velocity, a
string where a number belongs); everything that depends on the device, its state or
its reply is a ``DeviceError``.

When each error is raised
-------------------------
ConnectionFailed
    The transport cannot be opened, or it vanished (unplugged, ENODEV, pty closed).
DeviceTimeout
    A reply, a motion or a homing did not finish within its timeout.
ProtocolError
    Bytes arrived that do not decode as the protocol says (bad frame, wrong echo,
    unparseable number, reply to a different command).
ControllerError
    The device itself reported an error (SMC100 ``TE`` letter, positioner error bits,
    APT status error bits or HW_RESPONSE, SCPI ``SYST:ERR?``). ``code`` holds the raw code.
LimitError
    A target lies outside the soft limits or a hardware limit switch stopped the axis.
    Raised *before* any motion when the target is known to be out of range.
StateError / NotHomedError
    The command is not allowed in the device's present state (closed device, disabled
    axis, motion before homing).
MotionError
    A move ended, but not where it was sent (outside the position tolerance).
OverloadError
    A measuring instrument's input or output is beyond its range on every setting that
    could cure it (a lock-in overloaded on its largest full scale).
UnsupportedFeature
    The device or backend cannot do what was asked (for example, an OpenCV backend
    that ignores an exposure setting). Never silently ignored.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

__all__ = [
    "ConnectionFailed",
    "ControllerError",
    "DeviceError",
    "DeviceTimeout",
    "LimitError",
    "MotionError",
    "NotHomedError",
    "OverloadError",
    "ProtocolError",
    "StateError",
    "UnsupportedFeature",
    "attempts_exhausted",
]


class DeviceError(Exception):
    """Base class of all device errors.

    Parameters
    ----------
    message
        What went wrong, in words a physicist at the bench understands.
    device
        The device's configured name (for example ``"sample_theta"``).
    command
        The command or operation that failed (for example ``"MOT_MOVE_ABSOLUTE"``,
        ``"1PA45"`` or ``"home"``).
    hint
        What to do about it.
    """

    def __init__(
        self,
        message: str,
        *,
        device: str | None = None,
        command: str | None = None,
        hint: str | None = None,
    ) -> None:
        super().__init__(message)
        self.message = message
        self.device = device
        self.command = command
        self.hint = hint

    def __str__(self) -> str:
        text = self.message
        if self.device:
            text = f"{self.device}: {text}"
        if self.command:
            text = f"{text} [command {self.command}]"
        if self.hint:
            text = f"{text}. {self.hint}"
        return text

    # keep pickling (multiprocessing, logging) lossless
    def __reduce__(self) -> tuple[Callable[..., DeviceError], tuple[object, ...]]:
        return (
            _rebuild,
            (type(self), self.message, self.device, self.command, self.hint, self.__dict__),
        )


def _rebuild(cls: type[DeviceError], message: str, device: str | None, command: str | None,
             hint: str | None, state: dict[str, object]) -> DeviceError:
    err = cls.__new__(cls)
    DeviceError.__init__(err, message, device=device, command=command, hint=hint)
    err.__dict__.update(state)
    return err


class ConnectionFailed(DeviceError):
    """The transport could not be opened or was lost."""


class DeviceTimeout(DeviceError):
    """A reply or an operation did not complete in time."""


class ProtocolError(DeviceError):
    """Received bytes do not decode according to the wire protocol."""


class ControllerError(DeviceError):
    """The controller reported an error; ``code`` is its raw error code."""

    def __init__(self, message: str, *, code: object = None, **kw: Any) -> None:
        super().__init__(message, **kw)
        self.code = code


class LimitError(DeviceError):
    """A target is outside the soft limits, or a limit switch stopped the motion."""


class StateError(DeviceError):
    """The operation is not allowed in the device's present state."""


class NotHomedError(StateError):
    """The axis has no reference position yet; home it first."""


class MotionError(DeviceError):
    """A move finished outside the position tolerance of its target."""


class OverloadError(DeviceError):
    """The signal exceeds the instrument's range and no range setting cures it."""


class UnsupportedFeature(DeviceError):
    """The device or its backend does not support the requested feature."""


def attempts_exhausted(last: DeviceError, attempts: int, *, device: str, command: str,
                       hint: str | None = None) -> DeviceError:
    """The error to raise when every attempt of a command failed: the last failure's type
    and message, saying how many attempts were made (raise it ``from last``)."""
    suffix = f" (after {attempts} attempts)" if attempts > 1 else ""
    return type(last)(last.message + suffix, device=device, command=command,
                      hint=hint or last.hint or "check the connection and the device")

