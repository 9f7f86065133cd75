"""The goniometer view: a live drawing of the bench from the read-back positions.

It draws the :class:`gui.model.goniometer.Scene` the model computes — from above for
every bench (a type (i) bench's arms over its stationary sample), plus the hemisphere
projection on out-of-plane type (ii) benches — and redraws at most
10 times a second, whatever the rate of position updates.
"""

from __future__ import annotations

import time
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
    "source_rail": ("#e57373", 3, None, None, 0),
    "detector_rail": ("#64b5f6", 3, None, None, 0),
    "stationary_sample": ("#212121", 1, "#9e9e9e", "o", 18),
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
        self._items: list = []
        self._structure = None
        self._next_redraw = 0.0
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
        # a type (i) bench's view from above is already its hemisphere (gui.model)
        oop = (profile is not None and profile.geometry.kind == "out_of_plane"
               and not profile.geometry.is_type_i)
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
        # a redraw that took long waits ten times as long before the next one, so the
        # drawing never takes more than a tenth of the GUI thread
        if self._dirty and self.isVisible() and time.monotonic() >= self._next_redraw:
            t0 = time.monotonic()
            self.redraw()
            cost = time.monotonic() - t0
            self._next_redraw = t0 + max(0.1, 10.0 * cost)

    def redraw(self) -> None:
        """Draw the scene. The items are made once per structure (which shapes, which
        legend) and afterwards only their data changes: a redraw during a run of
        thousands of points costs a few milliseconds, not a rebuild of the plot."""
        self._dirty = False
        if self.profile is None:
            self.plot.clear()
            self.legend.clear()
            self._items, self._structure = [], None
            self.caption.setText("no bench")
            self.scene = None
            return
        hemi = self.which.currentData() == "hemisphere" and \
            self.profile.geometry.kind == "out_of_plane" and not self.profile.geometry.is_type_i
        if hemi:
            scene = hemisphere_view(self.profile, self.positions,
                                    planned_angles=self.planned_angles, done=self.done)
        else:
            scene = top_view(self.profile, self.positions, planned=self.planned,
                             done=self.done)
        self.scene = scene
        structure = (scene.title, tuple((s.role, s.kind, s.label) for s in scene.shapes))
        if structure != self._structure:
            self.plot.clear()
            self.legend.clear()
            self._items = [self._create(shape) for shape in scene.shapes]
            self._structure = structure
            e = scene.extent
            self.plot.setRange(xRange=(-e, e), yRange=(-e, e), padding=0.02)
        else:
            for item, shape in zip(self._items, scene.shapes, strict=True):
                _set_data(item, shape.xy)
        pos = ", ".join(f"{k} {v:.3f}" for k, v in sorted(self.positions.items()))
        n_done = sum(len(s.xy) for s in scene.by_role("points_done"))
        n_todo = sum(len(s.xy) for s in scene.by_role("points_todo"))
        plan = f"; plan: {n_done} done, {n_todo} to do" if n_done or n_todo else ""
        self.caption.setText(f"{scene.title}. {pos or 'no homed axis'}{plan}"
                             + ("" if not scene.notes else ". " + "; ".join(scene.notes)))

    def _create(self, shape):
        pen_c, width, brush, symbol, size = STYLES.get(shape.role,
                                                       ("#000000", 1, None, None, 0))
        xy = shape.xy
        if shape.kind == "markers":
            item = pg.ScatterPlotItem(xy[:, 0], xy[:, 1], symbol=symbol or "o",
                                      size=size or 8, pen=pg.mkPen(pen_c or "#000"),
                                      brush=pg.mkBrush(brush or pen_c or "#000"))
            sample = item
        elif shape.kind == "polygon":
            item = _polygon(xy, brush, pen_c)
            sample = pg.PlotDataItem([0, 0], [0, 0], pen=pg.mkPen(pen_c or brush),
                                     fillLevel=0, fillBrush=pg.mkBrush(brush))
        else:
            item = pg.PlotCurveItem(xy[:, 0], xy[:, 1], pen=pg.mkPen(pen_c, width=width))
            sample = item
        self.plot.addItem(item)
        if shape.label and shape.role not in ("grid", "horizon", "sample"):
            self.legend.addItem(sample, shape.label)
        return item


def _set_data(item, xy: np.ndarray) -> None:
    if isinstance(item, QGraphicsPolygonItem):
        item.setPolygon(QPolygonF([QPointF(float(x), float(y)) for x, y in xy]))
    else:
        item.setData(xy[:, 0], xy[:, 1])


def _polygon(xy: np.ndarray, brush, pen) -> QGraphicsPolygonItem:
    poly = QGraphicsPolygonItem(QPolygonF([QPointF(float(x), float(y)) for x, y in xy]))
    poly.setBrush(pg.mkBrush(brush))
    poly.setPen(pg.mkPen(pen) if pen else pg.mkPen(None))
    poly.setZValue(-10)
    return poly
