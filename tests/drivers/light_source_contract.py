"""The contract every :class:`drivers.base.LightSource` implementation keeps.

Subclass :class:`LightSourceContract` and provide a fixture ``source_factory``.
"""

from __future__ import annotations

import math

import pytest

from drivers.base import LightSource
from drivers.errors import StateError, UnsupportedFeature


class LightSourceContract:
    @pytest.fixture
    def source(self, source_factory):
        source = source_factory()
        yield source
        source.close()

    def test_on_off(self, source):
        assert isinstance(source, LightSource)
        source.turn_on()
        assert source.is_on
        source.turn_off()
        source.turn_off()  # idempotent
        assert not source.is_on

    def test_power_setpoint_within_range_or_unsupported(self, source):
        if source.power_range_w is None:
            with pytest.raises(UnsupportedFeature):
                source.power_w = 1e-3
            return
        low, high = source.power_range_w
        target = low + 0.25 * (high - low)
        source.power_w = target
        assert source.power_w == pytest.approx(target, rel=1e-6)
        for bad in (high * 2 + 1.0, -1.0, math.inf):
            with pytest.raises(ValueError):
                source.power_w = bad
        assert source.power_w == pytest.approx(target, rel=1e-6)

    def test_turn_off_is_always_allowed_and_closed_source_refuses_on(self, source_factory):
        source = source_factory()
        source.turn_on()
        source.close()
        source.turn_off()  # a no-op on a closed device, never an error
        with pytest.raises(StateError):
            source.turn_on()
