"""thorlabs_apt_device (an independent APT client) against the K10CR1 and KDC101
emulators on a real pty.

The client's ``KDC101`` class drives both (the K10CR1 speaks the same motor messages);
identity is read with the client's own message packer and unpacker
(:mod:`thorlabs_apt_device.protocol`), because its device classes do not ask for it.

The client is asynchronous: it polls status in a thread and updates ``status``; tests
wait for a state with a generous deadline instead of sleeping a fixed time. The
emulators run a :class:`~hw_mocks.clock.ScaledClock`, so a move's emulated duration is
fixed whatever the machine's load; only how long the test waits for it varies.

What the client expects and the emulators do agree; two power-up facts the client must
be told about (both in the emulator's docstring): the channel is disabled and the home
velocity is zero, so a program calls ``set_enabled(True)`` and ``set_home_params`` first.

Quirk of the client: its parser names HW_RICHRESPONSE ``"hw_richresponse"`` while its
device class waits for ``"hw_rich_response"``, so error callbacks never fire for the
device's rich error reports (0.3.8). The error test therefore reads them with the
client's unpacker.
"""

from __future__ import annotations

import time

import pytest
import serial

apt_device = pytest.importorskip("thorlabs_apt_device",
                                 reason="thorlabs_apt_device not installed")
apt = pytest.importorskip("thorlabs_apt_device.protocol")

from hw_mocks.clock import ScaledClock  # noqa: E402
from hw_mocks.firmware.apt import AptEmulator  # noqa: E402
from hw_mocks.pty_server import PtyServer  # noqa: E402
from tests.waiting import wait_for  # noqa: E402

SPEED = 20.0
HOST, DEVICE = 0x01, 0x50




def request_velparams(device) -> None:
    """Ask for the velocity parameters again. The class asks only when it opens and has
    no public call for it; this queues the client's own message on its own writer, as its
    status polling does."""
    device._loop.call_soon_threadsafe(device._write, apt.mot_req_velparams(
        source=HOST, dest=DEVICE, chan_ident=1))


@pytest.fixture(params=["K10CR1", "KDC101"])
def bench(request):
    emulator = AptEmulator(f"apt-{request.param}", model=request.param,
                           clock=ScaledClock(SPEED))
    server = PtyServer(emulator)
    yield request.param, emulator, server
    server.close()


@pytest.fixture
def client(bench):
    model, emulator, server = bench
    device = apt_device.KDC101(serial_port=server.path, home=False)
    wait_for(lambda: device.status.get("msg") is not None)  # first status polled
    yield model, emulator, device
    device.close()


def first_message(port: serial.Serial, name: str, timeout: float = 30.0):
    """The first message called ``name`` that the client's unpacker decodes."""
    unpacker = apt.Unpacker(port)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for message in unpacker:
            if message.msg == name:
                return message
    raise AssertionError(f"no {name} within {timeout} s")


def test_identity_through_the_clients_packer(bench):
    model, emulator, server = bench
    with serial.Serial(server.path, 115200, timeout=0.1) as port:
        port.write(apt.hw_req_info(dest=DEVICE, source=HOST))
        info = first_message(port, "hw_get_info")
    assert info.model_number.rstrip(b"\0").decode() == model
    assert str(info.serial_number).startswith(str(emulator.profile.serial_prefix))
    assert info.nchs == 1


def test_an_error_report_decodes_with_the_clients_unpacker(bench):
    _, emulator, server = bench
    with serial.Serial(server.path, 115200, timeout=0.1) as port:
        emulator.enter_error_state()
        report = first_message(port, "hw_richresponse")
    assert report.source == DEVICE and report.code == emulator.defaults.error_code
    assert report.notes.rstrip(b"\0") == b"emulated motion error"


def test_power_up_state_settings_and_a_move(client):
    _, emulator, device = client
    profile = emulator.profile
    # Power-up as the emulator documents it: channel disabled, zero home velocity.
    assert device.status["channel_enabled"] is False
    wait_for(lambda: "home_velocity" in device.homeparams)
    assert device.homeparams["home_velocity"] == 0
    # Settings round trip: velocity parameters.
    device.set_velocity_params(acceleration=12000, max_velocity=50_000_000)
    request_velparams(device)
    wait_for(lambda: device.velparams.get("max_velocity") == 50_000_000)
    assert device.velparams["acceleration"] == 12000
    device.set_enabled(True)
    wait_for(lambda: device.status["channel_enabled"])
    device.set_home_params(velocity=round(profile.velocity_scale * 5.0), offset_distance=0)
    target = round(5.0 * profile.counts_per_unit)
    device.move_absolute(target)
    wait_for(lambda: abs(device.status["position"] - target) <= profile.stop_short_counts
               and not (device.status["moving_forward"] or device.status["moving_reverse"]))
    assert emulator.stage.position() == pytest.approx(5.0, abs=(profile.stop_short_counts + 1)
                                                    / profile.counts_per_unit)


def test_a_disabled_channel_does_not_move(client):
    _, emulator, device = client
    start = emulator.stage.position()
    device.move_relative(100_000)  # channel disabled: ignored (no reply, no motion)
    # A later round trip on the same line proves the move was read and dropped.
    device.set_velocity_params(acceleration=11000, max_velocity=40_000_000)
    request_velparams(device)
    wait_for(lambda: device.velparams.get("max_velocity") == 40_000_000)
    assert emulator.stage.position() == start and not emulator.stage.is_moving()
    assert device.status["channel_enabled"] is False
