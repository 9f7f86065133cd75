"""The run browser: the catalog with filters, a run's provenance, plan, devices and
faults, resuming an interrupted run, and its analyses with their results shown here.

Catalog queries, run-file reads and analyses all run in the background; an analysis has
its own worker, so a long fit never holds up browsing.
"""

from __future__ import annotations

import time
from pathlib import Path

from PySide6.QtCore import QSettings, Qt, QUrl, Signal
from PySide6.QtGui import QDesktopServices, QPixmap
from PySide6.QtWidgets import (
    QAbstractItemView,
    QComboBox,
    QDoubleSpinBox,
    QFileDialog,
    QFormLayout,
    QGridLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QListWidget,
    QListWidgetItem,
    QPlainTextEdit,
    QProgressBar,
    QPushButton,
    QScrollArea,
    QSpinBox,
    QSplitter,
    QTableWidget,
    QTableWidgetItem,
    QTabWidget,
    QVBoxLayout,
    QWidget,
)

from analysis.brdf.registry import default_candidates
from gui.model.analyses import (
    FIT_DETECTORS,
    AnalysisOutcome,
    FitSettings,
    RunDetails,
    Table,
    resume_refusal,
    run_analysis,
    run_details,
    with_catalog,
)
from gui.model.faults import point_number
from gui.model.remedies import for_gui
from gui.qt.background import Background, JobDone
from gui.qt.report_view import ReportView
from gui.qt.tables import fit_columns
from instrument.plans.planfile import KINDS
from instrument.run.catalog import CATALOG_NAME, Catalog, RunRow

__all__ = ["RunBrowser"]

STATUSES = ("finished", "running", "paused", "aborted", "failed", "interrupted", "created")


def _table(columns: tuple[str, ...], name: str) -> QTableWidget:
    t = QTableWidget(0, len(columns))
    t.setObjectName(name)
    t.setHorizontalHeaderLabels(list(columns))
    t.setEditTriggers(QAbstractItemView.NoEditTriggers)
    t.setSelectionBehavior(QAbstractItemView.SelectRows)
    t.horizontalHeader().setStretchLastSection(True)
    fit_columns(t)
    return t



def _fill(table: QTableWidget, rows) -> None:
    table.setRowCount(len(rows))
    for r, row in enumerate(rows):
        for c, text in enumerate(row):
            item = QTableWidgetItem(str(text))
            item.setToolTip(str(text))
            table.setItem(r, c, item)
    table.resizeColumnsToContents()


class RunBrowser(QWidget):
    """Catalog, run details, resume, analyses."""

    resumeRequested = Signal(object)     # RunDetails
    analysisDone = Signal(object)        # AnalysisOutcome
    analysisFailed = Signal(str, str)    # analysis name, message
    refreshed = Signal(int)              # rows listed
    folderChanged = Signal(str)          # the runs folder now in use

    def __init__(self, background: Background, runs_dir: Path, *,
                 settings: QSettings | None = None, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("run_browser")
        self.background = background
        self.analysis_pool = Background(workers=1, parent=self)
        self.settings = settings
        self.runs_dir = Path(runs_dir)
        self.rows: list[RunRow] = []
        self.details: RunDetails | None = None
        self.outcome: AnalysisOutcome | None = None
        self.report_view: ReportView | None = None
        self._query = 0

        self.folder = QLabel(str(self.runs_dir))
        self.folder.setObjectName("runs_folder")
        self.choose_folder = QPushButton("Folder…")
        self.sample = QLineEdit()
        self.sample.setObjectName("filter_sample")
        self.sample.setPlaceholderText("sample contains …")
        self.kind = QComboBox()
        self.kind.setObjectName("filter_kind")
        self.kind.addItem("any kind", "")
        for k in KINDS:
            self.kind.addItem(k, k)
        self.status = QComboBox()
        self.status.setObjectName("filter_status")
        self.status.addItem("any status", "")
        for s in STATUSES:
            self.status.addItem(s, s)
        self.since = QSpinBox()
        self.since.setObjectName("filter_days")
        self.since.setRange(0, 100000)
        self.since.setSpecialValueText("any date")
        self.since.setSuffix(" days")
        self.refresh_button = QPushButton("Refresh")
        self.refresh_button.setObjectName("refresh")
        filters = QHBoxLayout()
        filters.addWidget(self.folder, 1)
        filters.addWidget(self.choose_folder)
        row2 = QHBoxLayout()
        for w in (self.sample, self.kind, self.status, self.since, self.refresh_button):
            row2.addWidget(w)

        self.table = _table(("run id", "sample", "kind", "status", "started", "points"),
                            "runs")
        self.table.setSelectionMode(QAbstractItemView.SingleSelection)
        self.resume = QPushButton("Resume this run")
        self.resume.setObjectName("resume_run")
        self.resume.setEnabled(False)
        self.open_folder = QPushButton("Open folder")
        actions = QHBoxLayout()
        actions.addWidget(self.resume)
        actions.addWidget(self.open_folder)
        actions.addStretch(1)

        self.tabs = QTabWidget()
        self.tabs.setObjectName("details")
        self.provenance = _table(("", "value"), "provenance")
        self.plan_text = QPlainTextEdit()
        self.plan_text.setObjectName("plan_text")
        self.plan_text.setReadOnly(True)
        self.devices = _table(("device", "vendor", "model", "serial", "firmware", "driver",
                               "url"), "devices")
        self.faults = _table(("time", "point", "device", "cause", "action"), "run_faults")
        self.tabs.addTab(self.provenance, "Provenance")
        self.tabs.addTab(self.plan_text, "Plan")
        self.tabs.addTab(self.devices, "Devices")
        self.tabs.addTab(self.faults, "Faults")
        self.tabs.addTab(self._analysis_page(), "Analysis")

        left = QWidget()
        ll = QVBoxLayout(left)
        ll.setContentsMargins(0, 0, 0, 0)
        ll.addLayout(filters)
        ll.addLayout(row2)
        ll.addWidget(self.table, 1)
        ll.addLayout(actions)
        split = QSplitter(Qt.Horizontal)
        split.addWidget(left)
        split.addWidget(self.tabs)
        split.setStretchFactor(0, 1)
        split.setStretchFactor(1, 1)
        lay = QVBoxLayout(self)
        lay.addWidget(split)

        self.choose_folder.clicked.connect(self.ask_folder)
        self.refresh_button.clicked.connect(self.refresh)
        self.sample.returnPressed.connect(self.refresh)
        self.kind.currentIndexChanged.connect(lambda _: self.refresh())
        self.status.currentIndexChanged.connect(lambda _: self.refresh())
        self.since.valueChanged.connect(lambda _: self.refresh())
        self.table.itemSelectionChanged.connect(self._selected)
        self.resume.clicked.connect(self._resume)
        self.open_folder.clicked.connect(
            lambda: QDesktopServices.openUrl(QUrl.fromLocalFile(str(self.runs_dir))))
        background.finished.connect(self._job_done)
        self.analysis_pool.finished.connect(self._analysis_done)

    def _fit_options_box(self) -> QGroupBox:
        """The fit's options, as ``scatterlab fit`` takes them (empty: the default)."""

        box = QGroupBox("Fit options")
        box.setObjectName("fit_options")
        box.setCheckable(False)

        def number(name: str, suffix: str, decimals: int, top: float, tip: str
                   ) -> QDoubleSpinBox:
            w = QDoubleSpinBox()
            w.setObjectName(name)
            w.setRange(0.0, top)
            w.setDecimals(decimals)
            w.setSuffix(suffix)
            w.setSpecialValueText("default")  # 0: the option not given
            w.setToolTip(tip)
            return w

        self.opt_distance = number(
            "opt_distance_mm", " mm", 2, 1e5, "sample-to-receiver distance; default: the "
            "profile's distance plus the camera_z read-back (--distance-mm)")
        self.opt_distance_u = number(
            "opt_distance_u_mm", " mm", 3, 1e3, "standard uncertainty of that distance; "
            "default: unknown, left out of the common scale (--distance-u-mm)")
        self.opt_power_u = number(
            "opt_power_u", "", 4, 1.0, "relative standard uncertainty of the incident "
            "power, e.g. 0.02 for 2 %; default: unknown (--incident-power-u)")
        self.opt_detector = QComboBox()
        self.opt_detector.setObjectName("opt_detector")
        for d in FIT_DETECTORS:
            self.opt_detector.addItem(d.replace("_", " "), d)
        self.opt_detector.setToolTip("the detector whose readings are reduced (--detector)")
        self.opt_models = QListWidget()
        self.opt_models.setObjectName("opt_models")
        self.opt_models.setToolTip("candidate models; the selection rule (BIC) picks one "
                                   "(--models)")
        # the fit's DEFAULT_MODELS, from the registry: importing the fit pipeline here would
        # import scipy.stats on the GUI thread (0.4 s of CPU at the browser's first build)
        for m in default_candidates():
            item = QListWidgetItem(m)
            item.setFlags(item.flags() | Qt.ItemIsUserCheckable)
            item.setCheckState(Qt.Checked)
            self.opt_models.addItem(item)
        self.opt_models.setMaximumHeight(110)
        form = QFormLayout(box)
        form.addRow("Distance (mm)", self.opt_distance)
        form.addRow("Distance uncertainty (mm)", self.opt_distance_u)
        form.addRow("Incident power uncertainty", self.opt_power_u)
        form.addRow("Detector", self.opt_detector)
        form.addRow("Candidate models", self.opt_models)
        return box

    def fit_settings(self) -> FitSettings:
        """The fit options as set in the Analysis tab."""
        def value(w: QDoubleSpinBox) -> float | None:
            return w.value() if w.value() > 0 else None

        models = tuple(self.opt_models.item(k).text() for k in range(self.opt_models.count())
                       if self.opt_models.item(k).checkState() == Qt.Checked)
        return FitSettings(value(self.opt_distance), value(self.opt_distance_u),
                           value(self.opt_power_u), models, self.opt_detector.currentData())

    def _analysis_page(self) -> QWidget:
        page = QWidget()
        self.analysis = QComboBox()
        self.analysis.setObjectName("analysis")
        self.analyse = QPushButton("Run analysis")
        self.analyse.setObjectName("analyse")
        self.analyse.setEnabled(False)
        self.open_report = QPushButton("Show report")
        self.open_report.setToolTip("the HTML report with its figures, in this window; "
                                    "a web browser from there on request")
        self.open_report.setObjectName("open_report")
        self.open_report.setEnabled(False)
        self.busy = QProgressBar()
        self.busy.setObjectName("analysis_busy")
        self.busy.setRange(0, 0)  # the pipelines report no steps: a busy bar and the time
        self.busy.hide()
        self.analysis_summary = QLabel("")
        self.analysis_summary.setObjectName("analysis_summary")
        self.analysis_summary.setWordWrap(True)
        self.analysis_summary.setTextInteractionFlags(Qt.TextSelectableByMouse)
        self.result_tables = QWidget()
        self._tables_layout = QVBoxLayout(self.result_tables)
        self._tables_layout.setContentsMargins(0, 0, 0, 0)
        self.figures = QWidget()
        self._figures_layout = QGridLayout(self.figures)
        scroll = QScrollArea()
        scroll.setWidgetResizable(True)
        body = QWidget()
        bl = QVBoxLayout(body)
        bl.addWidget(self.result_tables)
        bl.addWidget(self.figures)
        bl.addStretch(1)
        scroll.setWidget(body)
        top = QHBoxLayout()
        top.addWidget(self.analysis, 1)
        top.addWidget(self.analyse)
        top.addWidget(self.open_report)
        lay = QVBoxLayout(page)
        lay.addLayout(top)
        self.fit_options = self._fit_options_box()
        lay.addWidget(self.fit_options)
        lay.addWidget(self.busy)
        lay.addWidget(self.analysis_summary)
        lay.addWidget(scroll, 1)
        self.analyse.clicked.connect(self.start_analysis)
        self.analysis.currentIndexChanged.connect(
            lambda _: self.fit_options.setVisible(self.analysis.currentData() == "fit"))
        self.open_report.clicked.connect(self._open_report)
        self.result_table_widgets: list[QTableWidget] = []
        return page

    # catalog ------------------------------------------------------------------------
    def set_runs_dir(self, folder: str | Path) -> None:
        """List ``folder``'s runs and make it the runs folder now: the main window writes
        new runs there (``folderChanged``), and the next launch opens it."""
        self.runs_dir = Path(folder)
        self.folder.setText(str(self.runs_dir))
        self.folder.setToolTip(f"runs folder: new runs are written here\n{self.runs_dir}")
        if self.settings is not None:
            self.settings.setValue("runs_dir", str(self.runs_dir))
        self.details = None
        self.refresh()
        self.folderChanged.emit(str(self.runs_dir))

    def ask_folder(self) -> None:
        folder = QFileDialog.getExistingDirectory(self, "Runs folder", str(self.runs_dir))
        if folder:
            self.set_runs_dir(folder)

    def refresh(self) -> int:
        """List the catalog's runs that pass the filters (in the background)."""
        self._query += 1
        query = self._query
        folder = self.runs_dir
        sample = self.sample.text().strip() or None
        kind = self.kind.currentData() or None
        status = self.status.currentData() or None
        since = time.time() - 86400 * self.since.value() if self.since.value() else None

        def job():
            if not (folder / CATALOG_NAME).is_file():
                return query, []
            with Catalog(folder) as cat:
                cat.refresh_live()  # killed runs read "interrupted"
                return query, cat.find(status=status, sample=sample, kind=kind, since=since)

        return self.background.submit("catalog", job)

    def _show_rows(self, rows: list[RunRow]) -> None:
        selected = self.selected_row()
        self.rows = rows
        _fill(self.table, [(r.run_id, r.sample, r.plan_kind, r.status,
                            time.strftime("%Y-%m-%d %H:%M", time.localtime(r.started)),
                            f"{r.n_points}/{r.n_planned}") for r in rows])
        if selected is not None:
            self.select(selected.run_id)
            now = self.selected_row()
            if now is not None and now != selected:
                self._selected()  # the run moved on (resumed, finished): read it again
        self.refreshed.emit(len(rows))

    def selected_row(self) -> RunRow | None:
        sel = self.table.selectionModel().selectedRows() if self.table.selectionModel() else []
        if not sel or sel[0].row() >= len(self.rows):
            return None
        return self.rows[sel[0].row()]

    def select(self, run_id: str) -> bool:
        for k, r in enumerate(self.rows):
            if r.run_id == run_id:
                self.table.selectRow(k)
                return True
        return False

    def _selected(self) -> None:
        row = self.selected_row()
        self.resume.setEnabled(False)
        self.analyse.setEnabled(False)
        if row is None:
            return
        path = Path(row.path)
        self.background.submit("details", lambda: (row, run_details(path)))

    def _show_details(self, row: RunRow, d: RunDetails) -> None:
        d = with_catalog(d, row)
        self.details = d
        _fill(self.provenance, list(d.provenance.items()))
        self.plan_text.setPlainText(d.plan_text)
        _fill(self.devices, [(role, i.get("vendor", ""), i.get("model", ""),
                              i.get("serial", ""), i.get("firmware", ""), i.get("driver", ""),
                              i.get("url", "")) for role, i in d.devices.items()])
        _fill(self.faults, [(time.strftime("%H:%M:%S", time.localtime(e.get("time", 0))),
                             point_number(e.get("index")), e.get("device", ""),
                             for_gui(str(e.get("cause", ""))),
                             e.get("action", "")) for e in d.faults])
        self.tabs.setTabText(3, f"Faults ({len(d.faults)})")
        refusal = resume_refusal(d)
        self.resume.setEnabled(refusal is None)
        self.resume.setToolTip(refusal or f"continue {d.path.name} in its own file on "
                               f"bench {d.bench_name!r}")
        self.analysis.clear()
        for name in d.analyses:
            self.analysis.addItem(name, name)
        self.analyse.setEnabled(bool(d.analyses) and not self.analysis_pool.running)
        self.analysis_summary.setText("" if d.analyses else
                                      f"no analysis for {d.plan_kind} runs")

    def _resume(self) -> None:
        if self.details is not None:
            self.resumeRequested.emit(self.details)

    # analyses ---------------------------------------------------------------------------
    def start_analysis(self, name: str | None = None) -> int | None:
        d = self.details
        name = name or self.analysis.currentData()
        if d is None or not name:
            return None
        self.busy.show()
        self.analyse.setEnabled(False)
        self.open_report.setEnabled(False)
        self.analysis_summary.setText(f"{name} of {d.path.name} running …")
        path = d.path
        if name == "fit":
            settings = self.fit_settings()
            if not any(True for _ in settings.models):
                self._analysis_refused("Candidate models: check at least one")
                return None
            return self.analysis_pool.submit(name, lambda: run_analysis(name, path, settings))
        return self.analysis_pool.submit(name, lambda: run_analysis(name, path))

    def _analysis_refused(self, why: str) -> None:
        self.busy.hide()
        self.analyse.setEnabled(True)
        self.analysis_summary.setText(f"not started: {why}")

    def _analysis_done(self, done: JobDone) -> None:
        self.busy.hide()
        self.analyse.setEnabled(self.details is not None and bool(self.details.analyses))
        if done.error is not None:
            msg = f"{done.name} failed: {done.error}"
            self.analysis_summary.setText(msg)
            self.analysisFailed.emit(done.name, str(done.error))
            return
        self.show_outcome(done.result, done.elapsed_s)
        self.analysisDone.emit(done.result)

    def show_outcome(self, out: AnalysisOutcome, elapsed_s: float = 0.0) -> None:
        self.outcome = out
        lines = [f"<b>{out.name}</b> ({elapsed_s:.1f} s): {out.summary}"]
        lines += [f"note: {n}" for n in out.notes]
        lines += [f"<span style='color:#e65100'>warning: {w}</span>" for w in out.warnings]
        if out.report is not None:
            lines.append(f"report: {out.report}")
        self.analysis_summary.setText("<br>".join(lines))
        for w in self.result_table_widgets:
            w.setParent(None)
            w.deleteLater()
        self.result_table_widgets = []
        while self._tables_layout.count():
            item = self._tables_layout.takeAt(0)
            if item.widget() is not None:
                item.widget().hide()
                item.widget().deleteLater()
        for t in out.tables:
            self._add_table(t)
        while self._figures_layout.count():
            item = self._figures_layout.takeAt(0)
            if item.widget() is not None:
                item.widget().hide()
                item.widget().deleteLater()
        for k, fig in enumerate(out.figures[:12]):
            label = QLabel()
            pix = QPixmap(str(fig))
            if not pix.isNull():
                label.setPixmap(pix.scaledToWidth(360, Qt.SmoothTransformation))
            label.setToolTip(str(fig))
            self._figures_layout.addWidget(label, k // 2, k % 2)
        self.open_report.setEnabled(out.report is not None)
        self.tabs.setCurrentIndex(4)

    def _add_table(self, t: Table) -> None:
        title = QLabel(f"<b>{t.title}</b>")
        widget = _table(t.columns, f"result:{t.title}")
        _fill(widget, t.rows)
        widget.setMinimumHeight(min(300, 30 + 26 * max(1, len(t.rows))))
        self._tables_layout.addWidget(title)
        self._tables_layout.addWidget(widget)
        self.result_table_widgets.append(widget)

    def _open_report(self) -> ReportView | None:
        if self.outcome is None or self.outcome.report is None:
            return None
        if self.report_view is None:
            self.report_view = ReportView(self)
        self.report_view.show_report(self.outcome.report)
        return self.report_view

    # background results ---------------------------------------------------------------
    def _job_done(self, done: JobDone) -> None:
        if done.name == "catalog":
            if done.error is not None:
                self.analysis_summary.setText(f"catalog: {done.error}")
                return
            query, rows = done.result
            if query == self._query:
                self._show_rows(rows)
        elif done.name == "details":
            if done.error is not None:
                self.analysis_summary.setText(f"cannot read the run: {done.error}")
                return
            row, d = done.result
            current = self.selected_row()
            if current is not None and current.run_id == row.run_id:
                self._show_details(row, d)
