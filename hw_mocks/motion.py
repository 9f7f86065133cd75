"""Stage mechanics shared by the firmware emulators.

A :class:`StageMechanics` is the physical stage behind a controller: a position in
physical units (degrees or millimetres), trapezoidal velocity profiles, travel limits
with limit switches, and a home switch. Controllers (APT, SMC100) translate their wire
units into calls on it. Time comes from an injected :class:`~hw_mocks.clock.Clock`, and
every query is answered for ``clock.now()``, so the stage moves while nobody looks.

Default behaviour, declared once here:

- A move accelerates at ``acceleration`` up to ``velocity`` and decelerates to the
  target (a triangle profile when the move is too short to reach ``velocity``).
- Two frames: the *physical* position (the world's: the home switch is at physical 0)
  and the controller's *counter*, which reads 0 at power-up wherever the stage really
  is. Homing drives toward the switch at ``home_velocity`` and then zeroes the counter
  there, after which both frames agree. With ``home_velocity == 0`` (an APT power-up
  quirk) homing never ends: the stage "looks stationary while homing".
- Beyond the travel range a limit switch stops the stage at the limit and latches
  ``at_limit`` until the next move away from it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from hw_mocks.clock import Clock

__all__ = ["StageMechanics", "TrapezoidalProfile"]


@dataclass(frozen=True)
class TrapezoidalProfile:
    """Position along a point-to-point move with bounded velocity and acceleration.

    Starts at rest at ``start`` at time ``t0`` and ends at rest at ``end``.
    """

    start: float
    end: float
    velocity: float
    acceleration: float
    t0: float

    @property
    def distance(self) -> float:
        return abs(self.end - self.start)

    @property
    def _ramp(self) -> tuple[float, float]:
        """(peak velocity, duration of one ramp)."""
        d, v, a = self.distance, self.velocity, self.acceleration
        if v * v / a >= d:  # triangle: never reaches v
            v = math.sqrt(d * a)
        return v, v / a

    @property
    def duration(self) -> float:
        d = self.distance
        if d == 0.0:
            return 0.0
        v_peak, t_ramp = self._ramp
        cruise = (d - v_peak * t_ramp) / v_peak
        return 2.0 * t_ramp + max(cruise, 0.0)

    @staticmethod
    def duration_for(distance: float, velocity: float, acceleration: float) -> float:
        """Time to travel ``distance`` from rest to rest (the planner uses this too)."""
        d = abs(distance)
        if d == 0.0:
            return 0.0
        if velocity * velocity / acceleration >= d:
            return 2.0 * math.sqrt(d / acceleration)
        return d / velocity + velocity / acceleration

    def position(self, t: float) -> float:
        tau = t - self.t0
        total = self.duration
        if tau <= 0.0:
            return self.start
        if tau >= total:
            return self.end
        v_peak, t_ramp = self._ramp
        a = self.acceleration
        if tau < t_ramp:
            s = 0.5 * a * tau * tau
        elif tau <= total - t_ramp:
            s = 0.5 * v_peak * t_ramp + v_peak * (tau - t_ramp)
        else:
            left = total - tau
            s = self.distance - 0.5 * a * left * left
        return self.start + math.copysign(s, self.end - self.start)

    def velocity_at(self, t: float) -> float:
        tau = t - self.t0
        total = self.duration
        if tau <= 0.0 or tau >= total:
            return 0.0
        v_peak, _t_ramp = self._ramp
        v = min(v_peak, self.acceleration * tau, self.acceleration * (total - tau))
        return math.copysign(v, self.end - self.start)


class StageMechanics:
    """A single-axis stage in physical units driven by a controller emulator.

    Parameters
    ----------
    clock
        Time source.
    travel
        ``(low, high)`` hardware travel; limit switches sit there. Use
        ``(-inf, inf)`` for a continuous rotation stage.
    start_position
        Physical position at power-up (unknown to the controller until it homes).
    """

    def __init__(
        self,
        clock: Clock,
        *,
        velocity: float,
        acceleration: float,
        travel: tuple[float, float] = (-math.inf, math.inf),
        home_velocity: float = 10.0,
        start_position: float = 0.0,
    ) -> None:
        self.clock = clock
        self.velocity = float(velocity)
        self.acceleration = float(acceleration)
        self.travel = (float(travel[0]), float(travel[1]))
        self._home_velocity = float(home_velocity)
        self._homing = False
        self._position = float(start_position)  # physical
        self.counter_offset = float(start_position)  # physical - counter
        self._move: TrapezoidalProfile | None = None
        self._homing = False
        self.homed = False
        self.at_limit: str | None = None  # "forward" | "reverse" | None

    @property
    def home_velocity(self) -> float:
        return self._home_velocity

    @home_velocity.setter
    def home_velocity(self, value: float) -> None:
        """A new homing speed applies from now on, not retroactively."""
        self._update()
        if self._homing:
            self._home_t0 = self.clock.now()
            self._home_from = self._position
        self._home_velocity = float(value)

    # queries ------------------------------------------------------------------
    def position(self) -> float:
        """Position in the controller's counter frame."""
        self._update()
        return self._position - self.counter_offset

    def physical_position(self) -> float:
        """Position in the world's frame (home switch at 0)."""
        self._update()
        return self._position

    def is_moving(self) -> bool:
        self._update()
        return self._move is not None or self._homing

    def is_homing(self) -> bool:
        self._update()
        return self._homing

    def velocity_now(self) -> float:
        self._update()
        if self._move is None:
            return 0.0
        return self._move.velocity_at(self.clock.now())

    def target(self) -> float | None:
        """Target of the move in progress, counter frame."""
        self._update()
        return self._move.end - self.counter_offset if self._move else None

    # commands -----------------------------------------------------------------
    def move_to(self, target: float) -> float:
        """Start a move to ``target`` (counter frame); return its duration in seconds.

        A target beyond the travel stops at the limit switch, which then latches.
        """
        self._update()
        now = self.clock.now()
        start = self._position
        wanted = float(target) + self.counter_offset
        low, high = self.travel
        end = min(max(wanted, low), high)
        self._pending_limit = None
        if end != wanted:
            self._pending_limit = "forward" if wanted > high else "reverse"
        self.at_limit = None
        self._homing = False
        self._move = TrapezoidalProfile(start, end, self.velocity, self.acceleration, now)
        return self._move.duration

    def stop(self, immediate: bool = False) -> None:
        """Stop: at once, or decelerating at ``acceleration`` (profiled)."""
        self._update()
        now = self.clock.now()
        if self._homing:
            self._homing = False
        if self._move is None:
            return
        pos = self._move.position(now)
        v = self._move.velocity_at(now)
        if immediate or v == 0.0:
            self._position = pos
            self._move = None
            return
        braking = v * v / (2.0 * self.acceleration)
        end = pos + math.copysign(braking, v)
        # A new profile from the present state that ends at rest after braking.
        self._move = _BrakingProfile(pos, end, abs(v), self.acceleration, now)

    def start_homing(self) -> None:
        self._update()
        self._move = None
        self.homed = False
        self._homing = True
        self._home_t0 = self.clock.now()
        self._home_from = self._position

    def teleport(self, physical_position: float) -> None:
        """Backdoor for tests: put the stage somewhere without a move (counter follows)."""
        self._update()
        shift = float(physical_position) - self._position
        self._move = None
        self._homing = False
        self._position = float(physical_position)
        self.counter_offset += shift

    # internals ----------------------------------------------------------------
    def _update(self) -> None:
        now = self.clock.now()
        if self._homing:
            if self.home_velocity <= 0:
                return  # the power-up quirk: homing at zero speed never ends
            travelled = (now - self._home_t0) * self.home_velocity
            if travelled >= abs(self._home_from):
                self._homing = False
                self.homed = True
                self._position = 0.0
                self.counter_offset = 0.0
            else:
                self._position = self._home_from - math.copysign(travelled, self._home_from)
            return
        if self._move is not None:
            if now >= self._move.t0 + self._move.duration:
                self._position = self._move.end
                self._move = None
                self.at_limit = getattr(self, "_pending_limit", None)
            else:
                self._position = self._move.position(now)


class _BrakingProfile(TrapezoidalProfile):
    """Deceleration from speed ``velocity`` to rest over ``|end - start|``."""

    @property
    def duration(self) -> float:
        return self.velocity / self.acceleration

    def position(self, t: float) -> float:
        tau = min(max(t - self.t0, 0.0), self.duration)
        s = self.velocity * tau - 0.5 * self.acceleration * tau * tau
        return self.start + math.copysign(s, self.end - self.start)

    def velocity_at(self, t: float) -> float:
        tau = t - self.t0
        if tau <= 0 or tau >= self.duration:
            return 0.0
        return math.copysign(self.velocity - self.acceleration * tau, self.end - self.start)
