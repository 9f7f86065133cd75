"""ElliptecMount: byte-exact transcripts, the motion contract on both transports, the
shared bus, status codes and faults.

Transcripts pin the exact bytes of each operation, with nothing left unread. The contract
suite runs the driver against the independent firmware emulator in-process
(``simell://``) and through a real pseudo-terminal. Fault tests count attempts and check
typed errors; none depends on how fast the machine runs (emulated clocks are held where a
moment mid-move matters).
"""

from __future__ import annotations

import pytest

from drivers.errors import (
    ConnectionFailed,
    DeviceTimeout,
    LimitError,
    MotionError,
    NotHomedError,
    StateError,
    UnsupportedFeature,
)
from drivers.thorlabs_elliptec import (
    ElliptecBusy,
    ElliptecError,
    ElliptecMount,
    ElliptecOutOfRange,
    status_error,
)
from hw_mocks import registry
from hw_mocks.clock import ScaledClock
from hw_mocks.faults import FaultKind
from hw_mocks.firmware.elliptec import ElliptecEmulator
from hw_mocks.pty_server import PtyServer
from hw_mocks.transcript import TranscriptSerial
from tests.drivers.fault_checks import corrupted_reads
from tests.drivers.motion_contract import MotionAxisContract
from tests.drivers.serial_faults import (
    QUERY_FAULTS,
    QUERY_RETRIES,
    motion_fault_session,
    open_patiently,
    query_survives,
    unplug_during_move,
    unplug_during_query,
)

SPEED = 50.0
DEG = 360.0 / 143360  # degrees per pulse of an ELL14
IN_REPLY = b"0IN0E114000002023170101680002300" + b"0\r\n"
CONNECT = [(b"0in", IN_REPLY)]


def transcript_mount(steps, **kw) -> tuple[ElliptecMount, TranscriptSerial]:
    port = TranscriptSerial(steps, baudrate=9600)
    kw.setdefault("reply_timeout", 0.05)
    kw.setdefault("flush_s", 0.0)
    kw.setdefault("poll_interval", 0.0)
    return ElliptecMount(port, name="analyser", **kw), port


def status(code: str = "00", pulses: str = "00000000", address: str = "0"):
    """The two exchanges of one status poll: gs, then gp."""
    a = address.encode()
    return [(a + b"gs", a + b"GS" + code.encode() + b"\r\n"),
            (a + b"gp", a + b"PO" + pulses.encode() + b"\r\n")]


# --------------------------------------------------------------------------- transcripts


def test_connect_reads_pulses_per_revolution_and_identity():
    mount, port = transcript_mount(CONNECT)
    assert mount.degrees_per_pulse == pytest.approx(DEG)
    low, high = mount.soft_limits
    assert low == pytest.approx(-(2**31) * DEG) and high == pytest.approx((2**31 - 1) * DEG)
    ident = mount.identity
    assert (ident.vendor, ident.model, ident.serial, ident.firmware) == (
        "Thorlabs", "ELL14", "11400000", "17")
    assert ident.extra["pulses_per_revolution"] == "143360"
    port.assert_complete()


def test_move_absolute_relative_and_wait_transcript():
    steps = [*CONNECT,
             *status(),                               # move_to: ready?
             (b"0ma00000BAB", b""),                   # 7.5 deg = 2986.7 pulses
             *status("09", "00000400"),               # moving
             # the move's own reply arrives before the next gs answer and is skipped
             (b"0gs", b"0PO00000BAB\r\n0GS00\r\n"), (b"0gp", b"0PO00000BAB\r\n"),
             *status("00", "00000BAB"),               # move_by: ready?
             (b"0mrFFFFFE0E", b"")]                   # -1.25 deg: 2489 - 2987 pulses
    mount, port = transcript_mount(steps, assume_homed=True)
    mount.move_to(7.5)
    assert mount.wait(60) == pytest.approx(7.5, abs=DEG)
    mount.move_by(-1.25)
    assert mount.target == pytest.approx(6.25)
    assert mount.skipped_lines == 1
    port.assert_complete()


def test_home_transcript_and_move_before_home_refused():
    steps = [*CONNECT,
             *status("00", "00001000"),               # move_to: not homed
             *status("00", "00001000"),               # home(): enabled?
             (b"0ho0", b""),
             *status("09", "00000800"),
             (b"0gs", b"0PO00000000\r\n0GS00\r\n"), (b"0gp", b"0PO00000000\r\n"),
             *status()]
    mount, port = transcript_mount(steps)
    with pytest.raises(NotHomedError):
        mount.move_to(1.0)
    mount.home()
    assert mount.is_homed
    port.assert_complete()


def test_counter_ccw_home_direction_is_sent():
    steps = [*CONNECT, *status(), (b"0ho1", b""), *status("00")]
    mount, port = transcript_mount(steps, home_direction="ccw")
    mount.home()
    port.assert_complete()


def test_motion_failure_reply_is_latched_and_raised_by_wait():
    steps = [*CONNECT, *status(), (b"0ma00000BAB", b""),
             # the move fails: its GS02 reply, then the answer to gs (the latched code)
             (b"0gs", b"0GS02\r\n0GS02\r\n"), (b"0gp", b"0PO00000400\r\n"),
             (b"0st", b"0GS00\r\n"),                 # wait() stops the mount first
             *status("00", "00000400")]               # move_to: ready? (then refused)
    mount, port = transcript_mount(steps, assume_homed=True)
    mount.move_to(7.5)
    with pytest.raises(ElliptecError) as info:
        mount.wait(60)
    assert info.value.code == 2 and "mechanical time out" in str(info.value)
    assert "address 0" in str(info.value) and info.value.device == "analyser"
    assert mount.fault == 2
    with pytest.raises(ElliptecError):  # motion refused until enable()
        mount.move_to(1.0)
    port.assert_complete()


def test_enable_clears_a_fault():
    steps = [*CONNECT, *status(), (b"0ma00000BAB", b""),
             (b"0gs", b"0GS02\r\n0GS00\r\n"), (b"0gp", b"0PO00000400\r\n"),
             (b"0gs", b"0GS00\r\n")]                   # enable(): reads the status
    mount, port = transcript_mount(steps, assume_homed=True)
    mount.move_to(7.5)
    assert mount.status().error == "mechanical time out (GS02)"
    mount.enable()
    assert mount.fault is None
    port.assert_complete()


@pytest.mark.parametrize("code, cls, base", [
    (4, ElliptecOutOfRange, LimitError), (12, ElliptecOutOfRange, LimitError),
    (9, ElliptecBusy, StateError), (2, ElliptecError, ElliptecError),
    (13, ElliptecError, ElliptecError), (0x42, ElliptecError, ElliptecError)])
def test_status_codes_map_to_typed_errors(code, cls, base):
    err = status_error(code, "B", device="polariser", command="Bsv32")
    assert type(err) is cls and isinstance(err, base)
    assert err.code == code and "address B" in str(err) and err.device == "polariser"
    assert f"GS{code:02X}" in str(err) and err.hint


def test_velocity_in_percent_and_refusals_are_typed():
    steps = [*CONNECT, (b"0gv", b"0GV64\r\n"), (b"0sv32", b"0GS00\r\n"),
             (b"0sv19", b"0GS09\r\n")]
    mount, port = transcript_mount(steps)
    assert mount.velocity == pytest.approx(430.0)
    mount.velocity = 215.0
    with pytest.raises(ElliptecBusy):
        mount.velocity = 107.5
    with pytest.raises(ValueError):
        mount.velocity = 1000.0  # above 100 %: refused before anything is sent
    with pytest.raises(UnsupportedFeature):
        mount.acceleration = 100.0
    assert mount.acceleration == 5000.0
    port.assert_complete()


def test_noise_and_other_addresses_replies_are_kept_apart():
    reply = (b"\xff\x00garbage\r\n"
             b"1PO00000010\r\n"          # the neighbour's move ended
             b"\x07 0PO00000100\r\n")    # garbage before ours
    steps = [*CONNECT, (b"0gp", reply)]
    mount, port = transcript_mount(steps)
    assert mount.position_pulses == 256
    assert mount._bus.mailbox["1"][0].data == "00000010"  # kept for address 1
    port.assert_complete()


def test_query_is_retried_then_times_out_naming_the_packet():
    steps = [*CONNECT, *[(b"0gp", b"")] * 3]
    mount, port = transcript_mount(steps, retries=2)
    with pytest.raises(DeviceTimeout) as info:
        mount.position  # noqa: B018
    assert "3 attempts" in str(info.value) and info.value.command == "0gp"
    port.assert_complete()


def test_constructor_failures_are_connection_failed():
    port = TranscriptSerial([(b"3in", b"")] * 3, baudrate=9600)
    with pytest.raises(ConnectionFailed) as info:
        ElliptecMount(port, name="analyser", address="3", reply_timeout=0.05, flush_s=0)
    assert "address 3" in str(info.value) and isinstance(info.value.__cause__, DeviceTimeout)
    assert port.is_open  # a port handed in stays the caller's
    linear = b"0IN0711400000202317010028" + b"00000400\r\n"  # a linear stage, 28 mm travel
    port = TranscriptSerial([(b"0in", linear)], baudrate=9600)
    with pytest.raises(ConnectionFailed) as info:
        ElliptecMount(port, name="analyser", flush_s=0)
    assert "not a rotation mount" in str(info.value)


@pytest.mark.parametrize("kw", [{"address": "G"}, {"address": "10"},
                                {"home_direction": "up"}, {"reply_timeout": 0},
                                {"retries": -1}, {"max_velocity": float("nan")}])
def test_arguments_are_validated_before_opening(kw):
    with pytest.raises(ValueError):
        ElliptecMount("simell://never-opened", name="x", **kw)
    with pytest.raises(KeyError):
        registry.get("simell", "never-opened")


# --------------------------------------------------------------------------- emulator


def open_mount(transport: str, name: str, *, cleanup: list, address: str = "0",
               addresses: str = "0", **kw) -> ElliptecMount:
    kw.setdefault("flush_s", 0.0)
    if transport == "url":
        mount = open_patiently(ElliptecMount,
                               f"simell://{name}?addresses={addresses}&speed={SPEED:g}",
                               name=name, address=address, **kw)
    else:
        emulator = registry.get_or_create(
            "simell", name, lambda n, o: ElliptecEmulator(n, addresses=addresses,
                                                          clock=ScaledClock(SPEED)))
        server = PtyServer(emulator)
        cleanup.append(server)
        mount = open_patiently(ElliptecMount, server.path, name=name, address=address, **kw)
    cleanup.append(mount)
    return mount


def emulator_of(mount: ElliptecMount) -> ElliptecEmulator:
    emulator = registry.get("simell", mount.name)
    assert isinstance(emulator, ElliptecEmulator)
    return emulator


@pytest.fixture
def clock_of():
    return lambda mount: emulator_of(mount).clock


class TestContract(MotionAxisContract):
    @pytest.fixture
    def axis_factory(self, transport, cleanup):
        count = iter(range(100))
        return lambda: open_mount(transport, f"ell{transport}{next(count)}",
                                  cleanup=cleanup)

    def test_velocity_and_acceleration_round_trip(self, ready_axis):
        """An Elliptec module has velocity (percent of its maximum) but no acceleration
        setting: the acceleration reads its nominal value and setting it is refused."""
        v = ready_axis.velocity
        ready_axis.velocity = v / 2.0
        assert ready_axis.velocity == pytest.approx(v / 2.0, rel=0.01)
        a = ready_axis.acceleration
        with pytest.raises(UnsupportedFeature) as info:
            ready_axis.acceleration = a / 2.0
        assert info.value.device == ready_axis.name
        assert ready_axis.acceleration == a
        with pytest.raises(ValueError):
            ready_axis.velocity = -1.0


class TestContractSteppingClock(MotionAxisContract):
    """In-process with a stepping clock: simulated time passes only as the driver polls."""

    @pytest.fixture
    def axis_factory(self, cleanup):
        count = iter(range(100))

        def make():
            name = f"ellstep{next(count)}"
            mount = ElliptecMount(f"simell://{name}?step=0.002", name=name, flush_s=0.0)
            cleanup.append(mount)
            return mount
        return make

    test_velocity_and_acceleration_round_trip = \
        TestContract.test_velocity_and_acceleration_round_trip


@pytest.fixture
def homed(transport, cleanup):
    mount = open_mount(transport, f"beh{transport}", cleanup=cleanup)
    mount.home(timeout=30)
    return mount


def test_three_mounts_on_one_bus_share_the_port(transport, cleanup):
    name = f"bus{transport}"
    if transport == "url":
        url = f"simell://{name}?addresses=04A&speed={SPEED:g}"
    else:
        emulator = registry.get_or_create(
            "simell", name, lambda n, o: ElliptecEmulator(n, addresses="04A",
                                                          clock=ScaledClock(SPEED)))
        server = PtyServer(emulator)
        cleanup.append(server)
        url = server.path
    mounts = [ElliptecMount(url, name=f"{name}{a}", address=a, flush_s=0.0) for a in "04A"]
    cleanup.extend(mounts)
    assert len({id(m._bus) for m in mounts}) == 1  # one port, one lock, three mounts
    for mount in mounts:
        mount.home(wait=False)
    for mount in mounts:
        mount.wait(60)
    targets = (12.5, -30.0, 90.0)
    for mount, target in zip(mounts, targets, strict=True):
        mount.move_to(target)  # all three move together
    for mount, target in zip(mounts, targets, strict=True):
        assert mount.wait(60) == pytest.approx(target, abs=DEG)
    mounts[0].close()
    assert mounts[1].position == pytest.approx(-30.0, abs=DEG)  # the port stays open
    emulator = registry.get("simell", name)
    assert isinstance(emulator, ElliptecEmulator)
    for address, target in zip("04A", targets, strict=True):
        assert emulator.modules[address].stage.physical_position() == pytest.approx(
            target, abs=DEG)


def test_homing_references_the_physical_index(transport, cleanup):
    name = f"ref{transport}"
    if transport == "url":
        url = f"simell://{name}?start=123.4&speed={SPEED:g}"
        mount = ElliptecMount(url, name=name, flush_s=0.0)
        cleanup.append(mount)
    else:
        emulator = ElliptecEmulator(name, start_positions=[123.4], clock=ScaledClock(SPEED))
        registry.get_or_create("simell", name, lambda n, o: emulator)
        server = PtyServer(emulator)
        cleanup.append(server)
        mount = ElliptecMount(server.path, name=name, flush_s=0.0)
        cleanup.append(mount)
    assert mount.position == pytest.approx(0.0)  # the counter starts at 0 anywhere
    mount.home(timeout=30)
    mount.move_to(45.0, wait=True, timeout=30)
    assert emulator_of(mount).stage.physical_position() == pytest.approx(45.0, abs=DEG)


@pytest.fixture
def faulty(homed):
    homed.reply_timeout = 0.1
    return homed, emulator_of(homed).faults


@pytest.mark.parametrize("kind, params", QUERY_FAULTS)
def test_query_faults_recover(faulty, kind, params):
    mount, faults = faulty
    # more retries than a driver's default: a fault costs one attempt, and on a loaded
    # host an emulator thread on a pty may miss the 0.1 s deadline of another
    mount.retries = QUERY_RETRIES
    mount.move_to(4.0, wait=True, timeout=30)
    query_survives(faults, kind, params, lambda: mount.position_pulses, round(4.0 / DEG))


def test_corrupted_replies_are_retried_or_decoded_the_protocol_has_no_checksum(faulty):
    """A flip in the address, the mnemonic or the line end makes the reply not ours and
    the query is retried; a flip that turns one hex digit into another decodes as a wrong
    position, which the Elliptec protocol (no checksum) cannot catch: counted here."""
    mount, faults = faulty
    mount.move_to(4.0, wait=True, timeout=30)
    expected = round(4.0 / DEG)
    got = corrupted_reads(lambda: mount.position_pulses, lambda v: v == expected, faults,
                          n=30, device=mount.name, command="0gp")
    assert got.right + got.wrong + got.failed == 30 and got.right >= 10


def test_random_faults_on_a_long_session_never_hang(faulty):
    mount, faults = faulty
    motion_fault_session(mount, faults)


@pytest.mark.parametrize("code, cls", [("02", ElliptecError), ("0C", ElliptecOutOfRange),
                                       ("0D", ElliptecError)])
def test_error_state_during_move_raises_and_enable_recovers(homed, code, cls):
    emulator = emulator_of(homed)
    with emulator.clock.held():
        homed.move_to(8.0)
        assert homed.is_moving
        emulator.faults.schedule(FaultKind.ERROR_STATE, nth=1, code=code)
        with pytest.raises(cls) as info:
            homed.wait(30)
    assert info.value.code == int(code, 16) and info.value.device == homed.name
    assert "address 0" in str(info.value)
    assert homed.position < 8.0 - homed.position_tolerance  # stopped short
    homed.enable()
    homed.move_to(1.0, wait=True, timeout=30)
    assert homed.position == pytest.approx(1.0, abs=DEG)


def test_disconnect_is_typed_and_reconnect_finds_same_state(transport, cleanup, homed):
    homed.move_to(3.0, wait=True, timeout=30)
    mount = unplug_during_query(
        homed, emulator_of(homed), transport,
        lambda: open_mount(transport, homed.name, cleanup=cleanup, assume_homed=True),
        command="0gp")
    assert mount.position == pytest.approx(3.0, abs=DEG)


def test_unplugged_mid_move_is_typed_and_the_move_is_found_finished(transport, cleanup,
                                                                    homed):
    homed.move_to(9.0)
    mount = unplug_during_move(
        homed, emulator_of(homed), transport,
        lambda: open_mount(transport, homed.name, cleanup=cleanup, assume_homed=True))
    assert mount.position == pytest.approx(9.0, abs=DEG)


def test_a_missed_target_is_a_motion_error(homed):
    """A module that stops short without a status code (blocked optic) is caught by
    wait()'s arrival check."""
    emulator = emulator_of(homed)
    with emulator.clock.held():
        homed.move_to(5.0)
        assert homed.is_moving  # a round trip: the module has taken the move (pty too)
        emulator.modules["0"].stage.stop(immediate=True)
    with pytest.raises(MotionError):
        homed.wait(30)


# --------------------------------------------------------------------------- profile


def test_profile_names_two_mounts_on_one_bus():
    """``driver = "ell14"`` in a bench profile: two roles, one bus, one address each."""
    from instrument.bench.devices import open_device
    from instrument.bench.profile import ProfileError, parse_profile

    text = ('[bench]\nname = "b"\n'
            '[devices.sample_phi]\ndriver = "ell14"\n'
            'url = "simell://profbus?addresses=01&speed=50"\nlimits = [-360.0, 360.0]\n'
            'options = { address = "0" }\n'
            '[devices.sample_tilt]\ndriver = "ell14"\n'
            'url = "simell://profbus?addresses=01&speed=50"\nvelocity = 215.0\n'
            'options = { address = "1", home_direction = "ccw" }\n')
    profile = parse_profile(text)
    with open_device(profile.device("sample_phi")) as polariser, \
            open_device(profile.device("sample_tilt")) as analyser:
        assert isinstance(polariser, ElliptecMount) and polariser.soft_limits == (-360, 360)
        assert analyser.address == "1" and analyser.velocity == pytest.approx(215.0)
        assert polariser._bus is analyser._bus
        polariser.home()
        polariser.move_to(22.5, wait=True, timeout=30)
        assert polariser.position == pytest.approx(22.5, abs=DEG)
    with pytest.raises(ProfileError, match="address"):
        parse_profile(text.replace('address = "1"', 'address = "G"'))


def test_jog_steps_by_the_modules_step(homed):
    homed.move_to(10.0, wait=True, timeout=30)
    homed.jog_step = 22.5
    assert homed.jog_step == pytest.approx(22.5, abs=DEG)
    homed.jog(wait=True, timeout=30)
    homed.jog(wait=True, timeout=30)
    homed.jog(forward=False, wait=True, timeout=30)
    assert homed.position == pytest.approx(32.5, abs=2 * DEG)
    with pytest.raises(ValueError):
        homed.jog_step = 0.0


def test_jog_transcript():
    steps = [*CONNECT, (b"0sj00000FA0", b"0GS00\r\n"), *status(), (b"0bw", b""),
             (b"0gs", b"0POFFFFF060\r\n0GS00\r\n"), (b"0gp", b"0POFFFFF060\r\n")]
    mount, port = transcript_mount(steps, assume_homed=True)
    mount.jog_step = 4000 * DEG
    mount.jog(forward=False, wait=True)
    assert mount.target is None and mount.skipped_lines == 1
    port.assert_complete()


@pytest.mark.hardware
def test_real_mount_identity_and_status():
    """Opt-in: ``SCATTERLAB_HW_ELL14=/dev/ttyUSB0`` (``SCATTERLAB_HW_ELL14_ADDRESS``, default
    0). Moves nothing; confirms the ``in`` layout, ``gs``/``gp`` and the ``gv`` percentage."""
    import os

    port = os.environ.get("SCATTERLAB_HW_ELL14")
    if not port:
        pytest.skip("set SCATTERLAB_HW_ELL14 to the interface board's serial port")
    with ElliptecMount(port, name="hw_ell14", reply_timeout=1.0,
                       address=os.environ.get("SCATTERLAB_HW_ELL14_ADDRESS", "0")) as mount:
        assert mount.identity.vendor == "Thorlabs" and mount.identity.serial
        assert mount.degrees_per_pulse == pytest.approx(360 / 143360)
        assert mount.status().error is None
        assert 0 < mount.velocity <= mount.max_velocity
