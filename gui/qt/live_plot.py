"""Live plots of a run as its points arrive, one picture per plan kind.

* in-plane BRDF (and the reference/signature calibrations): signal against signed θr,
  one curve per θi;
* hemisphere: a polar map of the scattered directions (radius θr, angle φr) coloured by
  the signal;
* light field: the L(y, θ) image, one row per camera position, growing row by row;
* sphere capture: the latest image;
* the other calibrations: signal per point.

The main window calls :meth:`LivePlot.update_from` with a
:class:`gui.model.live.LiveSnapshot` at most ten times a second; nothing here is called
per point.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt
from PySide6.QtWidgets import (
    QHBoxLayout,
    QLabel,
    QSizePolicy,
    QStackedWidget,
    QVBoxLayout,
    QWidget,
)

from gui.model.live import LiveSnapshot, decade_label, log_ticks, plot_kind, signed_theta_r

__all__ = ["DecadeAxis", "LivePlot"]

#: Plans up to this many points get a marker per point and 2-px lines; larger ones
#: 1-px lines only: Qt's raster engine draws a 1-px (cosmetic) line several times faster
#: than a wider one, and each redraw of a 10,000-point in-plane plot repaints every curve
#: (20 curves of 470 points: 19 ms of CPU per repaint at 2 px, 5.5 ms at 1 px;
#: BENCHMARKS.md gui).
MARKERS_UP_TO = 600
#: The in-plane view's margin beyond the data when it has to grow: a fraction of the data's
#: span (θr in degrees; the signal in decades), at least the minimum given. The view
#: grows only when a point falls outside it, so that a redraw repaints the new curve only,
#: not both axes and every curve with them (BENCHMARKS.md gui).
VIEW_MARGIN = 0.25
VIEW_MIN_SPAN = (20.0, 0.5)
PALETTE = ["#1565c0", "#c62828", "#2e7d32", "#6a1b9a", "#ef6c00", "#00838f", "#4e342e",
           "#ad1457"]


class DecadeAxis(pg.AxisItem):
    """A log axis whose labels always name the decade (``2×10⁻³``, ``10⁻²``), also when
    the data span less than a decade or nothing is plotted yet."""

    def tickValues(self, minVal, maxVal, size):
        if not self.logMode:
            return super().tickValues(minVal, maxVal, size)
        ticks = log_ticks(minVal, maxVal)
        if len(ticks[0][1]) >= 2:  # two decades in view: label those, not the minors
            return ticks
        return [(1.0, ticks[0][1] + ticks[1][1])]  # label the 2…9 too, with the decade

    def tickStrings(self, values, scale, spacing):
        if not self.logMode:
            return super().tickStrings(values, scale, spacing)
        return [decade_label(v) for v in values]


class LivePlot(QWidget):
    """The live picture of the current (or last) run."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("live_plot")
        self.kind = "series"
        self.n_plotted = 0
        self.caption = QLabel("no run yet")
        self.caption.setObjectName("live_caption")
        # its text changes at every redraw: its width must not resize the plot below it
        self.caption.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Fixed)
        self.stack = QStackedWidget()
        # in-plane
        self.in_plane = pg.PlotWidget(background="w",
                                      axisItems={"left": DecadeAxis("left")})
        self.in_plane.setLabel("bottom", "θr (signed: > 0 specular side)", units="deg")
        self.in_plane.setLabel("left", "signal (DN/µs)")
        self.in_plane.getAxis("left").enableAutoSIPrefix(False)
        self.in_plane.setLogMode(y=True)
        self._grid = False
        self._set_grid(True)
        # the legend is a label beside the plot, not an item on it: it never covers data
        self.in_plane_legend = QLabel("")
        self.in_plane_legend.setObjectName("in_plane_legend")
        self.in_plane_legend.setAlignment(Qt.AlignTop | Qt.AlignLeft)
        # as wide as its widest row from the start: a row added with a new θi then does
        # not narrow (and so resize and repaint) the plot beside it
        self.in_plane_legend.setMinimumWidth(self.in_plane_legend.fontMetrics()
                                             .horizontalAdvance("━━ θi = -88.88°  "))
        self._view: tuple[float, float, float, float] | None = None
        #: the data's extent (θr, log10 signal) the view was last grown for
        self._extent: tuple[float, float, float, float] | None = None
        self._legend_rows: list[str] = []
        in_plane_page = QWidget()
        row = QHBoxLayout(in_plane_page)
        row.setContentsMargins(0, 0, 0, 0)
        row.addWidget(self.in_plane, 1)
        row.addWidget(self.in_plane_legend)
        self._curves: dict[float, pg.PlotDataItem] = {}
        self._counts: dict[float, int] = {}
        # points read through a neutral-density filter: an open square around the point
        # (its signal is the filtered light, about T times the open beam's)
        self.nd_points = self.in_plane.plot([], [], pen=None, symbol="s", symbolSize=13,
                                            symbolBrush=None,
                                            symbolPen=pg.mkPen("#000000", width=1.5))
        self.nd_points.setObjectName("nd_points")
        self.nd_points.setZValue(10)
        self.n_nd = 0
        self._power_axis = False
        # hemisphere
        self.polar = pg.PlotWidget(background="w")
        self.polar.setAspectLocked(True)
        self.polar.hideAxis("left")
        self.polar.hideAxis("bottom")
        rim = np.radians(np.linspace(0, 360, 181))
        for deg in (30, 60, 90):
            self.polar.addItem(pg.PlotCurveItem(deg * np.cos(rim), deg * np.sin(rim),
                                                pen=pg.mkPen("#9e9e9e")))
        self.polar_points = pg.ScatterPlotItem(size=9, pen=pg.mkPen(None))
        self.polar.addItem(self.polar_points)
        self.cmap = pg.colormap.get("viridis")
        # light field
        self.field_plot = pg.PlotWidget(background="w")
        self.field_plot.setLabel("bottom", "θ (sensor column)")
        self.field_plot.setLabel("left", "camera position", units="mm")
        self.field_image = pg.ImageItem(axisOrder="row-major")
        self.field_image.setColorMap(pg.colormap.get("inferno"))
        self.field_plot.addItem(self.field_image)
        # latest image
        self.image_plot = pg.PlotWidget(background="w")
        self.image_plot.setAspectLocked(True)
        self.image_plot.invertY(True)
        self.latest = pg.ImageItem(axisOrder="row-major")
        self.image_plot.addItem(self.latest)
        # series
        self.series = pg.PlotWidget(background="w")
        self.series.setLabel("bottom", "point")
        self.series.setLabel("left", "signal (DN/µs)")
        self.series_curve = self.series.plot([], [], pen=None, symbol="o", symbolSize=6,
                                             symbolBrush="#1565c0")
        self._pages = {"in_plane": in_plane_page, "hemisphere": self.polar,
                       "lightfield": self.field_plot, "image": self.image_plot,
                       "series": self.series}
        for page in self._pages.values():
            self.stack.addWidget(page)
        lay = QVBoxLayout(self)
        lay.addWidget(self.caption)
        lay.addWidget(self.stack, 1)

    def _set_grid(self, on: bool) -> None:
        """The in-plane plot's grid, for plans up to :data:`MARKERS_UP_TO` points. The
        axes draw the grid across the whole view, so with it every curve's redraw repaints
        both axes too, their tick labels included (6.5 ms of CPU per axis and repaint on
        the 10,000-point scan, BENCHMARKS.md gui); without it an axis repaints only when
        its range changes."""
        self._grid = on
        self.in_plane.showGrid(x=on, y=on, alpha=0.3)

    def start(self, plan_kind: str) -> None:
        """A new run of ``plan_kind``: pick its picture and clear it."""
        self.kind = plot_kind(plan_kind)
        self.stack.setCurrentWidget(self._pages[self.kind])
        self.n_plotted = 0
        for c in self._curves.values():
            self.in_plane.removeItem(c)
        self._curves.clear()
        self._counts.clear()
        if self._power_axis:
            self._power_axis = False
            for plot in (self.in_plane, self.series):
                plot.setLabel("left", "signal (DN/µs)")
        self._legend_rows = []
        self.in_plane_legend.setText("")
        self._view = None
        self._extent = None
        self.in_plane.enableAutoRange()
        self.nd_points.setData([], [])
        self.n_nd = 0
        self.polar_points.clear()
        self.field_image.clear()
        self.latest.clear()
        self.series_curve.setData([], [])
        self.caption.setText(f"{plan_kind}: waiting for the first point")

    def update_from(self, snap: LiveSnapshot) -> None:
        if not np.isfinite(snap.signal).any() and np.isfinite(snap.power_w).any():
            # a power-meter-only plan: its reading is the signal
            snap = replace(snap, signal=snap.power_w)
            if not self._power_axis:
                self._power_axis = True
                for plot in (self.in_plane, self.series):
                    plot.setLabel("left", "power (W)")
        ok = snap.ok & np.isfinite(snap.signal)
        getattr(self, f"_draw_{self.kind}")(snap, ok)
        behind = _behind_filter(snap)
        nd = (f"; {int(behind.sum())} read through an ND filter (slot "
              f"{', '.join(str(k) for k in np.unique(snap.nd_slot[behind]))}): □"
              if behind.any() else "")
        self.caption.setText(f"{snap.plan_kind}: {snap.n_received} of {snap.n_total} points "
                             f"received, {int(ok.sum())} plotted{nd}")

    # pictures -------------------------------------------------------------------------
    def _draw_in_plane(self, snap: LiveSnapshot, ok: np.ndarray) -> None:
        tr = signed_theta_r(snap.theta_r, snap.phi_i, snap.phi_r)
        # curves by the planned θi (the read-back one differs by the stage tolerance)
        ti = np.round(snap.planned_theta_i, 6)
        sel = ok & np.isfinite(tr) & (snap.signal > 0)
        plotted = 0
        # markers cost a paint per point: above a few hundred points lines alone
        markers = snap.n_total <= MARKERS_UP_TO
        if markers != self._grid:
            self._set_grid(markers)
        for k, value in enumerate(sorted(set(ti[sel].tolist()))):
            rows = sel & (ti == value)
            n = int(rows.sum())
            plotted += n
            curve = self._curves.get(value)
            if curve is not None and self._counts.get(value) == n:
                continue  # nothing new on this curve: no redraw
            order = np.argsort(tr[rows])
            x, y = tr[rows][order], snap.signal[rows][order]
            if curve is None:
                colour = PALETTE[k % len(PALETTE)]
                style = dict(symbol="o", symbolSize=6, symbolBrush=colour) if markers else {}
                curve = self.in_plane.plot([], [], pen=pg.mkPen(colour, width=2 if markers
                                                                else 1), **style)
                self._legend_rows.append(f"<span style='color:{colour}'>━━</span> "
                                         f"θi = {value:g}°")
                self.in_plane_legend.setText("<br>".join(self._legend_rows))
                self._curves[value] = curve
            curve.setData(x, y, skipFiniteCheck=True)  # selected finite and > 0 above
            self._counts[value] = n
        self.n_plotted = plotted
        if sel.any():
            self._keep_in_view(tr[sel], np.log10(snap.signal[sel]))
        behind = sel & _behind_filter(snap)
        if int(behind.sum()) != self.n_nd:
            self.n_nd = int(behind.sum())
            self.nd_points.setData(tr[behind], snap.signal[behind])
            rows = [r for r in self._legend_rows if "ND filter" not in r]
            if self.n_nd:
                rows.append("□ read through an ND filter")
            self._legend_rows = rows
            self.in_plane_legend.setText("<br>".join(rows))

    def _keep_in_view(self, x: np.ndarray, log_y: np.ndarray) -> None:
        """Show every point (``x``: θr, ``log_y``: log10 of the signal) without letting
        pyqtgraph auto-range: its range follows every new extreme, and each change
        repaints both axes and every curve. Here the view grows only when a point falls
        outside it, by :data:`VIEW_MARGIN` of the data's span: a handful of times a run."""
        x0, x1 = float(x.min()), float(x.max())
        y0, y1 = float(log_y.min()), float(log_y.max())
        v = self._view
        if v is not None and v[0] <= x0 and x1 <= v[1] and v[2] <= y0 and y1 <= v[3]:
            return
        e = self._extent
        if e is not None:  # the data seen so far; the view never shrinks during a run
            x0, x1, y0, y1 = min(x0, e[0]), max(x1, e[1]), min(y0, e[2]), max(y1, e[3])
        # the margin is taken on the data's extent, not on the previous view: margins on
        # margins compounded at each growth (a run's view ended twice the data's width)
        self._extent = (x0, x1, y0, y1)
        mx = VIEW_MARGIN * max(x1 - x0, VIEW_MIN_SPAN[0])
        my = VIEW_MARGIN * max(y1 - y0, VIEW_MIN_SPAN[1])
        self._view = (x0 - mx, x1 + mx, y0 - my, y1 + my)
        self.in_plane.setRange(xRange=self._view[:2], yRange=self._view[2:], padding=0)

    def _draw_hemisphere(self, snap: LiveSnapshot, ok: np.ndarray) -> None:
        sel = ok & np.isfinite(snap.theta_r) & (snap.signal > 0)
        if not sel.any():
            return
        t, p = snap.theta_r[sel], np.radians(snap.phi_r[sel])
        v = np.log10(snap.signal[sel])
        lo, hi = float(v.min()), float(v.max())
        colours = self.cmap.map((v - lo) / (hi - lo) if hi > lo else np.zeros_like(v),
                                mode="qcolor")
        self.polar_points.setData(t * np.cos(p), t * np.sin(p),
                                  brush=[pg.mkBrush(c) for c in colours])
        self.n_plotted = int(sel.sum())

    def _draw_lightfield(self, snap: LiveSnapshot, ok: np.ndarray) -> None:
        field, y = snap.field, snap.field_y
        if field is None or y is None:
            return
        measured = np.isfinite(field).all(axis=1)
        if not measured.any():
            return
        order = np.argsort(np.where(np.isfinite(y), y, np.inf))
        img = field[order]
        lo = float(np.nanmin(img))
        hi = float(np.nanmax(img))
        self.field_image.setImage(np.nan_to_num(img, nan=lo), levels=(lo, max(hi, lo + 1e-12)))
        ys = y[order][np.isfinite(y[order])]
        if ys.size:
            y0 = float(ys[0])
            dy = float(np.median(np.diff(ys))) if ys.size > 1 else 1.0
            self.field_image.setRect(0, y0 - dy / 2, img.shape[1], dy * img.shape[0])
        self.n_plotted = int(measured.sum())

    def _draw_image(self, snap: LiveSnapshot, ok: np.ndarray) -> None:
        if snap.image is not None:
            self.latest.setImage(snap.image, autoLevels=True)
        self.n_plotted = int(ok.sum())

    def _draw_series(self, snap: LiveSnapshot, ok: np.ndarray) -> None:
        self.series_curve.setData(np.flatnonzero(ok), snap.signal[ok])
        self.n_plotted = int(ok.sum())


def _behind_filter(snap: LiveSnapshot) -> np.ndarray:
    """Which of the snapshot's points were read through a neutral-density filter."""
    nd = snap.nd_slot
    if nd.size != snap.index.size:
        return np.zeros(snap.index.size, dtype=bool)
    return nd >= 0
