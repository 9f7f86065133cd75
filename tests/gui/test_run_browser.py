"""The run browser: filters, a run's details, resuming an interrupted run, fitting a run."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from instrument.run.catalog import Catalog, RunRow
from instrument.run.journal import read_journal
from instrument.run.runfile import read_run
from instrument.run.storage import journal_path
from tests.gui.conftest import connect
from tests.gui.test_run_control import PLAN, wait_end

ROOT = Path(__file__).resolve().parents[2]


def _listed(qtbot, browser, n=None, timeout=60000):
    with qtbot.waitSignal(browser.refreshed, timeout=timeout):
        browser.refresh()
    if n is not None:
        assert browser.table.rowCount() == n


def _select(qtbot, browser, run_id):
    assert browser.select(run_id)
    qtbot.waitUntil(lambda: browser.details is not None
                    and browser.details.provenance["run id"] == run_id, timeout=60000)


@pytest.mark.slow  # run by CI after the default run (ADR 0021)
def test_resume_an_interrupted_run_from_the_browser(qtbot, make_window, fast_bench_file,
                                                   tmp_path):
    bench = fast_bench_file()
    runs = tmp_path / "runs"
    plan = tmp_path / "plan.toml"
    plan.write_text(PLAN.format(step=5.0))
    child = subprocess.Popen([sys.executable, "-m", "tests.gui.interrupted_run", bench,
                              str(runs), str(plan)], cwd=ROOT, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    path = Path(child.stdout.readline().strip())
    deadline = time.monotonic() + 120
    while True:  # wait for three committed points, then pull the plug
        # Looked at while the process is stopped: it cannot finish the scan between the
        # look and the kill, however long this process is kept waiting by a busy machine.
        os.kill(child.pid, signal.SIGSTOP)
        if journal_path(path).exists():
            records, _ = read_journal(journal_path(path))
            if sum(r["t"] == "point" for r in records) >= 3:
                break
        os.kill(child.pid, signal.SIGCONT)
        assert time.monotonic() < deadline and child.poll() is None, child.stderr.read()
        time.sleep(0.02)
    os.kill(child.pid, signal.SIGKILL)
    child.wait()

    w = make_window(bench, out=runs)
    connect(qtbot, w)
    browser = w.browser
    browser.status.setCurrentIndex(browser.status.findData("interrupted"))
    _listed(qtbot, browser, 1)
    row = browser.rows[0]
    assert row.status == "interrupted" and row.path == str(path)
    _select(qtbot, browser, row.run_id)
    assert browser.resume.isEnabled()
    assert "gui-sample" in browser.details.provenance["sample"]
    assert {"sample_theta", "detector_theta", "camera"} <= set(browser.details.devices)
    browser.resume.click()
    qtbot.waitUntil(lambda: w.current_run is not None and w.current_run.resumed,
                    timeout=60000)
    ev = wait_end(qtbot, w, timeout=120000)
    assert ev.status == "finished" and ev.n_done == ev.n_total
    data = read_run(path)
    assert data.status == "finished" and sorted(data.index.tolist()) == list(range(ev.n_total))
    with Catalog(runs) as cat:
        assert cat.get(row.run_id).status == "finished"
    browser.status.setCurrentIndex(0)
    _listed(qtbot, browser, 1)
    assert browser.rows[0].status == "finished"


@pytest.fixture
def glossy_run_in_catalog(tmp_path):
    from tests.instrument.sim_scan import SAMPLES, ScanSetup, render, write_run_file

    runs = tmp_path / "runs"
    runs.mkdir()
    path = write_run_file(render(ScanSetup(), SAMPLES[1]), 3, runs / "glossy.h5")
    data = read_run(path)
    with Catalog(runs) as cat:
        cat.add(RunRow(data.run_id, data.sample_name, data.plan_kind, data.plan_name, "sim",
                       "finished", time.time() - 60, time.time(), data.n_points,
                       data.n_points, str(path)))
        cat.add(RunRow("other", "unrelated", "dark", "dark frames", "sim", "finished",
                       time.time() - 86400 * 10, None, 3, 3, str(runs / "other.h5")))
    return runs, path, data


def test_filters_and_fit_from_the_browser(qtbot, make_window, glossy_run_in_catalog):
    runs, path, data = glossy_run_in_catalog
    w = make_window("sim", out=runs)
    browser = w.browser
    _listed(qtbot, browser, 2)
    browser.kind.setCurrentIndex(browser.kind.findData("dark"))
    _listed(qtbot, browser, 1)
    browser.kind.setCurrentIndex(0)
    browser.sample.setText(data.sample_name[:4])
    _listed(qtbot, browser, 1)
    browser.sample.setText("")
    browser.since.setValue(2)
    _listed(qtbot, browser, 1)
    assert browser.rows[0].run_id == data.run_id
    _select(qtbot, browser, data.run_id)
    assert not browser.resume.isEnabled()  # finished
    assert browser.analysis.currentData() == "fit"
    with qtbot.waitSignal(browser.analysisDone, timeout=120000) as blocker:
        browser.analyse.click()
    out = blocker.args[0]
    assert out.name == "fit" and out.report is not None and out.report.exists()
    params = browser.result_table_widgets[0]
    names = [params.item(r, 0).text() for r in range(params.rowCount())]
    assert params.rowCount() >= 2 and all(names)
    # the parameters shown are those written into the results file next to the run
    # (ADR 0013), and the run file is only read
    import h5py

    with h5py.File(path.parent / path.stem / "fit" / "results.h5") as f:
        assert "analysis" in f["entry"]
    with h5py.File(path) as f:
        assert "analysis" not in f["entry"]
    value = float(params.item(0, 1).text())
    assert value == pytest.approx(float(out.tables[0].rows[0][1]))
    assert browser.open_report.isEnabled()
    assert "chosen model" in browser.analysis_summary.text()


def test_the_log_dock_collects_filters_and_copies(qtbot, make_window, glossy_run_in_catalog):
    import logging

    runs, _path, data = glossy_run_in_catalog
    w = make_window("sim", out=runs)
    log = w.log_dock
    _listed(qtbot, w.browser, 2)
    _select(qtbot, w.browser, data.run_id)
    with qtbot.waitSignal(w.browser.analysisDone, timeout=120000):
        w.browser.analyse.click()
    # the pipeline's own warning (the receiver distance was assumed) reaches the log
    qtbot.waitUntil(lambda: "assumed" in log.visible_text(), timeout=60000)
    logging.getLogger("drivers.thorlabs_apt").warning("unsolicited message skipped")
    qtbot.waitUntil(lambda: "unsolicited message skipped" in log.view.toPlainText(),
                    timeout=60000)
    log.level.setCurrentIndex(log.level.findData("error"))
    assert "assumed" not in log.view.toPlainText()
    log.level.setCurrentIndex(log.level.findData("info"))
    log.filter.setText("unsolicited")
    text = log.copy_visible()
    assert text.count("\n") == 0 and "WARNING drivers.thorlabs_apt" in text
    from PySide6.QtGui import QGuiApplication

    assert QGuiApplication.clipboard().text() == text
