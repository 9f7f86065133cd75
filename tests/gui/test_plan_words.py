"""The plan editor in the operator's words: tooltips that explain, the lobe model as a list,
an empty sample said without file jargon, a coverage picture that fills its space."""

from __future__ import annotations

from PySide6.QtWidgets import QApplication, QComboBox

from gui.model.planform import LOBE_MODELS
from tests.gui.test_plan_editor import EXAMPLES, _validated


def test_fields_explain_themselves_and_the_lobe_model_is_a_list(qtbot, make_window):
    w = make_window("sim")
    editor = w.plan_editor
    editor.open_plan(EXAMPLES[[p.stem for p in EXAMPLES].index("brdf_inplane")])
    _validated(qtbot, editor)
    for path in ("scan.theta_i", "acquisition.frames", "scan.lobe.step_deg"):
        tip = editor.field(path).toolTip()
        assert tip.endswith(f"(plan file: {path})") and len(tip) > len(path) + 20, tip
    assert "degrees" in editor.field("scan.lobe.step_deg").toolTip()
    prior = editor.field("scan.lobe.prior")
    assert isinstance(prior, QComboBox)
    assert prior.itemText(0) == "automatic" and prior.itemData(0) == ""
    assert [prior.itemData(k) for k in range(prior.count())] == list(LOBE_MODELS)
    # an empty sample: a requirement in the form's words, not "missing table"
    editor.set_field("sample.description", "")
    editor.set_field("sample.name", "")
    qtbot.waitUntil(lambda: editor.error_text("sample.name") != "", timeout=60000)
    assert "table" not in editor.error_text("sample.name")
    assert "required" in editor.error_text("sample.name")


def test_the_coverage_picture_fills_its_space(qtbot, make_window):
    w = make_window("sim")
    editor = w.plan_editor
    editor.open_plan(EXAMPLES[[p.stem for p in EXAMPLES].index("brdf_inplane")])
    _validated(qtbot, editor)
    qtbot.waitUntil(lambda: editor.coverage.source is not None, timeout=60000)
    w.docks["plan"].raise_()
    QApplication.processEvents()
    shown = editor.coverage.pixmap()
    box = editor.coverage.size()
    # scaled to the label (aspect kept): one side fills it, neither exceeds it
    assert shown.width() <= box.width() and shown.height() <= box.height()
    assert shown.width() >= box.width() - 1 or shown.height() >= box.height() - 1
    editor.coverage.resize(box.width() + 200, box.height() + 200)  # its resize event
    bigger = editor.coverage.pixmap()
    assert max(bigger.width() - shown.width(), bigger.height() - shown.height()) > 100
