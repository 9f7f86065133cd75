"""What an operator relies on around runs: the runs folder applies now, the run browser
agrees with the catalog, resume never reconnects a bench behind the operator's back, Abort
asks, Home all, the menus and their shortcuts."""

from __future__ import annotations

from pathlib import Path

from PySide6.QtCore import Qt
from PySide6.QtWidgets import QTextBrowser

from instrument.run.catalog import Catalog
from instrument.run.runfile import read_run
from tests.gui.conftest import connect
from tests.gui.test_run_control import start, wait_end, wait_points


def _listed(qtbot, browser):
    with qtbot.waitSignal(browser.refreshed, timeout=60000):
        browser.refresh()


def _select(qtbot, browser, run_id):
    assert browser.select(run_id)
    qtbot.waitUntil(lambda: browser.details is not None
                    and browser.details.provenance["run id"] == run_id, timeout=60000)


def _aborted_run(qtbot, w, tmp_path):
    """A run aborted after its first points (Abort confirmed)."""
    run = start(qtbot, w, tmp_path, step=20.0)
    wait_points(qtbot, run, 2)
    w.questions.answer("abort", True)
    w.run_control.abort.click()
    ev = wait_end(qtbot, w)
    assert ev.status == "aborted" and ev.n_done < ev.n_total
    return run, ev


def test_abort_asks_first_and_no_keeps_the_run(qtbot, make_window, fast_bench_file,
                                               tmp_path):
    w = make_window(fast_bench_file())
    connect(qtbot, w)
    run = start(qtbot, w, tmp_path, step=10.0)
    wait_points(qtbot, run, 1)
    w.questions.answer("abort", False)
    w.run_control.abort.click()
    assert w.questions.asked == ["abort"]
    n = run.live.n_received
    wait_points(qtbot, run, n + 1)  # still measuring: No kept the run
    assert w.session.run is run and run.finished is None
    w.questions.answer("abort", True)
    w.run_control.abort.click()
    assert wait_end(qtbot, w).status == "aborted"


def test_finished_run_details_match_the_catalog_and_resume_follows(
        qtbot, make_window, fast_bench_file, tmp_path):
    w = make_window(fast_bench_file())
    connect(qtbot, w)
    run, ev = _aborted_run(qtbot, w, tmp_path)
    browser = w.browser
    _listed(qtbot, browser)
    run_id = read_run(run.path).run_id
    _select(qtbot, browser, run_id)
    d = browser.details
    assert d.provenance["status"] == "aborted"
    assert d.provenance["points"] == f"{ev.n_done} of {ev.n_total} planned"
    assert browser.resume.isEnabled()
    browser.resume.click()  # the bench it was recorded on is connected: no question
    assert w.questions.asked == ["abort"]
    qtbot.waitUntil(lambda: w.current_run is not None and w.current_run.resumed,
                    timeout=60000)
    end = wait_end(qtbot, w, timeout=120000)
    assert end.status == "finished" and end.n_done == end.n_total
    # the browser re-reads the run it shows: the details now say what the list says
    qtbot.waitUntil(lambda: browser.details is not None
                    and browser.details.provenance["status"] == "finished", timeout=60000)
    with Catalog(tmp_path / "runs") as cat:
        row = cat.get(run_id)
    assert row.status == "finished"
    assert browser.details.provenance["points"] == \
        f"{row.n_points} of {row.n_planned} planned" == f"{end.n_total} of {end.n_total} planned"
    assert not browser.resume.isEnabled()
    assert "nothing to resume" in browser.resume.toolTip()
    # and resuming it anyway (a stale request) is refused with the reason
    assert not w.resume_run(browser.details)
    assert "nothing to resume" in w.run_control.state.text()


def test_a_disconnected_bench_is_never_reconnected_implicitly(
        qtbot, make_window, fast_bench_file, tmp_path):
    w = make_window(fast_bench_file())
    connect(qtbot, w)
    run, _ = _aborted_run(qtbot, w, tmp_path)
    w.bench_panel.disconnect_button.click()
    qtbot.waitUntil(lambda: not w.session.connected, timeout=60000)
    browser = w.browser
    _listed(qtbot, browser)
    _select(qtbot, browser, read_run(run.path).run_id)
    assert browser.resume.isEnabled()
    w.questions.answer("resume_connect", False)
    browser.resume.click()
    assert w.questions.asked[-1] == "resume_connect"
    text = w.run_control.state.text()
    assert text.startswith("not resumed") and "needs bench" in text
    w.session.wait_idle(10)
    assert not w.session.connected and w.session.run is None
    # Yes connects the run's own bench (from the profile stored in the run) and resumes
    w.questions.answer("resume_connect", True)
    browser.resume.click()
    qtbot.waitUntil(lambda: w.current_run is not None and w.current_run.resumed,
                    timeout=60000)
    assert w.session.profile.name == browser.details.bench_name
    assert wait_end(qtbot, w, timeout=120000).status == "finished"


def test_runs_folder_applies_now_and_is_kept(qtbot, make_window, fast_bench_file, tmp_path,
                                             settings):
    w = make_window(fast_bench_file())
    connect(qtbot, w)
    other = tmp_path / "elsewhere"
    with qtbot.waitSignal(w.browser.refreshed, timeout=60000):
        w.set_runs_dir(other)
    assert w.runs_dir == other and w.browser.runs_dir == other
    assert settings.value("runs_dir") == str(other)
    assert w.camera.snapshot_dir == other  # snapshots follow unless a folder was chosen
    run = start(qtbot, w, tmp_path, step=20.0)
    assert Path(run.path).parent == other
    wait_end(qtbot, w, timeout=120000)
    qtbot.waitUntil(lambda: any(r.path == str(run.path) for r in w.browser.rows),
                    timeout=60000)


def test_home_all_and_the_first_time_hint(qtbot, make_window, fast_bench_file):
    w = make_window(fast_bench_file())
    assert not w.home_all_button.isEnabled()  # nothing connected
    connect(qtbot, w)
    qtbot.waitUntil(lambda: "not homed" in w.home_hint.text(), timeout=60000)
    assert w.home_hint.text().startswith("3 axes not homed: press Home all")
    assert w.home_all_button.isEnabled()
    w.home_all_button.click()
    qtbot.waitUntil(lambda: all(s.value("homed") and not s.value("moving")
                                for s in w.session.states().values()
                                if s.kind == "motion_axis"), timeout=60000)
    qtbot.waitUntil(lambda: w.home_hint.text() == "", timeout=60000)


def test_menus_and_the_shortcut_list(qtbot, make_window):
    w = make_window()
    titles = [a.text() for a in w.menuBar().actions()]
    assert titles == ["&File", "&Bench", "&View", "&Help"]
    dialog = w.show_shortcuts()
    text = dialog.findChild(QTextBrowser, "dialog_text").toPlainText()
    for key in ("Esc", "Space", "Ctrl+H", "F1"):
        assert key in text
    about = w.show_about().findChild(QTextBrowser, "dialog_text").toPlainText()
    assert "scatterlab" in about and str(w.runs_dir) in about


def test_the_analysis_tab_sets_the_fit_options(qtbot, make_window):
    from gui.model.analyses import FitSettings

    w = make_window()
    b = w.browser
    assert b.fit_settings() == FitSettings(models=b.fit_settings().models)  # defaults
    assert len(b.fit_settings().models) == b.opt_models.count() > 1
    b.opt_distance.setValue(305.0)
    b.opt_distance_u.setValue(0.5)
    b.opt_power_u.setValue(0.02)
    b.opt_detector.setCurrentIndex(b.opt_detector.findData("power_meter"))
    for k in range(1, b.opt_models.count()):
        b.opt_models.item(k).setCheckState(Qt.Unchecked)
    s = b.fit_settings()
    assert (s.distance_mm, s.distance_u_mm, s.incident_power_u, s.detector) == \
        (305.0, 0.5, 0.02, "power_meter")
    assert s.models == (b.opt_models.item(0).text(),)
    # the controls the fit warnings name exist under those names
    from gui.model.remedies import ANALYSIS_CONTROLS

    form = b.fit_options.layout()
    labels = {form.itemAt(r, form.ItemRole.LabelRole).widget().text()
              for r in range(form.rowCount())}
    assert set(ANALYSIS_CONTROLS.values()) <= labels


def test_the_report_is_shown_inside_and_a_missing_browser_is_said(qtbot, tmp_path):
    from PySide6.QtGui import QImage

    from gui.qt.report_view import ReportView

    folder = tmp_path / "RUN" / "fit"
    folder.mkdir(parents=True)
    img = QImage(40, 30, QImage.Format_RGB32)
    img.fill(0x336699)
    assert img.save(str(folder / "brdf.png"))
    (folder / "index.html").write_text(
        "<html><body><h1>Fit of RUN</h1><table><tr><td>ggx.alpha</td><td>0.12</td></tr>"
        "</table><img src='brdf.png'></body></html>", encoding="utf-8")
    asked = []
    view = ReportView(opener=lambda url: asked.append(url.toLocalFile()) or False)
    qtbot.addWidget(view)
    view.show_report(folder / "index.html")
    text = view.view.toPlainText()
    assert "Fit of RUN" in text and "ggx.alpha" in text
    from PySide6.QtCore import QUrl
    from PySide6.QtGui import QTextDocument

    figure = view.view.loadResource(QTextDocument.ImageResource, QUrl("brdf.png"))
    assert figure is not None and not QImage.fromData(figure).isNull()  # found beside it
    assert not view.open_external()
    assert asked == [str(folder / "index.html")]
    assert "No web browser could be opened" in view.message.text()
    assert str(folder / "index.html") in view.message.text()
    view.opener = lambda url: True
    assert view.open_external() and "opened in the web browser" in view.message.text()


def test_runs_and_faults_columns_show_their_whole_text(qtbot, make_window):
    from instrument.run.events import Fault

    w = make_window()
    w.fault_panel.add(Fault("detector_theta", "the controller stopped answering on "
                            "/dev/ttyUSB0 after three polls", "pause", 26))
    w.docks["faults"].raise_()
    w.docks["runs"].raise_()
    from gui.qt.run_browser import _fill

    _fill(w.browser.table, [("20261126-151230-0a1b2c3d", "a rather long sample name, "
                             "batch 7", "brdf_in_plane", "interrupted", "2026-11-26 15:12",
                             "28/57")])
    for table in (w.fault_panel.table, w.browser.table):
        header = table.horizontalHeader()
        for c in range(table.columnCount() - 1):  # the last one stretches
            need = max(table.sizeHintForColumn(c), header.sectionSizeHint(c))
            qtbot.waitUntil(lambda h=header, c=c, n=need: h.sectionSize(c) >= n,
                            timeout=60000)
    assert w.fault_panel.rows()[0][1] == "27"  # plan index 26: the 27th point
