"""The sample spinner: a continuous-rotation stage that turns the sample about its normal
while the camera exposes, so that each exposure averages a laser's speckle over the
independent patterns it sweeps (ADR 0098).

The bench names it by the role :data:`~instrument.bench.profile.SPIN_ROLE`; a plan asks
for it with ``[acquisition] spin_deg_s``. :func:`instrument.plans.spin.check_spinner`
refuses a plan that asks for a spin the bench cannot give, before anything moves;
:func:`start_spinner` (the
engine, after homing) enables it, sets its velocity, starts the continuous move, waits out
its acceleration ramp (every wait bounded) and checks it is at speed: the controller's
velocity set-point reads back as asked (within its velocity unit) and its status says it
is moving, without error. The engine's ``make_safe`` stops it with every other axis at the
end of the run, on abort and on a fault.
"""

from __future__ import annotations

import time
from typing import Any, Protocol, runtime_checkable

from drivers.base import MotionAxis
from drivers.errors import MotionError
from instrument.bench.profile import SPIN_ROLE

__all__ = ["Spinner", "start_spinner"]

#: The at-speed check's tolerance on the velocity read back, relative: a controller's
#: velocity unit (the K10CR1's 1/7329109 °/s) is far finer.
VELOCITY_RTOL = 1e-3
#: Longest acceleration ramp waited for (s): a slower one is a configuration error.
MAX_RAMP_S = 60.0


@runtime_checkable
class Spinner(Protocol):
    """A motion axis that can turn without end (``thorlabs_apt``'s :meth:`move_continuous`)."""

    def move_continuous(self, *, forward: bool = True) -> None: ...


def start_spinner(bench_devices: dict[str, Any], rate_deg_s: float, *,
                  sleep: Any = time.sleep) -> MotionAxis:
    """Spin the bench's spinner at ``rate_deg_s`` and check it is at speed; return it.

    Raises
    ------
    MotionError
        It does not reach its speed (velocity not taken, not moving, or in error): it is
        stopped first.
    """
    axis = bench_devices.get(SPIN_ROLE)
    if not isinstance(axis, MotionAxis) or not isinstance(axis, Spinner):
        raise MotionError(f"the bench's {SPIN_ROLE} device cannot turn continuously "
                          "(a continuous-rotation stage of the thorlabs_apt driver can)",
                          device=SPIN_ROLE, command="spin")
    if not axis.status().is_enabled:
        axis.enable()
    try:
        axis.velocity = rate_deg_s
    except ValueError as err:  # beyond what the stage can: the driver says its limit
        raise MotionError(f"cannot spin at {rate_deg_s:g} °/s: {err}", device=SPIN_ROLE,
                          command="spin") from err
    ramp_s = rate_deg_s / axis.acceleration
    if ramp_s > MAX_RAMP_S:
        raise MotionError(f"reaching {rate_deg_s:g} °/s at {axis.acceleration:g} °/s² takes "
                          f"{ramp_s:.0f} s: raise the spinner's acceleration",
                          device=SPIN_ROLE, command="spin")
    axis.move_continuous(forward=True)
    try:
        sleep(ramp_s)
        got = axis.velocity
        status = axis.status()
        if abs(got - rate_deg_s) > VELOCITY_RTOL * rate_deg_s:
            raise MotionError(f"asked for {rate_deg_s:g} °/s, the controller runs at "
                              f"{got:g} °/s", device=SPIN_ROLE, command="spin")
        if not status.is_moving or status.error:
            why = status.error or "the controller reports no motion"
            raise MotionError(f"not turning after its {ramp_s:.2g} s ramp: {why}",
                              device=SPIN_ROLE, command="spin")
    except BaseException:
        axis.stop()
        raise
    return axis
