"""The camera view: the live picture with its histogram, saturation and ROI statistics.

Frames come from the session's :class:`gui.model.camera.FrameSlot` (the stream's pump, or
the engine's frames during a run). A display timer takes the newest frame at most
:data:`DISPLAY_HZ` times a second and paints it; frames that arrive faster are counted as
skipped, never queued. Statistics and the saturation mask of streamed frames are computed
on the pump's thread; the GUI thread only uploads the picture. Exposure and gain go to
the driver through the session; a value it rejects comes back with the driver's error.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import QTimer, Signal
from PySide6.QtGui import QTransform
from PySide6.QtWidgets import (
    QCheckBox,
    QFileDialog,
    QGridLayout,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

from gui.model import format as fmt
from gui.model.camera import RoiBox, save_frame
from gui.model.session import (
    BenchSession,
    CommandResult,
    RunHandle,
    SetSetting,
    StartStream,
    StopStream,
)
from gui.qt.background import Background, JobDone
from gui.qt.panels import spin_box
from gui.qt.setpoint import SetpointField
from instrument.bench.device_state import DeviceState, is_camera_kind

__all__ = ["CameraView"]

#: The display's frame rate ceiling.
DISPLAY_HZ = 30
#: RGBA of saturated pixels in the overlay.
SATURATION_RGBA = (255, 0, 255, 200)


class CameraView(QWidget):
    """Live image, histogram/LUT, saturation overlay, ROI statistics, rates, controls."""

    snapshotSaved = Signal(str)

    def __init__(self, session: BenchSession, background: Background,
                 parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("camera_view")
        self.session = session
        self.slot = session.frame_slot
        self.background = background
        self.role: str | None = None
        self.state: DeviceState | None = None
        self.shown = 0
        self.last_frame = None
        self._levels_set = False
        self._scale = 1
        # snapshots go to a chosen folder (the main window sets the runs folder), never
        # to the program's working directory
        self.snapshot_dir = Path.home()

        self.graphics = pg.GraphicsLayoutWidget()
        self.view = self.graphics.addViewBox(lockAspect=True, invertY=True)
        self.image = pg.ImageItem(axisOrder="row-major")
        self.image.setAutoDownsample(True)
        self.overlay = pg.ImageItem(axisOrder="row-major")
        self.overlay.setLookupTable(np.array([(0, 0, 0, 0), SATURATION_RGBA], np.uint8))
        self.overlay.setLevels([0, 1])
        self.overlay.setZValue(5)
        self.view.addItem(self.image)
        self.view.addItem(self.overlay)
        self.histogram = pg.HistogramLUTItem(image=self.image)
        self.graphics.addItem(self.histogram)
        self.roi = pg.RectROI([0, 0], [64, 64], pen=pg.mkPen("#00e5ff", width=2))
        self.roi.setZValue(10)
        self.view.addItem(self.roi)
        self.roi.sigRegionChangeFinished.connect(self._roi_moved)

        self.stream = QPushButton("Start live")
        self.stream.setObjectName("stream")
        self.stream.setCheckable(True)
        self.exposure = spin_box(0.01, 1e8, 2, 1000.0, "µs")
        self.exposure.setObjectName("exposure")
        self.exposure.setToolTip("the camera's exposure time; type a new one and press Set")
        self.exposure_field = SetpointField(self.exposure, "exposure")
        self.set_exposure = QPushButton("Set")
        self.set_exposure.setObjectName("set_exposure")
        self.gain = spin_box(-100.0, 1000.0, 2, 0.0, "")
        self.gain.setObjectName("gain")
        self.gain.setToolTip("the camera's analogue gain (its own units); type a new one "
                             "and press Set")
        self.gain_field = SetpointField(self.gain, "gain")
        self.set_gain = QPushButton("Set")
        self.set_gain.setObjectName("set_gain")
        self.show_saturation = QCheckBox("saturation")
        self.show_saturation.setChecked(True)
        self.auto_levels = QCheckBox("auto levels")
        self.auto_levels.setChecked(True)
        self.snapshot = QPushButton("Snapshot…")
        self.snapshot.setObjectName("snapshot")
        self.stats = QLabel("no frame")
        self.stats.setObjectName("stats")
        self.rates = QLabel("")
        self.rates.setObjectName("rates")
        self.error = QLabel("")
        self.error.setObjectName("error")
        self.error.setWordWrap(True)
        self.error.setStyleSheet("color: #b71c1c")

        controls = QGridLayout()
        controls.addWidget(self.stream, 0, 0)
        controls.addWidget(QLabel("exposure"), 0, 1)
        controls.addWidget(self.exposure, 0, 2)
        controls.addWidget(self.set_exposure, 0, 3)
        controls.addWidget(QLabel("gain"), 0, 4)
        controls.addWidget(self.gain, 0, 5)
        controls.addWidget(self.set_gain, 0, 6)
        row = QHBoxLayout()
        row.addWidget(self.show_saturation)
        row.addWidget(self.auto_levels)
        row.addStretch(1)
        row.addWidget(self.snapshot)
        lay = QVBoxLayout(self)
        lay.addLayout(controls)
        lay.addWidget(self.graphics, 1)
        lay.addLayout(row)
        lay.addWidget(self.stats)
        lay.addWidget(self.rates)
        lay.addWidget(self.error)

        self.stream.toggled.connect(self._toggle_stream)
        self.set_exposure.clicked.connect(
            lambda: self._set("exposure_us", self.exposure.value()))
        self.set_gain.clicked.connect(lambda: self._set("gain", self.gain.value()))
        self.snapshot.clicked.connect(self._ask_snapshot)
        self.show_saturation.toggled.connect(self.overlay.setVisible)
        background.finished.connect(self._job_done)
        self._timer = QTimer(self)
        self._timer.setInterval(int(1000 / DISPLAY_HZ))
        self._timer.timeout.connect(self.refresh)
        self._timer.start()
        self._rate_timer = QTimer(self)
        self._rate_timer.setInterval(500)
        self._rate_timer.timeout.connect(self._show_rates)
        self._rate_timer.start()
        self.set_camera(None, None)

    # inputs -------------------------------------------------------------------------
    def set_camera(self, role: str | None, state: DeviceState | None) -> None:
        first = self.role is None and role is not None
        self.role, self.state = role, state
        usable = role is not None and self.session.run is None
        for w in (self.stream, self.set_exposure, self.set_gain, self.exposure, self.gain):
            w.setEnabled(usable)
        if state is None:
            return
        streaming = bool(state.values.get("streaming"))
        if self.stream.isChecked() != streaming and self.session.run is None:
            self.stream.blockSignals(True)
            self.stream.setChecked(streaming)
            self.stream.blockSignals(False)
        self.stream.setText("Stop live" if streaming else "Start live")
        # the fields show the camera's settings as read back (unless an edit is pending)
        self.exposure_field.follow(state.values.get("exposure_us"))
        self.gain_field.follow(state.values.get("gain"))
        if first:
            h, w = state.info.get("sensor", (64, 64))
            self.roi.setPos((w * 3 // 8, h * 3 // 8))
            self.roi.setSize((max(4, w // 4), max(4, h // 4)))
            self._roi_moved()

    def on_states(self, states: dict[str, DeviceState]) -> None:
        cams = [(r, s) for r, s in states.items() if is_camera_kind(s.kind)]
        if cams:
            self.set_camera(*cams[0])
        elif self.role is not None:
            self.role = None
            self.set_camera(None, None)

    def on_run(self, run: RunHandle | None) -> None:
        if run is not None:
            self.stream.setChecked(False)
            self.error.setText("")
        self.set_camera(self.role, self.state)
        self.stream.setToolTip("" if run is None else "the run owns the camera: its frames "
                               "are shown here")

    def on_result(self, result: CommandResult) -> None:
        cmd = result.command
        mine = (isinstance(cmd, SetSetting) and cmd.role == self.role) or isinstance(
            cmd, StartStream | StopStream)
        if not mine:
            return
        field = {"exposure_us": self.exposure_field, "gain": self.gain_field}.get(
            getattr(cmd, "name", None))
        if field is not None:
            field.settled()  # done or refused: the field shows the camera's value again
        if result.ok:
            self.error.setText("")
        else:
            self.error.setText(result.message)
            if isinstance(cmd, StartStream):
                self.stream.setChecked(False)

    # actions ------------------------------------------------------------------------
    def _set(self, name: str, value: float) -> None:
        if self.role is not None:
            self.session.submit(SetSetting(self.role, name, value))

    def _toggle_stream(self, on: bool) -> None:
        self.session.submit(StartStream() if on else StopStream())
        if on:
            self._levels_set = False

    def _roi_moved(self) -> None:
        x, y = self.roi.pos()
        w, h = self.roi.size()
        self.slot.roi = RoiBox(round(x), round(y), max(1, round(w)), max(1, round(h)))

    # display ------------------------------------------------------------------------
    def refresh(self) -> bool:
        """Show the newest frame if there is a new one; return whether one was shown."""
        frame = self.slot.take()
        if frame is None:
            return False
        self.last_frame = frame
        auto = self.auto_levels.isChecked() and not self._levels_set
        shown = frame.display if frame.display is not None else frame.data
        self.image.setImage(shown, autoLevels=False)
        if frame.scale != self._scale:  # decimated: keep the frame's pixel coordinates
            self._scale = frame.scale
            for item in (self.image, self.overlay):
                item.setTransform(QTransform.fromScale(frame.scale, frame.scale))
        if auto or not self._levels_set:
            top = float(frame.saturation_dn)
            lo = float(np.percentile(shown[::8, ::8], 1))
            hi = float(np.percentile(shown[::8, ::8], 99.9))
            self.histogram.setLevels(lo, max(hi, lo + 1.0))
            self.histogram.setHistogramRange(0, top)
            self._levels_set = True
        mask = frame.display_mask if frame.display_mask is not None else frame.mask
        if self.show_saturation.isChecked() and mask is not None:
            self.overlay.setImage(mask, autoLevels=False, levels=(0, 1))
        s = frame.stats
        if s is not None:
            where = "ROI" if s.roi is not None else "frame"
            self.stats.setText(
                f"{where} mean {s.mean_dn:.1f} DN, max {s.max_dn:.0f} DN, "
                f"{s.dn_per_us:.4g} DN/µs; saturated {100 * s.saturated_fraction:.2f} % of "
                f"the frame; exposure {fmt.si(frame.exposure_us * 1e-6, 's')}; "
                f"frame {frame.index} ({frame.source})")
        self.shown += 1
        return True

    def _show_rates(self) -> None:
        dropped = int(self.state.values.get("dropped", 0)) if self.state else 0
        self.rates.setText(
            f"camera {self.slot.in_rate.rate():.1f} frames/s, displayed "
            f"{self.slot.shown_rate.rate():.1f} frames/s; skipped by the display "
            f"{self.slot.skipped}, dropped by the camera buffer {dropped}")

    # snapshot -----------------------------------------------------------------------
    def _ask_snapshot(self) -> None:
        path, _ = QFileDialog.getSaveFileName(
            self, "Snapshot", str(self.snapshot_dir / "snapshot.png"),
            "16-bit PNG (*.png);;TIFF (*.tif);;NumPy (*.npy)")
        if path:
            self.save_snapshot(path)

    def save_snapshot(self, path: str | Path) -> int | None:
        """Write the frame on screen to ``path`` in the background; None if no frame. A
        relative ``path`` is taken in :attr:`snapshot_dir`."""
        frame = self.slot.latest()
        if frame is None:
            self.error.setText("snapshot: no frame yet (start live first)")
            return None
        path = self.snapshot_dir / path  # an absolute path stays as it is
        self.snapshot_dir = path.parent
        data = frame.data
        return self.background.submit("snapshot", lambda: save_frame(data, path))

    def _job_done(self, done: JobDone) -> None:
        if done.name != "snapshot":
            return
        if done.error is not None:
            self.error.setText(f"snapshot: {done.error}")
        else:
            self.error.setText("")
            self.stats.setToolTip(f"saved {done.result}")
            self.snapshotSaved.emit(str(done.result))

