"""The device side of pylon's camera emulation, for tests: what a person does at the bench.

pylon's emulated camera (``PYLON_CAMEMU``) is a GenICam device with a few features a real
camera lacks; the tests use them, through the driver's transport, as the bench's stand-ins:

* ``TestImageSelector`` (``Off``: a uniform grey; ``Testimage1``/``Testimage2``: ramps,
  the second moving by one pixel per frame) — a scene that changes;
* ``ImageFileMode`` and ``ImageFilename`` — the camera shows an image file instead (the
  emulator reads 8-bit files as Mono8 and 16-bit files MSB-aligned: a Mono12 frame is the
  16-bit file's value >> 4, so a 12-bit frame is written as ``value << 4``);
* ``FirePnPCallback`` — pylon fires its device-removal callback as when a cable is pulled
  (the device itself stays, so it can be reopened: a replug).

The driver never uses these features itself.
"""

from __future__ import annotations

import os

import cv2
import numpy as np
import pytest

from drivers.base import PixelFormat
from drivers.genicam_camera import GenICamCamera

#: Serial number of pylon's first emulated camera.
EMULATED_SERIAL = "0815-0000"


def require_pylon() -> None:
    """Skip the module when pypylon cannot load here (it is in the dev extra)."""
    pytest.importorskip("pypylon", reason="pypylon (the basler extra) cannot be imported")


def show_test_image(camera: GenICamCamera, name: str) -> None:
    camera.genicam.set("ImageFileMode", "Off")
    camera.genicam.set("TestImageSelector", name)


def show_image_file(camera: GenICamCamera, path: str | os.PathLike) -> None:
    camera.genicam.stop()  # the file features are locked while the camera grabs
    camera.genicam.set("TestImageSelector", "Off")
    camera.genicam.set("ImageFileMode", "On")
    camera.genicam.set("ImageFilename", str(path))
    camera.invalidate()  # restarts the grab: no frame from before the new picture


def write_frame_file(path: str | os.PathLike, data: np.ndarray, fmt: PixelFormat) -> None:
    """Write a frame so that the emulator delivers exactly ``data`` in format ``fmt``:
    8-bit PNG for Mono8, 16-bit PNG MSB-aligned for Mono10/12/16."""
    if fmt is PixelFormat.MONO8:
        out = data.astype(np.uint8)
    else:
        out = (data.astype(np.uint16) << (16 - fmt.bit_depth)).astype(np.uint16)
    assert cv2.imwrite(str(path), out)


def unplug(camera: GenICamCamera) -> None:
    """The camera disappears, as far as pylon can tell (its removal callback fires)."""
    camera.genicam.execute("FirePnPCallback")
