"""zaber-motion (Zaber's own library) against the Zaber ASCII emulator on a real pty.

The emulator runs a :class:`~hw_mocks.clock.ScaledClock`; zaber-motion waits for a move
to end by polling the axis, so the outcome does not depend on the machine's speed. The
request timeout is generous for a loaded machine.

Limit of the check: ``detect_devices()`` with identification (the default) and
``Device.identify()`` look the device up in Zaber's online device database, which a test
cannot reach; they are skipped (``identify_devices=False``), so unit conversions (which
need that database) are not exercised and everything is in native units (microsteps).
"""

from __future__ import annotations

import pytest

from hw_mocks.clock import ScaledClock
from hw_mocks.firmware.zaber import ZaberEmulator
from hw_mocks.pty_server import PtyServer

SPEED = 50.0
TIMEOUT_MS = 10_000


@pytest.fixture
def zaber():
    """zaber-motion, imported by the tests that use it: at collection every test process
    would pay its import (0.6 s of CPU), and only one of them runs these tests."""
    return pytest.importorskip("zaber_motion", reason="zaber-motion not installed")


@pytest.fixture
def link(zaber):
    zaber_ascii = pytest.importorskip("zaber_motion.ascii")
    emulator = ZaberEmulator("zm", clock=ScaledClock(SPEED))
    server = PtyServer(emulator)
    connection = zaber_ascii.Connection.open_serial_port(server.path)
    connection.default_request_timeout = TIMEOUT_MS
    yield connection, emulator
    connection.close()
    server.close()


def test_detects_one_device_and_reads_its_identity(link):
    connection, _ = link
    # Detection collects the answers to a broadcast for a while (generous timeout above).
    devices = connection.detect_devices(identify_devices=False)
    assert [d.device_address for d in devices] == [1]
    device = devices[0]
    assert device.generic_command("get version").data == "7.38"
    assert int(device.generic_command("get system.axiscount").data) == 1


def test_power_up_position_warning_settings_and_a_move(link):
    connection, emulator = link
    device = connection.get_device(1)
    axis = device.get_axis(1)
    reply = axis.generic_command("get pos")
    assert (reply.data, reply.warning_flag, reply.status) == ("0", "WR", "IDLE")
    assert not axis.is_homed()
    speed = axis.settings.get("maxspeed")
    axis.settings.set("maxspeed", speed / 2)
    assert axis.settings.get("maxspeed") == speed / 2
    axis.home()
    assert axis.is_homed() and axis.get_position() == 0
    axis.move_absolute(10000)
    assert axis.get_position() == 10000
    assert not axis.is_busy()
    axis.move_relative(-2500)
    assert axis.get_position() == 7500
    assert emulator.axes[1].stage.position() == pytest.approx(
        7500 * emulator.axes[1].ms)


def test_rejections_become_the_libraries_typed_errors(link, zaber):
    connection, _ = link
    device = connection.get_device(1)
    axis = device.get_axis(1)
    with pytest.raises(zaber.BadCommandException):
        device.generic_command("frobnicate")
    limit = int(axis.settings.get("limit.max"))
    with pytest.raises(zaber.BadDataException):
        axis.generic_command(f"move abs {limit + 1}")
    with pytest.raises(zaber.BadDataException):
        axis.settings.set("maxspeed", -5)
