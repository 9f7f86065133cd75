"""The contract every :class:`drivers.base.FilterWheel` implementation keeps.

Subclass :class:`FilterWheelContract` and provide a fixture ``wheel_factory``: a callable
taking keyword arguments for the driver (``filters=...``) and returning a freshly opened
wheel (a fresh emulator behind it). Run it once per transport (in-process URL and
pseudo-terminal). Assertions are about what a user relies on: slots are 1-based and
checked before anything moves, a move ends at its slot, waits never hang.
"""

from __future__ import annotations

import math

import pytest

from drivers.base import DeviceIdentity, FilterSpec, FilterWheel, WheelSpeed
from drivers.errors import LimitError, StateError

#: Filters the contract configures: slots 1 and 2 (every wheel has at least two).
CONTRACT_FILTERS = {1: {"center_nm": 633.0, "bandwidth_nm": 10.0, "label": "HeNe line"},
                    "2": {"center_nm": 550.0, "bandwidth_nm": 40.0}}


class FilterWheelContract:
    """Mixin of contract tests; needs the fixture ``wheel_factory``."""

    #: Seconds a contract move may take at the emulator's speed.
    move_timeout = 20.0

    @pytest.fixture
    def wheel(self, wheel_factory):
        wheel = wheel_factory(filters=CONTRACT_FILTERS)
        yield wheel
        wheel.close()

    # identity and lifecycle ---------------------------------------------------
    def test_is_a_filter_wheel_with_identity_and_slots(self, wheel):
        assert isinstance(wheel, FilterWheel)
        ident = wheel.identity
        assert isinstance(ident, DeviceIdentity) and ident.vendor and ident.model
        assert wheel.position_count >= 2
        assert 1 <= wheel.position <= wheel.position_count

    def test_close_is_idempotent_and_closed_wheel_refuses(self, wheel):
        wheel.close()
        wheel.close()
        with pytest.raises(StateError):
            wheel.move_to(1)
        with pytest.raises(StateError):
            wheel.position  # noqa: B018

    def test_context_manager_closes(self, wheel_factory):
        with wheel_factory() as wheel:
            assert not wheel.closed
        assert wheel.closed

    # filters ------------------------------------------------------------------
    def test_configured_filters_are_described_by_slot(self, wheel):
        first = wheel.filter_at(1)
        assert first == FilterSpec(633.0, 10.0, "HeNe line")
        assert wheel.filter_at(2).center_nm == pytest.approx(550.0)
        assert wheel.filter_at(wheel.position_count).is_empty
        wheel.move_to(2, timeout=self.move_timeout)
        assert wheel.current_filter.bandwidth_nm == pytest.approx(40.0)

    def test_filters_outside_the_wheel_are_refused_at_connect(self, wheel_factory):
        with pytest.raises(ValueError):
            wheel_factory(filters={13: {"center_nm": 500.0, "bandwidth_nm": 10.0}})
        with pytest.raises(ValueError):
            wheel_factory(filters={1: {"center_nm": 500.0}})  # no bandwidth

    # motion -------------------------------------------------------------------
    def test_every_slot_is_reached_in_both_directions(self, wheel):
        count = wheel.position_count
        for target in (count, 2, 1, count // 2 + 1, 1):
            assert wheel.move_to(target, timeout=self.move_timeout) == target
            assert wheel.position == target

    def test_move_to_the_present_slot_returns_at_once(self, wheel):
        here = wheel.position
        assert wheel.estimated_move_s(here) == 0.0
        assert wheel.move_to(here, timeout=self.move_timeout) == here

    @pytest.mark.parametrize("bad", [0, -1, 13, 99])
    def test_slot_outside_the_wheel_raises_before_motion(self, wheel, bad):
        before = wheel.position
        if bad == 13 and wheel.position_count >= 13:
            pytest.skip("a wheel this large has slot 13")
        with pytest.raises(LimitError) as info:
            wheel.move_to(bad)
        assert info.value.device == wheel.name
        assert wheel.position == before

    @pytest.mark.parametrize("bad", [1.5, "2", None, True])
    def test_slot_must_be_an_int(self, wheel, bad):
        with pytest.raises(TypeError):
            wheel.move_to(bad)

    def test_bad_timeout_is_a_value_error(self, wheel):
        for bad in (0.0, -1.0, math.nan, math.inf):
            with pytest.raises(ValueError):
                wheel.move_to(2, timeout=bad)

    def test_estimate_grows_with_distance_and_the_slow_profile(self, wheel):
        wheel.speed = WheelSpeed.HIGH
        wheel.move_to(1, timeout=self.move_timeout)
        near, far = wheel.estimated_move_s(2), wheel.estimated_move_s(wheel.position_count // 2 + 1)
        assert 0.0 < near < far
        wheel.speed = "normal"
        assert wheel.speed is WheelSpeed.NORMAL
        assert wheel.estimated_move_s(2) > near
        wheel.move_to(2, timeout=self.move_timeout)
        assert wheel.position == 2

    def test_speed_round_trips_and_rejects_unknown(self, wheel):
        for speed in (WheelSpeed.NORMAL, WheelSpeed.HIGH, "normal", "HIGH"):
            wheel.speed = speed
            assert wheel.speed is WheelSpeed(str(getattr(speed, "value", speed)).lower())
        with pytest.raises(ValueError):
            wheel.speed = "ludicrous"
        with pytest.raises(TypeError):
            wheel.speed = 1
