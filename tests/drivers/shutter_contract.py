"""The contract every :class:`drivers.base.Shutter` implementation keeps.

A shutter is a light source (light reaches the sample while it is open), so the suite
includes :class:`~tests.drivers.light_source_contract.LightSourceContract`. Subclass
:class:`ShutterContract` and provide a fixture ``source_factory`` returning a freshly
opened shutter; run it once per transport.
"""

from __future__ import annotations

import pytest

from drivers.base import DeviceIdentity, Shutter, ShutterState
from drivers.errors import StateError
from tests.drivers.light_source_contract import LightSourceContract


class ShutterContract(LightSourceContract):
    def test_is_a_shutter_with_identity(self, source):
        assert isinstance(source, Shutter)
        ident = source.identity
        assert isinstance(ident, DeviceIdentity) and ident.vendor and ident.model

    def test_state_follows_open_and_close_and_agrees_with_is_on(self, source):
        source.close_shutter()
        assert source.shutter_state is ShutterState.CLOSED and not source.is_on
        source.open_shutter()
        assert source.shutter_state is ShutterState.OPEN and source.is_on
        source.open_shutter()  # idempotent: a second open must not toggle it shut
        assert source.shutter_state is ShutterState.OPEN
        source.close_shutter()
        source.close_shutter()  # idempotent: a second close must not toggle it open
        assert source.shutter_state is ShutterState.CLOSED and not source.is_on

    def test_alternating_many_times_ends_where_commanded(self, source):
        for i in range(7):
            source.turn_on() if i % 2 == 0 else source.turn_off()
        assert source.is_on  # the 7th command (i = 6) was turn_on

    def test_closed_shutter_refuses_but_close_shutter_is_harmless(self, source_factory):
        shutter = source_factory()
        shutter.close()
        shutter.close()
        shutter.close_shutter()  # a no-op on a closed device
        with pytest.raises(StateError):
            shutter.open_shutter()
        with pytest.raises(StateError):
            shutter.shutter_state  # noqa: B018

    def test_context_manager_closes(self, source_factory):
        with source_factory() as shutter:
            assert not shutter.closed
        assert shutter.closed
