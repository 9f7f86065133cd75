"""The contract every :class:`drivers.base.MotionAxis` implementation must keep.

A driver's test module subclasses :class:`MotionAxisContract` and provides two fixtures:
``axis_factory``, a callable returning a freshly opened axis (a fresh emulator behind it)
with soft limits that include ``CONTRACT_RANGE``; and ``clock_of``, a callable giving the
emulated clock (:class:`hw_mocks.clock.HoldableClock`) behind an axis. Run it once per
transport (in-process URL and pseudo-terminal), e.g. with a parametrised fixture.

The assertions are about behaviour a user relies on: limits refuse before motion, a
move ends within tolerance of its target, a stop really stops, waits never hang. What
happens *during* a move ("still moving", "stopped short") is observed with the
emulator's clock held, so that no assertion depends on how fast the machine runs.
"""

from __future__ import annotations

import math
import time

import pytest

from drivers.base import AxisStatus, DeviceIdentity, MotionAxis
from drivers.errors import DeviceTimeout, LimitError, NotHomedError, StateError

#: Targets used by the contract, in axis units; soft limits must include them.
CONTRACT_RANGE = (-10.0, 10.0)


class MotionAxisContract:
    """Mixin of contract tests; needs the fixture ``axis_factory``."""

    #: Seconds a short contract move may take at the emulator's speed.
    move_timeout = 20.0

    @pytest.fixture
    def axis(self, axis_factory):
        axis = axis_factory()
        yield axis
        axis.close()

    @pytest.fixture
    def ready_axis(self, axis):
        axis.enable()
        axis.home(timeout=self.move_timeout)
        return axis

    # identity and lifecycle ---------------------------------------------------
    def test_is_a_motion_axis_with_identity(self, axis):
        assert isinstance(axis, MotionAxis)
        ident = axis.identity
        assert isinstance(ident, DeviceIdentity)
        assert ident.model and ident.serial
        assert axis.units in ("deg", "mm")

    def test_close_is_idempotent_and_closed_axis_refuses(self, axis):
        axis.close()
        axis.close()
        with pytest.raises(StateError):
            axis.move_to(1.0)
        axis.stop()  # stopping a closed axis is harmless

    def test_context_manager_closes(self, axis_factory):
        with axis_factory() as axis:
            assert not axis.closed
        assert axis.closed

    # homing and state ---------------------------------------------------------
    def test_move_before_homing_is_refused(self, axis):
        axis.enable()
        if axis.is_homed:
            pytest.skip("this controller powers up referenced")
        with pytest.raises(NotHomedError):
            axis.move_to(1.0)

    def test_home_sets_reference(self, ready_axis):
        status = ready_axis.status()
        assert isinstance(status, AxisStatus)
        assert status.is_homed and not status.is_moving
        assert abs(status.position) <= ready_axis.position_tolerance

    # motion -------------------------------------------------------------------
    def test_out_of_limit_target_raises_before_motion(self, ready_axis):
        low, high = ready_axis.soft_limits
        before = ready_axis.position
        with pytest.raises(LimitError):
            ready_axis.move_to(high + 1.0)
        with pytest.raises(LimitError):
            ready_axis.move_by(low - high - 1.0)
        assert not ready_axis.is_moving
        assert ready_axis.position == pytest.approx(before, abs=ready_axis.position_tolerance)

    def test_non_finite_target_is_a_value_error(self, ready_axis):
        with pytest.raises(ValueError):
            ready_axis.move_to(math.nan)

    @pytest.mark.parametrize("target", [7.5, -3.25, 0.5])
    def test_absolute_move_arrives_within_tolerance(self, ready_axis, target):
        ready_axis.move_to(target)
        final = ready_axis.wait(self.move_timeout)
        assert final == pytest.approx(target, abs=ready_axis.position_tolerance)
        assert ready_axis.position == pytest.approx(target, abs=ready_axis.position_tolerance)
        assert not ready_axis.is_moving

    def test_relative_moves_accumulate_from_target(self, ready_axis):
        ready_axis.move_to(2.0, wait=True, timeout=self.move_timeout)
        ready_axis.move_by(1.5, wait=True, timeout=self.move_timeout)
        ready_axis.move_by(-4.0, wait=True, timeout=self.move_timeout)
        assert ready_axis.position == pytest.approx(-0.5, abs=ready_axis.position_tolerance)

    def _come_to_rest(self, axis: MotionAxis) -> None:
        """Poll until the axis stands still (a stop decelerates in emulated time)."""
        deadline = time.monotonic() + self.move_timeout
        while axis.is_moving and time.monotonic() < deadline:
            time.sleep(0.005)

    def _stop_mid_move(self, axis: MotionAxis, clock) -> None:
        """Start a slow move to the top of the range and stop it a quarter of the way.

        The clock is held from the move to the stop, so the stop lands mid-move however
        long the machine takes between the two commands.
        """
        axis.velocity = axis.velocity / 10.0
        with clock.held():
            axis.move_to(CONTRACT_RANGE[1])
            assert axis.is_moving
            # A quarter of the cruise time: the stage is under way, far from the target.
            clock.advance(0.25 * (CONTRACT_RANGE[1] - axis.position) / axis.velocity)
            assert axis.is_moving
            axis.stop()
            # A stop has no reply on most controllers: a query after it is answered only
            # once the controller has taken the stop, so time runs on only after that
            # (on a loaded box a pty's reader may otherwise take the stop late, after the
            # released clock has carried the stage to its target).
            _ = axis.position

    def test_move_is_non_blocking_and_reports_moving(self, ready_axis, clock_of):
        ready_axis.velocity = ready_axis.velocity  # round-trips
        with clock_of(ready_axis).held():  # no emulated time passes: it cannot arrive
            ready_axis.move_to(CONTRACT_RANGE[1])
            assert ready_axis.is_moving
        ready_axis.wait(self.move_timeout)
        assert not ready_axis.is_moving

    def test_stop_halts_short_of_target(self, ready_axis, clock_of):
        self._stop_mid_move(ready_axis, clock_of(ready_axis))
        self._come_to_rest(ready_axis)
        assert not ready_axis.is_moving
        assert ready_axis.position < CONTRACT_RANGE[1] - ready_axis.position_tolerance

    def test_wait_times_out_and_stops(self, ready_axis, clock_of):
        with clock_of(ready_axis).held():  # the move cannot end before the wait gives up
            ready_axis.move_to(CONTRACT_RANGE[1])
            with pytest.raises(DeviceTimeout) as info:
                ready_axis.wait(0.05)
            # one more round trip while the clock is held: over a pty the stop is only
            # written, and a starved emulator thread could otherwise take it after the
            # released clock had already run the move to its end
            ready_axis.position  # noqa: B018
        assert info.value.device == ready_axis.name
        self._come_to_rest(ready_axis)
        assert not ready_axis.is_moving
        assert ready_axis.position < CONTRACT_RANGE[1] - ready_axis.position_tolerance

    def test_after_stop_wait_checks_no_target_and_move_by_counts_from_rest(self, ready_axis,
                                                                            clock_of):
        self._stop_mid_move(ready_axis, clock_of(ready_axis))
        rest = ready_axis.wait(self.move_timeout)  # no MotionError: the target is gone
        assert rest < CONTRACT_RANGE[1] - ready_axis.position_tolerance
        ready_axis.velocity = ready_axis.velocity * 10.0
        ready_axis.move_by(-1.0, wait=True, timeout=self.move_timeout)
        assert ready_axis.position == pytest.approx(rest - 1.0,
                                                    abs=2 * ready_axis.position_tolerance)

    def test_home_on_a_disabled_axis_is_refused(self, ready_axis):
        ready_axis.disable()
        with pytest.raises(StateError):
            ready_axis.home(timeout=self.move_timeout)

    def test_velocity_and_acceleration_round_trip(self, ready_axis):
        v = ready_axis.velocity
        ready_axis.velocity = v / 2.0
        assert ready_axis.velocity == pytest.approx(v / 2.0, rel=0.01)
        a = ready_axis.acceleration
        ready_axis.acceleration = a / 2.0
        assert ready_axis.acceleration == pytest.approx(a / 2.0, rel=0.01)
        with pytest.raises(ValueError):
            ready_axis.velocity = -1.0

    def test_disabled_axis_refuses_motion(self, ready_axis):
        ready_axis.disable()
        with pytest.raises(StateError):
            ready_axis.move_to(1.0)
        ready_axis.enable()
        ready_axis.move_to(1.0, wait=True, timeout=self.move_timeout)
        assert ready_axis.position == pytest.approx(1.0, abs=ready_axis.position_tolerance)
