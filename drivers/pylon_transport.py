"""Basler cameras through pypylon: the one module that knows pylon (ADR 0096).

pypylon is Basler's own binding; its wheel carries the pylon runtime (USB3 Vision, GigE
Vision and the camera emulation transport), so ``pip install "scatterlab[basler]"`` is
all a bench PC needs. It is imported when a camera is opened, not before: without it,
:func:`open_basler_camera` raises :class:`~drivers.errors.ConnectionFailed` naming the
extra.

What is pylon-specific, and therefore here:

* finding a camera by serial number (``TlFactory.EnumerateDevices`` with a
  ``DeviceInfo`` filter) and opening it (``InstantCamera``);
* pylon's camera emulation: with ``emulation=True`` the ``PYLON_CAMEMU`` variable is set
  (to 1 if unset) before devices are enumerated, so the emulated cameras, serial numbers
  ``0815-0000``, ``0815-0001``, …, are found; pylon reads the variable at each
  enumeration;
* legacy Basler feature names of older firmware (``ExposureTimeAbs``, ``GainAbs``,
  ``BlackLevelAbs``), used when the SFNC name is absent;
* the grab: ``GrabStrategy_OneByOne`` into ``MaxNumBuffer`` buffers; each result is
  copied once out of its buffer (``GetArrayZeroCopy`` then one ``numpy`` copy) and
  released at once, so the buffer goes back to the camera's queue;
* device removal: pylon reports it with ``IsCameraDeviceRemoved`` (its removal callback
  has fired); the transport raises :class:`~drivers.errors.ConnectionFailed`, and
  :meth:`PylonTransport.reconnect` destroys the lost device and opens the camera with
  the same serial number again;
* turning pylon's exceptions into :mod:`drivers.errors` types.
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from drivers.base import DeviceIdentity, PixelFormat
from drivers.errors import (
    ConnectionFailed,
    ControllerError,
    DeviceError,
    DeviceTimeout,
    LimitError,
    StateError,
    UnsupportedFeature,
)
from drivers.genicam_camera import GenICamCamera, GenICamTransport, GrabbedBuffer, TriggerMode

__all__ = ["EXTRA_HINT", "PylonTransport", "import_pylon", "list_cameras",
           "open_basler_camera"]

#: What to install when pypylon is missing.
EXTRA_HINT = 'install the Basler extra: pip install "scatterlab[basler]" (pypylon)'
#: Basler feature names of older firmware, tried when the SFNC name is absent.
LEGACY_NAMES = {"ExposureTime": "ExposureTimeAbs", "Gain": "GainAbs",
                "BlackLevel": "BlackLevelAbs"}
_PIXEL_BITS = {"Mono8": 8, "Mono10": 10, "Mono12": 12, "Mono16": 16}


def _pixel_type_names(pylon: Any) -> dict[int, str]:
    """pylon's pixel-type codes of the unpacked mono formats → SFNC names."""
    return {getattr(pylon, f"PixelType_{name}"): name for name in _PIXEL_BITS}
# pylon's runtime is process-wide; enumeration and device creation are serialised.
_FACTORY_LOCK = threading.Lock()


def import_pylon(device: str = "camera") -> tuple[Any, Any]:
    """``(pylon, genicam)`` from pypylon; a typed error naming the extra when it is missing."""
    try:
        from pypylon import genicam, pylon
    except ImportError as err:
        raise ConnectionFailed(f"pypylon cannot be imported ({err})", device=device,
                               command="open", hint=EXTRA_HINT) from err
    return pylon, genicam


def _enable_emulation() -> None:
    if not os.environ.get("PYLON_CAMEMU", "").strip().isdigit() or int(
            os.environ["PYLON_CAMEMU"]) < 1:
        os.environ["PYLON_CAMEMU"] = "1"


def list_cameras(*, emulation: bool = False) -> list[dict[str, str]]:
    """Every camera pylon sees: model, serial number, vendor and full name."""
    pylon, _ = import_pylon()
    if emulation:
        _enable_emulation()
    with _FACTORY_LOCK:
        devices = pylon.TlFactory.GetInstance().EnumerateDevices()
    return [{"model": d.GetModelName(), "serial": d.GetSerialNumber(),
             "vendor": d.GetVendorName(), "name": d.GetFriendlyName()} for d in devices]


class PylonTransport(GenICamTransport):
    """One Basler camera, opened by serial number through pylon.

    Parameters
    ----------
    serial
        The camera's serial number (on its label; ``scatterlab devices`` lists them).
    name
        Role name for errors.
    emulation
        Enable pylon's camera emulation (``PYLON_CAMEMU``) before looking for ``serial``.
    """

    def __init__(self, serial: str, *, name: str = "camera", emulation: bool = False
                 ) -> None:
        self.serial = str(serial).strip()
        if not self.serial:
            raise ValueError(f"{name}: a Basler camera needs its serial number")
        self.name = name
        self._pylon, self._genicam = import_pylon(name)
        if emulation:
            _enable_emulation()
        self._cam = self._open()

    # ------------------------------------------------------------------ connection
    def _open(self) -> Any:
        pylon = self._pylon
        with _FACTORY_LOCK:
            factory = pylon.TlFactory.GetInstance()
            wanted = pylon.DeviceInfo()
            wanted.SetSerialNumber(self.serial)
            found = factory.EnumerateDevices([wanted])
            if not found:
                seen = [d.GetSerialNumber() for d in factory.EnumerateDevices()]
                raise ConnectionFailed(
                    f"no Basler camera with serial number {self.serial}", device=self.name,
                    command="open",
                    hint=f"cameras found: {', '.join(seen) or 'none'}; check the cable and "
                    "that no other program (pylon Viewer) holds the camera")
            try:
                cam = pylon.InstantCamera(factory.CreateDevice(found[0]))
                cam.Open()
            except self._genicam.GenericException as err:
                raise ConnectionFailed(
                    f"cannot open Basler camera {self.serial}: {_first_line(err)}",
                    device=self.name, command="open",
                    hint="is it open in another program?") from err
        return cam

    def reconnect(self) -> None:
        old, self._cam = self._cam, None
        if old is not None:
            # closes it and frees pylon's handle on the lost device
            with contextlib.suppress(self._genicam.GenericException):
                old.DestroyDevice()
        self._cam = self._open()

    def is_removed(self) -> bool:
        return self._cam is None or bool(self._cam.IsCameraDeviceRemoved())

    def close(self) -> None:
        cam, self._cam = self._cam, None
        if cam is None:
            return
        try:
            if cam.IsGrabbing():
                cam.StopGrabbing()
        finally:
            cam.DestroyDevice()

    # ------------------------------------------------------------------ errors
    def _call(self, what: str, fn: Callable[..., Any], *args: Any) -> Any:
        """Run a pylon call; its exceptions become :mod:`drivers.errors` types."""
        g = self._genicam
        if self._cam is None:
            raise ConnectionFailed("the camera is not connected", device=self.name,
                                   command=what, hint="reconnect it")
        try:
            return fn(*args)
        except g.GenericException as err:
            text = _first_line(err)
            if self._cam.IsCameraDeviceRemoved():
                raise self._removed(what) from err
            if isinstance(err, g.TimeoutException):
                raise DeviceTimeout(text, device=self.name, command=what) from err
            if isinstance(err, g.OutOfRangeException):
                raise LimitError(f"the camera refused it: {text}", device=self.name,
                                 command=what) from err
            if isinstance(err, g.AccessException):
                raise StateError(f"the camera refused it now: {text}", device=self.name,
                                 command=what) from err
            if isinstance(err, g.LogicalErrorException):
                raise UnsupportedFeature(f"not available on this camera: {text}",
                                         device=self.name, command=what) from err
            raise ControllerError(text, device=self.name, command=what) from err

    def _removed(self, what: str) -> ConnectionFailed:
        return ConnectionFailed(
            "the camera was removed", device=self.name, command=what,
            hint=f"plug it back in (s/n {self.serial}); the next operation reopens it")

    def _node(self, feature: str) -> Any:
        nodemap = self._call(feature, self._cam.GetNodeMap)
        for name in (feature, LEGACY_NAMES.get(feature)):
            if name is None:
                continue
            node = nodemap.GetNode(name)
            if node is not None and self._genicam.IsAvailable(node):
                return node
        raise UnsupportedFeature(f"the camera has no feature {feature}", device=self.name,
                                 command=feature)

    # ------------------------------------------------------------------ features
    def identity(self) -> DeviceIdentity:
        info = self._call("identity", self._cam.GetDeviceInfo)
        firmware = (str(self.get("DeviceFirmwareVersion"))
                    if self.has("DeviceFirmwareVersion") else "")
        extra = {"device_class": info.GetDeviceClass()}
        if self.has("DeviceVersion"):
            extra["device_version"] = str(self.get("DeviceVersion"))
        return DeviceIdentity(vendor=info.GetVendorName(), model=info.GetModelName(),
                              serial=info.GetSerialNumber(), firmware=firmware, extra=extra)

    def has(self, feature: str) -> bool:
        try:
            node = self._node(feature)
        except UnsupportedFeature:
            return False
        return bool(self._genicam.IsReadable(node) or self._genicam.IsWritable(node))

    def get(self, feature: str) -> Any:
        node = self._node(feature)
        if isinstance(node, self._genicam.IEnumeration):
            return self._call(feature, lambda: node.GetCurrentEntry().GetSymbolic())
        return self._call(feature, node.GetValue)

    def set(self, feature: str, value: Any) -> None:
        node = self._node(feature)
        g = self._genicam
        if isinstance(node, g.IInteger):
            value = int(value)
        elif isinstance(node, g.IFloat):
            value = float(value)
        elif isinstance(node, g.IBoolean):
            value = bool(value)
        else:
            value = str(value)
        self._call(f"{feature} = {value}", node.SetValue, value)

    def execute(self, feature: str) -> None:
        node = self._node(feature)
        self._call(feature, node.Execute)

    def limits(self, feature: str) -> tuple[float, float, float]:
        node = self._node(feature)
        low = self._call(feature, node.GetMin)
        high = self._call(feature, node.GetMax)
        inc = 0.0
        if isinstance(node, self._genicam.IInteger) or self._call(feature, node.HasInc):
            inc = float(self._call(feature, node.GetInc))
        return float(low), float(high), inc

    def choices(self, feature: str) -> tuple[str, ...]:
        node = self._node(feature)
        g = self._genicam
        entries = self._call(feature, node.GetEntries)
        return tuple(e.GetSymbolic() for e in entries if g.IsAvailable(e))

    # ------------------------------------------------------------------ grabbing
    def start(self, buffers: int) -> None:
        cam = self._cam
        if cam is not None and cam.IsGrabbing():
            return
        self._call("MaxNumBuffer", lambda: setattr(cam.MaxNumBuffer, "Value", int(buffers)))
        self._call("StartGrabbing", cam.StartGrabbing, self._pylon.GrabStrategy_OneByOne)

    def stop(self) -> None:
        cam = self._cam
        if cam is not None and cam.IsGrabbing():
            self._call("StopGrabbing", cam.StopGrabbing)

    def wait_trigger_ready(self, timeout: float) -> None:
        ms = max(1, round(timeout * 1000))
        ready = self._call("WaitForFrameTriggerReady", self._cam.WaitForFrameTriggerReady,
                           ms, self._pylon.TimeoutHandling_Return)
        if not ready:
            raise DeviceTimeout(f"the camera was not ready for a trigger within {timeout:g} s",
                                device=self.name, command="TriggerSoftware")

    #: Pause between two looks for a grab result while :meth:`retrieve` waits.
    RETRIEVE_POLL_S = 0.001

    def retrieve(self, timeout: float) -> GrabbedBuffer:
        """The next grab result, waiting at most ``timeout`` s.

        pylon is asked without waiting (``RetrieveResult(0)``), every
        ``RETRIEVE_POLL_S`` s, until the deadline: pylon's own timed wait once waited
        forever (hardware trigger, after a camera was removed and reopened in the same
        process; the emulated camera, the call idle in ``WaitObjects::WaitForAny``), and a
        wait that ignores its timeout is one no caller can end.
        """
        pylon = self._pylon
        deadline = time.monotonic() + max(timeout, 0.0)
        while True:
            result = self._call("RetrieveResult", self._cam.RetrieveResult, 0,
                                pylon.TimeoutHandling_Return)
            if (result is not None and result.IsValid()) or time.monotonic() >= deadline:
                break
            time.sleep(min(self.RETRIEVE_POLL_S, max(deadline - time.monotonic(), 0.0)))
        if result is None or not result.IsValid():
            if self._cam.IsCameraDeviceRemoved():
                raise self._removed("RetrieveResult")
            raise DeviceTimeout(f"no frame within {timeout:g} s", device=self.name,
                                command="RetrieveResult")
        try:
            if not result.GrabSucceeded():
                raise ControllerError(
                    f"the grab failed: {result.GetErrorDescription()}",
                    code=result.GetErrorCode(), device=self.name, command="RetrieveResult",
                    hint="frames lost in transport (bandwidth, cable)?")
            code = result.GetPixelType()
            fmt = _pixel_type_names(pylon).get(code, "")
            if not fmt:
                raise UnsupportedFeature(f"frames arrive as pylon pixel type {code:#x}",
                                         device=self.name,
                                         command="RetrieveResult",
                                         hint="use Mono8, Mono10, Mono12 or Mono16")
            with result.GetArrayZeroCopy() as view:
                data = np.array(view, dtype=PixelFormat(_PIXEL_BITS[fmt]).dtype, copy=True)
            chunks = {}
            if result.IsChunkDataAvailable():
                for name in ("Timestamp", "ExposureTime", "FrameID"):
                    node = result.GetChunkDataNodeMap().GetNode(f"Chunk{name}")
                    if node is not None and self._genicam.IsReadable(node):
                        chunks[name] = node.GetValue()
            return GrabbedBuffer(data=data, frame_id=int(result.GetBlockID()),
                                 device_timestamp=int(result.GetTimeStamp()),
                                 pixel_format=fmt, chunks=chunks)
        except DeviceError:
            raise
        except self._genicam.GenericException as err:
            raise ControllerError(_first_line(err), device=self.name,
                                  command="RetrieveResult") from err
        finally:
            result.Release()  # the buffer goes back to the camera's queue now

    def buffer_counts(self) -> dict[str, int]:
        cam = self._cam
        return {"queued": int(self._call("NumQueuedBuffers", lambda: cam.NumQueuedBuffers.Value)),
                "ready": int(self._call("NumReadyBuffers", lambda: cam.NumReadyBuffers.Value)),
                "max": int(self._call("MaxNumBuffer", lambda: cam.MaxNumBuffer.Value))}


def _first_line(err: BaseException) -> str:
    """pylon's message without the source-file trailer."""
    text = str(err).strip()
    return text.split(" : ", 1)[0] if " : " in text else text


def open_basler_camera(serial: str, *, name: str = "camera", emulation: bool = False,
                       **options: Any) -> GenICamCamera:
    """Open the Basler camera with this serial number as a :class:`GenICamCamera`.

    ``options`` go to :class:`~drivers.genicam_camera.GenICamCamera` (``pixel_format``
    as a name such as ``"MONO12"``, ``trigger_mode``, ``hardware_line``, ``buffers``).
    """
    fmt = options.pop("pixel_format", None)
    if isinstance(fmt, str):
        try:
            fmt = PixelFormat[fmt.upper()]
        except KeyError:
            raise ValueError(f"{name}: unknown pixel format {fmt!r}; use one of "
                             f"{[f.name for f in PixelFormat]}") from None
    mode = options.pop("trigger_mode", TriggerMode.SOFTWARE)
    transport = PylonTransport(serial, name=name, emulation=emulation)
    return GenICamCamera(transport, name=name, pixel_format=fmt, trigger_mode=mode, **options)
