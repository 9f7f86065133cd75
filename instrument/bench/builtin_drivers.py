"""scatterlab's own drivers, registered like any plugin's (``pyproject.toml``'s
``[project.entry-points."scatterlab.drivers"]`` names each entry here; ADR 0092).

Each entry says the device kind, the driver class (imported only when a device is opened:
neither OpenCV, the simulation nor NumPy is imported to validate a profile), the profile options
the constructor takes, the settings applied after opening, and the pyserial scheme of the
firmware emulator. The simulated camera and source live in ``hw_mocks``: production
code reaches them only by the strings here and their URL schemes (``simcam://``,
``simsource://``), never by an import.
"""

from __future__ import annotations

import inspect
import math
from typing import Any
from urllib.parse import parse_qsl, urlsplit

from drivers.errors import ConnectionFailed
from instrument.bench.driver_registry import Device, DriverEntry, Emulator, Option
from instrument.bench.profile import DeviceSpec

__all__ = ["APT", "BASLER", "ELL14", "FW102C", "NEWPORT_SMC100", "OPENCV_CAMERA", "PEM200",
           "PM100USB", "SC10", "SIM_CAMERA", "SIM_SOURCE", "SR830", "ZABER"]

#: The package of the firmware emulators' pyserial URL handlers.
SIM_URL_HANDLERS = "hw_mocks.urlhandler"

# Keys many serial drivers share (seconds; counts).
_SECONDS = Option(float, 0.0, 600.0, doc="seconds")
_LINK = {"reply_timeout": Option(float, 0.001, 60.0, doc="seconds to wait for a reply"),
         "retries": Option(int, 0, 20, doc="resends of an idempotent query")}
_BAUD = {"baudrate": Option(int, 300, 1_000_000, doc="the device's configured rate")}
_AXIS_KIND = {"kind": Option(str, choices=("rotary", "linear"),
                             doc="axis kind (default: linear on camera_z, else rotary)")}
_POLL = {"poll_interval": Option(float, 0.0, 10.0, doc="seconds between status polls")}


def _axis_kwargs(spec: DeviceSpec) -> dict[str, Any]:
    kw: dict[str, Any] = {"name": spec.role}
    if spec.limits is not None:
        kw["soft_limits"] = spec.limits
    if spec.position_tolerance is not None:
        kw["position_tolerance"] = spec.position_tolerance
    kw.update(spec.options)
    return kw


def _kind_kwargs(spec: DeviceSpec) -> dict[str, Any]:
    """The axis keywords with ``kind`` defaulted from the role (``camera_z`` is linear)."""
    kw = _axis_kwargs(spec)
    from drivers.base import AxisKind

    kw.setdefault("kind", "linear" if spec.role == "camera_z" else "rotary")
    kw["kind"] = AxisKind.LINEAR if kw["kind"] == "linear" else AxisKind.ROTARY
    return kw


def _open_apt(cls: type, spec: DeviceSpec) -> Device:
    kw = _axis_kwargs(spec)
    if spec.url.split("://", 1)[0] == "simapt":
        kw = _paced_by_emulator(cls, spec.url, kw, ("rts_settle_s", "flush_s"))
    return cls(spec.url, stage=spec.stage or "K10CR1", **kw)


def _paced_by_emulator(cls: type, url: str, kw: dict[str, Any],
                       pauses: tuple[str, ...]) -> dict[str, Any]:
    """``kw`` with the driver's default ``pauses`` divided by the emulator's ``speed``.

    The pauses a driver makes on opening for the device's sake (the APT document's RTS
    cycle, the wait for status messages already in flight) are device time; an emulator
    URL's ``speed=N`` runs the emulated controller N times faster than the wall clock, so
    they pass N times faster too (ADR 0115). A pause the profile sets is kept as set.
    """
    try:
        speed = float(dict(parse_qsl(urlsplit(url).query)).get("speed", 1.0))
    except ValueError:
        return kw  # the emulator names the bad option when it opens
    if not (math.isfinite(speed) and speed > 1.0):
        return kw
    params = inspect.signature(cls).parameters
    scaled = {name: float(params[name].default) / speed for name in pauses
              if name not in kw and name in params
              and isinstance(params[name].default, float)}
    return kw | scaled


def _open_axis_with_kind(cls: type, spec: DeviceSpec) -> Device:
    return cls(spec.url, **_kind_kwargs(spec))


def _open_zaber(cls: type, spec: DeviceSpec) -> Device:
    if "microstep_size" not in spec.options:
        raise ConnectionFailed("a Zaber axis needs options.microstep_size (degrees or mm per "
                               "microstep, from the product's specification)",
                               device=spec.role, command="open")
    return _open_axis_with_kind(cls, spec)


def _open_pem(cls: type, spec: DeviceSpec) -> Device:
    if "nm_per_drive" not in spec.options:
        raise ConnectionFailed("a PEM200 needs options.nm_per_drive (nm of peak retardation "
                               "at drive 1.0, the head's calibration)",
                               device=spec.role, command="open")
    return cls(spec.url, name=spec.role, **spec.options)


def _open_pm100(cls: type, spec: DeviceSpec) -> Device:
    from instrument.bench.devices import sim_entry_point
    kw: dict[str, Any] = {"name": spec.role, **spec.options}
    scheme = spec.url.split("://", 1)[0]
    if scheme == "simusb":
        kw["backend"] = sim_entry_point("simusb")(spec.url)
    elif spec.url.startswith("usb://"):
        serial = spec.url[len("usb://"):].strip("/")
        if serial:
            kw.setdefault("serial_number", serial)
    return cls(**kw)


def _open_sr830(cls: type, spec: DeviceSpec) -> Device:
    from instrument.bench.devices import sim_entry_point
    kw: dict[str, Any] = {"name": spec.role, **spec.options}
    if spec.url.split("://", 1)[0] == "simsr830":
        # An emulator on a host-paced clock (``clock=host``) lets time pass when the driver
        # waits, so its readings do not depend on how fast the machine runs the host.
        sleep = sim_entry_point("simsr830")(spec.url)
        if sleep is not None:
            kw.setdefault("sleep", sleep)
    return cls(spec.url, **kw)


def _open_basler(cls: type, spec: DeviceSpec) -> Device:
    # pylon finds the camera by its serial number, which the profile's ``serial`` gives
    # (it stands in ``spec.url``); the transport, not the class, is what is opened here
    from drivers.pylon_transport import open_basler_camera

    return open_basler_camera(spec.url, name=spec.role, **spec.options)


def _open_simulated(cls: type, spec: DeviceSpec) -> Device:
    from instrument.bench.devices import sim_entry_point
    scheme = spec.url.split("://", 1)[0]
    if scheme not in ("simcam", "simsource"):
        raise ConnectionFailed(f"driver {spec.driver!r} needs a simcam:// or simsource:// URL",
                               device=spec.role, command="open")
    device = sim_entry_point(scheme)(spec.url)
    device.name = spec.role
    return device


APT = DriverEntry(
    "motion_axis", "drivers.thorlabs_apt:AptMotor",
    summary="Thorlabs APT motor controllers (K10CR1, KDC101 with PRM1-Z8/MTS25-Z8)",
    options={"home_velocity": Option(float, 0.0, 1e4, doc="homing velocity, units/s"),
             "home_offset": Option(float, -1e4, 1e4, doc="zero after homing, axis units"),
             "velocity": Option(float, 0.0, 1e4), "acceleration": Option(float, 0.0, 1e5),
             "timeout": Option(float, 0.001, 60.0, doc="seconds to wait for a reply"),
             "retries": _LINK["retries"], **_POLL,
             "rts_settle_s": _SECONDS, "flush_s": _SECONDS,
             "stop_mode": Option(str, choices=("profiled", "immediate")),
             "channel": Option(int, 1, 16)},
    emulator=Emulator("simapt", SIM_URL_HANDLERS), open=_open_apt)

NEWPORT_SMC100 = DriverEntry(
    "motion_axis", "drivers.newport_smc100:Smc100Axis",
    summary="Newport SMC100 single-axis controllers",
    options={"address": Option(int, 1, 31), **_AXIS_KIND, **_POLL, **_LINK,
             "reset_timeout": _SECONDS, "xonxoff": Option(bool)},
    emulator=Emulator("simsmc", SIM_URL_HANDLERS), open=_open_axis_with_kind)

ZABER = DriverEntry(
    "motion_axis", "drivers.zaber_ascii:ZaberAxis",
    summary="Zaber stages over the ASCII protocol",
    options={"microstep_size": Option(float, 1e-12, 1e3,
                                      doc="degrees or mm per microstep (required)"),
             "device": Option(int, 1, 99), "axis": Option(int, 1, 9), **_AXIS_KIND,
             "resolution": Option(int, 1, 256), **_POLL, **_LINK,
             "checksum": Option(bool), "alerts": Option(bool), "message_ids": Option(bool),
             "flush_s": _SECONDS},
    emulator=Emulator("simzaber", SIM_URL_HANDLERS), open=_open_zaber)

ELL14 = DriverEntry(
    "motion_axis", "drivers.thorlabs_elliptec:ElliptecMount",
    summary="Thorlabs Elliptec ELL14 rotation mounts, several on one bus (address 0-F)",
    options={"address": Option(str, choices=tuple("0123456789ABCDEF"),
                               doc="the module's bus address"),
             "max_velocity": Option(float, 1.0, 1e4, doc="deg/s at 100 % velocity"),
             "nominal_acceleration": Option(float, 1.0, 1e6, doc="deg/s², for estimates"),
             "home_direction": Option(str, choices=("cw", "ccw")),
             "assume_homed": Option(bool), **_POLL, **_LINK, "flush_s": _SECONDS},
    emulator=Emulator("simell", SIM_URL_HANDLERS))

SR830 = DriverEntry(
    "lockin", "drivers.stanford_sr830:Sr830LockIn",
    summary="Stanford Research SR830 lock-in amplifier over RS-232",
    options={**_BAUD, **_LINK, "auto_gain_timeout": _SECONDS},
    # the SR830's ranges (manual, Rev. 2.5, ch. 5: SENS 2 nV…1 V, OFLT 10 µs…30 ks)
    settings={"time_constant_s": Option(float, 1e-5, 3e4),
              "sensitivity_v": Option(float, 2e-9, 1.0),
              "reference_source": Option(str, choices=("internal", "external"))},
    emulator=Emulator("simsr830", SIM_URL_HANDLERS), open=_open_sr830)

PEM200 = DriverEntry(
    "modulator", "drivers.hinds_pem:Pem200",
    summary="Hinds Instruments PEM200 photoelastic modulator controller",
    options={"nm_per_drive": Option(float, 1.0, 1e5, doc="nm of peak retardation at drive "
                                    "1.0, the head's calibration (required)"),
             "wavelength_nm": Option(float, 100.0, 25000.0), **_BAUD, **_LINK},
    # applied in this order: the wavelength first, then the amplitude in waves at it
    settings={"wavelength_nm": Option(float, 100.0, 25000.0),
              "retardation_waves": Option(float, 0.0, 10.0, doc="peak, in waves")},
    emulator=Emulator("simpem", SIM_URL_HANDLERS), open=_open_pem)

SC10 = DriverEntry(
    "shutter", "drivers.thorlabs_sc10:Sc10Shutter",
    summary="Thorlabs SC10 shutter controller",
    options={**_BAUD, **_LINK, "settle_timeout": _SECONDS, **_POLL,
             "close_on_exit": Option(bool), "serial_number": Option(str)},
    emulator=Emulator("simsc10", SIM_URL_HANDLERS))

FW102C = DriverEntry(
    "filter_wheel", "drivers.thorlabs_fw102c:Fw102cWheel",
    summary="Thorlabs FW102C/FW212C filter wheels",
    options={"filters": Option(dict, doc="slot → filter (center_nm, bandwidth_nm, od, label)"),
             "speed": Option(str, choices=("normal", "high")), **_BAUD, **_LINK,
             "move_timeout_factor": Option(float, 1.0, 100.0),
             "move_timeout_margin_s": _SECONDS, "serial_number": Option(str)},
    emulator=Emulator("simfw102c", SIM_URL_HANDLERS))

PM100USB = DriverEntry(
    "power_meter", "drivers.thorlabs_pm100:PM100USB",
    summary="Thorlabs PM100USB power meter over USBTMC (usb://SERIAL or simusb://)",
    options={"serial_number": Option(str), "timeout_s": Option(float, 0.001, 600.0),
             "zero_poll_s": Option(float, 0.0, 10.0), "vendor_id": Option(int, 0, 0xFFFF),
             "product_id": Option(int, 0, 0xFFFF)},
    settings={"wavelength_nm": Option(float, 100.0, 25000.0),
              "averaging": Option(int, 1, 100000), "auto_range": Option(bool)},
    open=_open_pm100)

OPENCV_CAMERA = DriverEntry(
    "camera", "drivers.opencv_camera:OpenCVCamera",
    summary="cameras OpenCV's VideoCapture opens (an index or a device path)",
    options={"api_preference": Option(int, 0, 1_000_000), "stale_frames": Option(int, 0, 1000),
             "bit_depth": Option(int, 1, 32), "nominal_exposure_us": Option(float, 0.0, 60e6),
             "buffer_size": Option(int, 1, 1000), "ring_capacity": Option(int, 1, 100_000)},
    settings={"exposure_us": Option(float, 1.0, 60e6), "gain": Option(float, 0.0, 1000.0)})

BASLER = DriverEntry(
    "camera", "drivers.genicam_camera:GenICamCamera",
    summary="Basler cameras through pypylon, found by serial number (ADR 0096)",
    options={"pixel_format": Option(str, choices=("MONO8", "MONO10", "MONO12", "MONO16")),
             "trigger_mode": Option(str, choices=("software", "hardware", "free_run")),
             "hardware_line": Option(str, doc="the trigger input line (Line1...)"),
             "buffers": Option(int, 1, 64, doc="frames pylon queues"),
             "emulation": Option(bool, doc="pylon's camera emulation (no camera needed)")},
    # the camera's node map holds the true limits; the driver checks against them
    settings={"exposure_us": Option(float, 1.0, 60e6), "gain": Option(float, 0.0, 48.0),
              "black_level": Option(float, 0.0, 4095.0)},
    by_serial=True, open=_open_basler)

SIM_CAMERA = DriverEntry(
    "camera", "hw_mocks.sim.camera:SimulatedCamera",
    summary="the simulated camera of the virtual bench (simcam://)",
    settings={"exposure_us": Option(float, 1.0, 60e6), "gain": Option(float, 0.0, 48.0)},
    open=_open_simulated)

SIM_SOURCE = DriverEntry(
    "light_source", "hw_mocks.sim.source:SimulatedSource",
    summary="the simulated light source of the virtual bench (simsource://)",
    settings={"power_w": Option(float, 0.0, 10.0)},
    open=_open_simulated)
