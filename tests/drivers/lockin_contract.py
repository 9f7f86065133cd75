"""The contract every :class:`drivers.base.LockIn` implementation keeps.

Subclass :class:`LockInContract` and provide two fixtures:

``lockin_factory``
    A callable returning a freshly opened lock-in (a fresh instrument behind it), using the
    internal reference.
``feed``
    A callable ``feed(lockin, ac_rms_v, dc_v=0.0)`` that puts a signal of ``ac_rms_v``
    volts rms at the reference frequency (plus ``dc_v`` of DC) on that lock-in's input.

Run it once per transport (in-process URL and pseudo-terminal). The assertions are about
what a user relies on: settings snap to the tables and refuse nonsense before anything is
sent, a settled reading equals the input within its noise, overloads are reported and
auto-ranging cures the curable ones, waits are bounded.
"""

from __future__ import annotations

import math

import pytest

from drivers.base import DeviceIdentity, LockIn, LockInReading, LockInStatus, ReferenceSource
from drivers.errors import DeviceTimeout, OverloadError, StateError

#: Time constant used by the contract (short, so that settling takes milliseconds).
TAU_S = 1e-3


class LockInContract:
    """Mixin of contract tests; needs the fixtures ``lockin_factory`` and ``feed``."""

    @pytest.fixture
    def lockin(self, lockin_factory):
        lockin = lockin_factory()
        lockin.time_constant_s = TAU_S
        lockin.filter_slope_db_per_oct = 12
        yield lockin
        lockin.close()

    # identity and lifecycle ---------------------------------------------------
    def test_is_a_lock_in_with_identity(self, lockin):
        assert isinstance(lockin, LockIn)
        ident = lockin.identity
        assert isinstance(ident, DeviceIdentity) and ident.model and ident.serial

    def test_close_is_idempotent_and_closed_lock_in_refuses(self, lockin_factory):
        lockin = lockin_factory()
        lockin.close()
        lockin.close()
        with pytest.raises(StateError):
            lockin.snapshot()
        with pytest.raises(StateError):
            lockin.settle()

    def test_context_manager_closes(self, lockin_factory):
        with lockin_factory() as lockin:
            assert not lockin.closed
        assert lockin.closed

    # settings -----------------------------------------------------------------
    def test_time_constant_snaps_to_the_table_and_refuses_nonsense(self, lockin):
        table = lockin.time_constants_s
        assert list(table) == sorted(table)
        # (An instrument may refuse its longest time constants at a high reference
        # frequency with a typed error; the contract stays clear of them.)
        for tau in (table[0], TAU_S, table[len(table) // 2]):
            lockin.time_constant_s = tau
            assert lockin.time_constant_s == pytest.approx(tau)
        lockin.time_constant_s = TAU_S * 1.2
        assert lockin.time_constant_s == pytest.approx(TAU_S)
        expected = min(table, key=lambda t: abs(math.log(t / (TAU_S * 2.0))))
        lockin.time_constant_s = TAU_S * 2.0
        assert lockin.time_constant_s == pytest.approx(expected)
        for bad in (math.nan, math.inf, 0.0, -1.0, table[-1] * 10, table[0] / 10):
            with pytest.raises(ValueError):
                lockin.time_constant_s = bad
        assert lockin.time_constant_s == pytest.approx(expected)  # nothing was sent

    def test_sensitivity_snaps_up_and_refuses_nonsense(self, lockin):
        table = lockin.sensitivities_v
        assert list(table) == sorted(table)
        lockin.sensitivity_v = 0.015
        assert lockin.sensitivity_v >= 0.015
        assert lockin.sensitivity_v == min(fs for fs in table if fs >= 0.015)
        lockin.sensitivity_v = table[0] / 10  # below the smallest: the smallest
        assert lockin.sensitivity_v == pytest.approx(table[0])
        for bad in (math.nan, 0.0, -0.1, table[-1] * 2):
            with pytest.raises(ValueError):
                lockin.sensitivity_v = bad
        assert lockin.sensitivity_v == pytest.approx(table[0])

    def test_filter_slope_round_trip_and_validation(self, lockin):
        for slope in lockin.filter_slopes_db_per_oct:
            lockin.filter_slope_db_per_oct = slope
            assert lockin.filter_slope_db_per_oct == slope
        for bad in (0, 9, 30, True, "12"):
            with pytest.raises(ValueError):
                lockin.filter_slope_db_per_oct = bad

    def test_reference_source_and_frequency(self, lockin):
        assert lockin.reference_source is ReferenceSource.INTERNAL
        frequency = lockin.reference_frequency_hz
        assert math.isfinite(frequency) and frequency > 0
        lockin.reference_source = "external"
        assert lockin.reference_source is ReferenceSource.EXTERNAL
        lockin.reference_source = ReferenceSource.INTERNAL
        assert lockin.reference_source is ReferenceSource.INTERNAL
        with pytest.raises(ValueError):
            lockin.reference_source = "sideways"
        with pytest.raises(TypeError):
            lockin.reference_source = 1

    # readings -----------------------------------------------------------------
    def test_settled_reading_equals_the_input(self, lockin, feed):
        lockin.sensitivity_v = 0.01
        feed(lockin, 3e-3)
        lockin.settle(2 * lockin.SETTLE_TIME_CONSTANTS[12])
        reading = lockin.snapshot()
        assert isinstance(reading, LockInReading)
        assert reading.r_v == pytest.approx(3e-3, rel=0.01)
        assert math.hypot(reading.x_v, reading.y_v) == pytest.approx(reading.r_v, rel=1e-3)
        assert -180.0 <= reading.theta_deg <= 180.0
        assert not lockin.overload_status().overloaded

    def test_settle_waits_the_99_percent_table_and_validates(self, lockin):
        assert lockin.SETTLE_TIME_CONSTANTS == {6: 5.0, 12: 7.0, 18: 9.0, 24: 10.0}
        assert lockin.settle_time_s() == pytest.approx(7.0 * TAU_S)
        lockin.filter_slope_db_per_oct = 24
        assert lockin.settle() == pytest.approx(10.0 * TAU_S)
        assert lockin.settle(3) == pytest.approx(3 * TAU_S)
        for bad in (0, -1, math.nan):
            with pytest.raises(ValueError):
                lockin.settle(bad)
        with pytest.raises(DeviceTimeout) as info:
            lockin.settle(100, timeout=10 * TAU_S)
        assert info.value.device == lockin.name and info.value.command == "settle"

    def test_overload_is_reported_and_auto_range_cures_it(self, lockin, feed):
        lockin.sensitivity_v = 1e-3
        feed(lockin, 20e-3)
        lockin.settle()
        lockin.overload_status()  # clear what settling latched
        lockin.settle()
        status = lockin.overload_status()
        assert isinstance(status, LockInStatus)
        assert status.output_overload and status.overloaded
        full_scale = lockin.auto_range(timeout=30.0)
        assert 0.5 * full_scale >= 20e-3
        assert full_scale == min(fs for fs in lockin.sensitivities_v if 0.5 * fs >= 20e-3)
        lockin.overload_status()
        lockin.settle()
        assert not lockin.overload_status().overloaded
        assert lockin.snapshot().r_v == pytest.approx(20e-3, rel=0.01)

    def test_auto_range_steps_down_for_a_small_signal(self, lockin, feed):
        lockin.sensitivity_v = lockin.sensitivities_v[-1]
        feed(lockin, 2e-3)
        full_scale = lockin.auto_range(timeout=30.0)
        assert full_scale == min(fs for fs in lockin.sensitivities_v if 0.5 * fs >= 2e-3)
        assert lockin.sensitivity_v == pytest.approx(full_scale)
        lockin.settle()
        assert lockin.snapshot().r_v == pytest.approx(2e-3, rel=0.01)

    def test_auto_range_raises_when_no_range_helps(self, lockin, feed):
        feed(lockin, 5.0)  # far beyond the input's range
        with pytest.raises(OverloadError) as info:
            lockin.auto_range(timeout=30.0)
        assert info.value.device == lockin.name and info.value.command == "auto_range"
        assert lockin.sensitivity_v == pytest.approx(lockin.sensitivities_v[-1])

    def test_auto_range_validates_its_arguments(self, lockin):
        with pytest.raises(ValueError):
            lockin.auto_range(max_steps=0)
        with pytest.raises(ValueError):
            lockin.auto_range(headroom=1.5)
        with pytest.raises(ValueError):
            lockin.auto_range(timeout=-1)
