"""The plan editor: a form for every plan kind, validated as the CLI validates, a preview,
and the speed/accuracy planner.

Every edit re-validates (after a short pause in typing, on a background thread, newest
edit wins): each problem is shown under its field, problems of the whole plan (points the
guard rejects) below the form, and **Start** stays disabled while any exist. The preview
gives the points, the travel per axis, the estimated duration and the coverage picture of
``scatterlab plan``. The planner searches the θr step, exposure cap and frame count for
the fastest in-plane scan whose predicted uncertainty of a parameter reaches a target; for
a dual-rotating-retarder plan it trades the retarder steps per geometry instead (the
Pareto front of ``scatterlab plan``, ADR 0108), and for a PEM plan it shows κ per
wavelength. Either runs on the background thread; a row of the front chosen in the table
is what **Apply** writes into the plan.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
from PySide6.QtCore import QSettings, Qt, QTimer, Signal
from PySide6.QtGui import QImage, QPixmap
from PySide6.QtWidgets import (
    QAbstractItemView,
    QCheckBox,
    QComboBox,
    QDialog,
    QDoubleSpinBox,
    QFileDialog,
    QFormLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QPlainTextEdit,
    QPushButton,
    QScrollArea,
    QSizePolicy,
    QSplitter,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
    QWidget,
)

from gui.model import format as fmt
from gui.model.planform import KIND_TITLES, FieldSpec, PlanForm, Validation
from gui.model.polarimetric_planner import PemSummary, PolarimetricTrade
from gui.qt.background import Background, JobDone
from instrument.bench.profile import BenchProfile
from instrument.plans.build import Plan
from instrument.plans.planfile import KINDS, PlanError

__all__ = ["PlanEditor"]

#: The planner table's columns: the scalar trade's, the DRR trade's, the PEM conditioning's.
SCALAR_COLUMNS = ("duration", "σ", "points", "option")
DRR_COLUMNS = ("steps", "points", "duration", "κ", "σ mean", "σ worst")
PEM_COLUMNS = ("λ (nm)", "κ", "PEM amplitude (rad)", "analyser retardance (°)")
#: The planner box's title per plan (no polarimetry, DRR, PEM).
PLANNER_TITLES = {"": "Speed / accuracy planner (in-plane BRDF)",
                  "drr": "Speed / accuracy planner (polarimetry: retarder steps per geometry)",
                  "pem": "Planner (PEM polarimetry: conditioning)"}

SECTIONS = (("plan", "Plan"), ("sample", "Sample"), ("scan", "Scan"),
            ("acquisition", "Acquisition"), ("calibration", "Calibration runs"),
            ("spectral", "Wavelength axis"), ("polarimetry", "Polarimetry"))


def field_tip(spec: FieldSpec) -> str:
    """A field's tooltip: what it means (with its unit), then where it goes in the plan
    file, for an operator who also edits plan files."""
    return f"{spec.help or spec.label} (plan file: {spec.path})"


class FittedImage(QLabel):
    """A picture scaled to the space it has (aspect kept), full size on a double-click:
    the coverage plot stays readable however the dock is sized."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setAlignment(Qt.AlignCenter)
        self.setSizePolicy(QSizePolicy.Ignored, QSizePolicy.Ignored)
        self.source: QPixmap | None = None

    def set_image(self, pixmap: QPixmap | None) -> None:
        self.source = pixmap
        self._fit()

    def clear(self) -> None:
        self.source = None
        super().clear()

    def resizeEvent(self, event) -> None:
        super().resizeEvent(event)
        self._fit()

    def _fit(self) -> None:
        if self.source is None or self.source.isNull():
            return
        self.setPixmap(self.source.scaled(self.size(), Qt.KeepAspectRatio,
                                          Qt.SmoothTransformation))

    def mouseDoubleClickEvent(self, event) -> None:
        if self.source is None:
            return
        dialog = QDialog(self)
        dialog.setWindowTitle("Plan coverage")
        full = QLabel()
        full.setPixmap(self.source)
        area = QScrollArea()
        area.setWidget(full)
        QVBoxLayout(dialog).addWidget(area)
        dialog.resize(min(self.source.width() + 40, 1400), min(self.source.height() + 40, 1000))
        dialog.show()


class PlanEditor(QWidget):
    """Form, problems, preview, planner; emits :attr:`startRequested` with the plan."""

    startRequested = Signal(object)   # Plan
    planChanged = Signal(object)      # Plan | None (valid plan, for the goniometer view)
    validated = Signal(object)        # Validation

    def __init__(self, background: Background,
                 profile_for_validation: Callable[[], BenchProfile | None], *,
                 settings: QSettings | None = None, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("plan_editor")
        self.background = background
        self.profile_for_validation = profile_for_validation
        self.settings = settings
        self.form = PlanForm("brdf_in_plane")
        self.path: Path | None = None
        self.validation: Validation | None = None
        self.plan: Plan | None = None
        self.can_start = False  # the bench is connected and free
        self._generation = 0
        self._widgets: dict[str, QWidget] = {}
        self._errors: dict[str, QLabel] = {}

        self.new_kind = QComboBox()
        self.new_kind.setObjectName("new_kind")
        for kind in KINDS:
            self.new_kind.addItem(KIND_TITLES.get(kind, kind), kind)
        self.new_button = QPushButton("New")
        self.open_button = QPushButton("Open…")
        self.save_button = QPushButton("Save")
        self.save_as_button = QPushButton("Save as…")
        self.file_label = QLabel("unsaved plan")
        self.file_label.setObjectName("file_label")
        self.start = QPushButton("Start run")
        self.start.setObjectName("start")
        self.start.setEnabled(False)
        self.start.setMinimumWidth(130)
        self.start.setStyleSheet("QPushButton:enabled { background: #2e7d32; color: white; "
                                 "font-weight: 700; padding: 4px 14px }")
        self.status = QLabel("")
        self.status.setObjectName("validation_status")
        self.status.setWordWrap(True)
        self.problems = QLabel("")
        self.problems.setObjectName("problems")
        self.problems.setWordWrap(True)
        self.problems.setStyleSheet("color: #b71c1c")
        self.problems.setTextInteractionFlags(Qt.TextSelectableByMouse)

        files = QHBoxLayout()
        files.addWidget(self.new_kind)
        files.addWidget(self.new_button)
        files.addWidget(self.open_button)
        files.addWidget(self.save_button)
        files.addWidget(self.save_as_button)
        files.addStretch(1)
        files.addWidget(self.start)

        self._form_host = QWidget()
        self._form_layout = QVBoxLayout(self._form_host)
        scroll = QScrollArea()
        scroll.setWidgetResizable(True)
        scroll.setWidget(self._form_host)

        self.preview = QLabel("")
        self.preview.setObjectName("preview")
        self.preview.setWordWrap(True)
        self.preview.setTextInteractionFlags(Qt.TextSelectableByMouse)
        self.coverage = FittedImage()
        self.coverage.setObjectName("coverage")
        self.coverage.setMinimumSize(240, 240)
        self.coverage.setToolTip("the plan's directions; double-click for full size")
        right = QWidget()
        rl = QVBoxLayout(right)
        rl.addWidget(QLabel("<b>Preview</b>"))
        rl.addWidget(self.preview)
        rl.addWidget(self.coverage, 1)
        rl.addWidget(self._planner_box())
        split = QSplitter(Qt.Horizontal)
        split.addWidget(scroll)
        split.addWidget(right)
        split.setStretchFactor(0, 3)
        split.setStretchFactor(1, 2)
        split.setSizes([620, 420])
        split.setChildrenCollapsible(False)
        scroll.setMinimumWidth(380)

        lay = QVBoxLayout(self)
        lay.addLayout(files)
        lay.addWidget(self.file_label)
        lay.addWidget(split, 1)
        lay.addWidget(self.status)
        lay.addWidget(self.problems)

        self._debounce = QTimer(self)
        self._debounce.setSingleShot(True)
        self._debounce.setInterval(250)
        self._debounce.timeout.connect(self.validate_now)
        self.new_button.clicked.connect(lambda: self.new_plan(self.new_kind.currentData()))
        self.open_button.clicked.connect(self._ask_open)
        self.save_button.clicked.connect(self._save)
        self.save_as_button.clicked.connect(self._ask_save_as)
        self.start.clicked.connect(self._start)
        background.finished.connect(self._job_done)
        self._build_form()
        self.validate_now()

    # form ---------------------------------------------------------------------------
    def _build_form(self) -> None:
        while self._form_layout.count():
            old = self._form_layout.takeAt(0).widget()
            if old is not None:
                old.hide()  # off the screen now, deleted later
                old.setParent(None)
                old.deleteLater()
        self._widgets, self._errors = {}, {}
        boxes: dict[str, QFormLayout] = {}
        for section, title in SECTIONS:
            box = QGroupBox(title)
            box.setObjectName(f"section_{section}")
            boxes[section] = QFormLayout(box)
            self._form_layout.addWidget(box)
        self._form_layout.addStretch(1)
        for spec in self.form.fields():
            widget = self._field_widget(spec)
            error = QLabel("")
            error.setObjectName(f"error:{spec.path}")
            error.setStyleSheet("color: #b71c1c")
            error.setWordWrap(True)
            error.hide()
            holder = QWidget()
            hl = QVBoxLayout(holder)
            hl.setContentsMargins(0, 0, 0, 0)
            hl.setSpacing(1)
            hl.addWidget(widget)
            hl.addWidget(error)
            label = QLabel(spec.label)
            tip = field_tip(spec)
            label.setToolTip(tip)
            widget.setToolTip(tip)
            boxes[spec.section].addRow(label, holder)
            self._widgets[spec.path] = widget
            self._errors[spec.path] = error

    def _field_widget(self, spec: FieldSpec) -> QWidget:
        value = self.form.get(spec.path)
        name = f"field:{spec.path}"
        if spec.kind == "bool":
            w = QCheckBox()
            w.setChecked(bool(value))
            w.toggled.connect(lambda v, p=spec.path: self._edited(p, v))
        elif spec.kind == "choice":
            w = QComboBox()
            for c in spec.choices:
                w.addItem(KIND_TITLES.get(c, c) if spec.path == "plan.kind" else
                          c or ("none" if spec.path == "polarimetry.mode" else "automatic"), c)
            if value and w.findData(value) < 0:  # a plan file's value not in the list
                w.addItem(str(value), value)
            w.setCurrentIndex(max(0, w.findData(value or "")))
            w.currentIndexChanged.connect(
                lambda _, p=spec.path, box=w: self._edited(p, box.currentData()))
        elif spec.kind == "objects":
            w = QPlainTextEdit(str(value or ""))
            w.setMaximumHeight(90)
            w.textChanged.connect(lambda p=spec.path, box=w: self._edited(p, box.toPlainText()))
        else:
            w = QLineEdit(str(value or ""))
            w.textEdited.connect(lambda v, p=spec.path: self._edited(p, v))
        w.setObjectName(name)
        return w

    def field(self, path: str) -> QWidget:
        return self._widgets[path]

    def error_text(self, path: str) -> str:
        label = self._errors.get(path)
        return label.text() if label is not None and not label.isHidden() else ""

    def set_field(self, path: str, value) -> None:
        """Set a field as if typed (tests, the planner's Apply)."""
        w = self._widgets[path]
        if isinstance(w, QCheckBox):
            w.setChecked(bool(value))
        elif isinstance(w, QComboBox):
            w.setCurrentIndex(w.findData(value))
        elif isinstance(w, QPlainTextEdit):
            w.setPlainText(str(value))
        else:
            w.setText(str(value))
            self._edited(path, str(value))

    def _edited(self, path: str, value) -> None:
        if path == "plan.kind" and value != self.form.kind:
            self.form.set_kind(str(value))
            self._build_form()
        else:
            self.form.set(path, value)
        self._invalidate()

    def _invalidate(self) -> None:
        self._generation += 1
        self.start.setEnabled(False)
        self.status.setText("checking …")
        self._debounce.start()

    # files --------------------------------------------------------------------------
    def new_plan(self, kind: str) -> None:
        self.form = PlanForm(kind)
        self.path = None
        self.file_label.setText("unsaved plan")
        self._build_form()
        self._invalidate()

    def open_plan(self, path: str | Path) -> bool:
        """Load a plan file into the form; False (with the problem shown) if it cannot."""
        path = Path(path)
        try:
            form = PlanForm.from_toml(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError) as err:
            self._show_problems([f"cannot read {path}: {err}"])
            return False
        except PlanError as err:
            self._show_problems([f"{path}: {e}" for e in err.errors])
            return False
        self.form = form
        self.path = path
        self.file_label.setText(str(path))
        self._remember_folder(path)
        self._build_form()
        self._invalidate()
        return True

    def save_plan(self, path: str | Path) -> Path:
        path = Path(path)
        path.write_text(self.form.to_toml(), encoding="utf-8")
        self.path = path
        self.file_label.setText(str(path))
        self._remember_folder(path)
        return path

    def _folder(self) -> str:
        if self.settings is not None:
            return str(self.settings.value("plan_folder", str(Path.cwd())))
        return str(Path.cwd())

    def _remember_folder(self, path: Path) -> None:
        if self.settings is not None:
            self.settings.setValue("plan_folder", str(path.parent))

    def _ask_open(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Open plan", self._folder(),
                                              "Plans (*.toml)")
        if path:
            self.open_plan(path)

    def _save(self) -> None:
        if self.path is None:
            self._ask_save_as()
        else:
            self.save_plan(self.path)

    def _ask_save_as(self) -> None:
        path, _ = QFileDialog.getSaveFileName(self, "Save plan", self._folder(),
                                              "Plans (*.toml)")
        if path:
            self.save_plan(path if path.endswith(".toml") else path + ".toml")

    # validation ---------------------------------------------------------------------
    def validate_now(self) -> int:
        """Validate the form on a background thread; the newest request wins."""
        self._debounce.stop()
        self._generation += 1
        gen = self._generation
        form_copy = PlanForm(self.form.kind)
        form_copy.values = dict(self.form.values)
        profile = self.profile_for_validation()

        def job():
            result = form_copy.validate(profile)
            image = None
            if result.plan is not None and result.ok:
                from instrument.plans.coverage import coverage_image

                image = coverage_image(result.plan)
            return gen, profile, result, image

        self.status.setText("checking …")
        return self.background.submit("validate plan", job)

    def _job_done(self, done: JobDone) -> None:
        if done.name == "validate plan":
            if done.error is not None:
                self._show_problems([f"validation failed: {done.error!r}"])
                return
            gen, profile, result, image = done.result
            if gen != self._generation:
                return  # an older edit's answer
            self._apply_validation(result, profile, image)
        elif done.name == "planner":
            self._planner_done(done)

    def _apply_validation(self, result: Validation, profile: BenchProfile | None,
                          image: np.ndarray | None) -> None:
        self.validation = result
        self.plan = result.plan if result.ok else None
        for path, label in self._errors.items():
            msgs = result.errors.get(path, [])
            label.setText("; ".join(msgs))
            label.setVisible(bool(msgs))
        self._show_problems(result.general)
        bench = profile.name if profile is not None else "no bench"
        if result.ok:
            self.status.setStyleSheet("color: #1b5e20")
            self.status.setText(f"valid on bench {bench!r}")
        else:
            self.status.setStyleSheet("color: #b71c1c")
            self.status.setText(f"{result.count()} problem(s) on bench {bench!r}: "
                                "Start is disabled until they are fixed")
        self._show_preview(result, image)
        self._show_planner_kind(result)
        self._update_start()
        self.planChanged.emit(self.plan)
        self.validated.emit(result)

    def _show_problems(self, lines: list[str]) -> None:
        self.problems.setText("\n".join(f"• {x}" for x in lines))
        self.problems.setVisible(bool(lines))

    def _show_preview(self, result: Validation, image: np.ndarray | None) -> None:
        plan = result.plan
        if plan is None:
            self.preview.setText("no preview while the plan has problems")
            self.coverage.clear()
            return
        est = plan.estimate()
        lines = [f"<b>{est.n_points}</b> points ({plan.spec.order} order)"]
        if plan.dropped_in_beam:
            lines.append(f"{plan.dropped_in_beam} point(s) with the detector in the beam "
                         "left out")
        for role, dist in est.travel.items():
            unit = "mm" if role == "camera_z" else "deg"
            lines.append(f"travel {role}: {dist:.1f} {unit}")
        lines.append(f"estimated duration <b>{fmt.duration(est.total_s)}</b> (motion "
                     f"{fmt.duration(est.motion_s)}, acquisition "
                     f"{fmt.duration(est.acquisition_s)})")
        self.preview.setText("<br>".join(lines))
        if image is not None:
            rgb = np.ascontiguousarray(image[:, :, ::-1])
            h, w, _ = rgb.shape
            qimg = QImage(rgb.data, w, h, 3 * w, QImage.Format_RGB888).copy()
            self.coverage.set_image(QPixmap.fromImage(qimg))

    def set_can_start(self, can: bool) -> None:
        """Whether a bench is connected and free (no run owns it)."""
        self.can_start = can
        self._update_start()

    def _update_start(self) -> None:
        ok = self.validation is not None and self.validation.ok and self.plan is not None
        self.start.setEnabled(ok and self.can_start)
        self.start.setToolTip("" if ok and self.can_start else
                              "fix the problems first" if not ok else
                              "connect a bench (and wait for the run in progress)")

    def _start(self) -> None:
        if self.plan is not None and self.start.isEnabled():
            self.startRequested.emit(self.plan)

    # the speed/accuracy planner -------------------------------------------------------
    def _planner_box(self) -> QGroupBox:
        box = QGroupBox(PLANNER_TITLES[""])
        box.setObjectName("planner")
        self.planner_box = box
        self.target_sigma = QDoubleSpinBox()
        self.target_sigma.setObjectName("target_sigma")
        self.target_sigma.setDecimals(5)
        self.target_sigma.setRange(1e-5, 1e3)
        self.target_sigma.setValue(0.01)
        self.target_param = QLineEdit("")
        self.target_param.setObjectName("target_param")
        self.target_param.setPlaceholderText("parameter (default: the model's last)")
        self.find = QPushButton("Find the fastest scan")
        self.find.setObjectName("find_fastest")
        self.apply_best = QPushButton("Apply to the plan")
        self.apply_best.setObjectName("apply_best")
        self.apply_best.setEnabled(False)
        self.planner_result = QLabel("")
        self.planner_result.setObjectName("planner_result")
        self.planner_result.setWordWrap(True)
        self.pareto = QTableWidget(0, len(SCALAR_COLUMNS))
        self.pareto.setObjectName("pareto")
        self.pareto.setHorizontalHeaderLabels(list(SCALAR_COLUMNS))
        self.pareto.setMaximumHeight(150)
        self.pareto.setSelectionBehavior(QAbstractItemView.SelectRows)
        self.pareto.setSelectionMode(QAbstractItemView.SingleSelection)
        self.pareto.setEditTriggers(QAbstractItemView.NoEditTriggers)
        self.pareto.setToolTip("the Pareto front, fastest first; choose a row, then Apply "
                               "writes it into the plan")
        form = QFormLayout(box)
        row = QHBoxLayout()
        row.addWidget(self.target_sigma)
        row.addWidget(self.target_param, 1)
        form.addRow("target σ", row)
        buttons = QHBoxLayout()
        buttons.addWidget(self.find)
        buttons.addWidget(self.apply_best)
        form.addRow(buttons)
        form.addRow(self.planner_result)
        form.addRow(self.pareto)
        self.find.clicked.connect(self.run_planner)
        self.apply_best.clicked.connect(self._apply_best)
        self.pareto.itemSelectionChanged.connect(self._row_chosen)
        self._best = None
        self._front: list = []
        return box

    @staticmethod
    def _polarimetry_mode(spec) -> str:
        """'' (no polarimetry), 'drr' or 'pem' for a plan spec (or None)."""
        pol = getattr(spec, "polarimetry", None)
        return "" if not pol else str(pol.get("mode") or "drr")

    def _show_planner_kind(self, result: Validation) -> None:
        """Title and target field for the kind of trade the validated plan has."""
        mode = (self._polarimetry_mode(result.spec) if result.spec is not None
                else str(self.form.get("polarimetry.mode") or ""))
        mode = mode if mode in PLANNER_TITLES else ""
        self.planner_box.setTitle(PLANNER_TITLES[mode])
        self.target_param.setPlaceholderText(
            "sigma_mean (or sigma_max, kappa)" if mode == "drr" else
            "parameter (default: the model's last)")
        self.target_param.setEnabled(mode != "pem")
        self.target_sigma.setEnabled(mode != "pem")
        self.find.setText("Show the conditioning" if mode == "pem" else
                          "Find the fastest scan")

    def _set_table(self, columns: tuple[str, ...], rows: list[tuple[str, ...]]) -> None:
        self.pareto.blockSignals(True)  # a refill is not a choice of row
        self.pareto.clearSelection()
        self.pareto.setColumnCount(len(columns))
        self.pareto.setHorizontalHeaderLabels(list(columns))
        self.pareto.setRowCount(len(rows))
        for k, cells in enumerate(rows):
            for j, text in enumerate(cells):
                self.pareto.setItem(k, j, QTableWidgetItem(text))
        self.pareto.resizeColumnsToContents()
        self.pareto.blockSignals(False)

    def run_planner(self) -> int | None:
        spec = self.validation.spec if self.validation is not None else None
        profile = self.profile_for_validation()
        mode = self._polarimetry_mode(spec)
        if spec is not None and profile is not None and mode:
            return self._run_polarimetric_planner(spec, profile, mode)
        if spec is None or profile is None or "theta_r" not in spec.scan:
            self.planner_result.setText("the planner needs a valid in-plane plan (θr) and a "
                                        "bench")
            return None
        target = self.target_sigma.value()
        wanted = self.target_param.text().strip() or None

        def job():
            from analysis.brdf import get_model
            from instrument.plans.tradeoff import (
                default_options,
                fastest_for_target,
                pareto_front,
                setup_from_profile,
                sweep,
            )

            prior, det = setup_from_profile(profile, spec)
            names = get_model(prior.model).param_names
            param = wanted or names[-1]
            if param not in names:
                raise ValueError(f"{prior.model} has no parameter {param!r}; it has "
                                 f"{', '.join(names)}")
            results = sweep(spec, profile, default_options(), prior=prior, det=det)
            return (param, target, pareto_front(results, param),
                    fastest_for_target(results, param, target), results)

        self.planner_result.setText("searching …")
        self.apply_best.setEnabled(False)
        return self.background.submit("planner", job)

    def _run_polarimetric_planner(self, spec, profile: BenchProfile, mode: str) -> int:
        """The DRR trade (or the PEM conditioning) on the background thread."""
        target = self.target_sigma.value()
        axis = self.target_param.text().strip() or None

        def job():
            from gui.model.polarimetric_planner import pem_summary, plan_trade

            if mode == "pem":
                return pem_summary(spec, profile)
            return plan_trade(spec, profile, axis, target)

        self.planner_result.setText("computing …" if mode == "pem" else "searching …")
        self.apply_best.setEnabled(False)
        return self.background.submit("planner", job)

    def _planner_done(self, done: JobDone) -> None:
        if done.error is not None:
            self.planner_result.setText(f"planner: {done.error}")
            return
        if isinstance(done.result, PolarimetricTrade):
            self._show_trade(done.result)
            return
        if isinstance(done.result, PemSummary):
            self._show_pem(done.result)
            return
        param, target, front, best, results = done.result
        self._front = list(front)
        self._set_table(SCALAR_COLUMNS, [
            (fmt.duration(r.duration_s), f"{r.sigma[param]:.3g}", str(r.n_points),
             r.option.label()) for r in front])
        self._best = best
        if best is None:
            reach = min(r.sigma[param] for r in results)
            self.planner_result.setText(f"no option reaches σ({param}) ≤ {target:g} (best "
                                        f"{reach:.3g}): add incidence angles or raise the "
                                        "exposure caps")
            return
        self.planner_result.setText(
            f"fastest for σ({param}) ≤ {target:g}: {best.option.label()} — "
            f"{best.n_points} points, {fmt.duration(best.duration_s)}, predicted "
            f"σ = {best.sigma[param]:.3g}")
        self.apply_best.setEnabled(True)

    def _show_trade(self, trade: PolarimetricTrade) -> None:
        """The DRR front in the table (the plan's own steps marked), the fastest
        candidate reaching the target as the point Apply writes."""
        self._front = list(trade.front)
        self._set_table(DRR_COLUMNS, [
            (f"{r.option.steps}" + (" (this plan)" if r.option.steps == trade.plan_steps
                                    else ""),
             str(r.n_points), fmt.duration(r.duration_s), f"{r.kappa:.3g}",
             f"{r.sigma['sigma_mean']:.3g}", f"{r.sigma['sigma_max']:.3g}")
            for r in trade.front])
        self._best = trade.best
        what = {"sigma_mean": "mean σ(m_ij/m00)", "sigma_max": "worst σ(m_ij/m00)",
                "kappa": "κ"}[trade.axis]
        if trade.best is None:
            reach = min(r.sigma[trade.axis] for r in trade.results)
            self.planner_result.setText(
                f"no step count reaches {what} ≤ {trade.target:g} (best {reach:.3g}): "
                "longer integration per reading lowers σ at every step count")
            return
        b = trade.best
        self.planner_result.setText(
            f"fastest for {what} ≤ {trade.target:g}: {b.option.steps} steps per geometry — "
            f"{b.n_points} points, {fmt.duration(b.duration_s)}, κ {b.kappa:.3g}, "
            f"σ mean {b.sigma['sigma_mean']:.3g}, worst {b.sigma['sigma_max']:.3g} "
            "(predicted for a non-depolarising sample; choose a row to apply another)")
        self.apply_best.setEnabled(True)

    def _show_pem(self, pem: PemSummary) -> None:
        """A PEM plan: κ per wavelength and the estimate; no front (none is computed)."""
        self._front, self._best = [], None
        self._set_table(PEM_COLUMNS, [
            ("—" if c.wavelength_nm is None else f"{c.wavelength_nm:g}", f"{c.kappa:.3g}",
             f"{c.amplitude_rad:.3f}", f"{c.analyser_retardance_deg:g}")
            for c in pem.conditioning])
        self.planner_result.setText(
            f"PEM plan: {pem.settings} settings per geometry, {pem.n_points} points, "
            f"{fmt.duration(pem.duration_s)} of instrument time. The planner predicts no "
            f"σ for PEM plans, so there is no speed/accuracy front: the time is set by the "
            f"lock-in's "
            f"settle ({pem.time_constants:g} τ per harmonic) and the snapshots per harmonic "
            f"({pem.reads}); the table gives κ of the DC/1f/2f instrument matrix per "
            "wavelength.")

    def _row_chosen(self) -> None:
        """A row of the front chosen in the table becomes the point Apply writes."""
        rows = {i.row() for i in self.pareto.selectedIndexes()}
        if len(rows) != 1 or not self._front:
            return
        (k,) = rows
        if k >= len(self._front):
            return
        self._best = self._front[k]
        self.apply_best.setEnabled(True)
        self.planner_result.setText(f"chosen: {self._best.option.label()} — "
                                    f"{self._best.n_points} points, "
                                    f"{fmt.duration(self._best.duration_s)}; Apply writes it "
                                    "into the plan")

    def choose_row(self, k: int) -> None:
        """Choose row ``k`` of the front, as a click on it does (tests, screenshots)."""
        self.pareto.selectRow(k)

    def _apply_best(self) -> None:
        best = self._best
        if best is None:
            return
        from instrument.plans.polarimetric_tradeoff import PolarimetricResult

        if isinstance(best, PolarimetricResult):
            self.set_field("polarimetry.steps", str(best.option.steps))
            return
        o = best.option
        current = self.form.get("scan.theta_r") or ""
        from gui.model.planform import parse_values

        try:
            tr = parse_values(str(current))
        except ValueError:
            tr = None
        if isinstance(tr, dict):
            start, stop = tr["start"], tr["stop"]
        elif isinstance(tr, list) and tr:
            start, stop = min(tr), max(tr)
        else:
            start, stop = -70, 80
        self.set_field("scan.theta_r", f"{start:g} to {stop:g} step {o.theta_r_step_deg:g}")
        self.set_field("acquisition.max_exposure_us", f"{o.max_exposure_us:g}")
        self.set_field("acquisition.frames", str(o.frames))
        exp = self.form.get("acquisition.exposure_us")
        try:
            if exp and float(exp) > o.max_exposure_us:
                self.set_field("acquisition.exposure_us", f"{o.max_exposure_us:g}")
        except ValueError:
            pass
