"""The goniometer view: a live drawing of the bench from the read-back positions.

It draws the :class:`gui.model.goniometer.Scene` the model computes — from above for
every bench, plus the hemisphere projection on out-of-plane benches — and redraws at most
10 times a second, whatever the rate of position updates.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import QPointF, QTimer
from PySide6.QtGui import QPolygonF
from PySide6.QtWidgets import (
    QComboBox,
    QGraphicsPolygonItem,
    QHBoxLayout,
    QLabel,
    QVBoxLayout,
    QWidget,
)

from gui.model.goniometer import Scene, hemisphere_view, top_view
from instrument.bench.kinematics import Angles
from instrument.bench.profile import BenchProfile
from instrument.plans.build import Plan

__all__ = ["GoniometerView"]

#: role → (pen colour, width, brush colour or None, marker symbol, size)
STYLES = {
    "beam": ("#d32f2f", 3, None, None, 0),
    "source": ("#d32f2f", 1, "#d32f2f", "star", 16),
    "bistatic_cone": ("#e57373", 1, (229, 115, 115, 70), None, 0),
    "behind_sample": (None, 0, (120, 120, 120, 40), None, 0),
    "sample": ("#212121", 6, None, None, 0),
    "normal": ("#388e3c", 2, None, None, 0),
    "arm": ("#1565c0", 4, None, None, 0),
    "detector": ("#1565c0", 1, "#1565c0", "s", 14),
    "collision": ("#ef6c00", 1, (239, 108, 0, 80), None, 0),
    "points_todo": ("#90a4ae", 1, "#cfd8dc", "o", 7),
    "points_done": ("#2e7d32", 1, "#66bb6a", "o", 7),
    "incident": ("#d32f2f", 1, "#d32f2f", "star", 16),
    "horizon": ("#424242", 2, None, None, 0),
    "grid": ("#bdbdbd", 1, None, None, 0),
}


class GoniometerView(QWidget):
    """Top view (and hemisphere projection) of the bench with the loaded plan's points."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("goniometer_view")
        self.which = QComboBox()
        self.which.addItem("from above", "top")
        self.which.addItem("hemisphere (sample frame)", "hemisphere")
        self.which.setObjectName("projection")
        self.plot = pg.PlotWidget(background="w")
        self.plot.setAspectLocked(True)
        self.plot.hideAxis("left")
        self.plot.hideAxis("bottom")
        self.plot.setMenuEnabled(False)
        self.legend = self.plot.addLegend(offset=(5, 5), labelTextSize="8pt")
        self.caption = QLabel("no bench")
        self.caption.setObjectName("caption")
        self.caption.setWordWrap(True)
        top = QHBoxLayout()
        top.addWidget(QLabel("View"))
        top.addWidget(self.which, 1)
        lay = QVBoxLayout(self)
        lay.addLayout(top)
        lay.addWidget(self.plot, 1)
        lay.addWidget(self.caption)
        self.profile: BenchProfile | None = None
        self.positions: dict[str, float] = {}
        self.planned: list[Mapping[str, float]] = []
        self.planned_angles: list[Angles | None] = []
        self.done: list[bool] = []
        self.scene: Scene | None = None
        self._dirty = False
        self._timer = QTimer(self)
        self._timer.setInterval(100)  # ≤ 10 redraws per second
        self._timer.timeout.connect(self._redraw_if_dirty)
        self._timer.start()
        self.which.currentIndexChanged.connect(lambda _: self.redraw())

    # inputs -------------------------------------------------------------------------
    def set_profile(self, profile: BenchProfile | None) -> None:
        self.profile = profile
        self.positions = {}
        oop = profile is not None and profile.geometry.kind == "out_of_plane"
        self.which.model().item(1).setEnabled(oop)
        if not oop:
            self.which.setCurrentIndex(0)
        self.redraw()

    def set_positions(self, positions: Mapping[str, float]) -> None:
        new = {k: float(v) for k, v in positions.items()}
        if new != self.positions:
            self.positions = new
            self._dirty = True

    def set_plan(self, plan: Plan | None) -> None:
        if plan is None:
            self.planned, self.planned_angles = [], []
        else:
            self.planned = [p.target_dict() for p in plan.points]
            self.planned_angles = [p.angles for p in plan.points]
        self.done = []
        self._dirty = True

    def set_done(self, done: Sequence[bool]) -> None:
        self.done = list(done)
        self._dirty = True

    # drawing ------------------------------------------------------------------------
    def _redraw_if_dirty(self) -> None:
        if self._dirty and self.isVisible():
            self.redraw()

    def redraw(self) -> None:
        self._dirty = False
        self.plot.clear()
        self.legend.clear()
        if self.profile is None:
            self.caption.setText("no bench")
            self.scene = None
            return
        if self.which.currentData() == "hemisphere" and \
                self.profile.geometry.kind == "out_of_plane":
            scene = hemisphere_view(self.profile, self.positions,
                                    planned_angles=self.planned_angles, done=self.done)
        else:
            scene = top_view(self.profile, self.positions, planned=self.planned,
                             done=self.done)
        self.scene = scene
        for shape in scene.shapes:
            self._draw(shape)
        e = scene.extent
        self.plot.setRange(xRange=(-e, e), yRange=(-e, e), padding=0.02)
        pos = ", ".join(f"{k} {v:.3f}" for k, v in sorted(self.positions.items()))
        self.caption.setText(f"{scene.title}. {pos or 'no homed axis'}"
                             + ("" if not scene.notes else ". " + "; ".join(scene.notes)))

    def _draw(self, shape) -> None:
        pen_c, width, brush, symbol, size = STYLES.get(shape.role,
                                                       ("#000000", 1, None, None, 0))
        xy = shape.xy
        legend = shape.role not in ("grid", "horizon", "sample")
        if shape.kind == "markers":
            item = pg.ScatterPlotItem(xy[:, 0], xy[:, 1], symbol=symbol or "o",
                                      size=size or 8, pen=pg.mkPen(pen_c or "#000"),
                                      brush=pg.mkBrush(brush or pen_c or "#000"))
            self.plot.addItem(item)
            sample = item
        elif shape.kind == "polygon":
            self.plot.addItem(_polygon(xy, brush, pen_c))
            # a legend sample with the same fill
            sample = pg.PlotDataItem([0, 0], [0, 0], pen=pg.mkPen(pen_c or brush),
                                     fillLevel=0, fillBrush=pg.mkBrush(brush))
        else:
            item = pg.PlotCurveItem(xy[:, 0], xy[:, 1], pen=pg.mkPen(pen_c, width=width))
            self.plot.addItem(item)
            sample = item
        if legend and shape.label:
            self.legend.addItem(sample, shape.label)


def _polygon(xy: np.ndarray, brush, pen) -> QGraphicsPolygonItem:
    poly = QGraphicsPolygonItem(QPolygonF([QPointF(float(x), float(y)) for x, y in xy]))
    poly.setBrush(pg.mkBrush(brush))
    poly.setPen(pg.mkPen(pen) if pen else pg.mkPen(None))
    poly.setZValue(-10)
    return poly
